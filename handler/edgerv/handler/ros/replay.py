"""`edgerv replay`: publish a recorded run as real ROS 2 messages, as it was run.

Each event is published on its topic with the message type the monitors give that
topic, in timestamp order (ties in file order), at the pace of its timestamps
(`--rate` scales it, as `ros2 bag play --rate`; `--interval` puts a fixed pause
between messages instead), each message as recorded: a header stamp is published as
it was. And `/clock` (`rosgraph_msgs/msg/Clock`) says the recorded time, as `ros2
bag play --clock` does: the stamp of each message just before it, in between as time
passes at the replay's pace (every 10 ms), and at the end the trace's last stamp. A
handler run with `--use-sim-time` then has the recorded time for its clock, and its
timed monitors give the verdicts and stamps of `edgerv check` on the same file
(docs/handler.md, "Sim time"). A stand-in for the robot when trying monitors or a
handler without one.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from edgerv.core.diagnostics import Diagnostic, InputError, Location
from edgerv.core.documents import load_monitors
from edgerv.core.traces import Trace, TraceEvent

CLOCK_SECONDS = 0.01  # /clock is published at least this often while time passes
CLOCK_WAIT = 1.0  # seconds to wait for a /clock subscriber once the topics have theirs
END_REPEATS = 5  # the last /clock is sent this many times (best-effort subscribers)
INT32 = range(-(2**31), 2**31)


def fill(msg: Any, data: dict[str, Any], where: str = "msg") -> Any:
    """Set the fields of an rclpy message from nested dicts (numbers widened to float), an
    array of messages from a list of dicts (``"wheels": [{"rpm": 5.0}]``)."""
    for key, value in data.items():
        if not hasattr(msg, key):
            raise ValueError(f"{where} has no field '{key}'")
        current = getattr(msg, key)
        if isinstance(value, dict):
            fill(current, value, f"{where}.{key}")
        elif isinstance(current, float) and isinstance(value, int) and not isinstance(value, bool):
            setattr(msg, key, float(value))
        elif isinstance(value, list):
            setattr(msg, key, _elements(msg, key, value, f"{where}.{key}"))
        else:
            setattr(msg, key, value)
    return msg


def _elements(msg: Any, key: str, items: list[Any], where: str) -> list[Any]:
    """The elements of ``msg``'s array field ``key`` from JSON: messages filled from dicts,
    integers widened for a float array, others as they are."""
    from rosidl_parser.definition import AbstractNestedType, BasicType, NamespacedType  # type: ignore[import-untyped]

    slot = msg.SLOT_TYPES[list(msg.get_fields_and_field_types()).index(key)]
    element = slot.value_type if isinstance(slot, AbstractNestedType) else None
    if isinstance(element, NamespacedType):
        module = importlib.import_module(".".join(element.namespaces))
        cls = getattr(module, element.name)
        out = []
        for i, item in enumerate(items):
            if not isinstance(item, dict):
                raise ValueError(f"{where}[{i}] must be an object (a {element.name} message)")
            out.append(fill(cls(), item, f"{where}[{i}]"))
        return out
    if isinstance(element, BasicType) and element.typename in ("float", "double"):
        return [float(v) if type(v) is int else v for v in items]
    return items


def positive_rate(text: str) -> float:
    with contextlib.suppress(ValueError):
        if 0 < (value := float(text)) < math.inf:
            return value
    raise argparse.ArgumentTypeError(f"'{text}' is not a rate above 0 (1: the recorded pace)")


def pause(text: str) -> float:
    with contextlib.suppress(ValueError):
        if 0 <= (value := float(text)) < math.inf:
            return value
    raise argparse.ArgumentTypeError(f"'{text}' is not a number of seconds from 0")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("trace", help="a JSON Lines trace")
    p.add_argument(
        "--monitors",
        required=True,
        metavar="FILE_OR_DIR",
        help="the monitors whose signals give each topic its message type",
    )
    pace = p.add_mutually_exclusive_group()
    pace.add_argument(
        "--rate",
        type=positive_rate,
        default=1.0,
        metavar="R",
        help="publish at R times the recorded pace (default 1: as recorded; 2: twice as "
        "fast), as `ros2 bag play --rate`",
    )
    pace.add_argument(
        "--interval",
        type=pause,
        metavar="SECONDS",
        help="publish the messages this far apart instead of at their recorded pace "
        "(/clock still says the recorded time)",
    )
    p.add_argument(
        "--no-clock",
        action="store_true",
        help="do not publish /clock (e.g. a simulator publishes it); by default /clock "
        "says the recorded time, for a handler run with --use-sim-time",
    )
    p.add_argument(
        "--wait",
        type=pause,
        default=10.0,
        metavar="SECONDS",
        help="wait this long for a subscriber on every topic (default 10)",
    )


@dataclass(frozen=True)
class Schedule:
    """When each event is published (seconds after the start) and the recorded time at
    any moment: the stamps at the replay's pace, or ``interval`` apart with time
    stretched linearly in between; after the last event, time runs on to ``end`` (the
    trace's last stamp, of any topic) at the same pace (one interval). Pure."""

    stamps: Sequence[int]  # the events', in order
    rate: float = 1.0
    interval: float | None = None
    end: int | None = None

    def due(self, i: int) -> float:
        """Seconds after the start at which the i-th event is published."""
        if self.interval is not None:
            return i * self.interval
        return (self.stamps[i] - self.stamps[0]) / 1e9 / self.rate

    @property
    def last(self) -> int:
        """The recorded time the replay ends at."""
        return max(self.stamps[-1], self.end) if self.end is not None else self.stamps[-1]

    @property
    def finish(self) -> float:
        """Seconds after the start at which the recorded time reaches :attr:`last`."""
        n, tail = len(self.stamps), self.last - self.stamps[-1]
        if not tail:
            return self.due(n - 1)
        if self.interval is not None:
            return self.due(n - 1) + self.interval
        return self.due(n - 1) + tail / 1e9 / self.rate

    def time_at(self, i: int, seconds: float) -> int:
        """The recorded time at ``seconds`` after the start, after event ``i - 1`` was
        published and before event ``i`` is (``i == len(stamps)``: the tail): between
        their stamps, proportionally, never reaching the next one."""
        n = len(self.stamps)
        before = self.stamps[i - 1]
        after, at, until = (
            (self.stamps[i], self.due(i - 1), self.due(i))
            if i < n
            else (self.last, self.due(n - 1), self.finish)
        )
        if after <= before or until <= at:
            return before
        ros = before + int((after - before) * min(1.0, (seconds - at) / (until - at)))
        return min(max(ros, before), after - 1)


def clock_message(cls: Any, ns: int) -> Any:
    """A rosgraph_msgs/msg/Clock saying ``ns``; ValueError if it does not fit (int32
    seconds, as builtin_interfaces/Time)."""
    sec, nanosec = divmod(ns, 1_000_000_000)
    if sec not in INT32:
        raise ValueError(f"the time {ns} ns does not fit a ROS time (int32 seconds)")
    msg = cls()
    msg.clock.sec, msg.clock.nanosec = sec, nanosec
    return msg


def read_events(args: argparse.Namespace) -> tuple[dict[str, str], list[TraceEvent], int | None]:
    """The topics' types, the events in stamp order and the trace's last stamp."""
    specs = load_monitors(args.monitors)
    types = {s.topic: s.msg_type for spec in specs for s in spec.signals.values()}
    trace = Trace(Path(args.trace))
    try:
        trace.inspect(types)
        events = sorted(trace.events(types), key=lambda e: e.stamp)
        end = trace.end
    finally:
        trace.close()
    if not events:
        raise InputError(
            [Diagnostic(Location(args.trace), "no message of a topic the monitors read")]
        )
    return types, events, end


def run(args: argparse.Namespace) -> int:
    try:
        types, events, end = read_events(args)
    except InputError as exc:
        print(exc, file=sys.stderr)
        return 2
    schedule = Schedule([e.stamp for e in events], args.rate, args.interval, end)
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rclpy.utilities import try_shutdown

    from edgerv.handler.ros.logs import ros_log_problem
    from edgerv.handler.ros.messages import message_class

    ClockMsg = message_class("rosgraph_msgs/msg/Clock")

    for event in [] if args.no_clock else events:  # each stamp fits /clock: checked first
        if event.stamp // 1_000_000_000 not in INT32:
            where = event.where if event.where.line else Location(args.trace)
            problem = f"the stamp {event.stamp} does not fit a ROS time (int32 seconds)"
            print(Diagnostic(where, problem).render(), file=sys.stderr)
            return 2
    no_files = ros_log_problem()
    if no_files:
        print(f"edgerv replay: {no_files}", file=sys.stderr)
    rclpy.init(args=["edgerv", "--ros-args", "--disable-external-lib-logs"] if no_files else None)
    node = rclpy.create_node("edgerv_replay")
    try:
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        classes = {t: message_class(m) for t, m in types.items()}
        pubs = {t: node.create_publisher(classes[t], t, qos) for t in types}
        clock = None
        if not args.no_clock:
            clock = node.create_publisher(
                ClockMsg, "/clock", QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
            )
        wait_for_subscribers(pubs, clock, args.wait)

        def make(event: TraceEvent) -> Any:
            try:
                return fill(classes[event.topic](), event.msg)
            except (ValueError, TypeError, AssertionError) as exc:
                where = event.where if event.where.line else Location(args.trace)
                problem = f"cannot make a {types[event.topic]} message: {exc}"
                raise InputError([Diagnostic(where, problem)]) from None

        tick: Callable[[int], None] = (
            (lambda _ns: None)
            if clock is None
            else (lambda ns: clock.publish(clock_message(ClockMsg, ns)))
        )
        try:
            took = publish(schedule, events, make, pubs, tick, with_clock=clock is not None)
        except InputError as exc:
            print(exc, file=sys.stderr)
            return 2
        recorded = (schedule.last - events[0].stamp) / 1e9
        print(
            f"edgerv replay: published {len(events)} messages: {recorded:.3f} s of the "
            f"recording in {took:.3f} s",
            file=sys.stderr,
        )
        return 0
    finally:
        node.destroy_node()
        try_shutdown()


def wait_for_subscribers(pubs: dict[str, Any], clock: Any, wait: float) -> None:
    """Until every topic has a subscriber (at most ``wait`` seconds), then briefly for one
    on /clock (a handler with --use-sim-time subscribes with its topics)."""
    deadline = time.monotonic() + wait
    while any(p.get_subscription_count() == 0 for p in pubs.values()):
        if time.monotonic() > deadline:
            missing = [t for t, p in pubs.items() if p.get_subscription_count() == 0]
            print(
                f"edgerv replay: no subscriber on {', '.join(missing)} after "
                f"{wait:g} s; publishing anyway",
                file=sys.stderr,
            )
            break
        time.sleep(0.05)
    if clock is not None:
        until = time.monotonic() + CLOCK_WAIT
        while clock.get_subscription_count() == 0 and time.monotonic() < until:
            time.sleep(0.05)
        if clock.get_subscription_count() == 0:
            print(
                "edgerv replay: nobody subscribes to /clock: a handler on the system clock "
                "reads recorded header stamps against its own time (timed monitors need "
                "`edgerv handler --use-sim-time` to give the verdicts of `edgerv check`)",
                file=sys.stderr,
            )
    time.sleep(0.3)  # let discovery settle on both sides


def publish(
    schedule: Schedule,
    events: Sequence[TraceEvent],
    make: Callable[[TraceEvent], Any],
    pubs: dict[str, Any],
    tick: Callable[[int], None],
    with_clock: bool,
) -> float:
    """Publish each event's message (``make``) when it is due, /clock before it and while
    time passes; the seconds it took, from the first message to the end."""
    start = time.monotonic()
    said: int | None = None  # the last time /clock said

    def say(ns: int) -> None:
        nonlocal said
        if said is None or ns > said:
            tick(ns)
            said = ns

    def wait_until(i: int, due: float) -> None:
        """Sleep until ``due``, saying the time every CLOCK_SECONDS meanwhile."""
        while (left := due - (time.monotonic() - start)) > 0:
            if with_clock and i > 0:
                say(schedule.time_at(i, time.monotonic() - start))
            time.sleep(min(left, CLOCK_SECONDS) if with_clock else left)

    for i, event in enumerate(events):
        msg = make(event)  # (raises InputError: a message its type cannot hold)
        wait_until(i, schedule.due(i))
        say(event.stamp)  # the recorded time, just before the message of that time
        pubs[event.topic].publish(msg)
    n = len(events)
    if schedule.last > events[-1].stamp:
        wait_until(n, schedule.finish)
    took = time.monotonic() - start
    for _ in range(END_REPEATS if with_clock else 0):
        tick(schedule.last)  # the end, again: a best-effort subscriber may lose one
        time.sleep(0.1)
    time.sleep(0.5)  # reliable delivery of the last messages before the node goes
    return took
