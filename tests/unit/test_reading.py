"""The one read path (:mod:`edgerv.handler.reading`): what it copies is what the slots
hold, and every face of the handler renders that reading and nothing else: /diagnostics'
reading, Prometheus' metrics, ``GET /v1/monitors`` and the load report agree with it,
monitor by monitor, on random runs (busy, buffered, violated, halted, inactive, held by
a handoff, removed and redefined)."""

from __future__ import annotations

import random
import time
from typing import Any

import pytest
from prometheus_client import generate_latest
from prometheus_client.parser import text_string_to_metric_families

from edgerv.handler import reading as reading_module
from edgerv.handler.engine import Engine
from edgerv.handler.health import read_engine
from edgerv.handler.metrics import build_registry
from edgerv.handler.reading import (
    MonitorReading,
    load_report,
    monitor_report,
    monitor_reports,
    read,
)
from kit.documents import compiled

SIGNALS = {"speed": "float"}
KINDS = (
    {"assertion": "always (speed < 100)"},  # plain: stepped as it comes
    {"assertion": "always (speed < 100)", "sortThreshold": 4},  # buffered, sorted
    {"assertion": "always (speed < 100)", "onVerdict": "halt"},  # halts
    {"assertion": "F (speed > 150)"},  # satisfied, then done
    {"assertion": "always (speed < 100)", "bufferCapacity": 3, "sortThreshold": 3},  # drops
)


def _spec(kind: dict[str, Any], name: str) -> Any:
    return compiled(
        kind["assertion"], SIGNALS, name=name, **{k: v for k, v in kind.items() if k != "assertion"}
    )


def _run(seed: int) -> Engine:
    """An engine after a random run: monitors of every kind, active or not, fed messages
    and evaluated, some held by a handoff, removed, redefined."""
    rng = random.Random(seed)
    e = Engine("edge", flush_after=1e9)
    names = [f"m{i}" for i in range(rng.randint(3, 9))]
    for name in names:
        e.put(_spec(rng.choice(KINDS), name), active=rng.random() < 0.8)
    stamp, epoch = 0, 0
    for _ in range(rng.randint(5, 40)):
        op = rng.random()
        if op < 0.6:
            batch = []
            for _ in range(rng.randint(1, 12)):
                stamp += rng.randint(-2, 10)  # late ones too
                batch.append((max(stamp, 1), "/speed", [rng.uniform(0, 160)]))
            e.ingest(batch)
        elif op < 0.8:
            e.emit(e.tick())
        elif op < 0.87:
            name = rng.choice(names)
            slot = e.slots.get(name)
            if slot is not None and slot.runtime is not None and slot.handoff is None:
                epoch += 1
                e.handoffs.hold(name, epoch, peer="cloud")
        elif op < 0.93:
            e.remove(rng.choice(names))
        else:
            name = rng.choice(names)
            slot = e.slots.get(name)
            if slot is None or slot.handoff is None:  # (one in a handoff is not redefined)
                e.put(_spec(rng.choice(KINDS), name), active=True)
    return e


def _from_slots(e: Engine) -> list[MonitorReading]:
    """An independent copy of the slots' state, field by field (the reference)."""
    out = []
    for slot in e.slots.values():
        rt = slot.runtime
        out.append(
            MonitorReading(
                name=slot.name,
                instance=id(slot),
                compiled=slot.compiled,
                active=slot.active,
                halted=rt is not None and rt.halted,
                automaton_state=None if rt is None else rt.state,
                step=0 if rt is None else rt.step,
                buffered_events=0 if rt is None else len(rt.events),
                buffered_letters=0 if rt is None else len(rt.letters),
                capacity=slot.capacity,
                events=slot.events,
                dropped=slot.dropped,
                late=0 if rt is None else rt.late_events,
                violations=slot.verdicts["violated"],
                satisfactions=slot.verdicts["satisfied"],
                last_verdict=slot.last_verdict,
                migration_wanted=slot.migration_wanted,
                handoff=slot.handoff,
                epoch=slot.epoch,
                peer=slot.peer,
                moved_in=slot.moved_in,
                moved_out=slot.moved_out,
                reactions=slot.reactions,
                reaction_failures=slot.reaction_failures,
                reaction_problem=slot.reaction_problem,
                cost_ns=0.0 if rt is None else rt.cost_ns,
            )
        )
    return out


def _metrics(e: Engine) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    text = generate_latest(build_registry(e, dict)).decode()
    return {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
    }


