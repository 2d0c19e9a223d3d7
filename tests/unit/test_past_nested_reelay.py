"""Past operators nested in any way (docs/semantics.md, "Past"; "Time", "Nesting"),
against Reelay's dense-time monitors and the brute-force references of tests/kit/dense.py.

* Reelay: random formulas over a and b in which once, historically and since, each
  timed (``[lo..hi]`` in milliseconds, point windows included) or untimed, nest in each
  other's operands (either side of since) and under ``!``, ``&``, ``|`` and ``->``, on
  random runs (gaps of milliseconds, some a nanosecond more): at every step edgerv takes
  (each message, each clock step) the formula's truth is Reelay's at that instant, and
  every instant at which Reelay's truth changes is one of edgerv's steps, from the run's
  first message on (before it both see nothing: no witness, no failure).
* ``prev``, which Reelay's dense monitors do not have: random formulas of every past
  operator and prev, nested at random, against dense.past_steps (every nanosecond: the
  steps, clock steps included, and the truth at each).
* Past inside time-bounded future inside past (``always (historically[0..2ns]
  (F[0..1ns] (once (a))))`` and deeper): the verdicts of ``always (f)`` against f's
  truth at every nanosecond (dense.evaluator), read its horizon late.

Per run of the module (seeded, the same every time): 44 formulas on 88 runs against
Reelay, 5,274 steps compared (874 of them clock steps; each of Reelay's 533 changes is
one); 40 formulas with prev on 120 runs, 1,189 steps compared (104 clock steps); 40
mixed formulas on 160 runs, their truth at 2,172 instants, 520 verdicts compared. The
one disagreement found, edgerv's (since fixed), is the regression test at the end.
"""

from __future__ import annotations

import functools
import random
from typing import Any

import pytest

from kit.checks import events, run, step_truths, truth_at, verdicts
from kit.dense import (
    BINARY,
    CONNECTIVES,
    PAST,
    SIGNALS,
    Formula,
    evaluator,
    formulas,
    horizon,
    past_steps,
    random_run,
    size,
    text,
    valid,
)
from kit.documents import compiled

MS = 1_000_000
BOOLS = {n: {"topic": f"/{n}", "type": "std_msgs/msg/Bool", "initial": False} for n in "ab"}


def subformulas(f: Formula) -> list[Formula]:
    """``f`` and its subformulas."""
    return [f, *(g for h in f[1:] if isinstance(h, tuple) for g in subformulas(h))]


def past_depth(f: Formula) -> int:
    """How many past operators (prev too) the deepest path from the top goes through."""
    below = max((past_depth(g) for g in f[1:] if isinstance(g, tuple)), default=0)
    return below + (f[0] in (*PAST, "prev"))


def random_past(rng: random.Random, depth: int, unit: int, prev: bool) -> Formula:
    """A past formula over a and b: connectives, once, historically and since, timed
    (bounds a few ``unit`` apart) or untimed, and prev if asked, nested at random."""
    if depth == 0 or rng.random() < 0.2:
        return ("atom", rng.choice("ab"))
    kind = rng.choice(["not", *CONNECTIVES, *PAST, *PAST, *(["prev"] if prev else [])])
    x = random_past(rng, depth - 1, unit, prev)
    if kind in ("not", "prev"):
        return (kind, x)
    y = random_past(rng, depth - 1, unit, prev)
    if kind in CONNECTIVES:
        return (kind, x, y)
    if rng.random() < 0.35:
        lo, hi = 0, None
    elif unit == MS:
        lo = rng.choice([0, 0, 5, 10, 20]) * MS
        hi = lo + rng.choice([5, 20, 40, *([0] if lo else [])]) * MS  # Reelay: [0:0] is once
    else:
        lo = rng.randint(0, 3)
        hi = lo + rng.randint(0, 3)
    return (kind, lo, hi, x, y) if kind == "since" else (kind, lo, hi, x)


# -- against Reelay's dense-time monitors ---------------------------------------------------


