"""Mocap-free tools: multi-position calibration, Allan variance, attitude-drift check."""
