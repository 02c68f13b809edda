"""The calibration engine:
session preparation, clock search, the three factor-graph stages, results."""
