"""What side-by-side tests compare: a monitor runtime's state (:func:`state_of`), a check's
outcome (:func:`outcome`), and two live engines fed the same messages, one in batches and
one a message at a time (:func:`run_side_by_side`)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

from edgerv.core.checker import MonitorResult
from edgerv.core.pipeline import MonitorRuntime, Verdict
from edgerv.core.traces import TraceEvent
from edgerv.handler.engine import Engine


def state_of(rt: MonitorRuntime) -> tuple[Any, ...]:
    clock = rt.clock
    return (
        [repr(v) for v in rt.values],
        rt.valuation,
        rt.missing,
        rt.state,
        rt.step,
        rt.halted,
        rt.last_released,
        None if clock is None else (clock.snapshot(), clock.deadline),
        None if rt.past is None else json.dumps(rt.past.save()),
    )


def outcome(result: MonitorResult, late: bool) -> tuple[Any, ...]:
    verdicts = [(v.verdict, v.stamp, v.step) for v in result.verdicts]
    return (verdicts, result.state, result.steps, result.late_events if late else None)


class Collect:
    """Each monitor's verdicts in order (between monitors, the order of a scheduler's
    round is not part of the contract)."""

    def __init__(self) -> None:
        self.verdicts: dict[str, list[tuple[str, int, int]]] = {}

    def write(self, handler: str, verdicts: Sequence[Verdict]) -> None:
        for v in verdicts:
            self.verdicts.setdefault(v.monitor, []).append((v.verdict, v.stamp, v.step))


def messages(events: list[TraceEvent]) -> list[tuple[int, str, list[Any]]]:
    """The events as the ROS layer hands them to the engine: each topic's one field."""
    return [(e.stamp, e.topic, [e.msg["data"]]) for e in events]


def engine_with(monitors: list[Any]) -> tuple[Engine, Collect]:
    sink = Collect()
    e = Engine("edge", [sink], flush_after=1e9)  # buffers released by count and at the end
    for m in monitors:
        e.put(m, active=True)
    return e, sink


def observe(e: Engine) -> list[Any]:
    out = []
    for slot in e.slots.values():
        rt = slot.runtime
        assert rt is not None
        out.append((slot.name, state_of(rt), rt.late_events, slot.events, slot.dropped))
        out.append((len(rt.events), rt.buffered))
    return out


def run_side_by_side(monitors: list[Any], msgs: list[Any], sizes: list[int]) -> None:
    batched, b_sink = engine_with(monitors)
    single, s_sink = engine_with(monitors)
    fed = 0
    for size in sizes:
        part = msgs[fed : fed + size]
        if not part:
            break
        assert batched.ingest(part, now=0.0)
        for msg in part:
            assert single.ingest([msg], now=0.0)
        fed += len(part)
        assert observe(batched) == observe(single), fed
        batched.emit(batched.evaluate())
        single.emit(single.evaluate())
        assert b_sink.verdicts == s_sink.verdicts, fed
    assert batched.messages == single.messages and batched.newest == single.newest
    batched.drain()
    single.drain()
    assert observe(batched) == observe(single)
    assert b_sink.verdicts == s_sink.verdicts
