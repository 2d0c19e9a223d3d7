"""edgerv: runtime verification for ROS 2 robots from the edge to the cloud."""

__version__ = "0.1.0"
