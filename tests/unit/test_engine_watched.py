"""The scheduler's tick looks only at the slots the engine watches (Engine.watched) and
the clocked ones (Engine.clocked), not at every slot: that is the same as looking at
every slot only if every slot outside them is idle, whatever happened. Random runs of
monitors of every kind (taking events as they come, sorting, with a clock, with past
operators, with a buffer small enough to come under pressure) through messages one at a
time and in columns, ticks, flushes, handoffs (committed and aborted), deactivations and
redefinitions: after every step, that holds on both engines."""

from __future__ import annotations

import random
from typing import Any

import pytest

from edgerv.core.handoff import HandoffError
from edgerv.handler.engine import Engine
from kit.documents import compiled
from kit.engines import ManualClock

SIGNALS = {"a": "bool", "x": "float"}
KINDS: list[tuple[str, dict[str, Any]]] = [
    ("always (a -> x < 5)", {}),
    ("always (a -> x < 5)", {"sortThreshold": 3}),
    ("always (a -> x < 5)", {"sortThreshold": 12, "bufferCapacity": 16}),
    ("always (a -> age(x) < 3ms)", {}),
    ("always (a -> F[0..2ms] (x < 5))", {"sortThreshold": 2}),
    ("always (a -> once (x > 8))", {}),
    ("always (a -> historically[0..1ms] (x < 9))", {"sortThreshold": 4}),
]


def define(e: Engine, i: int, active: bool) -> None:
    assertion, spec = KINDS[i]
    e.put(compiled(assertion, SIGNALS, name=f"m{i}", **spec), active=active)


def idle(e: Engine) -> list[str]:
    """The slots outside Engine.watched that a tick of every slot would not pass over."""
    wrong = []
    for name, slot in e.slots.items():
        if e.watched.get(name) is slot:
            continue
        rt = slot.runtime
        if rt is None:
            continue  # (a tick passes over it too)
        if rt.events or len(rt.letters) or slot.pending_since is not None:
            wrong.append(f"{name}: holds events or letters, unwatched")
        if slot.full_since is not None or slot.migration_wanted:
            wrong.append(f"{name}: its pressure followed, unwatched")
    for name, slot in e.watched.items():
        if e.slots.get(name) is not slot:
            wrong.append(f"{name}: a slot watched that is no longer defined here")
    clocked = {n: s for n, s in e.slots.items() if s.compiled.clocked}
    if e.clocked != clocked:
        wrong.append(f"clocked {sorted(e.clocked)}, expected {sorted(clocked)}")
    return wrong


