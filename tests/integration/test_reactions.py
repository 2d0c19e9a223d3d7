"""A monitor's reaction to its violation (``spec.onViolation``), done by real handlers: a
message published, a service called, once per violation, by the handler that evaluated it
(docs/handler.md, "Reactions"), also when the monitor moved between the violating
message and its evaluation; and the same violation on the typed verdict topic and at
level ERROR on /diagnostics, from that handler (issue #19's acceptance).

Real ``edgerv handler`` processes and a real publisher; this test's own rclpy node is the
robot's side: a /cmd_vel subscriber and a std_srvs/SetBool server on /estop, and what a
user's tools read: /edgerv/verdict and /diagnostics.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from edgerv_msgs.msg import Verdict  # noqa: E402
from geometry_msgs.msg import Twist  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_srvs.srv import SetBool  # noqa: E402

from kit.documents import monitors_yaml, speed_monitor  # noqa: E402
from kit.ros import HandlerProcess, migrate, own_node, publisher, wait_for  # noqa: E402

pytestmark = pytest.mark.integration
ERROR = bytes([2])  # diagnostic_msgs/DiagnosticStatus.ERROR (a byte, as rclpy gives it)


def stop_monitors(sort: int) -> str:
    """speed-cap, which stops the robot when violated (a Twist on /cmd_vel, /estop called),
    its sort window ``sort``; and quiet-cap, the same cap with no reaction."""
    stop = {
        "publish": {
            "topic": "/cmd_vel",
            "type": "geometry_msgs/msg/Twist",
            "message": {"linear": {"x": 0}, "angular": {"z": 0.5}},
        },
        "call": {"service": "/estop", "type": "std_srvs/srv/SetBool", "request": {"data": True}},
    }
    return monitors_yaml(
        speed_monitor("speed-cap", sortThreshold=sort, onViolation=stop),
        speed_monitor("quiet-cap"),
    )


@dataclass
class Robot:
    """What the robot's side received: Twists on /cmd_vel, SetBool requests on /estop."""

    twists: list[Any] = field(default_factory=list)
    estops: list[bool] = field(default_factory=list)
    verdicts: list[Any] = field(default_factory=list)  # edgerv_msgs/msg/Verdict
    errors: list[Any] = field(default_factory=list)  # speed-cap's ERROR statuses
    lock: threading.Lock = field(default_factory=threading.Lock)
    subscription: Any = None

    def counts(self) -> tuple[int, int]:
        with self.lock:
            return len(self.twists), len(self.estops)


@pytest.fixture
def robot(domain: int) -> Iterator[Robot]:
    got = Robot()

    def on_twist(msg: Any) -> None:
        with got.lock:
            got.twists.append(msg)

    def on_estop(request: Any, response: Any) -> Any:
        with got.lock:
            got.estops.append(request.data)
        response.success, response.message = True, "stopped"
        return response

    def on_verdict(msg: Any) -> None:
        with got.lock:
            got.verdicts.append(msg)

    def on_diagnostics(msg: Any) -> None:
        with got.lock:
            got.errors += [
                s for s in msg.status if s.name == "edgerv: speed-cap" and s.level == ERROR
            ]

    typed = QoSProfile(
        depth=100,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )
    with own_node(domain, "robot") as node:
        got.subscription = node.create_subscription(Twist, "/cmd_vel", on_twist, 100)
        node.create_service(SetBool, "/estop", on_estop)
        node.create_subscription(Verdict, "/edgerv/verdict", on_verdict, typed)
        node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 100)
        yield got


def monitors(tmp: Path, sort: int = 1) -> Path:
    path = tmp / "monitors.yaml"
    path.write_text(stop_monitors(sort))
    return path


def violations(h: HandlerProcess, monitor: str = "speed-cap") -> list[int]:
    return [
        v["step"] for v in h.verdicts() if v["monitor"] == monitor and v["verdict"] == "violated"
    ]


def test_each_violation_is_reacted_to_once(tmp_path: Path, domain: int, robot: Robot) -> None:
    """Two violations among good messages (the monitor resets after each): two Twists with
    the fields written and the rest zero, two SetBool calls with data true; the monitor
    without onViolation, violated as often, does nothing."""
    h = HandlerProcess(tmp_path, monitors(tmp_path), domain)
    pub = None
    try:
        # the reactor's publisher was made with the monitor: the subscriber matches it first
        assert wait_for(lambda: robot.subscription.get_publisher_count() > 0, timeout=15)
        good, bad = {"data": 1.0}, {"data": 150.0}
        pub = publisher(
            domain,
            "/speed",
            "std_msgs/msg/Float64",
            [good] * 10 + [bad] + [good] * 10 + [bad] + [good] * 10,
        )
        assert wait_for(lambda: len(violations(h)) == 2, timeout=30)
        assert violations(h) == [11, 22] and violations(h, "quiet-cap") == [11, 22]
        assert wait_for(lambda: min(robot.counts()) >= 2, timeout=10), robot.counts()
        time.sleep(1.0)  # nothing more comes
        assert robot.counts() == (2, 2)
        assert robot.estops == [True, True]
        for twist in robot.twists:
            assert (twist.linear.x, twist.linear.y, twist.linear.z) == (0.0, 0.0, 0.0)
            assert (twist.angular.x, twist.angular.y, twist.angular.z) == (0.0, 0.0, 0.5)
        log = h.stderr
        assert log.count("published geometry_msgs/msg/Twist on /cmd_vel") == 2
        assert log.count("called /estop (std_srvs/srv/SetBool): it answered success True") == 2
    finally:
        if pub is not None:
            pub.wait(timeout=30)
        assert h.stop() == 0, h.stderr


