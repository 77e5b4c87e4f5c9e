"""What a run or a bench leaves for people: the run report, the bench report, the config doc."""
