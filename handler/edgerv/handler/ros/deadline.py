"""``--deadline TOPIC=DURATION``: the task's output topic, subscribed to (raw, a subscription
of its own whatever the monitors read) once the ROS graph shows a publisher and so its
type; each message's makespan (source timestamp minus ``header.stamp``) goes to the
engine's :class:`~edgerv.core.deadline.MakespanWindow`."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

from edgerv.core.cdr import header_stamp_ns
from edgerv.core.deadline import MakespanWindow
from edgerv.core.documents import QosSpec
from edgerv.core.msgtypes import starts_with_header
from edgerv.handler.clock import SimClock
from edgerv.handler.ros.messages import message_class, type_problem
from edgerv.handler.ros.subscriptions import TAKE_PER_WAKE, Subscriptions, resolve_qos

log = logging.getLogger("edgerv.handler.ros")


class DeadlineTopic:
    """``--deadline``'s topic, as the handler learns and reads it: its type in the graph
    thread (:meth:`learn_type`), its subscription made and read in the take loop's
    (:meth:`subscribe`, :meth:`take`)."""

    def __init__(
        self,
        window: MakespanWindow,
        node: Any,
        subscriptions: Subscriptions,
        sim: SimClock | None,
        wake: Callable[[], None],
    ) -> None:
        self.window = window
        self.node = node
        self.subscriptions = subscriptions  # (its count of messages that cannot be read)
        self.sim = sim
        self.wake = wake
        self.msg_type: str | None = None  # from the ROS graph, once a publisher shows it
        self.subscription: Any = None  # made in the take loop's thread once the type is known
        self.given_up = False  # a type without a header, or several: no deadline data
        self.target: str | None = None  # another topic to measure (the take loop moves to it)
        # (a relative --deadline: the robot whose monitors it runs says which topic)
        self.namespace: Callable[[], str | None] = lambda: None

    @property
    def moving(self) -> bool:
        return self.target is not None

    @property
    def pending(self) -> bool:
        return self.msg_type is not None and self.subscription is None and not self.given_up

    def learn_type(self) -> None:
        """In the graph thread, each second: a relative topic resolved again (another
        robot's monitors here: the take loop moves to its topic, :meth:`move`); until a
        publisher shows it, the topic's type. One that does not start with a
        std_msgs/msg/Header is an error, logged once: the handler goes on without
        deadline data."""
        if self.window.relative and self.target is None:
            wanted = self.window.resolved(self.namespace())
            if wanted != self.window.topic:  # the take loop moves to it, then it is learnt
                self.target = wanted
                self.wake()
                return
        if self.msg_type is not None or self.given_up or self.target is not None:
            return
        topic = self.window.topic
        types = sorted({p.topic_type for p in self.node.get_publishers_info_by_topic(topic)})
        if not types:
            return  # no publisher yet: asked again in a second
        problem = None
        if len(types) > 1:
            problem = f"its publishers publish several types ({', '.join(types)})"
        elif not starts_with_header(types[0]):
            problem = (
                f"its type {types[0]} does not start with a std_msgs/msg/Header, so its "
                "messages carry no stamp of the input they were computed from"
            )
        elif (missing := type_problem(types[0])) is not None:
            problem = missing
        if problem is not None:
            self.given_up = True
            log.error("--deadline %s: %s: no deadline data", topic, problem)
            return
        self.msg_type = types[0]
        self.wake()  # the take loop subscribes

    def move(self) -> None:
        """In the take loop's thread: measure the topic :meth:`learn_type` resolved (the
        relative --deadline's, in the namespace of the robot whose monitors now run
        here): the old subscription goes, the new topic's type is learnt afresh."""
        target = self.target
        if target is None:
            return
        if self.subscription is not None:  # (the wait set holds its handle until rebuilt)
            self.node.destroy_subscription(self.subscription)
            self.subscription = None
        log.info("deadline: --deadline %s is %s here", self.window.name.lstrip("/"), target)
        self.window.retarget(target)
        self.msg_type, self.given_up = None, False
        self.target = None  # (last: the graph thread resolves again only from here on)

    def subscribe(self) -> None:
        """In the take loop's thread: the deadline topic's own raw subscription."""
        topic, msg_type = self.window.topic, str(self.msg_type)
        try:
            qos, _ = resolve_qos(self.node, topic, QosSpec())
            self.subscription = self.node.create_subscription(
                message_class(msg_type), topic, lambda _: None, qos, raw=True
            )
        except Exception as exc:  # carry on without deadline data
            self.given_up = True
            log.error("--deadline %s: cannot subscribe (%s): no deadline data", topic, exc)
            return
        log.info(
            "deadline: measuring the makespan of %s (%s) against %g ms",
            topic,
            msg_type,
            self.window.budget_ns / 1e6,
        )

    def take(self) -> None:
        """In the take loop's thread: the makespans of what waits on the deadline topic."""
        sub, window, topic = self.subscription, self.window, self.window.topic
        take, cls = sub.handle.take_message, sub.msg_type
        taken = time.monotonic_ns()
        for _ in range(TAKE_PER_WAKE):
            got = take(cls, True)
            if got is None:
                return
            raw, info = got
            try:
                stamp = header_stamp_ns(raw)
            except ValueError:
                self.subscriptions.bad_message(topic, str(self.msg_type))
                continue
            source = info["source_timestamp"]
            if self.sim is not None:  # --use-sim-time: the publication in ROS time, as the stamp
                source = self.sim.published(source)
            if not window.add(source, stamp, taken) and window.unstamped == 1:
                log.warning("%s: header.stamp is 0 (nobody stamped it): not measured", topic)
