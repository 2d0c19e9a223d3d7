"""The monitor core: assertions, synthesis, the event pipeline. Imports neither rclpy nor kopf."""
