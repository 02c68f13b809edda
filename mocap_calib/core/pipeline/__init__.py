"""The calibration pipeline: options, and the run from the prepared session to the result."""
