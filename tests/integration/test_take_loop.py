"""The handler's take loop (ros_node.RosIngest) on real rclpy subscriptions, in process.

A real publisher fills a real subscription's queue; the rounds of the take loop are
called one by one, so what each round takes, and how far it says everything is taken
(the instant the monitors' clocks wait for), is seen exactly.
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.duration import Duration  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from edgerv.core.documents import load_monitors_text  # noqa: E402
from edgerv.core.monitor import compile_monitor  # noqa: E402
from edgerv.handler.engine import Engine  # noqa: E402
from edgerv.handler.ros_node import TAKE_PER_WAKE, RosIngest, message_class  # noqa: E402

pytestmark = pytest.mark.integration

MONITORS = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: burst}
spec:
  assertion: "always (x < 1e9)"
  signals:
    x: {topic: /burst, type: std_msgs/msg/Float64, qos: {reliability: reliable, depth: 6000}}
---
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: quiet}
spec:
  assertion: "always (q < 1e9)"
  signals:
    q: {topic: /quiet, type: std_msgs/msg/Float64}
"""


@pytest.fixture
def ingest(domain: int) -> Iterator[RosIngest]:
    rclpy.init(domain_id=domain)
    engine = Engine("take-loop", flush_after=1e9)
    for spec in load_monitors_text("monitors.yaml", MONITORS):
        engine.put(compile_monitor(spec), active=True)
    ros = RosIngest(engine, "take-loop")
    try:
        ros._reconfigure()
        yield ros
    finally:
        ros.close()
        rclpy.shutdown()


def _publish(ros: RosIngest, n: int) -> None:
    """``n`` messages on /burst, all of them in the subscription's queue on return."""
    node = rclpy.create_node("take_loop_publisher")
    try:
        cls = message_class("std_msgs/msg/Float64")
        pub = node.create_publisher(
            cls, "/burst", QoSProfile(depth=6000, reliability=ReliabilityPolicy.RELIABLE)
        )
        deadline = time.monotonic() + 10
        while not pub.get_subscription_count() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert pub.get_subscription_count() == 1
        for i in range(n):
            pub.publish(cls(data=float(i)))
        # reliable, on loopback: delivered once every publish is acknowledged
        assert pub.wait_for_all_acked(Duration(seconds=10))
    finally:
        node.destroy_node()


def test_rounds_take_every_message_of_a_burst_larger_than_a_round(ingest: RosIngest) -> None:
    n = 2 * TAKE_PER_WAKE + 500
    _publish(ingest, n)
    subs = list(ingest.subs.values())
    values: list[float] = []
    rounds = []
    while True:
        before = time.time_ns()
        batch, through = ingest._take_all(subs)
        if not batch:
            break
        rounds.append((len(batch), through, before))
        values += [v[2][0] for v in batch]
    # every message once, in order: none lost where a round stops (a round takes at most
    # TAKE_PER_WAKE from one subscription, and what it does not take waits for the next)
    assert values == [float(i) for i in range(n)]
    assert [r[0] for r in rounds] == [TAKE_PER_WAKE, TAKE_PER_WAKE, 500]
    # a round that left messages behind says it took everything only up to the last
    # one it took (published before the round began); the round that emptied every
    # subscription says: up to its start
    assert rounds[0][1] < rounds[0][2] and rounds[1][1] < rounds[1][2]
    assert rounds[0][1] <= rounds[1][1]
    assert rounds[2][1] >= rounds[2][2]


def test_the_clock_waits_for_what_the_take_loop_has_not_taken(ingest: RosIngest) -> None:
    engine = ingest.engine
    _publish(ingest, TAKE_PER_WAKE + 10)
    subs = list(ingest.subs.values())
    _, through = ingest._take_all(subs)
    ingest._drained(through, None)
    # the queue still holds messages published before now: the monitors' clocks must not
    # pass them (until = min(wall, drained_at) - flush_after)
    assert engine.drained_at is not None and engine.drained_at < time.time_ns()
    held = engine.drained_at
    batch, through = ingest._take_all(subs)
    assert len(batch) == 10
    ingest._drained(through, None)
    assert engine.drained_at > held
    # a stale bound never moves the instant back
    ingest._drained(held - 1, None)
    assert engine.drained_at > held
