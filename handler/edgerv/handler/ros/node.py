"""The rclpy glue of the monitor handler: the only module of the handler that imports ROS.

One raw subscription per topic, shared by every monitor that reads it. Instead of
the stock executor (a Python callback per message, about 6,000 messages/s on a
small machine), one thread waits on a wait set and *takes* every ready message
as the bytes the publisher sent, reads just the needed fields from the CDR
(:mod:`edgerv.core.cdr`), orders what it took by timestamp and hands the batch
to the engine.

The timestamp of a message is its ``header.stamp`` when it has a header, else
the DDS source timestamp: the instant the robot published it (with ``--use-sim-time``,
the ROS time then: :meth:`edgerv.handler.clock.SimClock.published`).

With ``--deadline TOPIC=DURATION`` it also subscribes to TOPIC (raw, a subscription
of its own whatever the monitors read) once the ROS graph shows a publisher and
so its type, and feeds each message's makespan (source timestamp minus
``header.stamp``) to the engine's :class:`~edgerv.core.deadline.MakespanWindow`.

It publishes the handler's health on ``/diagnostics`` (``diagnostic_msgs/msg/
DiagnosticArray``, from a thread of its own: the statuses are built by
:mod:`edgerv.handler.health`) and forwards the handler's log lines to ``/rosout``
through the node's logger (:class:`RosoutHandler`).

Verdicts go out three ways: typed, ``edgerv_msgs/msg/Verdict`` on ``/edgerv/verdict``
(each as reached) and ``edgerv_msgs/msg/VerdictArray`` on ``/edgerv/last_verdicts`` (the
last verdict of each monitor, for late subscribers: :class:`TypedVerdicts`), when
edgerv_msgs is installed (interfaces/build.sh); and as JSON in ``std_msgs/msg/String`` on
``/edgerv/verdicts``, kept for compatibility.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import logging
import os
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from operator import itemgetter, lt
from typing import Any

import rclpy
from rclpy.exceptions import InvalidHandle
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import ok, try_shutdown

from edgerv.core.cdr import Reader, compile_reader, header_stamp_ns
from edgerv.core.deadline import MakespanWindow
from edgerv.core.documents import QosSpec
from edgerv.core.msgtypes import starts_with_header
from edgerv.core.pipeline import TopicRoute, Verdict
from edgerv.handler.clock import (
    CLOCK_DEPTH,
    CLOCK_TOPIC,
    CLOCK_TYPE,
    SYSTEM_CLOCK_HINT,
    SimClock,
)
from edgerv.handler.engine import Engine
from edgerv.handler.health import Health, Pacer, Reading, Status, read_engine
from edgerv.handler.outbox import Burst, Outbox
from edgerv.handler.reorder import ReorderWindow
from edgerv.handler.ros import types as ros_types
from edgerv.handler.ros.cdr_out import encode_diagnostic_array
from edgerv.handler.ros.logs import ros_log_problem
from edgerv.handler.ros.verdict_topics import (
    LAST_VERDICTS_SECONDS,
    LAST_VERDICTS_TOPIC,
    TypedVerdicts,
)
from edgerv.handler.sinks import verdict_record

log = logging.getLogger("edgerv.handler.ros")

VERDICT_TOPIC = "/edgerv/verdicts"  # JSON in std_msgs/String: kept for compatibility
BUILD_MSGS = (
    "edgerv_msgs is not installed in this Python environment: no typed verdicts on "
    "/edgerv/verdict and /edgerv/last_verdicts (the JSON on {VERDICT_TOPIC} goes "
    "on); build it from edgerv's source tree with `make install`, or `bash "
    "interfaces/build.sh <venv>` for another venv"
)
DIAGNOSTICS_TOPIC = "/diagnostics"
# diagnostic_updater's publisher (reliable, volatile; it keeps 1, we keep 10: an update
# made at once for a change of level and the periodic one right after both reach a reader)
DIAGNOSTICS_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
TAKE_PER_WAKE = 2000  # messages taken from one subscription before looking at the others
QOS_CHECK_SECONDS = 1.0
COALESCE_SECONDS = 0.0005  # at most this much latency for much less work per message
_FIRST = itemgetter(0)
LOST_LOG_SECONDS = 10.0  # a topic's lost messages are logged at most this often
# (stamp ns, topic, field values, the message's bytes, the routes version they were read for)
Taken = tuple[int, str, list[Any], bytes, int]


def message_class(msg_type: str) -> Any:
    """The rclpy class of ``pkg/msg/Type`` (or of a service's event, ``pkg/srv/Name_Event``,
    in its package's ``srv`` module). A type not installed, of a package of the robot's
    own, is built from its .msg files where ``edgerv check`` finds them (at its first use,
    cached: :mod:`edgerv.handler.ros.types`); raises ImportError saying what to do."""
    pkg, kind, name = msg_type.split("/")
    try:
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ImportError, AttributeError):
        return ros_types.message_class(msg_type)


def type_problem(msg_type: str) -> str | None:
    try:
        message_class(msg_type)
    except ImportError as exc:
        return str(exc)
    return None


def init_ros() -> None:
    """Start rclpy without its signal handlers (the handler's main() owns SIGINT/SIGTERM)
    and without ROS's console output: the handler's log lines reach stderr through
    Python's logging as they always did, and /rosout through the node's logger
    (:class:`RosoutHandler`); ROS's console would print each of them a second time."""
    if not ok():
        no_files = ros_log_problem()  # (ros_logs: a home rcl cannot write)
        if no_files:
            log.warning(no_files)
        rclpy.init(
            args=["edgerv", "--ros-args", "--disable-stdout-logs"]
            + (["--disable-external-lib-logs"] if no_files else []),
            signal_handler_options=SignalHandlerOptions.NO,
        )


def shutdown_ros() -> None:
    """Shut rclpy down, unless it is down already: the handler's last step."""
    try_shutdown()


# -- /rosout -------------------------------------------------------------------------------

# Python's levels -> rcutils' severities (DEBUG, INFO, WARN, ERROR, FATAL: 10 to 50)
_SEVERITIES = (
    (logging.CRITICAL, 50),
    (logging.ERROR, 40),
    (logging.WARNING, 30),
    (logging.INFO, 20),
)


def ros_severity(levelno: int) -> int:
    """The rcutils severity of a Python logging level: DEBUG, INFO, WARNING, ERROR and
    CRITICAL map to DEBUG, INFO, WARN, ERROR and FATAL (a level between two, down)."""
    return next((severity for at, severity in _SEVERITIES if levelno >= at), 10)


class RosoutHandler(logging.Handler):
    """A logging handler that hands each record to the node's rclpy logger (rcutils),
    which publishes it on /rosout under the node's name (and writes ROS's log file).

    Safe from any thread (logging serializes a handler's calls under its lock). It never
    raises and never logs: a line that cannot be sent is counted in :attr:`failures`
    (the handler's diagnostic status shows it) and the first failure is written to
    stderr directly, not through logging, which would come back here. A record logged
    while one is being sent (from within rclpy) is not sent, and a forked child (the
    Spot worker) sends nothing: the node is its parent's."""

    def __init__(self, logger_name: str) -> None:
        super().__init__()
        self.logger_name = logger_name
        self.failures = 0
        self._pid = os.getpid()
        self._sending = threading.local()

    def emit(self, record: logging.LogRecord) -> None:
        if os.getpid() != self._pid or getattr(self._sending, "on", False):
            return
        self._sending.on = True
        try:
            _rclpy.rclpy_logging_rcutils_log(
                ros_severity(record.levelno),
                self.logger_name,
                self.format(record),  # the message, and its traceback if any
                record.funcName or "",
                record.pathname or "",
                record.lineno or 0,
            )
        except Exception as exc:  # never into logging: it would come back here
            self.failures += 1
            if self.failures == 1:
                with contextlib.suppress(Exception):
                    sys.stderr.write(f"edgerv: a log line could not be sent to /rosout: {exc!r}\n")
        finally:
            self._sending.on = False

    def handleError(self, record: logging.LogRecord) -> None:
        self.failures += 1  # (logging's own would print a traceback for each)


@dataclass
class _Sub:
    route: TopicRoute
    fields: tuple[str, ...]
    subscription: Any
    reader: Reader
    qos: QoSProfile
    auto_reliability: bool
    # the publication sequence number of the last message taken, while the subscription
    # has one publisher (a gap after it: messages the middleware lost); None otherwise
    last_seq: int | None = None
    # the topic's publishers as the QoS thread last counted them (the ROS graph, once a
    # second; None until it has): asked in the take loop, the count takes a lock the
    # middleware's own threads hold, which on a starved CPU can stall the loop
    publishers: int | None = None


@dataclass
class _Deadline:
    """``--deadline``: the task's output topic, as the handler learns and reads it."""

    window: MakespanWindow
    msg_type: str | None = None  # from the ROS graph, once a publisher shows it (QoS thread)
    subscription: Any = None  # made by the ingest thread once the type is known
    given_up: bool = False  # a type without a header, or several: no deadline data

    @property
    def pending(self) -> bool:
        return self.msg_type is not None and self.subscription is None and not self.given_up


def node_name(name: str) -> str:
    """The handler's node name: ``edgerv_`` and its name, each other character ``_``."""
    clean = "".join(c if c.isalnum() else "_" for c in name)
    return f"edgerv_{clean}"


class RosIngest:
    """The handler's ROS node: subscriptions, the take loop, the verdict publishers (JSON;
    typed, with edgerv_msgs), the diagnostics (given ``health``, whose config's period is
    above 0) and /rosout."""

    def __init__(
        self,
        engine: Engine,
        name: str,
        reorder_window: float = 0.02,
        health: Health | None = None,
    ) -> None:
        from std_msgs.msg import String

        self.engine = engine
        self.node = rclpy.create_node(node_name(name))
        # --use-sim-time: ROS time from /clock (stamps of unstamped messages, the instant
        # everything is taken up to); None: the system clock's
        self.sim = engine.clock if isinstance(engine.clock, SimClock) else None
        if self.sim is not None:
            self._follow_clock(self.sim)
        self._clock_noted = False  # /clock published while on the system clock: said once
        self._string = String
        self.verdicts = self.node.create_publisher(
            String, VERDICT_TOPIC, QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        )
        self.wakeup = self.node.create_guard_condition(lambda: None)
        self.subs: dict[str, _Sub] = {}
        self.qos_problems: dict[str, int] = {}
        self.bad_messages: dict[str, int] = {}
        self._lost_logged: dict[str, float] = {}  # topic -> when its losses were last logged
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._qos_thread: threading.Thread | None = None
        self._version = -1
        self.ready = threading.Event()
        self.failed = False
        self._resubscribe: set[str] = set()  # topics the QoS thread wants re-created
        self.reorder_window = reorder_window
        self.deadline = _Deadline(engine.deadline) if engine.deadline is not None else None
        self.health = health if health is not None and health.config.period > 0 else None
        self.diagnostics: Any = None
        if self.health is not None:
            self.diagnostics = self.node.create_publisher(
                message_class("diagnostic_msgs/msg/DiagnosticArray"),
                DIAGNOSTICS_TOPIC,
                DIAGNOSTICS_QOS,
            )
        self._diagnostics_thread: threading.Thread | None = None
        self._diagnostics_failures = 0
        self.rosout: RosoutHandler | None = None
        self._rosout_logger: logging.Logger | None = None
        self.typed = self._typed_verdicts()
        self._last_verdicts_thread: threading.Thread | None = None
        self._last_verdicts_failures = 0
        self.outbox: Outbox | None = None  # the verdicts' lanes (main's): /diagnostics says

    # -- verdicts out ----------------------------------------------------------------------

    def _typed_verdicts(self) -> TypedVerdicts | None:
        """The typed verdict topics, or None (with a warning) without edgerv_msgs."""
        try:
            verdict_type = message_class("edgerv_msgs/msg/Verdict")
            array_type = message_class("edgerv_msgs/msg/VerdictArray")
        except ImportError:
            log.warning(BUILD_MSGS)
            return None
        try:  # (the typesupport libraries load here)
            return TypedVerdicts(self.node, self.engine, verdict_type, array_type)
        except Exception as exc:
            log.warning(
                "edgerv_msgs is installed but its typesupport does not load (%s): no typed "
                "verdicts (the JSON on %s goes on); rebuild it: `make install`",
                exc,
                VERDICT_TOPIC,
            )
            return None

    def write(self, handler: str, verdicts: Sequence[Verdict]) -> None:
        """A verdict sink: one std_msgs/String with a JSON object per verdict on
        /edgerv/verdicts (kept for compatibility), and each verdict typed on
        /edgerv/verdict (:class:`TypedVerdicts`)."""
        for v in verdicts:
            self.verdicts.publish(self._string(data=json.dumps(verdict_record(handler, v))))
        if self.typed is not None:
            self.typed.write(handler, verdicts)

    def write_bursts(self, handler: str, bursts: Sequence[Burst[Verdict]]) -> None:
        """Bursts a lane coalesced (this sink fell behind): on /edgerv/verdicts each one's
        first verdict, and its last with ``"coalesced": N``, the monitor's verdicts between
        them that are not published; typed, the first and the last."""
        string, publish = self._string, self.verdicts.publish
        for b in bursts:
            publish(string(data=json.dumps(verdict_record(handler, b.first))))
            if b.count > 1:
                last = verdict_record(handler, b.last)
                last["coalesced"] = b.between
                publish(string(data=json.dumps(last)))
        if self.typed is not None:
            self.typed.write(handler, [v for b in bursts for v in b.ends])

    def _last_verdicts_loop(self, typed: TypedVerdicts) -> None:
        """The /edgerv/last_verdicts thread: a look every LAST_VERDICTS_SECONDS (nothing
        to do unless a verdict was written or a monitor came or went), the first at once."""
        while True:
            try:
                typed.refresh()
            except Exception:  # retried next time; it must not stop the handler
                self._last_verdicts_failures += 1
                n = self._last_verdicts_failures
                if n in (1, 10, 100) or n % 1000 == 0:
                    log.exception("publishing %s failed (%d times)", LAST_VERDICTS_TOPIC, n)
            if self._stop.wait(LAST_VERDICTS_SECONDS):
                return

    # -- /rosout ---------------------------------------------------------------------------

    def forward_logs(self, logger: logging.Logger) -> RosoutHandler:
        """Send what ``logger`` (and its children) log to /rosout too, under this node's
        name, from the level Python's logging lets through (the node's rcutils logger is
        set to the same level: the default INFO would hold DEBUG back)."""
        ros_logger = self.node.get_logger()
        ros_logger.set_level(ros_severity(logger.getEffectiveLevel()))
        self.rosout = RosoutHandler(ros_logger.name)
        self._rosout_logger = logger
        logger.addHandler(self.rosout)
        return self.rosout

    # -- /clock (--use-sim-time) -----------------------------------------------------------

    def _follow_clock(self, sim: SimClock) -> None:
        """The clock takes /clock (raw, best effort as ROS's TimeSource: it matches any
        publisher) where time is read; the node's own clock follows it, as a node's with
        use_sim_time (/diagnostics' and /edgerv/last_verdicts' stamps)."""
        from rclpy.clock import ROSClock
        from rclpy.clock_type import ClockType
        from rclpy.time import Time
        from rclpy.time_source import TimeSource

        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=CLOCK_DEPTH,
            reliability=ReliabilityPolicy.BEST_EFFORT,
        )
        sub = self.node.create_subscription(
            message_class(CLOCK_TYPE), CLOCK_TOPIC, lambda _: None, qos, raw=True
        )
        clock, source = self.node.get_clock(), TimeSource()
        assert isinstance(clock, ROSClock)  # (a node's own clock is ROS time)
        source.attach_clock(clock)
        source.ros_time_is_active = True
        self._time_source = source  # (it holds the node's clock in ROS time)

        def follow(ns: int) -> None:
            clock.set_ros_time_override(Time(nanoseconds=ns, clock_type=ClockType.ROS_TIME))

        sim.attach(lambda: sub.handle.take_message(sub.msg_type, True), follow)

    # -- /diagnostics ----------------------------------------------------------------------

    def fingerprint(self) -> object:
        """A few counters that change whenever anything a diagnostic level reads may have
        (Health.settled): the engine's messages, routes and changes (evaluations, pressure,
        handoffs, reactions) and this node's counts; None with --deadline (its window's
        percentiles change with time alone)."""
        engine = self.engine
        if engine.deadline is not None:
            return None
        return (
            engine.router.seq,
            engine.routes_version,
            engine.changes,
            tuple(engine.lost.items()),
            tuple((t, s.publishers) for t, s in list(self.subs.items())),
            tuple(self.qos_problems.items()),
            tuple(self.bad_messages.items()),
            self.rosout.failures if self.rosout else 0,
            tuple(self.outbox.coalesced().items()) if self.outbox is not None else None,
        )

    def _reading_now(self, fingerprint: object = None) -> Reading:
        """The engine and this node's own counts, for the statuses."""
        publishers = {
            topic: sub.publishers
            for topic, sub in list(self.subs.items())
            if sub.publishers is not None
        }
        return read_engine(
            self.engine,
            publishers=publishers,
            incompatible=dict(self.qos_problems),
            bad=dict(self.bad_messages),
            rosout_failures=self.rosout.failures if self.rosout else 0,
            coalesced=self.outbox.coalesced() if self.outbox is not None else None,
            fingerprint=fingerprint,
        )

    def diagnose(self, health: Health, update: bool) -> list[Status] | None:
        """One check of the levels: the statuses published (all of them, as
        diagnostic_updater does) when ``update`` is due or a level changed, else None."""
        now = health.clock.monotonic()
        fingerprint = self.fingerprint()  # (taken before the reading: a change meanwhile
        if not update and health.settled(fingerprint, now):  # shows at the next look)
            return None  # nothing changed: the levels are those published
        levels = health.check(self._reading_now(fingerprint), now)
        if not update and not health.level_changed(levels):
            return None
        statuses = health.statuses()
        stamp = self.node.get_clock().now().nanoseconds
        self.diagnostics.publish(encode_diagnostic_array(statuses, stamp))
        health.published(statuses)
        return statuses

    def _diagnose_loop(self, health: Health) -> None:
        """The diagnostics thread: an update every period, a check of the levels between
        (published at once when one changed; a violation wakes it), within its CPU budget
        (health.Pacer). It takes the engine's lock only to copy a few hundred monitors at a
        time, and never waits for the take loop."""
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
            update = pacer.update_due(health.clock.monotonic())
            try:
                self.diagnose(health, update)
            except Exception:  # a failed update is retried; it must not stop the handler
                self._diagnostics_failures += 1
                n = self._diagnostics_failures
                if n in (1, 10, 100) or n % 1000 == 0:
                    log.exception("publishing /diagnostics failed (%d times)", n)
            pacer.worked(health.clock.monotonic(), time.thread_time() - started, update)

    # -- subscriptions ---------------------------------------------------------------------

    def _resolve_qos(self, topic: str, spec: QosSpec) -> tuple[QoSProfile, bool]:
        """Explicit settings as given; ``auto`` follows the publishers already there."""
        pubs = self.node.get_publishers_info_by_topic(topic)
        reliability = {
            "reliable": ReliabilityPolicy.RELIABLE,
            "best_effort": ReliabilityPolicy.BEST_EFFORT,
        }.get(spec.reliability)
        if reliability is None:  # auto: reliable unless a publisher only offers best effort
            best_effort = any(
                p.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for p in pubs
            )
            reliability = (
                ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE
            )
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

    def _subscribe(self, route: TopicRoute) -> _Sub:
        cls = message_class(route.msg_type)
        qos, auto = self._resolve_qos(route.topic, route.qos)
        sub = self.node.create_subscription(cls, route.topic, lambda _: None, qos, raw=True)
        log.info(
            "subscribed to %s (%s, %s, %s, depth %d)",
            route.topic,
            route.msg_type,
            qos.reliability.name.lower(),
            qos.durability.name.lower(),
            qos.depth,
        )
        return _Sub(
            route, tuple(route.fields), sub, compile_reader(route.msg_type, route.fields), qos, auto
        )

    def matched(self, topic: str) -> bool:
        """This handler's subscription to ``topic`` is matched with every publisher the
        ROS graph shows for it (with none, trivially): a receiver vouches for a silent
        topic by it (Engine.cut; docs/protocol.md, "Silent topics"). Called from the API's
        threads: the graph calls and the subscription take rclpy's handle locks."""
        sub = self.subs.get(topic)
        if sub is None:  # not subscribed yet (the ROS thread reconfigures) or any more
            return False
        try:
            return bool(sub.subscription.get_publisher_count() >= self.node.count_publishers(topic))
        except InvalidHandle:  # destroyed meanwhile
            return False

    def _reconfigure(self) -> None:
        version = self.engine.routes_version
        if version == self._version:
            return
        self._version = version
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

    def _watch_qos(self) -> None:
        """The QoS thread: graph queries take time, so they stay off the ingest thread."""
        while not self._stop.wait(QOS_CHECK_SECONDS):
            try:
                self._check_qos()
                self._learn_deadline_type()
                self._note_clock()
            except Exception:  # a failed check is retried; it must not stop the handler
                log.exception("QoS check failed")

    def _note_clock(self) -> None:
        """In the QoS thread: say once that /clock is published (a simulation, `edgerv
        replay`) while this handler keeps the system clock."""
        if self.sim is None and not self._clock_noted and self.node.count_publishers(CLOCK_TOPIC):
            self._clock_noted = True
            log.warning(SYSTEM_CLOCK_HINT)

    # -- --deadline ------------------------------------------------------------------------

    def _learn_deadline_type(self) -> None:
        """In the QoS thread, each second until a publisher shows it: the deadline topic's
        type. One that does not start with a std_msgs/msg/Header is an error, logged once:
        the handler goes on without deadline data."""
        d = self.deadline
        if d is None or d.msg_type is not None or d.given_up:
            return
        topic = d.window.topic
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
            d.given_up = True
            log.error("--deadline %s: %s: no deadline data", topic, problem)
            return
        d.msg_type = types[0]
        self.wake()  # the ingest thread subscribes

    def _subscribe_deadline(self, d: _Deadline) -> None:
        """In the ingest thread: the deadline topic's own raw subscription."""
        topic, msg_type = d.window.topic, str(d.msg_type)
        try:
            qos, _ = self._resolve_qos(topic, QosSpec())
            d.subscription = self.node.create_subscription(
                message_class(msg_type), topic, lambda _: None, qos, raw=True
            )
        except Exception as exc:  # carry on without deadline data
            d.given_up = True
            log.error("--deadline %s: cannot subscribe (%s): no deadline data", topic, exc)
            return
        log.info(
            "deadline: measuring the makespan of %s (%s) against %g ms",
            topic,
            msg_type,
            d.window.budget_ns / 1e6,
        )

    def _take_deadline(self, d: _Deadline) -> None:
        """The makespans of what waits on the deadline topic."""
        sub, window, topic = d.subscription, d.window, d.window.topic
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
                self._bad_message(topic, str(d.msg_type))
                continue
            source = info["source_timestamp"]
            if self.sim is not None:  # --use-sim-time: the publication in ROS time, as the stamp
                source = self.sim.published(source)
            if not window.add(source, stamp, taken) and window.unstamped == 1:
                log.warning("%s: header.stamp is 0 (nobody stamped it): not measured", topic)

    def _apply_resubscriptions(self) -> bool:
        """In the ingest thread: re-create the subscriptions the QoS thread asked for."""
        changed = False
        for topic in list(self._resubscribe):
            self._resubscribe.discard(topic)
            sub = self.subs.get(topic)
            if sub is not None:
                self.node.destroy_subscription(sub.subscription)
                self.subs[topic] = self._subscribe(sub.route)
                changed = True
        return changed

    def _check_qos(self) -> None:
        """Count publishers whose QoS cannot match ours; an ``auto`` subscription adapts."""
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
                if topic not in self._resubscribe:
                    log.warning(
                        "%s: a publisher offers only best-effort delivery: subscribing "
                        "best effort (qos.reliability is auto)",
                        topic,
                    )
                    self._resubscribe.add(topic)
                    self.wake()  # the ingest thread re-creates the subscription
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

    # -- the take loop ---------------------------------------------------------------------

    def _take_all(self, subs: list[_Sub]) -> tuple[list[Taken], int]:
        """One round over ``subs``: up to TAKE_PER_WAKE messages from each, in timestamp
        order across topics; and the instant (wall ns) before which everything that had
        reached these subscriptions is now taken: the round's start, or earlier where a
        subscription still holds messages (the source timestamp of the last one taken)."""
        batch: list[Taken] = []
        through = time.time_ns()
        version = self._version
        append = batch.append
        oldest_source: int | None = None
        delivered = 0  # subscriptions that had messages
        lags, lag_cap = self.engine.stamp_lag, int(self.engine.flush_after * 1e9)
        published = None if self.sim is None else self.sim.published  # ROS time of a source
        for sub in subs:
            topic = sub.route.topic
            handle, reader, cls = sub.subscription.handle, sub.reader, sub.subscription.msg_type
            take = handle.take_message
            got = take(cls, True)
            if got is None:
                continue
            delivered += 1
            first = got[1]["source_timestamp"]  # a subscription's first message is its oldest
            oldest_source = first if oldest_source is None else min(oldest_source, first)
            lag = 0  # the most a message here was published after its header stamp
            left = TAKE_PER_WAKE
            seqs: list[int] = []
            while got is not None:
                raw, info = got
                source = info["source_timestamp"]
                seqs.append(info["publication_sequence_number"])
                try:
                    values, stamp = reader(raw)
                except Exception:  # a malformed message is counted and skipped
                    self._bad_message(topic, sub.route.msg_type)
                else:
                    at = source if published is None else published(source)
                    if stamp and at - stamp > lag:
                        lag = at - stamp
                    # unstamped: 0; the bytes and the routes' version: read again if they change
                    append((stamp or at, topic, values, raw, version))
                left -= 1
                if not left:  # messages may be left: taken up to this one's publication
                    through = min(through, source)
                    break
                got = take(cls, True)
            if lag > lags.get(topic, 0):
                lags[topic] = min(lag, lag_cap)
            self._count_lost(sub, seqs)
        if oldest_source is not None:
            self.engine.ingest_lag = max(0.0, (time.time_ns() - oldest_source) / 1e9)
        if delivered > 1:
            batch.sort(key=_FIRST)  # one order across topics: by timestamp
        return batch, through

    def _count_lost(self, sub: _Sub, seqs: list[int]) -> None:
        """Messages the middleware lost before this handler took them (a subscription's
        queue that overflowed, best-effort delivery): the gaps in the publication sequence
        numbers of what a round took, counted while the topic has one publisher (the QoS
        thread's count, a second old at most; rclpy does not say which publisher sent a
        message: with several, their numbers interleave). A number that goes back (a new
        or restarted publisher) starts over."""
        last = sub.last_seq
        if sub.publishers != 1 or not all(map(lt, seqs, seqs[1:])):
            sub.last_seq = None  # several publishers, or one that started again
            return
        if last is not None and seqs[0] > last:
            lost = seqs[-1] - last - len(seqs)  # increasing: the gaps, summed
            if lost:
                topic = sub.route.topic
                n = self.engine.lost[topic] = self.engine.lost.get(topic, 0) + lost
                now = time.monotonic()
                if now - self._lost_logged.get(topic, -LOST_LOG_SECONDS) >= LOST_LOG_SECONDS:
                    self._lost_logged[topic] = now
                    log.warning(
                        "%s: %d message(s) lost before this handler took them, %d in all "
                        "(edgerv_messages_lost_total): its monitors' verdicts may differ "
                        "from a recording's; a larger qos.depth, or a handler less loaded",
                        topic,
                        lost,
                        n,
                    )
        sub.last_seq = seqs[-1] if last is None or seqs[0] > last else None

    def _ingest(self, items: list[Taken]) -> None:
        """Hand taken messages to the engine, read for the fields its routes have now.

        Messages wait in the reorder window while monitors come and go (a handoff adds
        some mid-stream), and the API changes the engine's routes from another thread:
        a message read for an older set of fields is read again from its bytes, and the
        engine refuses a batch read for routes it no longer has (then this retries)."""
        while items:
            if self.engine.routes_version != self._version:
                self._reconfigure()  # the loop rebuilds its wait set on its next turn
            version = self._version
            batch = []
            for stamp, topic, values, raw, read_for in items:
                if read_for != version:
                    sub = self.subs.get(topic)
                    if sub is None:
                        continue  # no monitor reads the topic any more
                    try:
                        values = sub.reader(raw)[0]
                    except Exception:  # a malformed message is counted and skipped
                        self._bad_message(topic, sub.route.msg_type)
                        continue
                batch.append((stamp, topic, values))
            if self.engine.ingest(batch, routes_version=version):
                return
            items = [(s, t, v, r, -1) for s, t, v, r, _ in items]  # all read again

    def _bad_message(self, topic: str, msg_type: str) -> None:
        n = self.bad_messages[topic] = self.bad_messages.get(topic, 0) + 1
        if n in (1, 10, 100) or n % 1000 == 0:
            log.warning("%s: %d messages could not be read as %s", topic, n, msg_type)

    def _drained(self, through: int, reorder: ReorderWindow[Taken] | None) -> None:
        """Everything that reached this handler before ``through`` (wall ns) is taken:
        it is in the engine once no older stamp waits in the reorder window. The
        monitors' clocks and a handoff's cut wait for this instant (engine.drained_at)."""
        if self.sim is not None:  # in ROS time, as the stamps
            through = self.sim.ros_ns(through)
        if reorder is not None and reorder.pending:
            through = min(through, reorder.pending[0][0])
        drained = self.engine.drained_at
        if drained is None or through > drained:
            self.engine.drained_at = through

    def _loop(self) -> None:
        stack = contextlib.ExitStack()
        wait_set: Any = None
        handles: list[Any] = []
        version = None
        # The window outlives reconfigurations: draining it early would reorder.
        reorder: ReorderWindow[Taken] | None = (
            ReorderWindow(self.reorder_window) if self.reorder_window > 0 else None
        )
        several = False  # one topic is delivered in order: only several need the window
        ingest, taken = self._ingest, self.engine.taken
        deadline = self.deadline
        timed: _Deadline | None = None  # --deadline once subscribed: waited on too
        waited: list[Any] = []
        burst = True  # the last round took several messages: more may be gathering
        try:
            while not self._stop.is_set():
                if self._resubscribe and self._apply_resubscriptions():
                    version = None  # a subscription was re-created: rebuild the wait set
                if deadline is not None and deadline.pending:
                    self._subscribe_deadline(deadline)
                    version = None
                if version != self.engine.routes_version:
                    stack.close()  # the wait set is rebuilt for the new subscriptions
                    self._reconfigure()
                    version = self._version
                    stack = contextlib.ExitStack()
                    handles = [s.subscription.handle for s in self.subs.values()]
                    subscribed = deadline is not None and deadline.subscription is not None
                    timed = deadline if subscribed else None
                    waited = [*handles, timed.subscription.handle] if timed else handles
                    for h in (*waited, self.wakeup.handle, self.node.context.handle):
                        stack.enter_context(h)  # keeps each alive while the wait set holds it
                    wait_set = _rclpy.WaitSet(len(waited), 1, 0, 0, 0, 0, self.node.context.handle)
                    several = len(handles) > 1
                    self.ready.set()
                wait_set.clear_entities()
                for h in waited:
                    wait_set.add_subscription(h)
                wait_set.add_guard_condition(self.wakeup.handle)
                holding = reorder is not None and reorder.pending
                timeout = self.reorder_window if holding else 0.1
                wait_set.wait(int(timeout * 1e9))  # 100 ms at most: reconfiguration goes on
                waited_at = time.time_ns()
                if reorder is not None:
                    ingest(reorder.due(time.monotonic()))
                ready = set(wait_set.get_ready_entities("subscription"))
                if timed is not None and timed.subscription.handle.pointer in ready:
                    ready.discard(timed.subscription.handle.pointer)  # not a monitor's topic
                    self._take_deadline(timed)
                if not ready:  # (the monitors' topics: the deadline's does not count)
                    self._drained(waited_at, reorder)  # everything here was taken
                    continue
                if burst:  # let a burst gather: fewer, larger batches
                    time.sleep(COALESCE_SECONDS)
                # Every round takes from every subscription, not only from those ready at
                # the wait: a topic that was quiet then is not left behind while the
                # others keep coming (it would reach the monitors later than the reorder
                # window allows), and a round over all of them says how far this
                # handler has taken everything (the monitors' clocks wait for that).
                subs, taking = list(self.subs.values()), self._version
                batch, through = self._take_all(subs)
                while batch and not self._stop.is_set():  # while messages keep coming
                    # A round that took one message is no burst: back to the wait, which
                    # returns at once if more came meanwhile (at a robot's rates, a round
                    # again over every subscription would take nothing).
                    burst = len(batch) > 1
                    if reorder is not None and (several or reorder.pending):
                        taken(batch)  # a monitor being received learns its cut sooner
                        ingest(reorder.add(batch, time.monotonic()))
                    else:
                        ingest(batch)
                    self._drained(through, reorder)
                    if timed is not None:  # an overloaded handler measures on, too
                        self._take_deadline(timed)
                    if self._version != taking:  # _ingest subscribed anew (a monitor came)
                        subs, taking = list(self.subs.values()), self._version
                    if not burst:
                        break
                    batch, through = self._take_all(subs)
                self._drained(through, reorder)
        finally:
            if reorder is not None:
                ingest(reorder.drain())  # nothing taken is lost at shutdown
            stack.close()

    def start(self, on_failure: Callable[[], None]) -> None:
        """Run the take loop in a thread; ``on_failure`` is called if it dies."""
        self._thread = threading.Thread(
            target=self._run, args=(on_failure,), name="edgerv-ingest", daemon=True
        )
        self._thread.start()
        self._qos_thread = threading.Thread(target=self._watch_qos, name="edgerv-qos", daemon=True)
        self._qos_thread.start()
        if self.health is not None:
            self._diagnostics_thread = threading.Thread(
                target=self._diagnose_loop,
                args=(self.health,),
                name="edgerv-diagnostics",
                daemon=True,
            )
            self._diagnostics_thread.start()
        if self.typed is not None:
            self._last_verdicts_thread = threading.Thread(
                target=self._last_verdicts_loop,
                args=(self.typed,),
                name="edgerv-last-verdicts",
                daemon=True,
            )
            self._last_verdicts_thread.start()

    def _run(self, on_failure: Callable[[], None]) -> None:
        try:
            self._loop()
        except Exception:
            log.exception("the ingest loop failed: stopping the handler")
            self.failed = True
            self.ready.set()
            on_failure()

    def wake(self) -> None:
        self.wakeup.trigger()

    def stop(self) -> None:
        self._stop.set()
        self.wake()
        if self.health is not None:
            self.health.changed.set()  # the diagnostics thread waits on it
        threads = (
            self._thread,
            self._qos_thread,
            self._diagnostics_thread,
            self._last_verdicts_thread,
        )
        for thread in threads:
            if thread is not None:
                thread.join(timeout=10)

    def close(self) -> None:
        if self.rosout is not None and self._rosout_logger is not None:
            self._rosout_logger.removeHandler(self.rosout)  # before the node goes
        if self.sim is not None:
            self.sim.detach()
        self.node.destroy_node()
