"""The handler's take loop (edgerv.handler.ros.take) on real rclpy subscriptions, in process.

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
from edgerv.handler.ros.messages import message_class  # noqa: E402
from edgerv.handler.ros.node import HandlerNode  # noqa: E402
from edgerv.handler.ros.subscriptions import TAKE_PER_WAKE  # noqa: E402

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
metadata: {name: small}
spec:
  assertion: "always (s < 1e9)"
  signals:
    s: {topic: /small, type: std_msgs/msg/Float64, qos: {reliability: reliable, depth: 5}}
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
def ingest(domain: int) -> Iterator[HandlerNode]:
    rclpy.init(domain_id=domain)
    engine = Engine("take-loop", flush_after=1e9)
    for spec in load_monitors_text("monitors.yaml", MONITORS):
        engine.put(compile_monitor(spec), active=True)
    ros = HandlerNode(engine, "take-loop")
    try:
        ros.subscriptions.reconfigure()
        yield ros
    finally:
        ros.close()
        rclpy.shutdown()


def _publish(ros: HandlerNode, n: int, topic: str = "/burst", start: int = 0) -> None:
    """``n`` messages on ``topic``, all of them in the subscription's queue (as far as
    its depth allows) on return."""
    node = rclpy.create_node("take_loop_publisher")
    try:
        cls = message_class("std_msgs/msg/Float64")
        pub = node.create_publisher(
            cls, topic, QoSProfile(depth=6000, reliability=ReliabilityPolicy.RELIABLE)
        )
        deadline = time.monotonic() + 10
        while not pub.get_subscription_count() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert pub.get_subscription_count() == 1
        for i in range(start, start + n):
            pub.publish(cls(data=float(i)))
        # reliable, on loopback: delivered once every publish is acknowledged
        assert pub.wait_for_all_acked(Duration(seconds=10))
    finally:
        node.destroy_node()


def test_rounds_take_every_message_of_a_burst_larger_than_a_round(ingest: HandlerNode) -> None:
    n = 2 * TAKE_PER_WAKE + 500
    _publish(ingest, n)
    subs = list(ingest.subscriptions.subs.values())
    values: list[float] = []
    rounds = []
    while True:
        before = time.time_ns()
        batch, through = ingest.take.take_all(subs)
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


def test_the_clock_waits_for_what_the_take_loop_has_not_taken(ingest: HandlerNode) -> None:
    engine = ingest.engine
    _publish(ingest, TAKE_PER_WAKE + 10)
    subs = list(ingest.subscriptions.subs.values())
    _, through = ingest.take.take_all(subs)
    ingest.take.drained(through, None)
    # the queue still holds messages published before now: the monitors' clocks must not
    # pass them (until = min(wall, drained_at) - flush_after)
    assert engine.drained_at is not None and engine.drained_at < time.time_ns()
    held = engine.drained_at
    batch, through = ingest.take.take_all(subs)
    assert len(batch) == 10
    ingest.take.drained(through, None)
    assert engine.drained_at > held
    # a stale bound never moves the instant back
    ingest.take.drained(held - 1, None)
    assert engine.drained_at > held


def test_messages_a_full_queue_lost_are_counted(ingest: HandlerNode) -> None:
    """A subscription of depth 5 (KEEP_LAST): of 50 messages one publisher sends before
    the handler takes any, the queue keeps the last 5; the other 45 are lost, and said so.
    (The first round only learns where the publisher's numbers stand: what came before
    the handler subscribed was never its to take.)"""
    engine = ingest.engine
    small = [ingest.subscriptions.subs["/small"]]
    node = rclpy.create_node("take_loop_small_publisher")
    try:
        cls = message_class("std_msgs/msg/Float64")
        pub = node.create_publisher(
            cls, "/small", QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        )
        deadline = time.monotonic() + 10
        while not pub.get_subscription_count() and time.monotonic() < deadline:
            time.sleep(0.05)
        ingest.subscriptions.check_qos()  # the graph thread's count of the topic's publishers: one
        assert ingest.subscriptions.subs["/small"].publishers == 1

        def send(first: int, n: int) -> list[float]:
            for i in range(first, first + n):
                pub.publish(cls(data=float(i)))
            assert pub.wait_for_all_acked(Duration(seconds=10))
            batch, _ = ingest.take.take_all(small)
            return [v[2][0] for v in batch]

        assert send(0, 5) == [0.0, 1.0, 2.0, 3.0, 4.0]
        assert engine.lost.get("/small", 0) == 0
        assert send(5, 3) == [5.0, 6.0, 7.0]
        assert engine.lost.get("/small", 0) == 0  # in sequence: nothing lost
        assert send(8, 50) == [53.0, 54.0, 55.0, 56.0, 57.0]
        assert engine.lost["/small"] == 45
    finally:
        node.destroy_node()
    # a new publisher numbers from 1 again: no loss read into that
    node = rclpy.create_node("take_loop_small_publisher_2")
    try:
        pub = node.create_publisher(
            cls, "/small", QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        )
        deadline = time.monotonic() + 10
        while not pub.get_subscription_count() and time.monotonic() < deadline:
            time.sleep(0.05)
        ingest.subscriptions.check_qos()
        for i in range(3):
            pub.publish(cls(data=float(100 + i)))
        assert pub.wait_for_all_acked(Duration(seconds=10))
        batch, _ = ingest.take.take_all(small)
        assert [v[2][0] for v in batch] == [100.0, 101.0, 102.0]
        assert engine.lost["/small"] == 45
    finally:
        node.destroy_node()
