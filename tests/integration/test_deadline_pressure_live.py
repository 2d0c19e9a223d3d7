"""--deadline on real ROS 2 traffic: the makespan of a stamped command stream in /v1/load."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from kit.ros import HandlerProcess, ros_env, wait_for

pytestmark = pytest.mark.integration

MONITOR = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: slow-enough}
spec:
  assertion: "always (vx < 10)"
  signals:
    vx: {topic: /cmd, type: geometry_msgs/msg/TwistStamped, field: twist.linear.x}
"""

# The robot's real-time task: a velocity command at 20 Hz, stamped with the capture of the
# input it was computed from, 140 ms before it is published; 50 ms after SIGUSR1.
TASK = r"""
import signal, time, rclpy
from geometry_msgs.msg import TwistStamped
age = [0.140]
signal.signal(signal.SIGUSR1, lambda *_: age.__setitem__(0, 0.050))
rclpy.init()
node = rclpy.create_node("task")
pub = node.create_publisher(TwistStamped, "/cmd", 10)
print("publishing", flush=True)
while True:
    msg = TwistStamped()
    stamp = time.time_ns() - int(age[0] * 1e9)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
    msg.header.frame_id = "camera"
    msg.twist.linear.x = 0.5
    pub.publish(msg)
    time.sleep(0.05)
"""


def deadline(handler: HandlerProcess) -> dict[str, Any]:
    status, load = handler.request("GET", "/v1/load")
    assert status == 200, load
    reading: dict[str, Any] = load["deadline"]
    return reading


def test_the_makespan_of_a_stamped_command_stream_is_in_the_load_report(
    tmp_path: Path, domain: int
) -> None:
    monitors = tmp_path / "m.yaml"
    monitors.write_text(MONITOR)
    handler = HandlerProcess(tmp_path, monitors, domain, "--deadline", "/cmd=125ms")
    task = subprocess.Popen(
        [sys.executable, "-c", TASK],
        env=ros_env(domain),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert deadline(handler)["count"] == 0
        full = wait_for(lambda: deadline(handler)["count"] >= 30, timeout=30)
        assert full, handler.stderr
        reading = deadline(handler)
        assert set(reading) == {
            "topic", "budgetMs", "windowSeconds", "count", "misses", "p50Ms", "p95Ms",
            "maxMs", "lastMs", "serviceP95Ms", "missesTotal", "messagesTotal",
        }  # fmt: skip
        assert (reading["topic"], reading["budgetMs"], reading["windowSeconds"]) == (
            "/cmd",
            125.0,
            2.0,
        )
        assert 135 <= reading["p95Ms"] <= 200, reading
        # each input was captured 140 ms before its command, the command before it 50 ms
        # before that: it waited 90 ms behind it, and was served in the 50 ms between
        assert 45 <= reading["serviceP95Ms"] <= 100, reading
        assert reading["misses"] > 0, reading
        assert "measuring the makespan of /cmd (geometry_msgs/msg/TwistStamped)" in handler.stderr
        assert (handler.metric("edgerv_deadline_misses_total", topic="/cmd") or 0) > 0
        # the monitor reading the same topic runs as ever
        assert (handler.metric("edgerv_events_total", monitor="slow-enough") or 0) > 0

        task.send_signal(signal.SIGUSR1)  # the task meets its deadline from now on
        time.sleep(2.5)
        calm = wait_for(lambda: deadline(handler)["misses"] == 0, timeout=10)
        reading = deadline(handler)
        assert calm and reading["count"] > 0 and reading["p95Ms"] < 125, reading
        assert reading["missesTotal"] > 0  # the counter keeps the past

        # what ingesting /cmd costs the handler, for the planner (issue 37): the take
        # loop's CPU on the topic its monitor reads, and which topics each monitor reads
        _, load = handler.request("GET", "/v1/load")
        assert load["monitors"]["slow-enough"]["topics"] == ["/cmd"]
        assert set(load["topics"]) == {"/cmd"}, load["topics"]
        assert load["topics"]["/cmd"]["messages"] > 30 and load["topics"]["/cmd"]["cpuSeconds"] > 0
        # each message waits a little before it is taken; the reading is the last round's,
        # and a round woken with nothing to take reads 0: some reading is above it
        lagging = wait_for(
            lambda: handler.request("GET", "/v1/load")[1]["ingestLag"] > 0, timeout=5, interval=0.01
        )
        assert lagging, handler.request("GET", "/v1/load")[1]["ingestLag"]
        # the monitor stopped, no monitor reads /cmd: the handler takes nothing, and its
        # ingest lag reads 0 (not the last one measured: it kept an idle handler from
        # reading as calm, and the policy from bringing monitors home)
        status, _ = handler.request("POST", "/v1/monitors/slow-enough/deactivate")
        assert status == 200
        idle = wait_for(lambda: handler.request("GET", "/v1/load")[1]["topics"] == {}, timeout=10)
        assert idle, handler.request("GET", "/v1/load")[1]["topics"]
        settled = wait_for(
            lambda: handler.request("GET", "/v1/load")[1]["ingestLag"] == 0.0, timeout=10
        )
        assert settled, handler.request("GET", "/v1/load")[1]["ingestLag"]
        assert deadline(handler)["count"] > 0  # the deadline's own subscription measures on
    finally:
        task.kill()
        task.wait()
        assert handler.stop() == 0, handler.stderr
