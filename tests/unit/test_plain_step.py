"""A plain monitor stepped as the ingest thread takes each event (issue 35): its letter
made from its topic's atoms, each computed once a message for every monitor reading the
topic (:mod:`edgerv.core.plain_step`), and walked at once unless it reaches a verdict
(docs/handler.md, "Buffers, the scheduler and pressure").

Held against the way it replaced: the same monitors with the step turned off
(``plain = False``: every letter made one event at a time and left to the evaluation),
fed the same messages: the same verdicts, steps and stamps, the same state. And the
counts it keeps in place of the handler's admission: every event taken is counted, a
walked monitor holds nothing and takes every event until a letter reaches a verdict.
"""

from __future__ import annotations

import math
import random
from typing import Any

import pytest

from edgerv.core.pipeline import MonitorRuntime, Router
from edgerv.handler.engine import COLUMNS_FROM, Engine
from edgerv.handler.reading import monitor_reports
from kit.documents import compiled
from kit.sidebyside import Collect

SIGNALS: dict[str, Any] = {
    "a": {"topic": "/a", "type": "std_msgs/msg/Bool"},
    "x": {"topic": "/p", "type": "geometry_msgs/msg/Point", "field": "x"},
    "y": {"topic": "/p", "type": "geometry_msgs/msg/Point", "field": "y", "initial": 1.0},
    "z": {"topic": "/z", "type": "std_msgs/msg/Float64"},
}
FIELDS = {"/a": ["data"], "/p": ["x", "y"], "/z": ["data"]}  # each topic's fields, published
POINT = {k: SIGNALS[k] for k in ("x", "y")}  # (every signal valued by /p's messages)
# the same comparisons in several monitors (shared), constants equal in value of another
# type (not shared), two fields of one message, signals of two topics (the monitor's own)
ATOMS = ["a", "!a", "x < 2", "x < 2.0", "x < 2", "x >= y", "y <= 1", "x != 3", "z > x",
         "z == 0", "y > -0.5", "x == 3", "x < 2"]  # fmt: skip
SHAPES = ["always ({p})", "always ({p} -> next ({q}))", "({p}) U ({q})", "eventually! ({p})",
          "always ({p} -> ({q}) W ({r}))", "always (({p}) | ({q}))", "({p}) R ({q})"]  # fmt: skip


def random_plain(rng: random.Random) -> str:
    parts = {k: rng.choice(ATOMS) for k in "pqr"}
    if rng.random() < 0.5:
        parts["p"] = f"{parts['p']} & {rng.choice(ATOMS)}"
    return rng.choice(SHAPES).format(**parts)


def random_messages(rng: random.Random, n: int) -> list[tuple[int, str, list[Any]]]:
    """(stamp, topic, field values) as the ROS layer hands them over: /p with x and y,
    runs of one value, ties and now and then one late."""
    stamp, out = 0, []
    held: dict[str, list[Any]] = {"/a": [False], "/p": [1.0, 2.0], "/z": [0.0]}
    for _ in range(n):
        stamp += rng.choice([0, 1, 1_000, 5_000_000])
        at = stamp - rng.randint(1, 9_000_000) if rng.random() < 0.03 else stamp
        topic = rng.choice(["/a", "/p", "/p", "/z"])
        if rng.random() < 0.3:
            if topic == "/a":
                held[topic] = [rng.random() < 0.5]
            elif topic == "/p":
                held[topic] = [rng.choice([0.0, 1.0, 2.0, 3.0, math.nan]), rng.choice([1.0, -1.0])]
            else:
                held[topic] = [rng.choice([0.0, 2.5, 5.0])]
        out.append((at, topic, list(held[topic])))
    return out


def reference(monitors: list[Any], msgs: list[tuple[int, str, list[Any]]]) -> dict[str, Any]:
    """Each monitor alone, its step turned off, offered each message and evaluated."""
    out: dict[str, Any] = {}
    for m in monitors:
        rt = MonitorRuntime(m)
        rt.plain = False
        router = Router([rt])
        verdicts: list[tuple[str, int, int]] = []
        for stamp, topic, values in msgs:
            route = router.routes.get(topic)
            if route is None:
                continue
            mine = [values[FIELDS[topic].index(f)] for f in route.fields]
            for runtime in router.offer_values(route, stamp, mine):
                verdicts += [(v.verdict, v.stamp, v.step) for v in runtime.evaluate()]
        values = None if rt.halted else ([repr(v) for v in rt.values], rt.valuation)
        out[m.name] = (verdicts, rt.state, rt.step, values)
    return out


