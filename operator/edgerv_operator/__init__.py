"""The edgerv Kubernetes operator (Kopf). Never imports rclpy.

``monitors`` holds the pure parts (documents, placement, status), ``config`` the
settings, ``handlers`` the Kopf glue.
"""
