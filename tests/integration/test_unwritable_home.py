"""A handler whose home cannot be written (a read-only root in a hardened container, a
service user without a home): rcl cannot create ~/.ros/log, and rclpy.init used to fail
with an internal error (exit 70). It now runs without ROS's log files, says so once, and
checks its monitors as ever (handler/ros/logs.py; tests/unit/test_ros_logs.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from kit.ros import HandlerProcess, publisher, wait_for

MONITOR = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: stays-on}
spec:
  assertion: "always (on)"
  signals:
    on: {topic: /on, type: std_msgs/msg/Bool}
"""


def test_a_home_rcl_cannot_write_runs_without_ros_log_files(
    tmp_path: Path, domain: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    home = tmp_path / "home"
    home.write_text("not a directory")  # as root, only a file stops mkdir
    monitors = tmp_path / "monitors.yaml"
    monitors.write_text(MONITOR)
    with monkeypatch.context() as env:  # the handler's environment only, not the publisher's
        env.setenv("HOME", str(home))
        env.delenv("ROS_LOG_DIR", raising=False)
        env.delenv("ROS_HOME", raising=False)
        handler = HandlerProcess(tmp_path, monitors, domain)
    try:
        assert f"ROS cannot write its log files in {home}/.ros/log" in handler.stderr
        pub = publisher(domain, "/on", "std_msgs/msg/Bool", [{"data": True}, {"data": False}])
        wait_for(lambda: handler.verdicts(), timeout=30)
        assert pub.wait(timeout=30) == 0, pub.stderr.read() if pub.stderr else ""
    finally:
        code = handler.stop()
    assert code == 0, handler.stderr
    assert [(v["monitor"], v["verdict"]) for v in handler.verdicts()] == [
        ("stays-on", "violated")
    ], json.dumps(handler.verdicts())
