"""``--use-sim-time`` on the node: /clock followed where time is read, the node's own clock
with it; and without it, a /clock published (a simulation, ``edgerv replay``) said once."""

from __future__ import annotations

import logging
from typing import Any

from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from edgerv.handler.clock import CLOCK_DEPTH, CLOCK_TOPIC, CLOCK_TYPE, SYSTEM_CLOCK_HINT, SimClock
from edgerv.handler.ros.messages import message_class

log = logging.getLogger("edgerv.handler.ros")


def follow_clock(node: Any, sim: SimClock) -> Any:
    """The clock takes /clock (raw, best effort as ROS's TimeSource: it matches any
    publisher) where time is read; the node's own clock follows it, as a node's with
    use_sim_time (/diagnostics' and /edgerv/last_verdicts' stamps). Returns the time
    source, to be kept as long as the node (it holds the node's clock in ROS time)."""
    from rclpy.clock import ROSClock
    from rclpy.clock_type import ClockType
    from rclpy.time import Time
    from rclpy.time_source import TimeSource

    qos = QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=CLOCK_DEPTH,
        reliability=ReliabilityPolicy.BEST_EFFORT,
    )
    sub = node.create_subscription(
        message_class(CLOCK_TYPE), CLOCK_TOPIC, lambda _: None, qos, raw=True
    )
    clock, source = node.get_clock(), TimeSource()
    assert isinstance(clock, ROSClock)  # (a node's own clock is ROS time)
    source.attach_clock(clock)
    source.ros_time_is_active = True

    def follow(ns: int) -> None:
        clock.set_ros_time_override(Time(nanoseconds=ns, clock_type=ClockType.ROS_TIME))

    sim.attach(lambda: sub.handle.take_message(sub.msg_type, True), follow)
    return source


class ClockNote:
    """On the system clock: says once that /clock is published (:meth:`check`, in the
    graph thread), with what to give to follow it."""

    def __init__(self, node: Any) -> None:
        self.node = node
        self.noted = False

    def check(self) -> None:
        if not self.noted and self.node.count_publishers(CLOCK_TOPIC):
            self.noted = True
            log.warning(SYSTEM_CLOCK_HINT)