def to_reelay(f: Formula) -> str:
    """Reelay's text of a formula without prev, in edgerv's meaning.

    Reelay 25's dense `since` differs from edgerv's at the two boundaries that
    test_past.py::test_reelays_dense_since_differs_at_two_boundaries argues, and they are
    written out here rather than left out (both readings agree everywhere else):

    * the present instant is a witness (with ``lo = 0``, and for the untimed `since`, which
      holds at a step where g does): `g or (...)`;
    * the junction: where g stops as f starts, no instant of g has f at every instant
      after it in edgerv's timed since (a value holds until the next message, that one
      excluded), so only instants of g where f holds too are witnesses: `f since (f and g)`
      (the untimed since, over steps, counts the junction as Reelay does)."""
    kind = f[0]
    if kind == "atom":
        return "{" + str(f[1]) + "}"
    if kind == "not":
        return f"(not {to_reelay(f[1])})"
    if kind in CONNECTIVES:  # Reelay's words: and, or, implies
        return f"({to_reelay(f[1])} {kind} {to_reelay(f[2])})"
    bound = "" if f[2] is None else f"[{f[1]}:{f[2]}]"
    if kind != "since":
        return f"({kind}{bound} {to_reelay(f[3])})"
    x, y = to_reelay(f[3]), to_reelay(f[4])
    if f[2] is None:
        return f"({y} or ({x} since {y}))"
    since = f"({x} since{bound} ({x} and {y}))"
    return f"({y} or {since})" if f[1] == 0 else since


def shifts(f: Formula) -> set[int]:
    """How long after a message the truth of ``f``, or of a formula in it, can change:
    each timed operator moves its operands' changes by its bounds (the first message
    starts every window: the operands' own instants count too)."""
    if f[0] == "atom":
        return {0}
    inner = {0}.union(*(shifts(g) for g in f[1:] if isinstance(g, tuple)))
    if f[0] not in PAST or f[2] is None:
        return inner
    return {s + d for s in inner for d in (0, f[1], f[2])}


@functools.cache
def reelay_options() -> tuple[Any, Any]:
    """Reelay's binding and the options reelay.dense_timed_monitor gives it."""
    from reelay import _pybind11_module as rym  # type: ignore[import-untyped]

    return rym, rym.monitor_options("time", "value", "constant", True)


def reelay_changes(
    f: Formula, rows: list[tuple[str, int, bool]], end: int
) -> list[tuple[int, bool]]:
    """Reelay's (instant, truth from then on) changes of ``f`` over the run, its time
    starting at the first message (0 for Reelay). The monitor is built as
    reelay.dense_timed_monitor builds it, without first parsing the text to choose
    the kind (as long as building it).

    Reelay is updated, with the values held, at every instant where the truth of the
    formula or of one in it can change (each message's, plus :func:`shifts`): Reelay 25
    is right only when each update's period holds one truth of each (see the test
    below)."""
    rym, options = reelay_options()
    monitor = rym.dense_monitor.make(to_reelay(f), options)
    t0 = rows[0][1]
    messages = {stamp: (topic[1:], value) for topic, stamp, value in rows}
    instants = {s + d for s in messages for d in shifts(f) if s + d <= end}
    held = dict.fromkeys("ab", False)
    changes: list[tuple[int, bool]] = []
    # the last update, after the end, reports the period up to it
    for t in [*sorted(instants | {end}), end + 1]:
        if t in messages:
            held[messages[t][0]] = messages[t][1]
        for rec in monitor.update({"time": t - t0, **held}):
            if not changes or changes[-1][1] != rec["value"]:
                changes.append((t0 + int(rec["time"]), bool(rec["value"])))
    return changes


def ms_run(rng: random.Random, n: int) -> list[tuple[str, int, bool]]:
    """``n`` messages, one a stamp, gaps of 1 to 30 ms, some a nanosecond more."""
    stamp, out = rng.randint(0, 10**9), []
    for _ in range(n):
        out.append((rng.choice(["/a", "/b"]), stamp, rng.random() < 0.5))
        stamp += rng.choice([1, 3, 5, 10, 20, 30]) * MS + rng.choice([0, 1])
    return out


def nested(f: Formula) -> bool:
    """A past operator in another's operand, and no more than fits in a monitor; not an
    untimed once or historically at the top (its truth changes once at most)."""
    monotone = f[0] in ("once", "historically") and f[2] is None
    return past_depth(f) >= 2 and size(f) <= 14 and not monotone


# a Reelay monitor takes 7 ms to build (its parser's grammar, whatever the formula), a run
# of 50 messages 3 ms in all: two runs of each formula
REELAY_FORMULAS = formulas(34, 44, nested, lambda rng: random_past(rng, 4, MS, prev=False))


@pytest.mark.parametrize("formula", REELAY_FORMULAS, ids=text)
def test_nested_past_formulas_match_reelays_dense_monitors(formula: Formula) -> None:
    rng = random.Random(text(formula))
    for _ in range(2):
        rows = ms_run(rng, 50)
        end = rows[-1][1] + rng.choice([0, 30, 80]) * MS
        got = step_truths(text(formula), BOOLS, rows, end)
        changes = reelay_changes(formula, rows, end)
        assert got == [(t, truth_at(changes, t)) for t, _ in got], (text(formula), rows, end)
        stamps = {t for t, _ in got}
        missed = [t for t, _ in changes if rows[0][1] < t <= end and t not in stamps]
        assert not missed, (text(formula), rows, end, missed)


