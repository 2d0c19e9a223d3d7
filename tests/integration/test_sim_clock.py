"""``edgerv handler --use-sim-time``: a simulation's /clock at twice real time, a robot
node with ``use_sim_time`` stamping its messages by it; the handler's timed monitors
follow that clock: their live verdicts, steps and stamps are those of ``edgerv check``
on the recorded messages, up to the instant the clock stopped. And each violation is a
line on the handler's console and on /rosout, or, within a second of its monitor's last
line, counted in the next.

Real processes and DDS: the handler as a user runs it; this test's own rclpy node is the
simulation (its /clock publisher) and the robot (a node with use_sim_time, spun by an
executor, as a ROS node takes sim time).
"""

from __future__ import annotations

import json
import re
import threading
import time
from pathlib import Path
from typing import Any

import pytest

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PointStamped  # noqa: E402
from rcl_interfaces.msg import Log  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402

from kit.ros import HandlerProcess, check_verdicts, own_node, wait_for  # noqa: E402

pytestmark = pytest.mark.integration

MONITORS = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: heartbeat}
spec:
  assertion: "always (age(beat) < 400ms)"
  signals:
    beat: {topic: /beat, type: geometry_msgs/msg/PointStamped, field: point.x}
---
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: reach}
spec:
  assertion: "always (goal > 0 -> F[0..300ms] at > 0)"
  signals:
    goal: {topic: /goal, type: geometry_msgs/msg/PointStamped, field: point.x}
    at: {topic: /at, type: geometry_msgs/msg/PointStamped, field: point.x}
---
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: steady}
spec:
  assertion: "always (fire > 0 -> historically[0..500ms] (aim > 0))"
  signals:
    fire: {topic: /fire, type: geometry_msgs/msg/PointStamped, field: point.x}
    aim: {topic: /aim, type: geometry_msgs/msg/PointStamped, field: point.x}
"""

BASE = 1000 * 10**9  # the simulation starts at 1000 s (as Gazebo's small times)
MS = 1_000_000
END = 3450  # ms: the clock stops here, 50 ms after the last heartbeat's violation
RATE = 2.0  # twice real time
# (sim ms, topic, point.x): what the robot publishes, when its clock says so
SCRIPT = sorted(
    [(t, "/beat", 1.0) for t in range(0, 3001, 100) if not 1000 < t < 2000]
    + [(500, "/goal", 1.0), (550, "/goal", 0.0), (700, "/at", 1.0), (750, "/at", 0.0)]
    + [(1500, "/goal", 1.0), (1550, "/goal", 0.0), (2000, "/at", 1.0), (2050, "/at", 0.0)]
    + [(2600, "/goal", 1.0), (2650, "/goal", 0.0)]
    + [(100, "/aim", 1.0), (600, "/fire", 1.0), (650, "/fire", 0.0), (1200, "/aim", 0.0)]
    + [(1300, "/aim", 1.0), (1500, "/fire", 1.0), (1550, "/fire", 0.0), (2300, "/fire", 1.0)]
    + [(2350, "/fire", 0.0)]
)
TOPICS = sorted({topic for _, topic, _ in SCRIPT})
ROSOUT_QOS = QoSProfile(
    depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)


def violation_line(monitor: str, step: int, stamp: int) -> str:
    """The start of a monitor's violation line on the console and /rosout."""
    return f"monitor {monitor} violated at step {step} (stamp {stamp // 10**9}."


class Simulation:
    """/clock from BASE at RATE times real time, every 5 ms, until it stops at END."""

    def __init__(self, node: Any) -> None:
        self.pub = node.create_publisher(Clock, "/clock", QoSProfile(depth=1))  # as ClockQoS
        self.stop = threading.Event()
        self.started = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self.started.is_set() and not self.stop.is_set():
            self._say(BASE)  # the clock stands at BASE until the run starts
            time.sleep(0.005)
        start = time.monotonic()
        while not self.stop.is_set():
            ns = min(BASE + int((time.monotonic() - start) * RATE * 1e9), BASE + END * MS)
            self._say(ns)
            time.sleep(0.005)

    def _say(self, ns: int) -> None:
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(ns, 10**9)
        self.pub.publish(msg)


