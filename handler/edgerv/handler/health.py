"""A handler's health as ROS 2 diagnostics report it, without ROS: one status per
active monitor and one for the handler, built from the engine's state and the time.

:func:`read_engine` takes what the statuses need from the engine's reading
(:mod:`edgerv.handler.reading`, the one read path: its lock taken a few hundred monitors
at a time); :class:`Health` remembers what it saw before
(when a monitor was last violated, when its events last came, the counters a period
ago) and turns a reading into :class:`Status` records: plain data that the ROS layer
(:mod:`edgerv.handler.ros.diagnostics`) publishes on ``/diagnostics`` as
``diagnostic_msgs/msg/DiagnosticArray``. :class:`Pacer` says when the next reading is
due. docs/handler.md, "Topics", says what each level and value means.

A monitor's status is named ``edgerv: <monitor>`` whatever handler runs it (a moved
monitor stays one entry in the tools, updated by its new handler, whose name is the
status's ``hardware_id``); the handler's own is ``edgerv handler: <name>``.
"""

from __future__ import annotations

import bisect
import itertools
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Collection, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import NamedTuple, TypeVar

from edgerv.core.deadline import DeadlineLoad
from edgerv.core.pipeline import Verdict
from edgerv.handler.clock import Clock, SystemClock
from edgerv.handler.engine import HIGH_WATER, Engine
from edgerv.handler.reading import MonitorReading, read

T = TypeVar("T")

MONITOR_PREFIX = "edgerv: "
HANDLER_PREFIX = "edgerv handler: "
# Between two periodic updates the levels are checked this often, so that a change of
# level is published at once (a violation wakes the check sooner: Health.write).
CHECK_SECONDS = 0.25
# Diagnostics use at most this share of one CPU on average: with thousands of monitors a
# publication is made less often than the period asks (Pacer); and, within one, at most
# this share of any stretch of BREATH_SECONDS of its CPU (Breather): a check and an update
# of 10,000 monitors (~0.3 s of Python) are spread over seconds, not taken at once from
# the take loop, which shares the interpreter's lock with them (bench/scale.py's p99).
CPU_BUDGET = 0.05
BREATH_SECONDS = 0.002
BREATH_EVERY = 256  # monitors (or statuses) between two looks at the CPU spent
# A STALE monitor says "no event for over X", X the stale seconds, then each of these
# (1 min, 10 min, 1 h, 1 d) it passes: an age that changes a status only at these
# instants, so an idle handler's statuses stay as published between them (Health.due)
STALE_STEPS = (60.0, 600.0, 3600.0, 86400.0)


class Level(IntEnum):
    """``diagnostic_msgs/msg/DiagnosticStatus``'s levels, by their values there."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


# Which level wins when several conditions hold: ERROR, then STALE, then WARN. A held
# violation outranks silence (a monitor violated and then cut off must still show the
# violation), and silence outranks a warning (a monitor that receives nothing checks
# nothing: its warnings, such as a topic without a publisher, are given as the reason).
RANK = {Level.OK: 0, Level.WARN: 1, Level.STALE: 2, Level.ERROR: 3}


def worst(levels: Iterable[Level]) -> Level:
    return max(levels, key=RANK.__getitem__, default=Level.OK)


@dataclass(frozen=True)
class DiagnosticsConfig:
    """``--diagnostics-period``, ``--diagnostics-hold``, ``--diagnostics-stale``."""

    period: float = 1.0  # seconds between updates; 0: no /diagnostics
    hold: float = 10.0  # a violation shows as ERROR this long
    stale: float = 10.0  # a monitor without an event this long is STALE; 0: never


@dataclass(frozen=True)
class Status:
    """One ``diagnostic_msgs/msg/DiagnosticStatus``; ``values`` are its KeyValues."""

    level: Level
    name: str
    message: str
    hardware_id: str
    values: tuple[tuple[str, str], ...]


@dataclass(frozen=True)
class Reading:
    """The handler at one instant: its active monitors and its counters. The ROS
    layer's own counts come with it (absent without ROS)."""

    monitors: tuple[MonitorReading, ...]  # the active ones (all, or some: Health.check_some)
    defined: int
    active: int  # monitors active here (all of them)
    messages: int  # messages ingested, all topics
    lost: Mapping[str, int]  # topic -> messages lost before the handler took them
    ingest_lag: float
    deadline: DeadlineLoad | None = None
    # topic -> its publishers as the ROS layer last counted them (absent: not yet counted)
    publishers: Mapping[str, int] = field(default_factory=dict)
    incompatible: Mapping[str, int] = field(default_factory=dict)  # publishers, bad QoS
    bad: Mapping[str, int] = field(default_factory=dict)  # topic -> unreadable messages
    rosout_failures: int = 0  # log lines that could not be sent to /rosout
    # verdict sink -> verdicts it got only as a burst's count (it fell behind: outbox.py)
    coalesced: Mapping[str, int] = field(default_factory=dict)
    # what the reading was made from, in a few counters that change whenever anything a
    # level reads may have (the ROS layer's :meth:`~edgerv.handler.ros.diagnostics.Diagnostics.
    # fingerprint`); None: not known, every check reads everything
    fingerprint: object = None


