"""The odometry run that the live handler's tests replay: two Monitor documents over
/running, /odom (nav_msgs/msg/Odometry's twist.twist.linear.x) and /stop
(:data:`MONITORS`: speed-limit, no-stop-while-fast), one over /speed (:data:`SPEED`:
speed-cap), and random JSON Lines traces of their topics (:func:`random_trace`)."""

from __future__ import annotations

import json
import random
from pathlib import Path

MONITORS = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: speed-limit}
spec:
  assertion: "always (running -> (speed < limit until stop))"
  signals:
    running: {topic: /running, type: std_msgs/msg/Bool}
    speed: {topic: /odom, type: nav_msgs/msg/Odometry, field: twist.twist.linear.x}
    stop: {topic: /stop, type: std_msgs/msg/Bool, initial: false}
  parameters: {limit: 100}
  sortThreshold: 2
---
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: no-stop-while-fast}
spec:
  assertion: "always (speed > 90 -> next !stop)"
  signals:
    speed: {topic: /odom, type: nav_msgs/msg/Odometry, field: twist.twist.linear.x}
    stop: {topic: /stop, type: std_msgs/msg/Bool}
"""

SPEED = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: speed-cap}
spec:
  assertion: "always (speed < 100)"
  signals:
    speed: {topic: /speed, type: std_msgs/msg/Float64}
"""


def random_trace(path: Path, n: int, seed: int) -> Path:
    rng = random.Random(seed)
    lines, stamp = [], 1_000
    for _ in range(n):
        stamp += rng.randint(1, 50)
        topic = rng.choice(["/running", "/odom", "/odom", "/stop"])
        if topic == "/odom":
            msg = {"twist": {"twist": {"linear": {"x": rng.choice([20.0, 60.0, 95.0, 120.0])}}}}
        else:
            msg = {"data": rng.random() < (0.8 if topic == "/running" else 0.15)}
        lines.append(json.dumps({"topic": topic, "stamp": stamp, "msg": msg}))
    path.write_text("\n".join(lines) + "\n")
    return path
