"""The handler's subscriptions: one raw subscription per topic the monitors read, shared by
every monitor that reads it, with its QoS (given, or ``auto``: following the publishers)
and the counts /diagnostics shows (publishers, publishers of incompatible QoS, messages
that could not be read)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from rclpy.exceptions import InvalidHandle
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from edgerv.core.cdr import Reader, compile_reader
from edgerv.core.documents import QosSpec
from edgerv.core.pipeline import TopicRoute
from edgerv.handler.engine import Engine
from edgerv.handler.ros.messages import message_class

log = logging.getLogger("edgerv.handler.ros")

# messages taken from one subscription at a time (a round of the take loop, before it looks
# at the others; --deadline's topic likewise)
TAKE_PER_WAKE = 2000


@dataclass
class Subscription:
    """A topic's raw subscription and what the take loop reads from its messages."""

    route: TopicRoute
    fields: tuple[str, ...]
    subscription: Any
    reader: Reader
    qos: QoSProfile
    auto_reliability: bool
    # the publication sequence number of the last message taken, while the subscription
    # has one publisher (a gap after it: messages the middleware lost); None otherwise
    last_seq: int | None = None
    # the topic's publishers as the graph thread last counted them (the ROS graph, once a
    # second; None until it has): asked in the take loop, the count takes a lock the
    # middleware's own threads hold, which on a starved CPU can stall the loop
    publishers: int | None = None


def resolve_qos(node: Any, topic: str, spec: QosSpec) -> tuple[QoSProfile, bool]:
    """Explicit settings as given; ``auto`` follows the publishers already there."""
    pubs = node.get_publishers_info_by_topic(topic)
    reliability = {
        "reliable": ReliabilityPolicy.RELIABLE,
        "best_effort": ReliabilityPolicy.BEST_EFFORT,
    }.get(spec.reliability)
    if reliability is None:  # auto: reliable unless a publisher only offers best effort
        best_effort = any(p.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for p in pubs)
        reliability = ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE
    durability = {
        "volatile": DurabilityPolicy.VOLATILE,
        "transient_local": DurabilityPolicy.TRANSIENT_LOCAL,
    }.get(spec.durability)
    if durability is None:  # auto: latched only if every publisher keeps its last message
        latched = bool(pubs) and all(
            p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in pubs
        )
        durability = DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE
    qos = QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=spec.depth,
        reliability=reliability,
        durability=durability,
    )
    return qos, spec.reliability == "auto"