@pytest.mark.parametrize("seed", range(12))
def test_every_slot_a_tick_passes_over_is_idle(seed: int) -> None:
    rng = random.Random(seed)
    clock = ManualClock()
    engines = [Engine(f"h{i}", [], clock=clock, flush_after=0.05) for i in (0, 1)]
    for i in range(len(KINDS)):
        owner = rng.randint(0, 1)
        for k, e in enumerate(engines):
            define(e, i, active=k == owner)
    # stamps behind the engines' clock, as a robot's are: its steps come as time passes
    stamp, epoch, watched_most = clock.wall_ns() - 200_000_000, 0, 0
    for _ in range(300):
        op = rng.random()
        e = rng.choice(engines)
        if op < 0.5:  # messages: one at a time, or a batch taken a column at a time
            batch = []
            for _ in range(rng.choice([1, 2, 3, 80])):
                stamp += rng.choice([0, 1, 100_000, 2_000_000])
                topic = rng.choice(["/a", "/x"])
                value = rng.random() < 0.6 if topic == "/a" else rng.uniform(0, 10)
                batch.append((stamp, topic, [value]))
            for one in engines:
                one.ingest(batch)
        elif op < 0.7:  # time passes: flushes, clock steps, pressure
            clock.advance(rng.choice([0.0, 0.001, 0.01, 0.06, 1.5]))
            e.emit(e.tick())
        elif op < 0.75:  # the clocks' steps alone (a tick evaluates their letters)
            e.advance_clocks(clock.wall_ns())
        elif op < 0.9:  # a handoff of one monitor, committed or aborted
            name = f"m{rng.randrange(len(KINDS))}"
            src = next((x for x in engines if x.slots[name].active), None)
            if src is None:
                continue
            dst = engines[1 - engines.index(src)]
            epoch += 1
            src.handoffs.hold(name, epoch)
            dst.handoffs.receive(name, epoch)
            for _ in range(rng.randint(0, 6)):  # messages while it holds, before the cut
                stamp += rng.choice([1, 100_000])
                message = (stamp, "/x", [rng.uniform(0, 10)])
                if rng.random() < 0.5:
                    message = (stamp, "/a", [rng.random() < 0.6])
                for one in engines:
                    one.ingest([message])
                if rng.random() < 0.3:  # (the receiver's buffer found idle meanwhile)
                    dst.emit(dst.tick())
            cut = dst.handoffs.cut(name, epoch)
            snap = src.handoffs.release(name, epoch, cut, grace=0.0) if cut is not None else None
            if rng.random() < 0.3:  # (the sender's slot found idle meanwhile)
                src.emit(src.tick())
            if snap is not None and rng.random() < 0.6:
                dst.handoffs.adopt(name, epoch, snap)
                src.handoffs.commit(name, epoch)
            else:
                src.handoffs.abort(name, epoch)
                dst.handoffs.abort(name, epoch)
        elif op < 0.95:  # deactivated, or activated where no other engine runs it
            i = rng.randrange(len(KINDS))
            slot = e.slots[f"m{i}"]
            other = engines[1 - engines.index(e)].slots[f"m{i}"]
            try:
                e.set_active(f"m{i}", not slot.active and not other.active)
            except HandoffError:
                continue
        else:  # redefined: a fresh runtime where it was active
            i = rng.randrange(len(KINDS))
            define(e, i, active=e.slots[f"m{i}"].active)
        for one in engines:
            assert idle(one) == []
            watched_most = max(watched_most, len(one.watched))
    for e in engines:
        e.drain()
        e.emit(e.tick())
        assert idle(e) == []
    assert watched_most > 0  # (the runs gave it slots to watch)
    assert sum(len(e.watched) for e in engines) < 2 * len(KINDS)  # and idle ones leave it


def test_idle_monitors_cost_a_tick_nothing() -> None:
    """A thousand monitors, one of which takes messages: the tick looks at that one."""
    e = Engine("h", [], clock=ManualClock(), flush_after=0.05)
    e.put(compiled("always (a -> x < 5)", SIGNALS, name="busy", sortThreshold=3), active=True)
    for k in range(1000):
        e.put(compiled("always (y < 5)", {"y": "float"}, name=f"idle{k}"), active=True)
    e.emit(e.tick())  # (each is watched once activated, until a tick finds it idle)
    assert e.watched == {}
    e.ingest([(1, "/a", [True]), (2, "/x", [1.0])])
    assert list(e.watched) == ["busy"]
    assert e.clocked == {}


def test_a_clock_step_of_an_idle_monitor_is_watched() -> None:
    """A monitor with a clock goes idle, then its clock steps as time passes (its x
    grows older than 3 ms with no message): the letter it makes is a tick's to look at."""
    clock = ManualClock()
    e = Engine("h", [], clock=clock, flush_after=0.05)
    e.put(compiled("always (a -> age(x) < 3ms)", SIGNALS, name="aged"), active=True)
    now = clock.wall_ns()
    e.ingest([(now, "/x", [1.0]), (now + 1, "/a", [True])])
    for _ in range(2):  # evaluated, then found idle
        e.emit(e.tick())
    assert e.watched == {} and e.clocked == {"aged": e.slots["aged"]}
    clock.advance(1.0)
    e.advance_clocks(clock.wall_ns())
    assert len(e.slots["aged"].runtime.letters) > 0  # type: ignore[union-attr]
    assert idle(e) == []
