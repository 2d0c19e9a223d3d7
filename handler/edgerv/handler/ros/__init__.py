"""The handler's ROS layer: the only part of edgerv that imports ROS (rclpy, rosidl, the
message packages); everything else in edgerv.handler stays ROS-free (lint-imports).

Importing this package imports no ROS: ``edgerv check`` and ``edgerv types`` use
:mod:`edgerv.handler.ros.types` without it.
"""
