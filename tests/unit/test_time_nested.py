"""Time-bounded operators nested in any boolean combination, under always or at the
run's first instant (docs/semantics.md, "Time", "Nesting").

The reference evaluates each formula straight from its definition at every nanosecond
(signals hold their values between messages): ``F[a..b] f`` at t is f at some instant of
``[t+a, t+b]``, ``G[a..b] f`` at every one. Under ``always`` a nested formula is read its
horizon H late: its first failure at t is reported at t + H. At the top it is read at
the run's first instant t0: a single operator over atoms as soon as it is certain, a
nested one at t0 + H.
"""

from __future__ import annotations

import random

import pytest
import spot

from edgerv.core.diagnostics import InputError
from edgerv.core.pipeline import MonitorRuntime
from kit.checks import events, run, verdicts
from kit.dense import (
    BINARY,
    SIGNALS,
    Formula,
    evaluator,
    formulas,
    horizon,
    random_formula,
    random_run,
    size,
    text,
    timed,
    valid,
)
from kit.documents import compiled
from kit.reference import ReferenceMonitor


def nested_bodies(seed: int, count: int) -> list[Formula]:
    """Disjunctions holding two or more time-bounded operators, some nested: none of
    them in the shape ``P -> op`` that obligations take (test_time.py has those)."""

    def disjunction(rng: random.Random) -> Formula:
        return ("or", random_formula(rng, 3), random_formula(rng, 3))

    def keep(f: Formula) -> bool:
        return timed(f) >= 2 and horizon(f) <= 8 and size(f) <= 11 and not valid(f)

    return formulas(seed, count, keep, disjunction)


@pytest.mark.parametrize("body", nested_bodies(7, 80), ids=text)
def test_nested_under_always_fail_their_horizon_after_the_first_failure(body: Formula) -> None:
    rng = random.Random(text(body))
    h = horizon(body)
    for _ in range(4):
        end = rng.randint(h, 24)
        rows = random_run(rng, end)
        at = evaluator(rows)
        failures = [t for t in range(0, end - h + 1) if not at(body, t)]
        expected = [("violated", failures[0] + h)] if failures else []
        m = compiled(f"always ({text(body)})", SIGNALS, onVerdict="halt")
        (result,) = run([m], events(rows))
        got = [(v, stamp) for v, _, stamp in verdicts(result)]
        assert got == expected, (text(body), rows)


def top_level(seed: int, count: int) -> list[Formula]:
    """A time-bounded operator at the top holding another in its operand."""

    def keep(f: Formula) -> bool:
        top = f[0] in ("F", "G", *BINARY)
        return top and timed(f) >= 2 and horizon(f) <= 8 and size(f) <= 11

    return formulas(seed, count, keep)


@pytest.mark.parametrize("formula", top_level(11, 50), ids=text)
def test_nested_at_the_top_are_read_at_the_first_instant(formula: Formula) -> None:
    rng = random.Random(text(formula))
    h = horizon(formula)
    for _ in range(4):
        end = rng.randint(h, 20)
        rows = random_run(rng, end)
        holds = evaluator(rows)(formula, 0)
        m = compiled(text(formula), SIGNALS, onVerdict="halt")
        (result,) = run([m], events(rows))
        got = [(v, stamp) for v, _, stamp in verdicts(result)]
        assert got == [("satisfied" if holds else "violated", h)], (text(formula), rows)


def first_certain(kind: str, lo: int, hi: int, rows: list[tuple[str, int, bool]], end: int
                  ) -> tuple[str, int] | None:  # fmt: skip
    """The verdict of ``a U[lo..hi] b`` (``W``, ``F[lo..hi] b``, ``G[lo..hi] b``) at
    instant 0 and the first instant from which it is certain, from the definitions
    (edgerv's until: b at some t' of the window, a at every instant of [0, t'))."""
    at = evaluator(rows)
    a, b = ("atom", "a"), ("atom", "b")
    for t in range(0, end + 1):
        if kind == "F" and lo <= t <= hi and at(b, t):
            return "satisfied", t
        if kind == "F" and t == hi:
            return "violated", t
        if kind == "G" and lo <= t <= hi and not at(b, t):
            return "violated", t
        if kind == "G" and t == hi + 1:
            return "satisfied", t
        if kind in ("U", "W") and lo <= t <= hi and at(b, t):
            return "satisfied", t
        if kind in ("U", "W") and t <= hi and not at(a, t):
            return "violated", t
        if kind == "U" and t == hi:
            return "violated", t
        if kind == "W" and t == hi + 1:
            return "satisfied", t
        if kind in ("R", "M"):  # the dual of U (W) over !a, !b: the verdicts swapped
            dual = first_certain("U" if kind == "R" else "W", lo, hi,
                                 [(x, s, not v) for x, s, v in rows], end)  # fmt: skip
            swap = {"satisfied": "violated", "violated": "satisfied"}
            return None if dual is None else (swap[dual[0]], dual[1])
    return None


