"""The mocap-free commands: multi-position intrinsics, Allan variance, the attitude-drift check."""