class Subscriptions:
    """The subscriptions to the topics of the engine's routes, made, changed and re-created
    in the take loop's thread (:meth:`reconfigure`, :meth:`resubscribe`), their publishers
    and QoS checked in the graph thread (:meth:`check_qos`), which asks ``wake`` to have
    the take loop re-create one."""

    def __init__(self, node: Any, engine: Engine, wake: Callable[[], None]) -> None:
        self.node = node
        self.engine = engine
        self.wake = wake
        self.subs: dict[str, Subscription] = {}
        self.version = -1  # the engine's routes version the subscriptions are for
        self.qos_problems: dict[str, int] = {}
        self.bad_messages: dict[str, int] = {}
        self.resubscribing: set[str] = set()  # topics the graph thread wants re-created

    def _subscribe(self, route: TopicRoute) -> Subscription:
        cls = message_class(route.msg_type)
        qos, auto = resolve_qos(self.node, route.topic, route.qos)
        sub = self.node.create_subscription(cls, route.topic, lambda _: None, qos, raw=True)
        log.info(
            "subscribed to %s (%s, %s, %s, depth %d)",
            route.topic,
            route.msg_type,
            qos.reliability.name.lower(),
            qos.durability.name.lower(),
            qos.depth,
        )
        return Subscription(
            route, tuple(route.fields), sub, compile_reader(route.msg_type, route.fields), qos, auto
        )

    def matched(self, topic: str) -> bool:
        """This handler's subscription to ``topic`` is matched with every publisher the
        ROS graph shows for it (with none, trivially): a receiver vouches for a silent
        topic by it (Engine.handoffs.cut; docs/protocol.md, "Silent topics"). Called from the API's
        threads: the graph calls and the subscription take rclpy's handle locks."""
        sub = self.subs.get(topic)
        if sub is None:  # not subscribed yet (the ROS thread reconfigures) or any more
            return False
        try:
            return bool(sub.subscription.get_publisher_count() >= self.node.count_publishers(topic))
        except InvalidHandle:  # destroyed meanwhile
            return False

    def reconfigure(self) -> None:
        """In the take loop's thread: the subscriptions and readers the engine's routes
        need now."""
        version = self.engine.routes_version
        if version == self.version:
            return
        self.version = version
        routes = self.engine.routes()
        for topic in list(self.subs):
            if topic not in routes or routes[topic].msg_type != self.subs[topic].route.msg_type:
                self.node.destroy_subscription(self.subs.pop(topic).subscription)
                log.info("unsubscribed from %s", topic)
        for topic, route in routes.items():
            current = self.subs.get(topic)
            if current is None:
                try:
                    self.subs[topic] = self._subscribe(route)
                except Exception as exc:  # an unusable topic must not stop the others
                    log.error("cannot subscribe to %s: %s", topic, exc)
            elif current.fields != tuple(route.fields) or current.route is not route:
                current.route = route
                current.fields = tuple(route.fields)
                current.reader = compile_reader(route.msg_type, route.fields)

    def resubscribe(self) -> bool:
        """In the take loop's thread: re-create the subscriptions the graph thread asked
        for; True if any was."""
        changed = False
        for topic in list(self.resubscribing):
            self.resubscribing.discard(topic)
            sub = self.subs.get(topic)
            if sub is not None:
                self.node.destroy_subscription(sub.subscription)
                self.subs[topic] = self._subscribe(sub.route)
                changed = True
        return changed

    def check_qos(self) -> None:
        """In the graph thread: count each topic's publishers, and those whose QoS cannot
        match ours; an ``auto`` subscription adapts."""
        for topic, sub in list(self.subs.items()):
            bad = 0
            pubs = self.node.get_publishers_info_by_topic(topic)
            sub.publishers = len(pubs)
            for pub in pubs:
                offered = pub.qos_profile
                if (
                    sub.qos.reliability == ReliabilityPolicy.RELIABLE
                    and offered.reliability == ReliabilityPolicy.BEST_EFFORT
                ) or (
                    sub.qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
                    and offered.durability == DurabilityPolicy.VOLATILE
                ):
                    bad += 1
            if bad and sub.auto_reliability and sub.qos.reliability == ReliabilityPolicy.RELIABLE:
                if topic not in self.resubscribing:
                    log.warning(
                        "%s: a publisher offers only best-effort delivery: subscribing "
                        "best effort (qos.reliability is auto)",
                        topic,
                    )
                    self.resubscribing.add(topic)
                    self.wake()  # the take loop re-creates the subscription
                continue
            if bad != self.qos_problems.get(topic, 0):
                if bad:
                    log.warning(
                        "%s: %d publisher(s) with incompatible QoS: their messages do "
                        "not reach this handler (subscription is %s, %s)",
                        topic,
                        bad,
                        sub.qos.reliability.name.lower(),
                        sub.qos.durability.name.lower(),
                    )
                self.qos_problems[topic] = bad

    def bad_message(self, topic: str, msg_type: str) -> None:
        """A message of ``topic`` that could not be read as ``msg_type``: counted, logged
        at the 1st, 10th, 100th and every 1000th."""
        n = self.bad_messages[topic] = self.bad_messages.get(topic, 0) + 1
        if n in (1, 10, 100) or n % 1000 == 0:
            log.warning("%s: %d messages could not be read as %s", topic, n, msg_type)
