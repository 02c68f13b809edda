"""Clock alignment: the coarse search for the offset between the IMU and mocap clocks."""
