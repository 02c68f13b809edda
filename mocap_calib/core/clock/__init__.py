"""Clock alignment: the coarse search for the offset between the IMU and mocap clocks, and the
convention check (which reading of the inputs, at which offset, explains the data)."""
