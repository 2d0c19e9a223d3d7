"""The one read path over the engine: :func:`read` copies its monitors and counters
into a frozen :class:`EngineReading`, taking the engine's lock a few hundred monitors at
a time; every face of the handler renders that reading, none reads the engine's slots
itself: /diagnostics (:mod:`edgerv.handler.health`), Prometheus
(:mod:`edgerv.handler.metrics`), ``GET /v1/monitors`` (:func:`monitor_report`) and the
typed load report of ``GET /v1/load`` (:func:`load_report`).

What stays outside it, on purpose: the liveness probe's count of active monitors, the
typed verdicts' glance at a slot's assertion and the diagnostics' glance at a few of the
engine's counters (``Engine.fingerprint``, ``health.alarm_counts``: whether a reading is
needed at all), each read without the lock so that none ever waits for the engine; and
the handoff's steps (they change the slots, under the lock).
"""

from __future__ import annotations

import time
from collections.abc import Collection, Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

from edgerv.control.wire import (
    LastVerdict,
    LoadReport,
    MonitorLoadReport,
    MonitorReport,
    PlacementJson,
    placement_json,
)
from edgerv.core.monitor import CompiledMonitor
from edgerv.core.pipeline import Verdict, status_of
from edgerv.handler.handoff_state import HandoffState
from edgerv.handler.host import read_host_cpu

if TYPE_CHECKING:
    from edgerv.handler.engine import Engine
    from edgerv.handler.slot import MonitorSlot

READ_CHUNK = 256  # monitors read under one hold of the engine's lock
READ_PAUSE = 0.003  # seconds between two holds: the lock's waiters take it meanwhile
_AWAY = (HandoffState.RECEIVING, HandoffState.RELEASED)  # a runtime kept, not active here


class MonitorReading(NamedTuple):
    """One monitor defined here, as it was when :func:`read` copied it (under the
    engine's lock)."""

    name: str
    instance: int  # its slot's identity: a redefined monitor is a new one
    compiled: CompiledMonitor  # its definition (immutable)
    active: bool
    halted: bool
    automaton_state: int | None  # None: no runtime here
    step: int
    buffered_events: int
    buffered_letters: int
    capacity: int
    events: int
    dropped: int
    late: int
    violations: int
    satisfactions: int
    last_verdict: Verdict | None
    migration_wanted: bool
    handoff: HandoffState | None
    epoch: int
    peer: str | None
    moved_in: int  # handoffs that moved it here, and away from here
    moved_out: int
    reactions: int  # spec.onViolation, done here
    reaction_failures: int
    reaction_problem: str | None  # why the newest failed; None: it was done
    cost_ns: float  # its CPU here (the load report's; engine.COST_EVERY)

    @property
    def state(self) -> str:
        """Its runtime's (pending, violated, satisfied, halted) when it is active here,
        else "inactive"."""
        if not self.active or self.automaton_state is None:
            return "inactive"
        return status_of(self.compiled, self.halted, self.step, self.automaton_state)

    @property
    def buffered(self) -> int:
        """Events in its buffer plus letters not yet evaluated."""
        return self.buffered_events + self.buffered_letters


@dataclass(frozen=True)
class EngineReading:
    """The engine at one read: every monitor defined here, or those asked for (in
    definition order; one removed or redefined while it was read is left out), and the
    counters."""

    handler: str
    monitors: tuple[MonitorReading, ...]
    defined: int  # monitors defined when the read began (all, if some were read)
    running: int  # of those, active here
    messages: Mapping[str, int]  # topic -> messages ingested
    lost: Mapping[str, int]  # topic -> messages lost before the handler took them
    taking_ns: Mapping[str, int]  # topic -> CPU spent taking and decoding its messages
    routed: tuple[str, ...]  # the topics subscribed to now
    ingest_lag: float
    reach_ms: float | None  # publication to here, p95 of the recent rounds (reach.py)

    def active(self) -> tuple[MonitorReading, ...]:
        """The monitors that run here (or are paused here for a handoff)."""
        return tuple(m for m in self.monitors if m.active)


