"""Preparing a session: checks, relative clocks, mocap spikes, IMU faults, and kinematics on a
common grid."""
