"""Simulated trackers and the ground-truth world they observe."""