def test_the_reelay_formulas_nest_every_operator_everywhere() -> None:
    """What the formulas above hold, together: every past operator timed and untimed,
    over a past operator (either side of since), and every connective over one."""
    seen = set()
    for f in REELAY_FORMULAS:
        for g in subformulas(f):
            timing = "" if g[0] not in PAST else "untimed" if g[2] is None else "timed"
            for side, h in enumerate(x for x in g[1:] if isinstance(x, tuple)):
                if past_depth(h):
                    seen.add((g[0], timing, side if g[0] == "since" else 0))
    wanted = {(k, "", 0) for k in (*CONNECTIVES, "not")}
    for k in PAST:
        for timing in ("timed", "untimed"):
            wanted |= {(k, timing, side) for side in ((0, 1) if k == "since" else (0,))}
    assert wanted <= seen, sorted(wanted - seen)


def test_reelay_is_right_where_each_update_holds_one_truth() -> None:
    """Why Reelay is updated wherever a formula in the monitored one may change: Reelay 25
    answers right where each update's period holds one truth of every formula in it.

    * Its Python output: after a true period, one that starts false and turns true
      reports neither change. The `or` of
      test_past.py::test_reelays_dense_or_loses_what_its_de_morgan_dual_keeps is one:
      with an update at 446, where it turns true again, the segment from 426.5 is there.
    * Its since: an operand that makes it false within a period clears the whole period.
      `(once[0:5] {b}) since {a}`, a and b true until 10, holds until 15: updated at 10
      and 30, Reelay says false from 10; with an update at 15 too, from 15."""
    rym, options = reelay_options()

    def segments(pattern: str, seq: list[tuple[float, bool, bool]]) -> list[tuple[float, bool]]:
        monitor = rym.dense_monitor.make(pattern, options)
        out = []
        for t, a, b in seq:
            out += [(r["time"], r["value"]) for r in monitor.update({"time": t, "a": a, "b": b})]
        return out

    seq = [(0, True, True), (403, True, False), (406, True, True), (426.5, False, True),
           (456, True, True), (500, False, True)]  # fmt: skip
    pattern = "((historically[0:40] {b}) or {a})"
    assert segments(pattern, seq) == [(0.0, True)]
    assert segments(pattern, sorted([*seq, (446, False, True)])) == [
        (0.0, True), (426.5, False), (446.0, True)]  # fmt: skip
    seq = [(0, True, True), (10, False, False), (30, False, False), (40, False, False)]
    pattern = "((once[0:5] {b}) since {a})"
    assert segments(pattern, seq) == [(0.0, True), (10.0, False)]
    assert segments(pattern, sorted([*seq, (15, False, False)])) == [(0.0, True), (15.0, False)]


# -- prev: against the brute-force reference -------------------------------------------------


def ns_run(rng: random.Random, end: int) -> list[tuple[str, int, bool]]:
    """A message at a first instant of 0 to 3 ns, then at about two instants in five up
    to ``end``, one a stamp."""
    first = rng.randint(0, 3)
    stamps = [t for t in range(first, end + 1) if t == first or rng.random() < 0.4]
    return [(rng.choice(["/a", "/b"]), t, rng.random() < 0.5) for t in stamps]


def with_prev(f: Formula) -> bool:
    return any(g[0] == "prev" for g in subformulas(f)) and past_depth(f) >= 2 and size(f) <= 14


PREV_FORMULAS = formulas(35, 40, with_prev, lambda rng: random_past(rng, 4, 1, prev=True))


@pytest.mark.parametrize("formula", PREV_FORMULAS, ids=text)
def test_nested_past_formulas_with_prev_match_the_definition(formula: Formula) -> None:
    rng = random.Random(text(formula))
    for _ in range(3):
        end = rng.randint(12, 30)
        rows = ns_run(rng, end)
        got = step_truths(text(formula), BOOLS, rows, end)
        assert got == past_steps(formula, rows, end), (text(formula), rows, end)


# -- past inside time-bounded future inside past ------------------------------------------------


def small(rng: random.Random) -> Formula:
    """An atom, its negation, or a past operator over one."""
    atom = ("atom", rng.choice("abc"))
    roll = rng.random()
    if roll < 0.5:
        return atom
    if roll < 0.65:
        return ("not", atom)
    return past_over(rng, atom)