def read_engine(
    engine: Engine,
    publishers: Mapping[str, int] | None = None,
    incompatible: Mapping[str, int] | None = None,
    bad: Mapping[str, int] | None = None,
    rosout_failures: int = 0,
    coalesced: Mapping[str, int] | None = None,
    fingerprint: object = None,
    names: Collection[str] | None = None,
) -> Reading:
    """A :class:`Reading` of ``engine``'s active monitors (:func:`edgerv.handler.reading.
    read`, paced: the lock held a few hundred monitors at a time), with the ROS layer's
    counts;
    of those of ``names`` only, if given."""
    engine_reading = read(engine, names, paced=True)
    deadline = engine.deadline.report(time.monotonic_ns()) if engine.deadline else None
    return Reading(
        engine_reading.active(),
        engine_reading.defined,
        engine_reading.running,
        sum(engine_reading.messages.values()),
        engine_reading.lost,
        engine_reading.ingest_lag,
        deadline,
        dict(publishers or {}),
        dict(incompatible or {}),
        dict(bad or {}),
        rosout_failures,
        dict(coalesced or {}),
        fingerprint,
    )


def alarm_counts(engine: Engine, stale_topics: Iterable[str] = ()) -> tuple[object, ...]:
    """A few counters of ``engine`` that change whenever a status's level may change
    other than by a violation or by time alone (which wake a look themselves:
    :meth:`Health.woken`): the engine's alarms (a dropped event, a buffer past or back
    under HIGH_WATER, a migration wanted or no longer, a reaction's outcome), its routes
    (a monitor defined, redefined, removed, activated), the messages lost, the messages
    on ``stale_topics`` (a stale monitor's events coming back) and whether the deadline
    is at risk. Read without the engine's lock: each is one attribute or one copy.
    Health.due checks every monitor between updates only when these changed."""
    deadline = engine.deadline
    at_risk = None
    if deadline is not None:
        d = deadline.report(time.monotonic_ns())
        at_risk = d["p95Ms"] is not None and d["p95Ms"] >= d["budgetMs"]
    messages = engine.messages
    return (
        engine.alarms,
        engine.routes_version,
        tuple(list(engine.lost.items())),
        tuple(messages.get(t, 0) for t in sorted(stale_topics)),
        at_risk,
    )


