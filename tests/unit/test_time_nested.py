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
from collections.abc import Callable
from functools import cache
from typing import Any

import pytest
import spot

from helpers import compiled, events, run, verdicts

SIGNALS = {name: "bool" for name in "abc"}
Formula = tuple[Any, ...]  # ("atom", name) | ("not", f) | ("and"|"or", f, g) | ("F"|"G", lo, hi, f)


def text(f: Formula) -> str:
    kind = f[0]
    if kind == "atom":
        return str(f[1])
    if kind == "not":
        return f"!({text(f[1])})"
    if kind in ("and", "or"):
        return f"({text(f[1])}) {'&' if kind == 'and' else '|'} ({text(f[2])})"
    return f"{kind}[{f[1]}ns..{f[2]}ns] ({text(f[3])})"


def horizon(f: Formula) -> int:
    kind = f[0]
    if kind == "atom":
        return 0
    if kind == "not":
        return horizon(f[1])
    if kind in ("and", "or"):
        return max(horizon(f[1]), horizon(f[2]))
    return int(f[2]) + horizon(f[3])


def timed(f: Formula) -> int:
    """How many time-bounded operators ``f`` holds."""
    kind = f[0]
    if kind == "atom":
        return 0
    if kind == "not":
        return timed(f[1])
    if kind in ("and", "or"):
        return timed(f[1]) + timed(f[2])
    return 1 + timed(f[3])


def evaluator(rows: list[tuple[str, int, bool]]) -> Callable[[Formula, int], bool]:
    """The truth of a formula at an instant, from the definitions, over the run ``rows``
    (one message a stamp; a value holds from its message until the next)."""

    def value(name: str, t: int) -> bool:
        last = False
        for topic, stamp, v in rows:
            if topic == f"/{name}" and stamp <= t:
                last = v
        return last

    @cache
    def at(f: Formula, t: int) -> bool:
        kind = f[0]
        if kind == "atom":
            return value(f[1], t)
        if kind == "not":
            return not at(f[1], t)
        if kind == "and":
            return at(f[1], t) and at(f[2], t)
        if kind == "or":
            return at(f[1], t) or at(f[2], t)
        window = range(t + f[1], t + f[2] + 1)
        return (any if kind == "F" else all)(at(f[3], u) for u in window)

    return at


def random_formula(rng: random.Random, depth: int) -> Formula:
    if depth == 0 or rng.random() < 0.2:
        return ("atom", rng.choice("abc"))
    kind = rng.choice(["not", "and", "or", "F", "G", "F", "G"])
    if kind == "not":
        return ("not", random_formula(rng, depth - 1))
    if kind in ("and", "or"):
        return (kind, random_formula(rng, depth - 1), random_formula(rng, depth - 1))
    lo = rng.randint(0, 3)
    return (kind, lo, lo + rng.randint(0, 3), random_formula(rng, depth - 1))


def random_run(rng: random.Random, end: int) -> list[tuple[str, int, bool]]:
    """Every signal at 0 (the run's first instant), then a change now and then, one
    message a stamp."""
    rows = [("/a", 0, rng.random() < 0.5), ("/b", 0, rng.random() < 0.5)]
    rows.append(("/c", 0, rng.random() < 0.5))
    rows += [(f"/{rng.choice('abc')}", t, rng.random() < 0.5) for t in range(1, end)
             if rng.random() < 0.4]  # fmt: skip
    if end > 0:  # the run's time reaches ``end``: a message there
        rows.append((f"/{rng.choice('abc')}", end, rng.random() < 0.5))
    return rows


def propositional(f: Formula, names: dict[str, str]) -> str:
    """``f`` with each time-bounded subformula a proposition of its own (by its text)."""
    kind = f[0]
    if kind == "atom":
        return str(f[1])
    if kind == "not":
        return f"!({propositional(f[1], names)})"
    if kind in ("and", "or"):
        op = "&" if kind == "and" else "|"
        return f"({propositional(f[1], names)}) {op} ({propositional(f[2], names)})"
    return names.setdefault(text(f), f"t{len(names)}")


def valid(f: Formula) -> bool:
    """True whatever its propositions: a monitor of it is satisfied at its first step."""
    return bool(spot.are_equivalent(spot.formula(propositional(f, {})), spot.formula.tt()))


def nested_bodies(seed: int, count: int) -> list[Formula]:
    """Disjunctions holding two or more time-bounded operators, some nested: none of
    them in the shape ``P -> op`` that obligations take (test_time.py has those)."""
    rng = random.Random(seed)
    out: list[Formula] = []
    while len(out) < count:
        f: Formula = ("or", random_formula(rng, 3), random_formula(rng, 3))
        if timed(f) >= 2 and horizon(f) <= 8 and not valid(f):
            out.append(f)
    return out


@pytest.mark.parametrize("body", nested_bodies(7, 60), ids=text)
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
    rng = random.Random(seed)
    out: list[Formula] = []
    while len(out) < count:
        f = random_formula(rng, 3)
        if f[0] in ("F", "G") and timed(f[3]) >= 1 and horizon(f) <= 8:
            out.append(f)
    return out


@pytest.mark.parametrize("formula", top_level(11, 40), ids=text)
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
    return None


@pytest.mark.parametrize("kind", ["F", "G", "U", "W"])
def test_one_operator_at_the_top_is_decided_as_soon_as_it_is_certain(kind: str) -> None:
    rng = random.Random(kind)
    for _ in range(80):
        lo = rng.randint(0, 4)
        hi = lo + rng.randint(0, 4)
        end = rng.randint(0, 14)
        rows = random_run(rng, end)
        bound = f"{kind}[{lo}ns..{hi}ns]"
        formula = f"a {bound} b" if kind in ("U", "W") else f"{bound} b"
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
