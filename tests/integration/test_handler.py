"""The monitor handler on real ROS 2 traffic: separate processes, real DDS, real HTTP."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from kit.documents import write
from kit.odom_run import MONITORS, SPEED, random_trace
from kit.ros import (
    TOKEN,
    HandlerProcess,
    live_verdicts,
    offline_verdicts,
    publisher,
    replay_command,
    ros_env,
    wait_for,
)

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]


def test_live_verdicts_equal_edgerv_check_on_the_replayed_trace(
    tmp_path: Path, domain: int
) -> None:
    monitors = write(tmp_path, "monitors.yaml", MONITORS)
    trace = random_trace(tmp_path / "run.jsonl", 400, seed=3)
    handler = HandlerProcess(tmp_path, monitors, domain)
    try:
        replay = subprocess.run(
            replay_command(monitors, trace, 0.003),
            env=ros_env(domain),
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert replay.returncode == 0, replay.stderr
        wait_for(lambda: handler.metric("edgerv_messages_total", topic="/odom") is not None)
    finally:
        assert handler.stop() == 0, handler.stderr
    offline, live = offline_verdicts(monitors, trace), live_verdicts(handler)
    assert len(offline) > 20
    assert live == offline
    assert {v["handler"] for v in handler.verdicts()} == {"edge"}


def test_a_bad_monitor_is_reported_and_the_others_run(tmp_path: Path, domain: int) -> None:
    bad = SPEED.replace("speed-cap", "broken").replace(
        "std_msgs/msg/Float64", "std_msgs/msg/Flaot64"
    )
    monitors = write(tmp_path, "m.yaml", SPEED + "---\n" + bad)
    handler = HandlerProcess(tmp_path, monitors, domain)
    try:
        assert (
            "m.yaml:15:34: error: spec.signals.speed.type: unknown message type "
            "'std_msgs/msg/Flaot64'" in handler.stderr
        )
        assert "did you mean std_msgs/msg/Float64" in handler.stderr
        pub = publisher(domain, "/speed", "std_msgs/msg/Float64", [{"data": 50.0}, {"data": 150.0}])
        assert pub.wait(timeout=60) == 0
        assert wait_for(lambda: handler.verdicts()), handler.stderr
        assert [(v["monitor"], v["verdict"], v["step"]) for v in handler.verdicts()] == [
            ("speed-cap", "violated", 2)
        ]
    finally:
        assert handler.stop() == 0


def test_message_package_not_installed(tmp_path: Path, domain: int) -> None:
    doc = SPEED.replace("std_msgs/msg/Float64", "sensor_msgs/msg/Temperature").replace(
        "speed: {topic", "speed: {field: temperature, topic"
    )
    monitors = write(tmp_path, "t.yaml", doc + "---\n" + SPEED.replace("speed-cap", "other"))
    handler = HandlerProcess(tmp_path, monitors, domain)
    try:
        _, listing = handler.request("GET", "/v1/monitors")
        names = [m["name"] for m in listing["monitors"]]
        if "speed-cap" in names:  # sensor_msgs is installed here: the monitor simply runs
            assert "error" not in handler.stderr
        else:
            assert "pip install ros-jazzy-sensor-msgs" in handler.stderr
        assert "other" in names
    finally:
        handler.stop()


def test_incompatible_qos_is_a_warning_and_a_metric(tmp_path: Path, domain: int) -> None:
    doc = SPEED.replace(
        "std_msgs/msg/Float64}", "std_msgs/msg/Float64, qos: {reliability: reliable}}"
    )
    handler = HandlerProcess(tmp_path, write(tmp_path, "q.yaml", doc), domain)
    pub = publisher(
        domain,
        "/speed",
        "std_msgs/msg/Float64",
        [{"data": 1.0}] * 400,
        reliability="best_effort",
        interval=0.01,
    )
    try:
        problems = wait_for(
            lambda: handler.metric("edgerv_qos_incompatible_publishers", topic="/speed")
        )
        assert problems == 1.0
        assert "1 publisher(s) with incompatible QoS" in handler.stderr
        assert handler.metric("edgerv_events_total", monitor="speed-cap") == 0.0
    finally:
        pub.kill()
        pub.wait()
        assert handler.stop() == 0


def test_auto_qos_follows_a_best_effort_publisher(tmp_path: Path, domain: int) -> None:
    handler = HandlerProcess(tmp_path, write(tmp_path, "a.yaml", SPEED), domain)
    pub = publisher(
        domain,
        "/speed",
        "std_msgs/msg/Float64",
        [],
        reliability="best_effort",
        interval=0.01,
        forever=True,
    )
    try:
        assert wait_for(
            lambda: (handler.metric("edgerv_events_total", monitor="speed-cap") or 0) > 5,
            timeout=30,
        ), handler.stderr
        assert "subscribing best effort" in handler.stderr
    finally:
        pub.kill()
        pub.wait()
        assert handler.stop() == 0


def test_monitors_added_and_removed_at_run_time(tmp_path: Path, domain: int) -> None:
    handler = HandlerProcess(tmp_path, write(tmp_path, "m.yaml", SPEED), domain)
    try:
        added = SPEED.replace("speed-cap", "speed-floor").replace("speed < 100", "speed > 10")
        status, body = handler.request("PUT", "/v1/monitors/speed-floor", added)
        assert (status, body) == (201, {"name": "speed-floor", "created": True})
        status, body = handler.request("POST", "/v1/monitors", added)
        assert status == 409
        pub = publisher(
            domain,
            "/speed",
            "std_msgs/msg/Float64",
            [{"data": 50.0}, {"data": 5.0}, {"data": 150.0}],
        )
        assert pub.wait(timeout=60) == 0
        assert wait_for(lambda: len(handler.verdicts()) == 2), handler.verdicts()
        assert sorted((v["monitor"], v["step"]) for v in handler.verdicts()) == [
            ("speed-cap", 3),
            ("speed-floor", 2),
        ]
        status, _ = handler.request("DELETE", "/v1/monitors/speed-floor")
        assert status == 200
        _, listing = handler.request("GET", "/v1/monitors")
        assert [m["name"] for m in listing["monitors"]] == ["speed-cap"]
        status, body = handler.request("PUT", "/v1/monitors/x", "kind: Monitor\n")
        assert status == 400
        assert body["errors"][0]["location"].startswith("request:1")
        status, _ = handler.request("DELETE", "/v1/monitors/speed-floor")
        assert status == 404
    finally:
        assert handler.stop() == 0


def test_a_monitor_spot_cannot_build_in_time_is_refused_and_the_others_run_meanwhile(
    tmp_path: Path, domain: int
) -> None:
    """Spot holds the GIL while it builds an automaton; ``X[30]`` needs 2^30 states. The
    handler builds in a child process: it takes messages and reports verdicts meanwhile,
    and refuses the monitor with the reason once --synthesis-budget has passed."""
    handler = HandlerProcess(
        tmp_path, write(tmp_path, "m.yaml", SPEED), domain, "--synthesis-budget", "8"
    )
    slow = SPEED.replace("speed-cap", "slow").replace(
        "always (speed < 100)", "always (speed > 100 -> X[30] speed < 100)"
    )
    answer: list[tuple[int, Any]] = []
    put = threading.Thread(
        target=lambda: answer.append(handler.request("PUT", "/v1/monitors/slow", slow))
    )
    try:
        started = time.monotonic()
        put.start()
        pub = publisher(domain, "/speed", "std_msgs/msg/Float64", [{"data": 50.0}, {"data": 150.0}])
        assert pub.wait(timeout=60) == 0
        assert wait_for(lambda: handler.verdicts(), timeout=30), handler.stderr
        assert put.is_alive(), "the verdict came after the monitor was refused: not meanwhile"
        put.join(timeout=60)
        assert 8.0 <= time.monotonic() - started < 30.0
        ((status, body),) = answer
        assert status == 400, body
        error = body["errors"][0]
        assert "took more than 8 s" in error["message"], error
        assert error["location"].startswith("request:5"), error
        _, listing = handler.request("GET", "/v1/monitors")
        assert [m["name"] for m in listing["monitors"]] == ["speed-cap"]
        assert [(v["monitor"], v["verdict"], v["step"]) for v in handler.verdicts()] == [
            ("speed-cap", "violated", 2)
        ]
    finally:
        assert handler.stop() == 0, handler.stderr


@pytest.mark.parametrize("token", [None, "wrong"])
def test_control_calls_need_the_token(tmp_path: Path, domain: int, token: str | None) -> None:
    handler = HandlerProcess(tmp_path, write(tmp_path, "m.yaml", SPEED), domain)
    try:
        for method, path, body in [
            ("GET", "/v1/monitors", None),
            ("PUT", "/v1/monitors/x", SPEED.replace("speed-cap", "x")),
            ("POST", "/v1/monitors", SPEED.replace("speed-cap", "y")),
            ("DELETE", "/v1/monitors/speed-cap", None),
            ("POST", "/v1/monitors/speed-cap/deactivate", None),
        ]:
            status, _ = handler.request(method, path, body, token=token)
            assert status == 401, (method, path)
        _, listing = handler.request("GET", "/v1/monitors", token=TOKEN)
        assert [(m["name"], m["active"]) for m in listing["monitors"]] == [("speed-cap", True)]
        assert handler.request("GET", "/healthz", token=None)[0] == 200
    finally:
        handler.stop()


def test_no_token_no_control_api(tmp_path: Path, domain: int) -> None:
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "edgerv",
            "handler",
            "--name",
            "e",
            "--monitors",
            str(write(tmp_path, "m.yaml", SPEED)),
            "--listen",
            "127.0.0.1:0",
        ],
        env={k: v for k, v in ros_env(domain).items() if k != "EDGERV_TOKEN"},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert "refusing to serve the control API without a token" in proc.stderr


def test_sigterm_mid_stream_flushes_and_exits_0(tmp_path: Path, domain: int) -> None:
    doc = (
        SPEED.replace("speed < 100", "speed < 1000000")
        .replace("    speed:", "  sortThreshold: 50\n  signals:\n    speed:")
        .replace("  signals:\n  ", "  ", 1)
    )
    handler = HandlerProcess(tmp_path, write(tmp_path, "s.yaml", doc), domain)
    pub = publisher(domain, "/speed", "std_msgs/msg/Float64", [], interval=0.001, forever=True)
    try:
        assert wait_for(
            lambda: (handler.metric("edgerv_events_total", monitor="speed-cap") or 0) > 200,
            timeout=30,
        )
        code = handler.stop(signal.SIGTERM)
    finally:
        pub.kill()
        pub.wait()
    assert code == 0, handler.stderr
    assert "SIGTERM: stopping" in handler.stderr and "stopped" in handler.stderr
    assert "Traceback" not in handler.stderr


def test_sigint_stops_too(tmp_path: Path, domain: int) -> None:
    handler = HandlerProcess(tmp_path, write(tmp_path, "m.yaml", SPEED), domain)
    assert handler.stop(signal.SIGINT) == 0
    assert "SIGINT: stopping" in handler.stderr


DEADLINE = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: cmd-deadline}
spec:
  assertion: "always (age(cmd) < 125ms)"
  signals:
    cmd: {topic: /cmd, type: geometry_msgs/msg/TwistStamped, field: twist.linear.x}
"""

