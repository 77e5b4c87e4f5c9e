"""The console's panels, one per module; each renders a RunSnapshot and holds no run state of its own."""
