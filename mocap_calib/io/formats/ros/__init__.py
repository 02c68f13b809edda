"""ROS messages below the bag reader: bulk decoding of serialised messages, /tf chains."""