@pytest.mark.parametrize("seed", range(16))
def test_every_face_renders_the_one_reading(seed: int) -> None:
    e = _run(seed)
    reading = read(e)
    assert list(reading.monitors) == _from_slots(e)
    for m in reading.monitors:
        slot = e.slots[m.name]
        rt = slot.runtime
        assert m.state == (rt.status if rt is not None and slot.active else "inactive")
    assert reading.defined == len(e.slots)
    assert dict(reading.messages) == e.messages

    # GET /v1/monitors
    reports = monitor_reports(e)
    assert reports == [monitor_report(m, "edge") for m in reading.monitors]
    for m, r in zip(reading.monitors, reports, strict=True):
        assert (r["name"], r["active"], r["state"], r["step"], r["automatonState"]) == (
            m.name,
            m.active,
            m.state,
            m.step,
            m.automaton_state,
        )
        assert (r["events"], r["droppedEvents"], r["lateEvents"]) == (m.events, m.dropped, m.late)
        assert r["buffer"]["events"] + r["buffer"]["letters"] == m.buffered
        assert r["verdicts"] == {"violated": m.violations, "satisfied": m.satisfactions}
        assert (r["handoff"], r["epoch"], r["peer"]) == (m.handoff, m.epoch, m.peer)
    # GET /v1/load
    load = load_report(e)
    assert list(load["monitors"]) == [m.name for m in reading.monitors]
    for m in reading.monitors:
        entry = load["monitors"][m.name]
        assert (entry["active"], entry["handoff"], entry["epoch"], entry["events"]) == (
            m.active,
            m.handoff,
            m.epoch,
            m.events,
        )
        assert entry["cpuSeconds"] == m.cost_ns / 1e9
        assert entry["migrationWanted"] == m.migration_wanted
        assert entry["topics"] == list(m.compiled.spec.topics)
    assert {t: v["messages"] for t, v in load["topics"].items()} == {
        t: e.messages.get(t, 0) for t in e.router.routes
    }
    # /diagnostics: the active monitors
    assert read_engine(e).monitors == reading.active()
    assert all(m.active for m in reading.active())
    # Prometheus
    samples = _metrics(e)
    for m in reading.monitors:
        label = (("monitor", m.name),)
        assert samples[("edgerv_events_total", label)] == m.events
        assert samples[("edgerv_events_dropped_total", label)] == m.dropped
        assert samples[("edgerv_late_events_total", label)] == m.late
        assert samples[("edgerv_buffer_events", label)] == m.buffered
        assert samples[("edgerv_monitor_active", label)] == (1 if m.active else 0)
        for kind, n in (("violated", m.violations), ("satisfied", m.satisfactions)):
            key = ("edgerv_verdicts_total", (("monitor", m.name), ("verdict", kind)))
            assert samples[key] == n


def test_the_read_takes_the_lock_a_chunk_at_a_time_and_leaves_out_what_changed_meanwhile(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Paced (the diagnostics'), between two holds of the lock (READ_PAUSE), the engine
    goes on: a monitor removed or redefined then is left out of this reading (the next
    one has it as it is). Not paced (the API's), one hold."""
    monkeypatch.setattr(reading_module, "READ_CHUNK", 3)
    e = Engine("edge", flush_after=1e9)
    for i in range(8):
        e.put(_spec(KINDS[0], f"m{i}"), active=True)
    holds = []  # the reader's
    lock = e.lock
    engine_goes_on = [False]

    class Counting:
        def __enter__(self) -> None:
            if not engine_goes_on[0]:
                holds.append(time.monotonic())
            lock.__enter__()

        def __exit__(self, *exc: object) -> None:
            lock.__exit__(*exc)

    pauses = []

    def pause(seconds: float) -> None:
        pauses.append(seconds)
        if len(pauses) == 1:  # after the first chunk: m4 removed, m5 redefined
            engine_goes_on[0] = True
            e.remove("m4")
            e.put(_spec(KINDS[1], "m5"), active=True)
            engine_goes_on[0] = False

    monkeypatch.setattr(e, "lock", Counting())
    monkeypatch.setattr(reading_module.time, "sleep", pause)
    reading = read(e, paced=True)
    assert [m.name for m in reading.monitors] == ["m0", "m1", "m2", "m3", "m6", "m7"]
    assert reading.defined == 8
    assert len(holds) == 1 + 3 and pauses == [reading_module.READ_PAUSE] * 2
    holds.clear()
    whole = read(e)
    assert len(holds) == 1 and len(pauses) == 2 and len(whole.monitors) == 7
    monkeypatch.setattr(e, "lock", lock)
    again = read(e, paced=True)
    assert [m.name for m in again.monitors] == ["m0", "m1", "m2", "m3", "m5", "m6", "m7"]
    assert again.monitors[4].compiled.spec.sort_threshold == 4
