"""The speed-limit run that ``edgerv check``'s tests read: two Monitor documents
(:data:`MONITORS`: speed-limit over /running, /speed, /stop and target-reached over
/target), a run of events on their topics (:data:`RUN`, one of them on an unmonitored
topic) and each topic's message type (:data:`TYPES`, for :func:`kit.traces.write_mcap`)."""

from __future__ import annotations

from typing import Any

MONITORS = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: speed-limit}
spec:
  assertion: "always (running -> (speed < limit until stop))"
  signals:
    running: {topic: /running, type: std_msgs/msg/Bool}
    speed: {topic: /speed, type: std_msgs/msg/Float64}
    stop: {topic: /stop, type: std_msgs/msg/Bool, initial: false}
  parameters: {limit: 100}
  sortThreshold: 2
---
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: target-reached}
spec:
  assertion: "eventually! (px > 9.5)"
  signals:
    px: {topic: /target, type: geometry_msgs/msg/PointStamped, field: point.x}
  onVerdict: halt
"""

# (topic, log time, message): /target carries a header whose stamp differs from the log time
RUN: list[tuple[str, int, dict[str, Any]]] = [
    ("/running", 100, {"data": True}),
    ("/speed", 110, {"data": 50.0}),
    (
        "/target",
        115,
        {
            "header": {"stamp": {"sec": 0, "nanosec": 90}, "frame_id": "map"},
            "point": {"x": 3.0, "y": 0.0, "z": 0.0},
        },
    ),
    ("/speed", 130, {"data": 120.0}),
    ("/speed", 120, {"data": 80.0}),
    ("/stop", 140, {"data": True}),
    (
        "/target",
        150,
        {
            "header": {"stamp": {"sec": 0, "nanosec": 145}, "frame_id": "map"},
            "point": {"x": 10.0, "y": 0.0, "z": 0.0},
        },
    ),
    ("/speed", 160, {"data": 150.0}),
    ("/ignored", 170, {"data": "not monitored"}),
]

# the run's message types (their definitions: kit.traces.ROS_DEFS)
TYPES = {
    "/running": "std_msgs/msg/Bool",
    "/stop": "std_msgs/msg/Bool",
    "/speed": "std_msgs/msg/Float64",
    "/target": "geometry_msgs/msg/PointStamped",
    "/ignored": "std_msgs/msg/String",
}
