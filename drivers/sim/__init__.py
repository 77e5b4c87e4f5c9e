"""The simulated instrument: the only place that knows the ground truth."""
