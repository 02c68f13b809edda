"""Model diagnosis:
IMU prediction through the calibrated model, residual tests, candidate effects."""