@pytest.mark.parametrize("kind", ["F", "G", "U", "W", "R", "M"])
def test_one_operator_at_the_top_is_decided_as_soon_as_it_is_certain(kind: str) -> None:
    rng = random.Random(kind)
    for _ in range(80):
        lo = rng.randint(0, 4)
        hi = lo + rng.randint(0, 4)
        end = rng.randint(0, 14)
        rows = random_run(rng, end)
        bound = f"{kind}[{lo}ns..{hi}ns]"
        formula = f"a {bound} b" if kind in BINARY else f"{bound} b"
        m = compiled(formula, SIGNALS, onVerdict="halt")
        (result,) = run([m], events(rows))
        got = [(v, stamp) for v, _, stamp in verdicts(result)]
        expected = first_certain(kind, lo, hi, rows, end)
        assert got == ([] if expected is None else [expected]), (formula, rows)


MS = 1_000_000


def test_reach_and_hold() -> None:
    """Reach the goal within 2 s, then stay there 500 ms: reached at 1.5 s and left at
    1.8 s fails; the failure of the obligation opened at 0 is certain at 2.5 s."""
    m = compiled("always (a -> F[0..2s] (b & G[0..500ms] b))", SIGNALS, onVerdict="halt")
    ok = events([("/a", 0, True), ("/b", 0, False), ("/c", 0, False), ("/a", 1, False),
                 ("/b", 1500 * MS, True), ("/c", 3000 * MS, True)])  # fmt: skip
    assert verdicts(run([m], ok)[0]) == []
    left = events([("/a", 0, True), ("/b", 0, False), ("/c", 0, False), ("/a", 1, False),
                   ("/b", 1500 * MS, True), ("/b", 1800 * MS, False),
                   ("/c", 3000 * MS, True)])  # fmt: skip
    ((verdict, _, stamp),) = verdicts(run([m], left)[0])
    assert (verdict, stamp) == ("violated", 2500 * MS)


def test_top_level_deadline_is_satisfied_when_its_answer_comes() -> None:
    """The issue's example: ``F[0..1s] b`` on a run where b comes at 0.6 s."""
    m = compiled("F[0..1s] b", SIGNALS, onVerdict="halt")
    rows = [("/a", 0, False), ("/b", 0, False), ("/c", 0, False), ("/b", 600 * MS, True)]
    assert [(v, s) for v, _, s in verdicts(run([m], events(rows))[0])] == [("satisfied", 600 * MS)]


# -- under untimed temporal operators ----------------------------------------------------

TEMPLATES = {  # over three formulas x, y, z holding time-bounded operators
    "always (({x}) -> (({y}) U ({z})))": "G(x -> (y U z))",
    "always (({x}) -> (({y}) W ({z})))": "G(x -> (y W z))",
    "({x}) U ({z})": "x U z",
    "F (({x}) & ({y}))": "F(x & y)",
    "(({x}) W ({y})) | F ({z})": "(x W y) | F z",
    "always (({x}) -> F ({z}))": "G(x -> F z)",
}


def triples(seed: int, count: int) -> list[tuple[str, Formula, Formula, Formula]]:
    rng = random.Random(seed)
    out: list[tuple[str, Formula, Formula, Formula]] = []
    while len(out) < count:
        xyz = tuple(random_formula(rng, 2) for _ in range(3))
        distinct = len({text(f) for f in xyz}) == 3 and sum(map(size, xyz)) <= 12
        if distinct and all(timed(f) for f in xyz) and sum(horizon(f) for f in xyz) <= 10:
            out.append((rng.choice(sorted(TEMPLATES)), *xyz))
    return out