def read(
    engine: Engine, names: Collection[str] | None = None, paced: bool = False
) -> EngineReading:
    """A frozen reading of ``engine``: of every monitor defined here, or of those of
    ``names`` (``defined`` counts them all), under one hold of its lock; ``paced`` (the
    diagnostics' reading, made in the background), READ_CHUNK monitors at a time with
    READ_PAUSE between two holds, so that the take loop and the scheduler wait for it no
    longer than that, whatever the number of monitors. (Not the API's: a reader that
    takes the lock again and again waits as often for the take loop's batch in hand;
    under a CPU budget a tenth of a core, 2,000 monitors' load report paced took over
    10 s: tests/integration/test_cpu_budget_docker.py.)"""
    monitors: list[MonitorReading] = []
    with engine.lock:
        defined = engine.slots
        if names is None:
            slots = list(defined.values())
        else:
            slots = [slot for n in names if (slot := defined.get(n)) is not None]
        count = len(defined)
        running = None if names is None else sum(1 for slot in defined.values() if slot.active)
        messages = dict(engine.messages)
        lost = dict(engine.lost)
        taking = dict(engine.taking_ns)
        routed = tuple(engine.router.routes)
        lag = engine.ingest_lag
        reach = engine.reach.p95_ms()
        if not paced:
            _copy(defined, slots, monitors)
    for start in range(0, len(slots) if paced else 0, READ_CHUNK):
        if start:
            # Between two holds, a pause for the threads waiting for the lock and the
            # interpreter's: the take loop's, the scheduler's. Without one this thread,
            # still holding the GIL, took the lock again before a waiter could, and 10,000
            # monitors were read in one hold (up to 70 ms of waiting for the take loop);
            # with 0.2 ms it shared the interpreter half and half with the take loop for
            # the read's 70 ms, which fell behind by as much (bench/scale.py's p99: 31-33
            # ms without /diagnostics, 42-53 with; with 3 ms, 34). Each monitor is read
            # at about the same offset into every reading: its rate is not skewed by it.
            time.sleep(READ_PAUSE)
        with engine.lock:
            _copy(engine.slots, slots[start : start + READ_CHUNK], monitors)
    got = tuple(monitors)
    if running is None:
        running = sum(1 for m in got if m.active)
    return EngineReading(
        engine.name, got, count, running, messages, lost, taking, routed, lag, reach
    )


def _copy(
    current: Mapping[str, MonitorSlot], slots: Iterable[MonitorSlot], out: list[MonitorReading]
) -> None:
    """Append to ``out`` a reading of each of ``slots`` still defined as it is in
    ``current`` (the engine's slots; under its lock)."""
    add, new = out.append, tuple.__new__  # (a monitor at ~1 us: a report twice a second)
    for slot in slots:
        compiled = slot.compiled
        name = compiled.spec.name
        if current.get(name) is not slot:
            continue  # removed or redefined since the list was taken
        verdicts = slot.verdicts
        rt = slot._runtime
        if rt is None:
            runtime: tuple[Any, ...] = (False, False, None, 0, 0, 0, 0)
            taken, cost = 0, 0.0
        else:
            runtime = (
                slot.handoff not in _AWAY,  # (MonitorSlot.active)
                rt.halted,
                rt.state,
                rt.step,
                len(rt.events),
                len(rt.letters),
                rt.late_events,
            )
            taken, cost = rt.taken, rt.cost_ns
        add(
            new(
                MonitorReading,
                (
                    name,
                    id(slot),
                    compiled,
                    *runtime[:6],
                    slot.capacity,
                    slot.admitted + taken,  # (MonitorSlot.events)
                    slot.dropped,
                    runtime[6],
                    verdicts["violated"],
                    verdicts["satisfied"],
                    slot.last_verdict,
                    slot.migration_wanted,
                    slot.handoff,
                    slot.epoch,
                    slot.peer,
                    slot.moved_in,
                    slot.moved_out,
                    slot.reactions,
                    slot.reaction_failures,
                    slot.reaction_problem,
                    cost,
                ),
            )
        )


# -- GET /v1/monitors ------------------------------------------------------------------


