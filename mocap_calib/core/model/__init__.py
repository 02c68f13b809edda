"""Shared maths: rotations, data types, the effect ladder and measurement model, IMU integration."""
