"""One reader per input format (EuRoC/ASL, TUM, generic CSV, ROS bags and MCAP, PX4 ULog,
Motive/Vicon exports, imu_tk), and the delimited-text parsing they share."""