def _last_verdict(v: Verdict | None) -> LastVerdict | None:
    return None if v is None else {"verdict": v.verdict, "stamp": v.stamp, "step": v.step}


def monitor_report(m: MonitorReading, handler: str) -> MonitorReport:
    """One monitor's entry of ``GET /v1/monitors`` (docs/handler.md)."""
    spec = m.compiled.spec
    return {
        "name": m.name,
        "handler": handler,
        "active": m.active,
        "state": m.state,
        "assertion": spec.assertion,
        "topics": spec.topics,
        "automatonState": m.automaton_state,
        "step": m.step,
        "buffer": {
            "events": m.buffered_events,
            "letters": m.buffered_letters,
            "capacity": m.capacity,
            "fill": round(m.buffered / m.capacity, 4),
        },
        "events": m.events,
        "droppedEvents": m.dropped,
        "lateEvents": m.late,
        "verdicts": {"violated": m.violations, "satisfied": m.satisfactions},
        "lastVerdict": _last_verdict(m.last_verdict),
        "migrationWanted": m.migration_wanted,
        "handoff": m.handoff,
        "epoch": m.epoch,
        "peer": m.peer if m.handoff else None,
        "placement": placement_json(spec.placement),
    }


def monitor_reports(engine: Engine) -> list[MonitorReport]:
    """``GET /v1/monitors``: every monitor defined here."""
    reading = read(engine)
    return [monitor_report(m, reading.handler) for m in reading.monitors]


# -- GET /v1/load ----------------------------------------------------------------------


class Definitions:
    """Each monitor's definition's part of its load entry, made once per definition (a
    report is made every poll, for every monitor defined here)."""

    def __init__(self) -> None:
        self._kept: dict[str, tuple[CompiledMonitor, PlacementJson, list[str]]] = {}

    def part(self, compiled: CompiledMonitor) -> tuple[PlacementJson, list[str]]:
        kept = self._kept.get(compiled.name)
        if kept is None or kept[0] is not compiled:
            spec = compiled.spec
            kept = self._kept[compiled.name] = (
                compiled,
                placement_json(spec.placement),
                list(spec.topics),
            )
        return kept[1], kept[2]

    def keep_only(self, names: Iterable[str]) -> None:
        """Forget the definitions of monitors no longer defined here."""
        keep = set(names)
        for name in [n for n in self._kept if n not in keep]:
            del self._kept[name]


def _monitor_load(m: MonitorReading, definitions: Definitions) -> MonitorLoadReport:
    placement, topics = definitions.part(m.compiled)
    return {
        "active": m.active,
        "handoff": m.handoff,
        "epoch": m.epoch,
        "peer": m.peer if m.handoff else None,
        "events": m.events,
        "cpuSeconds": m.cost_ns / 1e9,
        "migrationWanted": m.migration_wanted,
        "placement": placement,
        "topics": topics,
    }


def load_report(engine: Engine, definitions: Definitions | None = None) -> LoadReport:
    """The load report the orchestrator reads (``GET /v1/load``): counters, not rates;
    ``deadline`` is the makespan window's reading (null without ``--deadline``).
    ``definitions``: the parts kept from the last report (the API keeps one)."""
    definitions = definitions if definitions is not None else Definitions()
    now_ns = int(engine.clock.monotonic() * 1e9)
    deadline = engine.deadline.report(now_ns) if engine.deadline else None
    host = read_host_cpu()
    reading = read(engine)
    definitions.keep_only(m.name for m in reading.monitors)
    return {
        "handler": reading.handler,
        "monotonic": engine.clock.monotonic(),
        "cpuSeconds": time.process_time(),
        "host": None if host is None else host.json(),
        "ingestLag": reading.ingest_lag,
        "reachMs": reading.reach_ms,
        "deadline": deadline,
        "topics": {
            topic: {
                "messages": reading.messages.get(topic, 0),
                "cpuSeconds": reading.taking_ns.get(topic, 0) / 1e9,
            }
            for topic in reading.routed
        },
        "monitors": {m.name: _monitor_load(m, definitions) for m in reading.monitors},
    }