# Publishes stamped commands every 20 ms and records each as a JSON Lines event, then
# says "done" and waits to be killed: the recording is exactly what it published.
COMMANDER = r"""
import json, sys, time, rclpy
from geometry_msgs.msg import TwistStamped
rclpy.init()
node = rclpy.create_node("commander")
pub = node.create_publisher(TwistStamped, "/cmd", 100)
deadline = time.monotonic() + 15
while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
    time.sleep(0.05)
time.sleep(0.3)
with open(sys.argv[1], "w") as rec:
    for i in range(40):
        now = time.time_ns()
        m = TwistStamped()
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(now, 10**9)
        m.twist.linear.x = 0.5
        pub.publish(m)
        rec.write(json.dumps({"topic": "/cmd", "stamp": now, "msg": {"header": {"stamp":
            {"sec": now // 10**9, "nanosec": now % 10**9}}, "twist": {"linear": {"x": 0.5}}}}))
        rec.write("\n")
        time.sleep(0.02)
print("done", flush=True)
time.sleep(600)
"""


def test_a_deadline_is_reported_live_when_the_publisher_is_killed(
    tmp_path: Path, domain: int
) -> None:
    """No message comes after the kill: the handler's clock alone decides the violation,
    at the instant it became certain, and `edgerv check` on the recorded commands (and
    the time that passed after them) gives the same verdict, stamp and step."""
    monitors = write(tmp_path, "deadline.yaml", DEADLINE)
    recording = tmp_path / "cmd.jsonl"
    handler = HandlerProcess(tmp_path, monitors, domain, "--flush-after", "0.2")
    commander = subprocess.Popen(
        [sys.executable, "-c", COMMANDER, str(recording)],
        env=ros_env(domain),
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert commander.stdout is not None
        assert commander.stdout.readline().strip() == "done"
        commander.send_signal(signal.SIGKILL)
        live = wait_for(handler.verdicts, timeout=30)
    finally:
        commander.kill()
        commander.wait()
        assert handler.stop() == 0, handler.stderr
    last = json.loads(recording.read_text().splitlines()[-1])["stamp"]
    assert [(v["verdict"], v["stamp"]) for v in live] == [("violated", last + 125_000_000)]
    with recording.open("a") as rec:  # the time that passed after the last command
        rec.write(json.dumps({"topic": "/clock", "stamp": last + 10**9, "msg": {}}) + "\n")
    assert live_verdicts(handler) == offline_verdicts(monitors, recording)


POINT_X = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: pt-x}
spec:
  assertion: "always (x < 1000000000 & s < 1000000000)"
  signals:
    x: {topic: /pt, type: geometry_msgs/msg/Point, field: x}
    s: {topic: /speed, type: std_msgs/msg/Float64}
