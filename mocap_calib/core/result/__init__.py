"""The calibration's result types, its state for inspection, and priors from earlier results."""
