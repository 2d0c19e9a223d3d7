"""The environment of a bench's ROS 2 processes: the tests' one builder (tests/kit/ros.py:
a domain of the bench's own, discovery on this host only so nothing leaves the machine,
unbuffered output) with the handlers' API token of the benches."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the tests' kit

from kit.ros import ros_env as kit_ros_env


def ros_env(domain: str) -> dict[str, str]:
    return kit_ros_env(domain, EDGERV_TOKEN="bench")