def test_a_monitor_moved_between_its_violation_and_its_evaluation_reacts_once_there(
    tmp_path: Path, domain: int, robot: Robot
) -> None:
    """The violating message reaches the edge handler, which holds it unevaluated (a sort
    threshold of 50 and a flush after 60 s); the monitor then moves to the cloud handler
    with its buffer, and the cloud evaluates it: the cloud reacts, once, and the edge
    never does."""
    path = monitors(tmp_path, sort=50)
    edge = HandlerProcess(tmp_path, path, domain, "--flush-after", "60", name="edge")
    cloud = HandlerProcess(tmp_path, path, domain, "--active", "none", name="cloud")
    pub = None
    try:
        assert wait_for(lambda: robot.subscription.get_publisher_count() >= 2, timeout=15)
        sent = [{"data": 1.0}] * 5 + [{"data": 150.0}] + [{"data": 1.0}] * 4
        pub = publisher(domain, "/speed", "std_msgs/msg/Float64", sent)
        assert pub.wait(timeout=30) == 0
        assert wait_for(
            lambda: (edge.metric("edgerv_events_total", monitor="speed-cap") or 0) >= 10,
            timeout=15,
        )
        time.sleep(1.0)
        assert violations(edge) == [] and robot.counts() == (0, 0)  # held, not evaluated
        moved = migrate(edge, cloud, "speed-cap", domain)
        assert moved.returncode == 0, moved.stderr
        assert wait_for(lambda: robot.counts() == (1, 1), timeout=30), robot.counts()
        time.sleep(1.5)
        assert robot.counts() == (1, 1)
        assert violations(cloud) == [6] and violations(edge) == []
        assert "published geometry_msgs/msg/Twist" in cloud.stderr
        assert "published" not in edge.stderr and "called /estop" not in edge.stderr
        # the same violation, typed, from the cloud, once; and ERROR there on /diagnostics
        assert wait_for(lambda: robot.errors, timeout=10), "no ERROR on /diagnostics"
        with robot.lock:
            typed = [
                (v.handler, v.verdict, v.step) for v in robot.verdicts if v.monitor == "speed-cap"
            ]
            errors = list(robot.errors)
        assert [t for t in typed if t[0:2] == ("cloud", "violated")] == [("cloud", "violated", 6)]
        assert not [t for t in typed if t[0] == "edge" and t[1] == "violated"]
        assert {e.hardware_id for e in errors} == {"cloud"}
        assert errors[0].message.startswith("violated at step 6")
        assert {kv.key: kv.value for kv in errors[0].values}["migrations"] == "1 here, 0 away"
    finally:
        stopped = (edge.stop(), cloud.stop())
        assert stopped == (0, 0), edge.stderr + cloud.stderr
    # the edge's shutdown drains what it holds: the quiet monitor's events, not speed-cap's
    assert robot.counts() == (1, 1)


UNANSWERED = speed_monitor(
    "nobody-answers",
    onViolation={
        "call": {"service": "/nobody", "type": "std_srvs/srv/Trigger", "timeoutMs": 600000}
    },
)


def test_a_handler_stopping_gives_its_calls_seconds_not_their_timeouts(
    tmp_path: Path, domain: int
) -> None:
    """Violations whose service has no server (a 10-minute timeout each) queue their
    calls; SIGTERM stops the handler within the few seconds it gives them (CLOSE_SECONDS),
    exit 0, saying which calls it did not make: not ten minutes a call."""
    path = tmp_path / "m.yaml"
    path.write_text(UNANSWERED)
    h = HandlerProcess(tmp_path, path, domain)
    try:
        sent = [{"data": 150.0}] * 5
        pub = publisher(domain, "/speed", "std_msgs/msg/Float64", sent)
        assert pub.wait(timeout=30) == 0
        assert wait_for(lambda: len(violations(h, "nobody-answers")) == 5, timeout=30)
    finally:
        started = time.monotonic()
        code = h.stop(timeout=60)
        took = time.monotonic() - started
    assert code == 0, h.stderr
    assert took < 20, took  # CLOSE_SECONDS (5) and the ordered shutdown, not 600 s a call
    assert "service call(s) of reactions not made: the handler stopped" in h.stderr
    assert "nobody-answers -> /nobody" in h.stderr
