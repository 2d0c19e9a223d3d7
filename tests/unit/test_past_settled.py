"""The past operators' shortcuts against what they stand for.

A monitor with past operators takes the last letter again, with no step, for a message
that leaves its atoms as they were while no timed operator may change with time and no
``prev`` is unsettled (:meth:`MonitorRuntime._compress_one`); :class:`Past` steps its
timed once and historically inline and finds their next change from the first edges
after now; an operand may be any function of the bits. Each is held here against the
plain way: every step taken, every edge looked at, operands from truth tables.
"""

from __future__ import annotations

import random
from typing import Any

import pytest
import spot

from edgerv.core.checker import CheckRun
from edgerv.core.language.past import Past, PastOp, _Runs, compile_boolean
from edgerv.core.pipeline import MonitorRuntime
from kit.checks import events
from kit.documents import compiled
from kit.randomruns import SIGNALS, random_assertion, random_events
from kit.sidebyside import state_of


def every_step(rt: MonitorRuntime) -> None:
    """``rt`` taking every step: its past operators never settled, and never stepped
    before a message (its valuation is the atoms' alone)."""
    if rt.past is None:
        return
    rt.past.always_settled = False
    rt.past.settled = lambda bits: False  # type: ignore[method-assign]
    compress_one = rt._compress_one

    def stepping(*args: Any) -> None:
        rt.past_stepped = False
        compress_one(*args)

    rt._compress_one = stepping  # type: ignore[method-assign]


@pytest.mark.parametrize("seed", range(150))
def test_a_letter_taken_again_without_a_step_is_the_steps_letter(seed: int) -> None:
    """Random monitors (past operators timed or not, nested, prev; ages; time-bounded
    F, G, U), random runs with ties, gaps and late messages, a message at a time (through
    :meth:`MonitorRuntime.offer` and the router's ``offer_event`` in turn): after each, the
    same letters and stamps, signal values, time, clock deadline and past operators' state
    as a monitor that steps its past operators at every message; then the same verdicts."""
    rng = random.Random(seed)
    m = compiled(random_assertion(rng), SIGNALS)
    evs = random_events(rng, rng.randint(1, 200))
    quick, stepped = CheckRun([m]), CheckRun([m])
    (q,), (s,) = quick.router.runtimes.values(), stepped.router.runtimes.values()
    every_step(s)
    route_of = quick.router.routes
    for i, event in enumerate(evs):
        if i % 2:  # the live handler's call
            route = route_of[event.topic]
            values = route.extract(event.msg)
            for runtime, b in route.readers:
                updates = tuple((sig, values[f]) for sig, f in route.bindings[b])
                runtime.offer(event.stamp, 0, updates)
        else:
            quick._feed_events([event])
        stepped._feed_events([event])
        assert (list(q.letters), list(q.stamps)) == (list(s.letters), list(s.stamps))
        assert state_of(q) == state_of(s), (m.spec.assertion, seed, i)
    end = max(e.stamp for e in evs) + rng.choice([0, 3_000_000, 100_000_000])
    (a,), (b,) = quick.finish(end), stepped.finish(end)
    assert [(v.verdict, v.stamp, v.step) for v in a.verdicts] == [
        (v.verdict, v.stamp, v.step) for v in b.verdicts
    ]
    assert (a.state, a.steps) == (b.state, b.steps)


def test_a_prev_is_stepped_at_a_message_that_changes_no_atom() -> None:
    """``prev a`` at a message on /b that leaves the atoms as they were: a's value at the
    step before, which the message on /a changed (the letter changes with no atom)."""
    m = compiled("always (prev a -> b)", {"a": "bool", "b": "bool"})
    run = CheckRun([m])
    (rt,) = run.router.runtimes.values()
    rows = [("/a", 1, False), ("/b", 2, True), ("/a", 3, True), ("/b", 4, True), ("/b", 5, True)]
    run._feed_events(events(rows))
    # bits: a 1, b 2, prev a 4
    assert list(rt.letters) == [0b010, 0b011, 0b111, 0b111]


def every_edge(runs: list[list[Any]], now: int, lo: int, hi: int) -> int | None:
    """The first instant after ``now`` among every run's start plus lo and end plus hi."""
    edges = [start + lo for start, _ in runs] + [end + hi for _, end in runs if end is not None]
    return min((at for at in edges if at > now), default=None)


def random_runs(rng: random.Random) -> list[list[Any]]:
    """Runs in order, some empty ([t, t]), some touching, the last one maybe ongoing."""
    runs: list[list[Any]] = []
    t = rng.randint(0, 20)
    for _ in range(rng.randint(0, 6)):
        start = t + rng.choice([0, 0, 1, 5, 30])
        t = start + rng.choice([0, 1, 4, 25])
        runs.append([start, t])
    if runs and rng.random() < 0.5:
        runs[-1][1] = None
    return runs


@pytest.mark.parametrize("seed", range(40))
def test_the_next_change_is_the_first_edge_after_now(seed: int) -> None:
    """A timed once's or historically's next change (:meth:`_Runs.next_change`, and
    :meth:`Past.next_change` of one) is the first of every edge after now, whatever its
    runs and now (before, among and after them)."""
    rng = random.Random(seed)
    operand = compile_boolean(spot.formula("p0"))
    for _ in range(200):
        runs = random_runs(rng)
        lo = rng.choice([0, 0, 1, 3, 10])
        hi = lo + rng.choice([0, 1, 5, 40, 2**62])
        now = rng.randint(-5, 120)
        expected = every_edge(runs, now, lo, hi)
        assert _Runs([list(r) for r in runs]).next_change(now, lo, hi) == expected
        for kind in ("once", "historically"):
            past = Past([PastOp(kind, 1, (operand,), (lo, hi))])  # type: ignore[arg-type]
            past.load([[list(r) for r in runs]])
            assert past.next_change(now) == expected, (runs, now, lo, hi)


OPS = [
    ("once", None), ("historically", None), ("prev", None), ("since", None),
    ("once", (0, 20)), ("once", (5, 5)), ("historically", (0, 20)), ("historically", (10, 30)),
    ("since", (0, 15)), ("since", (5, 25)), ("until", (0, 10)), ("until", (5, 12)),
]  # fmt: skip


@pytest.mark.parametrize("seed", range(20))
def test_an_operand_may_be_any_function_of_the_bits(seed: int) -> None:
    """Operators whose operands are plain functions step as those whose operands are
    compile_boolean's tables: the same letters, next changes and state."""
    rng = random.Random(seed)
    f, g = "p0 & !p1", "p1 | p2"
    plain = (lambda b: bool(b & 1) and not b & 2, lambda b: bool(b & 6))
    tables = (compile_boolean(spot.formula(f)), compile_boolean(spot.formula(g)))

    def ops(operands: tuple[Any, Any]) -> list[PastOp]:
        out = []
        for i, (kind, window) in enumerate(OPS):
            two = kind in ("since", "until")
            delay = window[1] + 3 if kind == "until" and window else 0
            out.append(PastOp(kind, 3 + i, operands if two else operands[:1], window, "", delay))  # type: ignore[arg-type]
        return out

    a, b = Past(ops(plain)), Past(ops(tables))
    now = 0
    for _ in range(300):
        now += rng.choice([0, 1, 2, 5, 11, 40])
        bits = rng.randrange(8)
        assert a.step(now, bits) == b.step(now, bits)
        assert a.next_change(now) == b.next_change(now)
        assert a.save() == b.save()