def engine_of(monitors: list[Any], **kwargs: Any) -> tuple[Engine, Collect]:
    sink = Collect()
    e = Engine("edge", [sink], flush_after=1e9, **kwargs)
    for m in monitors:
        e.put(m, active=True)
    return e, sink


def routed(e: Engine, msgs: list[tuple[int, str, list[Any]]]) -> list[tuple[int, str, list[Any]]]:
    """The messages read for the engine's routes (each topic's fields, in its order)."""
    out = []
    for stamp, topic, values in msgs:
        route = e.router.routes.get(topic)
        if route is not None:
            out.append((stamp, topic, [values[FIELDS[topic].index(f)] for f in route.fields]))
    return out


@pytest.mark.parametrize("seed", range(60))
def test_plain_monitors_stepped_as_they_take_give_what_evaluating_every_letter_gives(
    seed: int,
) -> None:
    """Two to six random plain monitors sharing topics and atoms, fed a message at a time
    (evaluated now and then) or in long batches, against each alone with its step off."""
    rng = random.Random(seed)
    monitors = [
        compiled(random_plain(rng), SIGNALS, name=f"m{i}", onVerdict=rng.choice(["reset", "halt"]))
        for i in range(rng.randint(2, 6))
    ]
    msgs = random_messages(rng, rng.randint(1, 300))
    e, sink = engine_of(monitors)
    feed = routed(e, msgs)
    fed = 0
    while fed < len(feed):
        size = rng.choice([1, 1, 1, 5, COLUMNS_FROM, 100])
        part = feed[fed : fed + size]
        if size == 1 or len(part) < COLUMNS_FROM:
            for message in part:
                assert e.ingest([message], now=0.0)
        else:
            assert e.ingest(part, now=0.0)
        fed += len(part)
        if rng.random() < 0.4:
            e.emit(e.evaluate())
    e.emit(e.evaluate())
    expected = reference(monitors, msgs)
    for m in monitors:
        slot = e.slots[m.name]
        rt = slot.runtime
        assert rt is not None
        # (a halted monitor's values: those of the messages before its evaluation halted it)
        values = None if rt.halted else ([repr(v) for v in rt.values], rt.valuation)
        got = (rt.state, rt.step, values)
        assert (sink.verdicts.get(m.name, []), *got) == expected[m.name], m.spec.assertion
        assert slot.dropped == 0 and not rt.letters


def test_a_topics_atoms_are_computed_once_for_all_its_monitors() -> None:
    """Equal comparisons of one field are one atom of the topic; a constant of another
    type, or an atom that reads another topic's signal, is not shared."""
    monitors = [
        compiled("always (x < 2 & y <= 1)", SIGNALS, name="m0"),
        compiled("always (x < 2 -> next (y <= 1))", SIGNALS, name="m1"),
        compiled("always (x < 2.0)", SIGNALS, name="m2"),
        compiled("always (z > x)", SIGNALS, name="m3"),
    ]
    e, _ = engine_of(monitors)
    route = e.router.routes["/p"]
    assert len(route.atoms.reads) == 3  # x < 2, y <= 1, x < 2.0
    plans = {rt.name: plan for (rt, _), plan in zip(route.readers, route.plans, strict=True)}
    assert all(plan is not None for plan in plans.values())
    assert plans["m0"] is not None and plans["m1"] is not None
    assert {k for k, _ in plans["m0"].shared} == {k for k, _ in plans["m1"].shared}
    assert plans["m3"] is not None and plans["m3"].own and not plans["m3"].shared
    e.set_active("m0", False)  # its atoms stay for m1; m2's own
    assert len(e.router.routes["/p"].atoms.reads) == 3
    e.set_active("m2", False)
    assert len(e.router.routes["/p"].atoms.reads) == 2


def routing(router: Router) -> dict[str, Any]:
    """What a router does with a topic's message: its readers in order, each one's
    binding and plan (the atoms' places it reads), and the topic's atoms."""
    return {
        topic: (
            [(rt.name, b) for rt, b in route.readers],
            [None if p is None else (p.shared, p.own) for p in route.plans],
            [(left, right, const) for left, right, _, const in route.atoms.reads],
        )
        for topic, route in sorted(router.routes.items())
    }


