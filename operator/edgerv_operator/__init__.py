"""The edgerv Kubernetes operator (Kopf). Never imports rclpy.

Its handlers arrive with the operator issue; the package exists now so that the
layering contract (`make lint`) already guards it.
"""