def test_timed_monitors_follow_a_clock_at_twice_real_time(tmp_path: Path, domain: int) -> None:
    monitors = tmp_path / "timed.yaml"
    monitors.write_text(MONITORS)
    handler = HandlerProcess(tmp_path, monitors, domain, "--use-sim-time")
    recorded: list[dict[str, Any]] = []
    logs: list[Any] = []
    diagnostics: list[int] = []  # the stamps of the handler's /diagnostics
    try:
        with own_node(domain, "simulation") as node:
            node.set_parameters([Parameter("use_sim_time", Parameter.Type.BOOL, True)])
            node.create_subscription(Log, "/rosout", logs.append, ROSOUT_QOS)
            node.create_subscription(
                DiagnosticArray,
                "/diagnostics",
                lambda m: diagnostics.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec),
                10,
            )
            sim = Simulation(node)
            sim.thread.start()
            qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
            pubs = {t: node.create_publisher(PointStamped, t, qos) for t in TOPICS}
            assert wait_for(
                lambda: (
                    all(p.get_subscription_count() for p in pubs.values())
                    and sim.pub.get_subscription_count()
                ),
                timeout=20,
            ), handler.stderr
            assert wait_for(lambda: node.get_clock().now().nanoseconds == BASE, timeout=10)
            time.sleep(0.5)  # discovery settles on the handler's side too
            sim.started.set()
            wall = time.monotonic()
            for at, topic, x in SCRIPT:  # the robot, by its sim clock
                while node.get_clock().now().nanoseconds < BASE + at * MS:
                    time.sleep(0.001)
                msg = PointStamped()
                msg.header.stamp = node.get_clock().now().to_msg()
                msg.point.x = x
                pubs[topic].publish(msg)
                stamp = {"sec": msg.header.stamp.sec, "nanosec": msg.header.stamp.nanosec}
                recorded.append({"topic": topic, "msg": {"header": {"stamp": stamp},
                                                          "point": {"x": x}}})  # fmt: skip
            assert wait_for(lambda: node.get_clock().now().nanoseconds == BASE + END * MS)
            took = time.monotonic() - wall
            # the clock stopped at END: the monitors reach it --flush-after (0.5 s) later
            time.sleep(1.5)
            sim.stop.set()
            sim.thread.join(timeout=5)
            lines = [
                m.msg for m in list(logs) if m.name == "edgerv_edge" and "violated at step" in m.msg
            ]
    finally:
        assert handler.stop() == 0, handler.stderr
    assert took < END / 1000 / RATE + 0.5  # the run took half its simulated time
    recorded.append({"topic": "/sim_end", "stamp": BASE + END * MS, "msg": {"data": "end"}})
    trace = tmp_path / "recorded.jsonl"
    trace.write_text("".join(json.dumps(r) + "\n" for r in recorded))
    offline = check_verdicts(monitors, trace)
    live = sorted((v["monitor"], v["verdict"], v["step"], v["stamp"]) for v in handler.verdicts())
    assert live == offline, handler.stderr
    # heartbeat inside its gap and after the last beat (50 ms before the clock stopped),
    # reach missed twice, steady once: each decided by the clock, stamped in sim time
    assert [(m, v) for m, v, *_ in offline] == [
        ("heartbeat", "violated"), ("heartbeat", "violated"), ("reach", "violated"),
        ("reach", "violated"), ("steady", "violated"),
    ]  # fmt: skip
    assert all(BASE < stamp <= BASE + END * MS for *_, stamp in live)
    # the handler node's own clock too: /diagnostics stamped in sim time (0 before a clock)
    assert any(BASE < t <= BASE + END * MS for t in diagnostics), diagnostics
    assert all(t == 0 or BASE <= t <= BASE + END * MS for t in diagnostics), diagnostics
    # each violation a line on the console and on /rosout (under the handler's node), at
    # most one a monitor a second of wall time: a violation within a second of its
    # monitor's last line (reach's two are 0.55 s apart at twice real time, heartbeat's
    # 1 s) is counted in the monitor's next line or in the one said at exit instead
    for monitor in {m for m, *_ in offline}:
        said = [(step, stamp) for m, _, step, stamp in offline if m == monitor]
        own = [s for s in said if violation_line(monitor, *s) in handler.stderr]
        assert own[:1] == said[:1], handler.stderr  # the first always has its line
        held = re.findall(rf"monitor {monitor}\b.*\((\d+) more violations? since", handler.stderr)
        held += re.findall(rf"monitor {monitor}: (\d+) more violations? since", handler.stderr)
        assert len(own) + sum(map(int, held)) == len(said), handler.stderr
        for s in own:  # /rosout has the same lines (those held back to exit: the console)
            assert any(m.startswith(violation_line(monitor, *s)) for m in lines), lines