@pytest.mark.parametrize(
    ("template", "x", "y", "z"), triples(5, 40), ids=lambda v: v if isinstance(v, str) else text(v)
)
def test_under_untimed_operators_the_letters_are_read_their_horizon_late(
    template: str, x: Formula, y: Formula, z: Formula
) -> None:
    """Untimed operators over time-bounded ones range over the instants at which one of
    their operands changes (their steps), read H late: the LTL3 verdicts of the
    independent reference over the operands' truths at those instants, each reported H
    after its instant. The operands are free propositions to both (a verdict that only
    their meaning makes certain is not reported early)."""
    assertion = template.format(x=text(x), y=text(y), z=text(z))
    reference = ReferenceMonitor(spot.formula(TEMPLATES[template]), ["x", "y", "z"], halt=True)
    used = [f for name, f in zip("xyz", (x, y, z), strict=True) if "{" + name + "}" in template]
    h = max(horizon(f) for f in used)
    rng = random.Random(assertion)
    m = compiled(assertion, SIGNALS, onVerdict="halt")
    for _ in range(4):
        end = rng.randint(h, 24)
        rows = random_run(rng, end)
        at = evaluator(rows)
        instants, letters = [], []
        for u in range(0, end - h + 1):
            letter = sum(1 << i for i, f in enumerate((x, y, z)) if at(f, u))
            if not letters or letter != letters[-1]:
                instants.append(u)
                letters.append(letter)
        expected = [(v, instants[k - 1] + h) for v, k in reference.run(letters)]
        got = [(v, stamp) for v, _, stamp in verdicts(run([m], events(rows))[0])]
        assert got == expected, (assertion, rows)


def test_an_assertion_about_the_first_instant_is_warned_about_with_reset() -> None:
    """Reset restarts the automaton, not the run's clock: a second reading of the first
    instant's window would come at each step after the verdict."""
    warned = compiled("F[0..1s] b", SIGNALS)  # onVerdict: reset, the default
    assert [w.message for w in warned.parsed.warnings] == [
        "this assertion is read at the run's first instant (a time-bounded operator outside "
        "always): after its verdict, reset reads it again at each step, its window long past"
    ]
    assert compiled("F[0..1s] b", SIGNALS, onVerdict="halt").parsed.warnings == ()
    assert compiled("always (a -> F[0..1s] b)", SIGNALS).parsed.warnings == ()


def failing(seed: int, count: int) -> list[tuple[Formula, list[tuple[str, int, bool]]]]:
    """Nested bodies, each with a run of 60 ns on which it fails (by the definitions)."""
    rng = random.Random(seed)
    out = []
    for body in nested_bodies(seed, 4 * count):
        rows = random_run(rng, 60)
        at = evaluator(rows)
        if any(not at(body, t) for t in range(0, 60 - horizon(body))) and len(out) < count:
            out.append((body, rows))
    return out


@pytest.mark.parametrize(
    ("body", "rows"),
    failing(13, 20),
    ids=lambda v: text(v) if isinstance(v[0], str) else "run",
)
def test_live_clock_steps_give_what_a_recorded_run_gives(
    body: Formula, rows: list[tuple[str, int, bool]]
) -> None:
    """The handler's way (events one by one, the clock advanced at instants of its own
    between them, evaluated each time) gives the steps and verdicts of a check."""
    rng = random.Random(text(body))
    m = compiled(f"always ({text(body)})", SIGNALS)
    (offline,) = run([m], events(rows))
    assert verdicts(offline)  # something to compare
    live, got = MonitorRuntime(m), []
    index = {name: i for i, name in enumerate(m.signal_names)}
    for seq, (topic, stamp, value) in enumerate(rows):
        if seq and rng.random() < 0.5 and stamp > 0:
            live.advance(rng.randint(rows[seq - 1][1], stamp - 1))
            got += live.evaluate()
        live.offer(stamp, seq, [(index[topic[1:]], value)])
        got += live.evaluate()
    live.advance(rows[-1][1])
    got += live.evaluate()
    assert [(v.verdict, v.step, v.stamp) for v in got] == verdicts(offline)


@pytest.mark.parametrize(
    "text", ["F[0..1ns] " * 1500 + "b", "always (" + "once (" * 200 + "F[0..1s] b" + ")" * 201]
)
def test_time_bounded_operators_nested_past_the_limit_are_refused_at_their_place(
    text: str,
) -> None:
    """Each nested one is a call deeper in reading it late (a RecursionError from 1,000
    on, found with F[0..1ns] nested 1,500 deep): more than 64 in one assertion, far past
    the 16 placeholders they would take, are refused at the 65th."""
    with pytest.raises(InputError) as info:
        compiled(text, SIGNALS)
    (error,) = info.value.errors
    assert "more than 64 time-bounded operators" in error.message
