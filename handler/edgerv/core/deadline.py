"""The robot's real-time task and its deadline, as a handler measures it (``--deadline``).

``edgerv handler --deadline TOPIC=DURATION``: each message on TOPIC is an output
of the robot's real-time task, and its ``header.stamp`` is the instant the input
it was computed from was captured (a velocity command stamped with its camera
frame's stamp). The task's **makespan** for that message is its DDS source
timestamp (the instant it was published) minus its ``header.stamp``; it misses
the deadline when the makespan is longer than DURATION (the budget).

:class:`MakespanWindow` keeps the makespans of the last ``window`` of publish
time and answers with their count, misses, median, 95th percentile, maximum and
the last one, and the 95th percentile of the task's *service times* (below): the
reading the orchestration policy weighs against the budget
(:mod:`edgerv.control.placement`, "deadline pressure"). No ROS here: the handler's
ROS layer feeds it what it takes.

An output's **service time** is its makespan less the time its input waited for the
task's previous output: its publication minus the later of its ``header.stamp`` and the
previous output's publication. A task that handles its inputs one at a time, in order,
has service times equal to its makespans while it keeps up; once it falls behind, its
outputs queue behind late ones and their makespans grow with the backlog, while their
service times stay what sharing its CPU makes them (the planner sizes what to move from
them, :func:`edgerv.core.planner.calm_cpu`).
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypedDict

from edgerv.core.diagnostics import Diagnostic, InputError, Location
from edgerv.core.documents import topic_name
from edgerv.core.language.lexer import UNITS, duration_ns

WINDOW_NS = 2_000_000_000  # the makespans of the last 2 s of publish time
MAX_ENTRIES = 100_000  # at most this many makespans in the window (the oldest go first)


@dataclass(frozen=True)
class DeadlineOption:
    """``--deadline TOPIC=DURATION``: the task's output topic and its budget."""

    topic: str
    budget_ns: int
    # written without a leading "/" (``cmd_vel=125ms``): in the namespace of the robot
    # whose monitors the handler runs, as a ROS node resolves a relative name in its own
    relative: bool = False


def parse_deadline(text: str, flag: str = "--deadline") -> DeadlineOption:
    """``/cmd_vel=125ms`` (a duration as the assertion language writes it); raises
    :class:`InputError` located at ``flag``."""
    topic, eq, duration = (part.strip() for part in text.partition("="))
    if not eq or not topic or not duration:
        raise _bad(flag, f"'{text}' is not TOPIC=DURATION", "e.g. --deadline /cmd_vel=125ms")
    name = topic_name(topic)
    if name is None:
        raise _bad(flag, f"'{topic}' is not a ROS topic name", "e.g. --deadline /cmd_vel=125ms")
    budget = duration_ns(duration)
    if budget is None:
        raise _bad(
            flag,
            f"'{duration}' is not a duration",
            f"a number and its unit written together ({', '.join(UNITS)}), e.g. 125ms",
        )
    if budget <= 0:
        raise _bad(flag, f"the deadline of {name} must be longer than 0, not {duration}")
    return DeadlineOption(name, budget, relative=not topic.startswith(("/", "~")))


def _bad(flag: str, message: str, hint: str | None = None) -> InputError:
    return InputError([Diagnostic(Location(flag), message, hint=hint)])


class DeadlineLoad(TypedDict):
    """``deadline`` in ``GET /v1/load``: the window's reading, in milliseconds.

    The four makespan figures are null while the window is empty."""

    topic: str
    budgetMs: float
    windowSeconds: float
    count: int  # makespans in the window
    misses: int  # of those, longer than the budget
    p50Ms: float | None
    p95Ms: float | None
    maxMs: float | None
    lastMs: float | None  # the newest in the window
    serviceP95Ms: float | None  # the 95th percentile of their service times
    missesTotal: int  # since the handler started
    messagesTotal: int  # messages measured since the handler started


@dataclass(frozen=True)
class MakespanStats:
    """The makespans of one window, in nanoseconds (None: the window is empty)."""

    count: int
    misses: int
    p50: int | None
    p95: int | None
    max: int | None
    last: int | None
    service_p95: int | None = None  # the 95th percentile of the service times


def percentile(ordered: list[int], q: float) -> int:
    """The nearest-rank ``q`` quantile of a non-empty sorted list."""
    return ordered[max(0, math.ceil(q * len(ordered)) - 1)]


def _ms(ns: int | None) -> float | None:
    return None if ns is None else round(ns / 1e6, 3)