def _duration(seconds: float) -> str:
    """``seconds`` as "10 s", "1 min", "1 h", "1 d" (whole units where they are)."""
    for unit, size in (("d", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= size and seconds % size == 0:
            return f"{seconds / size:g} {unit}"
    return f"{seconds:g} s"


def stamp_text(ns: int) -> str:
    """A stamp as ROS tools print one: seconds.nanoseconds."""
    seconds, nanoseconds = divmod(ns, 1_000_000_000)
    return f"{seconds}.{nanoseconds:09d}"


def _verdict_text(v: Verdict) -> str:
    return f"{v.verdict} at step {v.step} (stamp {stamp_text(v.stamp)})"


def _rate(count: float, seconds: float) -> str:
    return f"{count / seconds:.1f}" if seconds > 0 else "0.0"


@dataclass
class _Track:
    """What the statuses remember of one active monitor."""

    instance: int
    since: float  # first seen active here
    events: int  # its events when first seen (the base of a rate until a sample has it)
    dropped: int  # its dropped events when first seen
    seen: int  # events and drops at the last reading
    last_event: float  # when they last grew (or since)
    violations: int  # at the last reading
    violated_at: float | None = None  # when the handler last reached a violation
    violation: Verdict | None = None  # that violation, when known
    checked: float = -math.inf  # when a check last read it (Health.woken)


class _Sample(NamedTuple):
    """The counters at one reading: the base of "in the last period"."""

    at: float
    messages: int
    lost: Mapping[str, int]
    bad: Mapping[str, int]
    monitors: Mapping[str, tuple[int, int, int]]  # name -> (instance, events, dropped)
    coalesced: Mapping[str, int] = {}


# what a monitor's status values are made of: its reading and its events per second
_StatusKey = tuple[MonitorReading, str]


class Health:
    """The statuses of one handler over time. :meth:`write` (a verdict sink, on the
    scheduler thread) notes violations as they are reached and sets :attr:`changed`;
    :meth:`check` and :meth:`statuses` are called by one thread (the ROS layer's
    diagnostics thread)."""

    def __init__(
        self,
        handler: str,
        config: DiagnosticsConfig | None = None,
        clock: Clock | None = None,
    ) -> None:
        self.handler = handler
        self.config = config or DiagnosticsConfig()
        self.clock: Clock = clock or SystemClock()
        self.changed = threading.Event()  # a violation came: check the levels now
        self._lock = threading.Lock()
        self._violated: dict[str, tuple[float, Verdict]] = {}  # write(): the newest, when
        self._tracks: dict[str, _Track] = {}
        self._samples: deque[_Sample] = deque()
        self._published: dict[str, Level] = {}
        self._last: tuple[Reading, _Sample, float, dict[str, list[tuple[Level, str]]]] | None = None
        # called every BREATH_EVERY monitors by check and statuses, as the reading is
        # turned into statuses (a Breather, the diagnostics thread's; else nothing)
        self.breathe: Callable[[], None] = _hold_breath
        # Settled (:meth:`settled`): the fingerprint of the last check's reading, the
        # first check that saw it, and until when a check would give the last levels
        # again (None: not settled); whether the last levels were published
        self._fingerprint: object = None
        self._fingerprint_since = 0.0
        self._quiet_until: float | None = None
        self._unpublished = False
        self._sent: list[Status] | None = None  # the statuses last published
        self._sent_settled = False  # made by a check after which the next were settled
        self._some: list[Status] | None = None  # the statuses of a change of level, made last
        # next_change's instants, sorted (None: to be made), from the tracks of the check
        # at _checked_at; "no event for over X": X one of _stale_edges
        self._times: list[float] | None = None
        self._checked_at = 0.0
        self._whole_at = -math.inf  # the last check of every monitor
        self._alarms: object = None  # alarm_counts at it (None: not given)
        self._stale: dict[str, Sequence[str]] = {}  # stale monitors' topics, as last checked
        stale = self.config.stale
        self._stale_edges = [stale, *(s for s in STALE_STEPS if s > stale)] if stale > 0 else []
        # each monitor's last status values and what they were made of: made again only
        # when that changed (statuses(); the diagnostics thread's alone)
        self._kept_statuses: dict[str, tuple[_StatusKey, tuple[tuple[str, str], ...]]] = {}
        self._statuses_now: dict[str, tuple[_StatusKey, tuple[tuple[str, str], ...]]] = {}

    # -- a verdict sink ----------------------------------------------------------------

    def write(self, handler: str, verdicts: Sequence[Verdict]) -> None:
        """Note when each monitor was last violated (the hold counts from here), and wake
        the diagnostics thread if that makes a status ERROR that was published otherwise
        (a monitor violated at every step does not wake it at every step)."""
        violated = {v.monitor: v for v in verdicts if v.verdict == "violated"}
        if violated:
            now = self.clock.monotonic()
            with self._lock:
                for name, v in violated.items():
                    self._violated[name] = (now, v)
            published = self._published
            if any(published.get(MONITOR_PREFIX + name) != Level.ERROR for name in violated):
                self.changed.set()

    # -- readings ------------------------------------------------------------------------

    def _update(self, reading: Reading, now: float, whole: bool = True) -> _Sample:
        """Track each monitor of ``reading``; return the base sample of "the last period"
        (the newest at least a period old, else the oldest kept) and, ``whole`` (a reading
        of every active monitor), keep this one; else (some monitors: :meth:`check_some`)
        the others' tracks stay as they are."""
        with self._lock:
            violated, self._violated = self._violated, {}
        tracks: dict[str, _Track] = {} if whole else self._tracks
        for m in reading.monitors:
            seen = m.events + m.dropped
            t = self._tracks.get(m.name)
            if t is None or t.instance != m.instance:
                t = _Track(m.instance, now, m.events, m.dropped, seen, now, m.violations)
            elif seen != t.seen:
                t.seen, t.last_event = seen, now
            noted = violated.get(m.name)  # as the sink saw it: when, exactly
            if noted is not None:
                t.violated_at, t.violation = noted
            elif m.violations > t.violations:  # reached since the last reading: about now
                last = m.last_verdict
                t.violated_at = now
                t.violation = last if last is not None and last.verdict == "violated" else None
            t.violations = m.violations
            t.checked = now
            tracks[m.name] = t
        self._tracks = tracks
        self._times, self._checked_at = None, now  # (next_change: made anew)
        if not whole:
            return self._base(now)
        sample = _Sample(
            now,
            reading.messages,
            reading.lost,
            reading.bad,
            {m.name: (m.instance, m.events, m.dropped) for m in reading.monitors},
            reading.coalesced,
        )
        return self._keep(sample)

    def _base(self, now: float) -> _Sample:
        """The base of "the last period" at ``now``, of the samples kept (some)."""
        samples, since = self._samples, now - self.config.period
        base = samples[0]
        for sample in itertools.islice(samples, 1, None):
            if sample.at > since:
                break
            base = sample
        return base

    def _keep(self, sample: _Sample) -> _Sample:
        """Keep ``sample``; return the base of "the last period" at its instant (the
        newest sample at least a period older, else the oldest kept)."""
        samples, period = self._samples, self.config.period
        while len(samples) > 1 and samples[1].at <= sample.at - period:
            samples.popleft()
        base = samples[0] if samples else sample
        samples.append(sample)
        return base

    def _monitor_problems(
        self, m: MonitorReading, t: _Track, base: _Sample, reading: Reading, now: float
    ) -> list[tuple[Level, str]]:
        """The conditions that make ``m`` other than OK, each with its level and why."""
        problems: list[tuple[Level, str]] = []
        last = m.last_verdict
        if m.halted and last is not None and last.verdict == "violated":  # (m is active)
            problems.append((Level.ERROR, f"halted after it was {_verdict_text(last)}"))
        elif t.violated_at is not None and now - t.violated_at < self.config.hold:
            what = "violated" if t.violation is None else _verdict_text(t.violation)
            problems.append((Level.ERROR, f"{what}, within the last {self.config.hold:g} s"))
        if self.config.stale > 0 and now - t.last_event >= self.config.stale:
            edge = max(e for e in self._stale_edges if e <= now - t.last_event)
            problems.append((Level.STALE, f"no event for over {_duration(edge)}"))
        fill = m.buffered / m.capacity
        if fill >= HIGH_WATER:
            problems.append((Level.WARN, f"buffer {fill:.0%} full"))
        if m.migration_wanted:
            problems.append((Level.WARN, "wants to migrate (its buffer stayed half full)"))
        if m.reaction_problem is not None:
            problems.append((Level.WARN, f"its last reaction failed: {m.reaction_problem}"))
        before = base.monitors.get(m.name)
        since = before if before is not None and before[0] == m.instance else None
        dropped = m.dropped - (t.dropped if since is None else since[2])
        span = now - (t.since if since is None else base.at)
        if dropped > 0:
            problems.append(
                (Level.WARN, f"{dropped} events dropped in the last {span:.1f} s (buffer full)")
            )
        topics = m.compiled.spec.topics
        publishers = reading.publishers
        silent = [topic for topic in topics if publishers.get(topic, 1) == 0]
        if silent:
            problems.append((Level.WARN, f"no publisher on {', '.join(silent)}"))
        incompatible = reading.incompatible
        for topic in topics if incompatible else ():
            n = incompatible.get(topic, 0)
            if n:
                problems.append((Level.WARN, f"{n} publisher(s) of {topic} with incompatible QoS"))
        return problems

    def _handler_problems(
        self, reading: Reading, base: _Sample, now: float
    ) -> list[tuple[Level, str]]:
        problems: list[tuple[Level, str]] = []
        span = now - base.at
        for counts, before, what in (
            (reading.lost, base.lost, "lost before the handler took them"),
            (reading.bad, base.bad, "could not be read"),
        ):
            grew = {t: n - before.get(t, 0) for t, n in counts.items() if n > before.get(t, 0)}
            if grew:
                topics = ", ".join(f"{t} {n}" for t, n in sorted(grew.items()))
                problems.append(
                    (
                        Level.WARN,
                        f"{sum(grew.values())} messages {what} in the last {span:.1f} s ({topics})",
                    )
                )
        grew = {
            sink: n - base.coalesced.get(sink, 0)
            for sink, n in reading.coalesced.items()
            if n > base.coalesced.get(sink, 0)
        }
        if grew:
            sinks = ", ".join(f"{s} {n}" for s, n in sorted(grew.items()))
            problems.append(
                (
                    Level.WARN,
                    f"verdict sinks fell behind: {sum(grew.values())} verdicts coalesced in the "
                    f"last {span:.1f} s ({sinks}; each monitor's count, first and last go out)",
                )
            )
        d = reading.deadline
        if d is not None and d["p95Ms"] is not None and d["p95Ms"] >= d["budgetMs"]:
            problems.append(
                (
                    Level.WARN,
                    f"deadline pressure: {d['topic']}'s makespan p95 {d['p95Ms']:g} ms "
                    f"reaches its {d['budgetMs']:g} ms deadline",
                )
            )
        return problems

    def check(self, reading: Reading, now: float) -> dict[str, Level]:
        """Take ``reading`` (made at ``now``) into account; return each status's level by
        its name. :meth:`statuses` then builds the statuses of this reading."""
        base = self._update(reading, now)
        levels = self._levels(reading, base, now)
        self._whole_at = now
        self._settle(reading.fingerprint, base, now, levels)
        return levels

    def check_some(self, reading: Reading, now: float) -> dict[str, Level]:
        """:meth:`check` of the monitors of ``reading`` only (those :meth:`woken` names,
        between two checks of all of them), and of the handler: their levels."""
        levels = self._levels(reading, self._update(reading, now, whole=False), now, whole=False)
        self._unpublished = self.level_changed(levels)
        self._quiet_until = None  # (settled: only by a check of every monitor)
        return levels

    def _levels(
        self, reading: Reading, base: _Sample, now: float, whole: bool = True
    ) -> dict[str, Level]:
        tracks, stale = self._tracks, self._stale
        if whole:
            stale.clear()
        problems = {}
        for m in breathing(reading.monitors, self.breathe):
            found = problems[MONITOR_PREFIX + m.name] = self._monitor_problems(
                m, tracks[m.name], base, reading, now
            )
            if any(level == Level.STALE for level, _ in found):
                stale[m.name] = m.compiled.spec.topics
            elif not whole:
                stale.pop(m.name, None)
        problems[HANDLER_PREFIX + self.handler] = self._handler_problems(reading, base, now)
        self._last = (reading, base, now, problems)
        return {name: worst(level for level, _ in p) for name, p in problems.items()}

    def woken(self, now: float) -> set[str]:
        """The monitors whose level may have changed since a check last read them other
        than by what a check of all of them finds: those violated since (:meth:`write`),
        and those whose hold ended or that passed a stale step since (:meth:`next_change`'s
        instants)."""
        with self._lock:
            names = set(self._violated)
        hold, edges = self.config.hold, self._stale_edges
        for name, t in self._tracks.items():  # (as _monitor_problems reads them)
            v = t.violated_at
            if v is not None and t.checked - v < hold <= now - v:
                names.add(name)
                continue
            was, quiet = t.checked - t.last_event, now - t.last_event
            if any(was < e <= quiet for e in edges):
                names.add(name)
        return names

    def stale_topics(self) -> set[str]:
        """The topics of the monitors stale at their last check (:func:`alarm_counts`:
        their events coming back change a level)."""
        return {t for topics in self._stale.values() for t in topics}

    def _settle(
        self, fingerprint: object, base: _Sample, now: float, levels: Mapping[str, Level]
    ) -> None:
        """After a check: whether the next ones may be skipped (:meth:`settled`)."""
        self._unpublished = self.level_changed(levels)
        if fingerprint is None or fingerprint != self._fingerprint:
            self._fingerprint, self._fingerprint_since = fingerprint, now
            self._quiet_until = None
        elif base.at >= self._fingerprint_since:
            # "the last period" began after the last change: every counter it compares
            # is as now, and only a hold's end or a monitor going stale changes a level
            later = self.next_change(now)
            self._quiet_until = math.inf if later is None else later
        else:
            self._quiet_until = None

    def settled(self, fingerprint: object, now: float) -> bool:
        """Whether a check at ``now`` would give the levels of the last one, published:
        nothing a level reads changed since (the reading's ``fingerprint``, None: not
        known), "the last period" of that check began after the last change (so no
        count "in the last period" changes with time alone), and no hold ends nor a
        monitor goes stale before ``now``. The diagnostics thread then skips the check
        between two updates: an idle handler reads none of its monitors then."""
        quiet = self._quiet_until
        return (
            fingerprint is not None
            and fingerprint == self._fingerprint
            and quiet is not None
            and now < quiet
            and not self._unpublished
        )

    def statuses(self, names: Collection[str] | None = None) -> list[Status]:
        """The statuses of the last :meth:`check`: the handler's, then each active
        monitor's by name; given ``names``, only the monitors' statuses of those names
        (a change of level: :meth:`due`)."""
        if self._last is None:
            return []
        reading, base, now, problems = self._last
        out = [self._handler_status(reading, base, now, problems[HANDLER_PREFIX + self.handler])]
        self._statuses_now = {}
        for m in breathing(sorted(reading.monitors, key=lambda m: m.name), self.breathe):
            name = MONITOR_PREFIX + m.name
            if names is None or name in names:
                out.append(self._monitor_status(m, self._tracks[m.name], base, now, problems[name]))
        if names is None:
            self._kept_statuses = self._statuses_now  # (the monitors gone are forgotten)
        else:
            self._kept_statuses.update(self._statuses_now)
        self._some = out if names is not None else None
        return out

    def _monitor_status(
        self,
        m: MonitorReading,
        t: _Track,
        base: _Sample,
        now: float,
        problems: list[tuple[Level, str]],
    ) -> Status:
        problems = sorted(problems, key=lambda p: -RANK[p[0]])  # the worst first
        last, state = m.last_verdict, m.state
        if problems:
            message = "; ".join(text for _, text in problems)
        elif last is None:
            message = state  # pending: no verdict yet
        elif state == "satisfied":
            message = _verdict_text(last)
        elif state == "violated":  # the hold is over and no step came since
            message = f"{_verdict_text(last)}; no step since"
        elif state == "halted":
            message = f"halted after it was {_verdict_text(last)}"
        else:
            message = f"{state} (last verdict: {_verdict_text(last)})"
        before = base.monitors.get(m.name)
        if before is not None and before[0] == m.instance and now > base.at:
            rate = _rate(m.events - before[1], now - base.at)
        else:
            rate = _rate(m.events - t.events, now - t.since)
        level = worst(p[0] for p in problems)
        key = (m, rate)  # all its values are made of
        kept = self._kept_statuses.get(m.name)
        if kept is not None and kept[0] == key:  # an idle monitor's values are made once
            self._statuses_now[m.name] = kept
            return Status(level, MONITOR_PREFIX + m.name, message, self.handler, kept[1])
        handoff = f" (handoff: {m.handoff})" if m.handoff else ""
        spec = m.compiled.spec
        tier, buffered = spec.placement.tier, m.buffered
        values = (
            ("state", state),
            ("step", str(m.step)),
            ("last verdict", f"{last.verdict} at step {last.step}" if last else "none"),
            ("last verdict stamp", stamp_text(last.stamp) if last else ""),
            ("violations", str(m.violations)),
            ("satisfactions", str(m.satisfactions)),
            ("events", str(m.events)),
            ("events per second", rate),
            ("buffer fill", f"{buffered / m.capacity:.0%} ({buffered} of {m.capacity})"),
            ("dropped events", str(m.dropped)),
            ("late events", str(m.late)),
            ("migration wanted", "yes" if m.migration_wanted else "no"),
            (
                "tier",
                (tier or "lowest") + (" (pinned)" if spec.placement.migrate == "pinned" else ""),
            ),
            ("epoch", f"{m.epoch}{handoff}"),
            ("migrations", f"{m.moved_in} here, {m.moved_out} away"),
            ("topics", ", ".join(spec.topics)),
            (
                "reactions",
                f"{m.reactions} done, {m.reaction_failures} failed"
                if spec.on_violation is not None
                else "off",
            ),
        )
        self._statuses_now[m.name] = (key, values)
        return Status(level, MONITOR_PREFIX + m.name, message, self.handler, values)

    def _handler_status(
        self, reading: Reading, base: _Sample, now: float, problems: list[tuple[Level, str]]
    ) -> Status:
        span = now - base.at
        rate = _rate(reading.messages - base.messages, span)
        active = reading.active
        message = "; ".join(text for _, text in problems) or (
            f"{active} of {reading.defined} monitors active, {rate} messages/s"
        )
        values = [
            ("monitors active", str(active)),
            ("monitors defined", str(reading.defined)),
            ("messages", str(reading.messages)),
            ("messages per second", rate),
            ("ingest lag", f"{reading.ingest_lag:.3f} s"),
            ("messages lost", str(sum(reading.lost.values()))),
            ("bad messages", str(sum(reading.bad.values()))),
            ("log lines not sent to /rosout", str(reading.rosout_failures)),
            ("verdicts coalesced", str(sum(reading.coalesced.values()))),
        ]
        d = reading.deadline
        if d is not None:

            def ms(v: float | None) -> str:
                return "" if v is None else f"{v:g} ms"

            values += [
                ("deadline topic", d["topic"]),
                ("deadline", f"{d['budgetMs']:g} ms"),
                ("deadline window", f"{d['windowSeconds']:g} s"),
                ("deadline makespans in window", str(d["count"])),
                ("deadline misses in window", str(d["misses"])),
                ("deadline makespan p50", ms(d["p50Ms"])),
                ("deadline makespan p95", ms(d["p95Ms"])),
                ("deadline makespan max", ms(d["maxMs"])),
                ("deadline misses total", str(d["missesTotal"])),
            ]
        return Status(
            worst(p[0] for p in problems),
            HANDLER_PREFIX + self.handler,
            message,
            self.handler,
            tuple(values),
        )

    # -- when to publish -----------------------------------------------------------------

    def level_changed(self, levels: Mapping[str, Level]) -> bool:
        """Whether a status's level differs from the one last published (a status that
        comes or goes is published with the next periodic update)."""
        return bool(self.changed_levels(levels))

    def changed_levels(self, levels: Mapping[str, Level]) -> set[str]:
        """The statuses whose level differs from the one last published."""
        published = self._published
        return {name for name, level in levels.items() if published.get(name, level) != level}

    def published(self, statuses: list[Status]) -> None:
        """``statuses`` (:meth:`statuses`' or :meth:`due`'s) are published."""
        self._unpublished = False
        if statuses is self._sent:  # (sent again: nothing to note)
            return
        if statuses is self._some:  # a change of level: those statuses only
            self._published.update((s.name, s.level) for s in statuses)
            self._sent_settled = False  # (the next update is made anew)
            return
        self._sent_settled = self._quiet_until is not None  # (was the check that made them?)
        self._published = {s.name: s.level for s in statuses}
        self._sent = statuses

    def due(
        self,
        read: Callable[[object, Collection[str] | None], Reading],
        fingerprint: object,
        now: float,
        update: bool,
        alarms: object = None,
    ) -> list[Status] | None:
        """One look (the diagnostics thread's), at ``now``: the statuses to publish, else
        None. ``update``: the periodic update is due (every status, as diagnostic_updater
        publishes them); else, when a level changed, the handler's status and those whose
        level changed (a monitor violated does not send the other hundreds again: each
        status is a whole, and diagnostic_aggregator keeps each by its name).

        Settled (:meth:`settled`: nothing a status shows changed since the last check,
        given ``fingerprint``), nothing is read: between updates None; at an update, if
        the statuses last published were made by a check that was itself settled (its
        "last period" began after the last change), those, the very list (what a reading
        would give again: tests/unit/test_idle_wakeups.py), which the caller sends again
        as it sent them, only its stamp new.

        Not settled, every monitor is checked at an update, and every CHECK_SECONDS
        when ``alarms`` (:func:`alarm_counts` and the ROS layer's counts; None: not known)
        changed since the last such check; a look between those (a violation woke it, or
        a hold ends or a monitor goes stale: :meth:`next_change`) reads and checks only
        the monitors that woke it (:meth:`woken`), and the handler's counts: a look costs
        what changed, not the hundreds of monitors that did not. (A level no alarm
        counts, one "in the last period" that time brings back to OK, is published by the
        next update.)
        ``read(fingerprint, names)``: a reading of the active monitors (None: all of
        them, else those of ``names``), when one is needed."""
        if self.settled(fingerprint, now):
            if not update:
                return None
            if self._sent is not None and self._sent_settled and self._samples:
                # the counts are those of the last reading: kept as this instant's, as a
                # reading would have (the base of "the last period" later on)
                self._keep(self._samples[-1]._replace(at=now))
                return self._sent
        polled = now - self._whole_at >= CHECK_SECONDS and (
            alarms is None or alarms != self._alarms
        )
        if update or polled or not self._samples:
            levels = self.check(read(fingerprint, None), now)
            self._alarms = alarms
            if update:
                return self.statuses()
        else:  # between two checks of every monitor: those a violation or the time woke
            names = self.woken(now)
            if not names:
                self._sent_settled = False  # (not settled: a status may show otherwise)
                return None
            levels = self.check_some(read(fingerprint, names), now)
        changed = self.changed_levels(levels)
        if not changed:
            self._sent_settled = False  # a status may show otherwise (an age's step)
            return None
        return self.statuses(changed)

    def next_change(self, now: float) -> float | None:
        """The next instant a status changes by time alone, if any: a hold ends, a monitor
        goes stale or its "no event for over ..." passes the next of STALE_STEPS; the
        check is made then. Nothing else a status shows changes with time alone: its
        texts name no age but those (tests/unit/test_idle_wakeups.py)."""
        times = self._times
        if times is None:
            hold, edges = self.config.hold, self._stale_edges
            tracks = self._tracks.values()
            times = [t.violated_at + hold for t in tracks if t.violated_at is not None]
            if edges:
                at = self._checked_at
                for t in tracks:
                    later = [t.last_event + e for e in edges if t.last_event + e > at]
                    if later:
                        times.append(later[0])
            self._times = times = sorted(times)
        i = bisect.bisect_right(times, now)
        return times[i] if i < len(times) else None


def _hold_breath() -> None:
    """(No Breather: the work is done at once.)"""


def breathing(items: Iterable[T], breathe: Callable[[], None] | None) -> Iterator[T]:
    """``items``, with ``breathe`` called after every BREATH_EVERY of them (a Breather:
    the work on them spread in time; None: at once)."""
    if breathe is None:
        yield from items
        return
    for i, item in enumerate(items, 1):
        if not i % BREATH_EVERY:
            breathe()
        yield item


class Breather:
    """A long piece of work spread in time: called every so often as it goes, it sleeps
    after each BREATH_SECONDS of the thread's CPU, long enough that the work takes
    ``budget`` of one CPU meanwhile. :attr:`paid`: the CPU seconds its sleeps followed
    (the Pacer does not make them wait again); ``stop``, set, ends a sleep at once."""

    def __init__(
        self,
        stop: threading.Event,
        budget: float = CPU_BUDGET,
        cpu: Callable[[], float] = time.thread_time,
    ) -> None:
        self.stop = stop
        self.budget = budget
        self.cpu = cpu  # the thread's CPU seconds
        self.paid = 0.0
        self.mark = cpu()

    def begin(self) -> None:
        """A new piece of work: the CPU counts from here, nothing paid yet."""
        self.paid, self.mark = 0.0, self.cpu()

    def __call__(self) -> None:
        spent = self.cpu() - self.mark
        if spent >= BREATH_SECONDS:
            self.stop.wait(spent * (1 / self.budget - 1))
            self.paid += spent
            self.mark = self.cpu()


class Pacer:
    """When the diagnostics thread works next: a periodic update every ``period``, a
    check of the levels every CHECK_SECONDS and at the instants :meth:`Health.next_change`
    names; never more than ``budget`` of one CPU on average (a reading and a
    publication that took ``c`` CPU seconds are followed by ``c / budget - c`` idle)."""

    def __init__(self, period: float, budget: float = CPU_BUDGET, start: float = 0.0) -> None:
        self.period = period
        self.budget = budget
        self.next_update = start  # the first update is made at once
        self.not_before = start

    def wait(self, now: float, change: float | None) -> float:
        """Seconds to wait before the next check (or update)."""
        due = min(self.next_update, now + CHECK_SECONDS)
        if change is not None:
            due = min(due, change)
        return max(due, self.not_before) - now

    def update_due(self, now: float) -> bool:
        return now >= self.next_update

    def worked(self, now: float, cpu_seconds: float, updated: bool, paid: float = 0.0) -> None:
        """A check (or, ``updated``, an update) ended at ``now`` and took ``cpu_seconds``,
        ``paid`` of which were followed by a Breather's sleeps already."""
        self.not_before = now + max(0.0, cpu_seconds - paid) * (1 / self.budget - 1)
        if updated:
            self.next_update = max(now + self.period, self.not_before)