def past_over(rng: random.Random, f: Formula) -> Formula:
    """A past operator, timed or untimed, over ``f`` (on either side of since)."""
    kind = rng.choice(PAST)
    lo, hi = (0, None) if rng.random() < 0.35 else (rng.randint(0, 2), rng.randint(0, 2))
    hi = None if hi is None else lo + hi
    if kind != "since":
        return (kind, lo, hi, f)
    other = small(rng) if rng.random() < 0.5 else ("atom", rng.choice("abc"))
    return (kind, lo, hi, *((f, other) if rng.random() < 0.5 else (other, f)))


def layered(rng: random.Random, layers: str, top: bool = True) -> Formula:
    """A formula whose operators, from the top, go through ``layers``: ``p`` a past
    operator, ``f`` a time-bounded future one, each with the next layer in one of its
    operands (the other a small formula), now and then under a connective. At the top,
    no conjunction (nor a negation, which could make one): ``always`` splits one into
    conjuncts, each reported as soon as its own horizon allows (test_verdict_delay.py
    measures that; the bodies here are read exactly H late, as test_time_nested's are)."""
    if not layers:
        return small(rng)
    inner = layered(rng, layers[1:], top=False)
    if layers[0] == "p":
        f = past_over(rng, inner)
    else:
        kind = rng.choice(["F", "G", "F", "G", *BINARY])
        lo = rng.randint(0, 2)
        hi = lo + rng.randint(0, 2)
        if kind in BINARY:
            other = small(rng)
            f = (kind, lo, hi, *((inner, other) if rng.random() < 0.5 else (other, inner)))
        else:
            f = (kind, lo, hi, inner)
    roll = rng.random()
    if roll < 0.15 and not top:
        return ("not", f)
    if roll < 0.4:
        kind = rng.choice(["or", "implies"] if top else list(CONNECTIVES))
        return (kind, *((f, small(rng)) if rng.random() < 0.5 else (small(rng), f)))
    return f


def mixed(f: Formula) -> bool:
    return horizon(f) <= 8 and size(f) <= 12 and not valid(f)


MIXED_FORMULAS = formulas(
    36, 40, mixed, lambda rng: layered(rng, rng.choice(["pfp", "fpfp", "pfpf", "ppfp"]))
)


@pytest.mark.parametrize("body", MIXED_FORMULAS, ids=text)
def test_past_in_future_in_past_fails_its_horizon_after_each_failure(body: Formula) -> None:
    """With reset, each instant t at which the body starts to fail is reported at t + H
    (a step there: its reading H late changes), and a violation at s only where the body
    fails at s - H (other steps where it still fails may report it again); so the first
    verdict is the first failure's, H late, as with halt (test_time_nested.py)."""
    rng = random.Random(text(body))
    h = horizon(body)
    m = compiled(f"always ({text(body)})", SIGNALS)
    for _ in range(4):
        end = rng.randint(h + 4, 24)
        rows = random_run(rng, end)
        at = evaluator(rows)
        holds = [at(body, t) for t in range(0, end - h + 1)]
        failures = [t for t, v in enumerate(holds) if not v]
        starts = {t + h for t in failures if t == 0 or holds[t - 1]}
        got = verdicts(run([m], events(rows))[0])
        assert {v for v, _, _ in got} <= {"violated"}, (text(body), rows)
        stamps = {stamp for _, _, stamp in got}
        assert starts <= stamps <= {t + h for t in failures}, (text(body), rows, got)


def test_an_untimed_since_read_late_counts_the_junction_as_over_steps() -> None:
    """`(!b) since b` holds at the step where b turns false (b at the step before, !b at
    every step after it: docs/semantics.md, "Past"), and always does on this run;
    `(F[1ns..1ns] !b) since (F[1ns..1ns] b)` is the same formula 1 ns ahead, read 1 ns
    late, and always holds too (dense.kleene's untimed since, over steps). An untimed
    since over time-bounded operands was read as a timed one over [0, MAX_WINDOW], in
    dense time, where the junction is no witness: violated at 5 and 10 (found by this
    module; edgerv.core.language.bounded now keeps it untimed, over steps)."""
    ab = {name: "bool" for name in "ab"}
    rows = [("/a", 0, False), ("/b", 0, True), ("/b", 5, False), ("/a", 10, True)]
    assert verdicts(run([compiled("always ((!b) since b)", ab)], events(rows))[0]) == []
    late = compiled("always ((F[1ns..1ns] (!b)) since (F[1ns..1ns] b))", ab)
    assert verdicts(run([late], events(rows))[0]) == []
