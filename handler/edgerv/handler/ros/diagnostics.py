"""/diagnostics: the handler's health as ``diagnostic_msgs/msg/DiagnosticArray``, from a
thread of its own (``edgerv-diagnostics``). The statuses are built by
:mod:`edgerv.handler.health`, the message's bytes by :mod:`edgerv.handler.ros.cdr_out`."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Collection
from typing import Any

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from edgerv.handler.engine import Engine
from edgerv.handler.health import (
    Breather,
    Health,
    Pacer,
    Reading,
    Status,
    alarm_counts,
    read_engine,
)
from edgerv.handler.outbox import Outbox
from edgerv.handler.ros.cdr_out import encode_diagnostic_array, restamp_diagnostic_array
from edgerv.handler.ros.messages import message_class
from edgerv.handler.ros.rosout import Rosout
from edgerv.handler.ros.subscriptions import Subscriptions

log = logging.getLogger("edgerv.handler.ros")

DIAGNOSTICS_TOPIC = "/diagnostics"
# diagnostic_updater's publisher (reliable, volatile; it keeps 1, we keep 10: an update
# made at once for a change of level and the periodic one right after both reach a reader)
DIAGNOSTICS_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)


class Diagnostics:
    """The node's /diagnostics: ``health``'s statuses, of the engine and of the node's own
    counts (``subscriptions``' publishers, QoS problems and unreadable messages, what
    ``rosout`` could not send, what ``outbox``'s lanes coalesced), published by
    :meth:`start`'s thread until ``stop`` is set."""

    def __init__(
        self,
        node: Any,
        engine: Engine,
        health: Health,
        subscriptions: Subscriptions,
        rosout: Rosout,
        outbox: Outbox | None,
        stop: threading.Event,
    ) -> None:
        self.node = node
        self.engine = engine
        self.health = health
        self.subscriptions = subscriptions
        self.rosout = rosout
        self.outbox = outbox  # the verdicts' lanes (main's)
        self._stop = stop
        self.publisher = node.create_publisher(
            message_class("diagnostic_msgs/msg/DiagnosticArray"),
            DIAGNOSTICS_TOPIC,
            DIAGNOSTICS_QOS,
        )
        self._failures = 0
        self._sent: tuple[list[Status], bytes] | None = None  # the statuses last sent, as sent
        # the reading turned into statuses and bytes a little at a time (health.CPU_BUDGET)
        self.breather = Breather(stop)
        health.breathe = self.breather
        self._thread: threading.Thread | None = None

    def fingerprint(self, counts: tuple[object, ...]) -> object:
        """A few counters that change whenever anything a status shows may have
        (Health.settled): the engine's (Engine.fingerprint) and this node's ``counts``
        (:meth:`_counts`); None with --deadline (its window's percentiles change with time
        alone)."""
        if self.engine.deadline is not None:
            return None
        return (self.engine.fingerprint(), counts)

    def alarms(self, counts: tuple[object, ...]) -> object:
        """What a level other than a violation's or time's may change with
        (health.alarm_counts), and this node's ``counts``."""
        return (alarm_counts(self.engine, self.health.stale_topics()), counts)

    def _counts(self) -> tuple[object, ...]:
        """This node's own counts that statuses show."""
        subscriptions = self.subscriptions
        return (
            tuple((t, s.publishers) for t, s in list(subscriptions.subs.items())),
            tuple(list(subscriptions.qos_problems.items())),
            tuple(list(subscriptions.bad_messages.items())),
            self.rosout.failures,
            tuple(self.outbox.coalesced().items()) if self.outbox is not None else None,
        )

    def _reading_now(
        self, fingerprint: object = None, names: Collection[str] | None = None
    ) -> Reading:
        """The engine (its monitors, or those of ``names``) and this node's own counts,
        for the statuses."""
        subscriptions = self.subscriptions
        publishers = {
            topic: sub.publishers
            for topic, sub in list(subscriptions.subs.items())
            if sub.publishers is not None
        }
        return read_engine(
            self.engine,
            publishers=publishers,
            incompatible=dict(subscriptions.qos_problems),
            bad=dict(subscriptions.bad_messages),
            rosout_failures=self.rosout.failures,
            coalesced=self.outbox.coalesced() if self.outbox is not None else None,
            fingerprint=fingerprint,
            names=names,
        )

    def diagnose(self, update: bool) -> list[Status] | None:
        """One look (Health.due): the statuses published, all of them when ``update``
        is due, the handler's and those whose level changed when one did; else None.
        Statuses that are those last published (an idle handler's) are sent as the same
        bytes, with a new stamp: nothing is read, made or encoded again."""
        health = self.health
        now = health.clock.monotonic()
        # (taken before the reading: a change meanwhile shows next)
        counts = self._counts()
        fingerprint, alarms = self.fingerprint(counts), self.alarms(counts)
        statuses = health.due(self._reading_now, fingerprint, now, update, alarms)
        if statuses is None:
            return None
        stamp = self.node.get_clock().now().nanoseconds
        sent = self._sent
        if sent is not None and sent[0] is statuses:
            data = restamp_diagnostic_array(sent[1], stamp)
        else:
            data = encode_diagnostic_array(statuses, stamp, self.breather)
        self.publisher.publish(data)
        self._sent = (statuses, data)
        health.published(statuses)
        return statuses

    def _loop(self) -> None:
        """The diagnostics thread: an update every period, a check of the levels between
        (published at once when one changed; a violation wakes it), within its CPU budget
        (health.Pacer), which a long one keeps to as it goes (health.Breather). It takes
        the engine's lock only to copy a few hundred monitors at a time, and never waits
        for the take loop."""
        health = self.health
        pacer = Pacer(health.config.period, start=health.clock.monotonic())
        while not self._stop.is_set():
            now = health.clock.monotonic()
            wait = pacer.wait(now, health.next_change(now))
            if wait > 0:
                health.changed.wait(wait)  # set by a violation, or to stop
                rest = pacer.not_before - health.clock.monotonic()
                if rest > 0 and self._stop.wait(rest):  # the CPU budget comes first
                    break
            if self._stop.is_set():
                break
            health.changed.clear()
            started = time.thread_time()
            self.breather.begin()
            update = pacer.update_due(health.clock.monotonic())
            try:
                self.diagnose(update)
            except Exception:  # a failed update is retried; it must not stop the handler
                self._failures += 1
                n = self._failures
                if n in (1, 10, 100) or n % 1000 == 0:
                    log.exception("publishing /diagnostics failed (%d times)", n)
            spent = time.thread_time() - started
            pacer.worked(health.clock.monotonic(), spent, update, self.breather.paid)

    def start(self) -> None:
        self._thread = threading.Thread(target=self._loop, name="edgerv-diagnostics", daemon=True)
        self._thread.start()

    def wake(self) -> None:
        """Wake the thread (it waits on health.changed): to see ``stop`` at once."""
        self.health.changed.set()

    def join(self, timeout: float) -> None:
        if self._thread is not None:
            self._thread.join(timeout=timeout)