class MakespanWindow:
    """Makespans of the last ``window_ns`` of publish time. Thread-safe.

    The window ends at the newest publish time plus the (local, monotonic) time
    since that message was taken: when the task stops publishing, its old
    makespans leave the window as time goes on, without comparing the robot's
    clock with this handler's.
    """

    def __init__(
        self,
        topic: str,
        budget_ns: int,
        window_ns: int = WINDOW_NS,
        max_entries: int = MAX_ENTRIES,
        relative: bool = False,
    ) -> None:
        if budget_ns <= 0 or window_ns <= 0:
            raise ValueError("the budget and the window must be longer than 0")
        self.topic = topic  # the topic measured now
        self.name = topic  # as --deadline named it (absolute)
        self.relative = relative  # (DeadlineOption.relative)
        self.budget_ns = budget_ns
        self.window_ns = window_ns
        # (published, makespan, service time)
        self._entries: deque[tuple[int, int, int]] = deque(maxlen=max_entries)
        self._newest: tuple[int, int] | None = None  # (published, taken) of the newest
        self._lock = threading.Lock()
        self.messages_total = 0
        self.misses_total = 0
        self.unstamped = 0  # messages whose header nobody stamped: not measured
        # called (outside the lock, on the thread that adds) after each makespan that
        # misses the budget: the control API wakes who waits for one (GET /v1/deadline)
        self.on_miss: Callable[[], None] | None = None

    def add(self, published_ns: int, stamp_ns: int, taken_ns: int) -> bool:
        """One output of the task: published at ``published_ns`` (its source timestamp),
        computed from an input captured at ``stamp_ns`` (its header.stamp), taken here at
        ``taken_ns`` (monotonic). False (not measured) for a header stamped 0."""
        with self._lock:
            if stamp_ns == 0:
                self.unstamped += 1
                return False
            span = published_ns - stamp_ns
            previous = self._newest[0] if self._newest is not None else stamp_ns
            service = published_ns - max(stamp_ns, min(previous, published_ns))
            self._entries.append((published_ns, span, service))
            if self._newest is None or published_ns >= self._newest[0]:
                self._newest = (published_ns, taken_ns)
            self.messages_total += 1
            missed = span > self.budget_ns
            self.misses_total += missed
        if missed and self.on_miss is not None:
            self.on_miss()
        return True

    def retarget(self, topic: str) -> None:
        """Measure ``topic`` from now on: the makespans read so far leave the window (they
        were another topic's); the totals since the handler started stay."""
        with self._lock:
            self.topic = topic
            self._entries.clear()
            self._newest = None

    def resolved(self, namespace: str | None) -> str:
        """The topic to measure for a handler running the monitors of the robot of
        ``namespace`` (None: no robot's, or several robots'): a relative name is
        resolved in it, an absolute one is as given."""
        return f"{namespace}{self.name}" if self.relative and namespace else self.name

    def _evict(self, now_ns: int) -> None:
        if self._newest is None:
            return
        published, taken = self._newest
        horizon = published + max(0, now_ns - taken) - self.window_ns
        entries = self._entries
        while entries and entries[0][0] <= horizon:
            entries.popleft()

    def stats(self, now_ns: int) -> MakespanStats:
        """The reading at ``now_ns`` (monotonic, the clock of :meth:`add`'s ``taken_ns``)."""
        with self._lock:
            self._evict(now_ns)
            spans = [span for _, span, _ in self._entries]
            services = [service for _, _, service in self._entries]
        if not spans:
            return MakespanStats(0, 0, None, None, None, None)
        ordered = sorted(spans)
        return MakespanStats(
            count=len(spans),
            misses=sum(1 for s in spans if s > self.budget_ns),
            p50=percentile(ordered, 0.5),
            p95=percentile(ordered, 0.95),
            max=ordered[-1],
            last=spans[-1],
            service_p95=percentile(sorted(services), 0.95),
        )

    def report(self, now_ns: int) -> DeadlineLoad:
        """The ``deadline`` of the load report."""
        s = self.stats(now_ns)
        with self._lock:
            misses_total, messages_total = self.misses_total, self.messages_total
        return DeadlineLoad(
            topic=self.topic,
            budgetMs=self.budget_ns / 1e6,
            windowSeconds=self.window_ns / 1e9,
            count=s.count,
            misses=s.misses,
            p50Ms=_ms(s.p50),
            p95Ms=_ms(s.p95),
            maxMs=_ms(s.max),
            lastMs=_ms(s.last),
            serviceP95Ms=_ms(s.service_p95),
            missesTotal=misses_total,
            messagesTotal=messages_total,
        )