"""

# Other fields of /pt, a topic the handler already reads (for x only).
POINT_YZ = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: pt-yz}
spec:
  assertion: "always (y < z)"
  signals:
    y: {topic: /pt, type: geometry_msgs/msg/Point, field: y}
    z: {topic: /pt, type: geometry_msgs/msg/Point, field: z}
"""

# Publishes a Point on /pt and a Float64 on /speed every 5 ms (some 400 messages a
# second in all) until killed; says "publishing" once both are matched.
TWO_TOPICS = r"""
import time, rclpy
from geometry_msgs.msg import Point
from std_msgs.msg import Float64
rclpy.init()
node = rclpy.create_node("two_topics")
pt = node.create_publisher(Point, "/pt", 1000)
speed = node.create_publisher(Float64, "/speed", 1000)
deadline = time.monotonic() + 30
while (pt.get_subscription_count() == 0 or speed.get_subscription_count() == 0) and (
    time.monotonic() < deadline
):
    time.sleep(0.05)
time.sleep(0.3)
print("publishing", flush=True)
i = 0
while True:
    pt.publish(Point(x=float(i), y=float(i), z=float(i + 1)))
    speed.publish(Float64(data=float(i)))
    i += 1
    time.sleep(0.005)
"""


def test_a_monitor_reading_new_fields_of_a_subscribed_topic_is_added_mid_stream(
    tmp_path: Path, domain: int
) -> None:
    """Messages wait long in the reorder window, read for the fields the handler read
    then (x of /pt); a monitor added meanwhile reads other fields of /pt (y, z). They are
    read again for the new fields: the handler lives on and the new monitor takes events
    (it crashed with an IndexError in offer_values, 'the ingest loop failed')."""
    handler = HandlerProcess(
        tmp_path, write(tmp_path, "pt.yaml", POINT_X), domain, "--reorder-window", "0.3"
    )
    pub = subprocess.Popen(
        [sys.executable, "-c", TWO_TOPICS],
        env=ros_env(domain),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )

    def events(name: str) -> int:
        try:
            _, listing = handler.request("GET", "/v1/monitors")
        except OSError as exc:  # it died (and closed its API) meanwhile
            raise AssertionError(f"the handler died: {exc}\n{handler.stderr}") from exc
        assert handler.proc.poll() is None, f"the handler died:\n{handler.stderr}"
        return sum(m["events"] for m in listing["monitors"] if m["name"] == name)

    def takes(name: str, more: int) -> bool:
        """The monitor takes ``more`` events from now on (the handler alive)."""
        start = events(name)
        return bool(wait_for(lambda: events(name) >= start + more, timeout=60))

    try:
        assert pub.stdout is not None
        assert pub.stdout.readline().strip() == "publishing", handler.stderr
        assert takes("pt-x", 200), handler.stderr
        for _ in range(4):  # the window is full of messages read for x only each time
            status, _ = handler.request("PUT", "/v1/monitors/pt-yz", POINT_YZ)
            assert status == 201, handler.stderr
            assert takes("pt-yz", 50), handler.stderr
            assert handler.request("DELETE", "/v1/monitors/pt-yz")[0] == 200
            # messages read for x, y and z wait in the window now; let x-only ones in again
            assert takes("pt-x", 100), handler.stderr
        status, _ = handler.request("POST", "/v1/monitors", POINT_YZ)
        assert status == 201, handler.stderr
        assert takes("pt-yz", 50), handler.stderr
        assert handler.proc.poll() is None, handler.stderr
        assert handler.request("GET", "/healthz", token=None) == (
            200,
            {"status": "ok", "handler": "edge", "activeMonitors": 2},
        )
        _, listing = handler.request("GET", "/v1/monitors")
        assert {m["name"]: m["verdicts"]["violated"] for m in listing["monitors"]} == {
            "pt-x": 0,
            "pt-yz": 0,
        }
    finally:
        pub.kill()
        pub.wait()
        code = handler.stop()
    assert code == 0, handler.stderr
    assert "ingest loop failed" not in handler.stderr
    assert "Traceback" not in handler.stderr
    assert "could not be read" not in handler.stderr
