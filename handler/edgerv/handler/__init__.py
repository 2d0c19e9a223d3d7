"""The monitor handler: one ROS 2 node per machine running the monitors placed on it."""
