"""IMU ground truth from mocap and a calibration (error-state filter and RTS smoother)."""
