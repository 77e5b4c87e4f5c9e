"""Instrument drivers: simulated, KLA, replay. Never import the console."""
