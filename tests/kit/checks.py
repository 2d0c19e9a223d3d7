"""A check over a run given as rows: events from (topic, stamp, value) rows
(:func:`events`), ``edgerv check``'s run over them (:func:`run`), its verdicts as tuples
(:func:`verdicts`); and a formula's truth at each step (:func:`step_truths`) or at an
instant of a truth given by its changes (:func:`truth_at`)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

from edgerv.core.checker import CheckRun, MonitorResult
from edgerv.core.diagnostics import Location
from edgerv.core.monitor import CompiledMonitor
from edgerv.core.pipeline import MonitorRuntime
from edgerv.core.traces import TraceEvent
from kit.documents import compiled


def events(rows: Iterable[Sequence[Any]]) -> list[TraceEvent]:
    """Events from (topic, stamp, value) rows; the value becomes msg.data."""
    return [
        TraceEvent(topic, stamp, {"data": value}, Location("test", i + 1))
        for i, (topic, stamp, value) in enumerate(rows)
    ]


def run(monitors: Sequence[CompiledMonitor], evs: Iterable[TraceEvent]) -> list[MonitorResult]:
    """A check over the events; its clock ends at their last stamp (any topic), as a
    trace's does."""
    evs = list(evs)
    check = CheckRun(monitors)
    check.feed(evs)
    return check.finish(max((e.stamp for e in evs), default=None))


def truth_at(changes: list[tuple[int, bool]], t: int) -> bool:
    """A truth given as (instant, value from then on) changes, at instant ``t``."""
    value = changes[0][1]
    for at, v in changes:
        if at > t:
            break
        value = v
    return value


def step_truths(
    formula: str, signals: dict[str, Any], rows: Sequence[tuple[str, int, Any]], end: int
) -> list[tuple[int, bool]]:
    """(stamp, truth) of a formula without future operators at each step a monitor of
    ``always (formula)`` takes over the (topic, stamp, value) rows, one event each, its
    clock advanced to ``end`` (with reset, ``always`` is violated at each step where the
    formula is false)."""
    m = compiled(f"always ({formula})", signals)
    rt = MonitorRuntime(m)
    index = {name: i for i, name in enumerate(m.signal_names)}
    for seq, (topic, stamp, value) in enumerate(rows):
        rt.offer(stamp, seq, [(index[topic[1:]], value)])
    rt.advance(end)
    stamps = list(rt.stamps)
    violated = {v.step for v in rt.evaluate() if v.verdict == "violated"}
    return [(t, i + 1 not in violated) for i, t in enumerate(stamps)]


def verdicts(result: MonitorResult) -> list[tuple[str, int, int]]:
    return [(v.verdict, v.step, v.stamp) for v in result.verdicts]