@pytest.mark.parametrize("seed", range(20))
def test_monitors_removed_at_once_are_routed_as_removed_one_at_a_time(seed: int) -> None:
    """Router.removing (a handoff's commit of many monitors) rebuilds each topic's
    readers and atoms once, when it ends: the routes are then those of removing them one
    at a time, a monitor redefined inside keeps its new runtime, and the monitors left
    take the same steps. Inside it, what was removed is still routed to."""
    rng = random.Random(seed)
    monitors = [compiled(random_plain(rng), SIGNALS, name=f"m{i}") for i in range(8)]
    names = [m.name for m in monitors]
    gone, again = rng.sample(names, 5), rng.choice(names)
    one, batch = (Router([MonitorRuntime(m) for m in monitors]) for _ in range(2))
    for n in [*gone, again]:
        one.remove(n)
    one.add(MonitorRuntime(monitors[names.index(again)]))
    with batch.removing():
        for n in [*gone, again]:
            batch.remove(n)
        batch.add(MonitorRuntime(monitors[names.index(again)]))
        routed_to = {rt.name for route in batch.routes.values() for rt, _ in route.readers}
        assert routed_to == set(names)  # the removed ones too, until it ends
    assert routing(batch) == routing(one)
    assert set(batch.runtimes) == (set(names) - set(gone)) | {again}
    msgs = random_messages(rng, 200)
    steps = []
    for router in (batch, one):
        seen = []
        for stamp, topic, values in msgs:
            route = router.routes.get(topic)
            if route is not None:
                mine = [values[FIELDS[topic].index(f)] for f in route.fields]
                for runtime in router.offer_values(route, stamp, mine):
                    seen += [(runtime.name, v.verdict, v.step) for v in runtime.evaluate()]
        seen += sorted((n, rt.step, rt.state) for n, rt in router.runtimes.items())
        steps.append(seen)
    assert steps[0] == steps[1]


def test_not_plain_monitors_get_no_plan() -> None:
    monitors = [
        compiled("always (x < 2 | once a)", SIGNALS, name="past"),
        compiled("always (age(x) < 10ms)", SIGNALS, name="aged"),
        compiled("always (x < 2)", SIGNALS, name="window", sortThreshold=3),
    ]
    e, _ = engine_of(monitors)
    assert e.router.routes["/p"].plans == [None, None, None]


def test_every_event_taken_is_counted_across_runtimes() -> None:
    """The events it took, counted in place of the admission, stay in its slot's count
    when its runtime goes (deactivated) and a new one comes."""
    e, _ = engine_of([compiled("always (x < 5)", POINT, name="m")])
    e.ingest([(i, "/p", [1.0, 1.0]) for i in range(1, 6)], now=0.0)
    for i in range(6, 9):
        e.ingest([(i, "/p", [1.0, 1.0])], now=0.0)
    slot = e.slots["m"]
    assert slot.events == 8 and monitor_reports(e)[0]["events"] == 8
    e.set_active("m", False)
    assert slot.events == 8
    e.set_active("m", True)
    e.ingest([(20, "/p", [1.0, 1.0])], now=0.0)
    assert slot.events == 9 and slot.pending_since is None and not e.waiting


def test_a_walked_monitor_takes_every_event_until_a_verdict_then_its_buffer_fills() -> None:
    """Capacity 3: quiet letters are walked (nothing held, nothing dropped); from a
    violation on the letters wait, and the buffer fills and drops as ever. One at a time
    and in a long batch alike."""
    quiet = [(i, "/p", [1.0, 1.0]) for i in range(1, 41)]
    loud = [(i, "/p", [9.0, 1.0]) for i in range(41, 81)]
    for batch in (False, True):
        e, sink = engine_of([compiled("always (x < 5)", POINT, name="m", bufferCapacity=3)])
        e.dozing = False  # a scheduler busy elsewhere: the ingest thread evaluates nothing
        for part in (quiet, loud):
            if batch:
                assert len(part) >= COLUMNS_FROM and e.ingest(part, now=0.0)
            else:
                for message in part:
                    e.ingest([message], now=0.0)
        slot = e.slots["m"]
        assert slot.events == 43 and slot.dropped == 37, batch
        e.emit(e.evaluate())
        assert [v[2] for v in sink.verdicts["m"]] == [41, 42, 43], batch
