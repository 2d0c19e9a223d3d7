"""The dense-time reference for time-bounded and past formulas over boolean signals:
formulas as tuples, their text in the assertion language, their horizon, and their truth
at each nanosecond straight from the definitions (docs/semantics.md, sections 6 and 7;
signals hold their values between messages), two-valued over a whole run or three-valued
(Kleene: None where the run so far does not decide); for past formulas with ``prev``,
which counts steps, the truth at each step a monitor takes (:func:`past_steps`). Shared
by the tests of nesting and of when verdicts are reported (tests/unit/test_time_nested.py,
test_verdict_delay.py, test_past_nested_reelay.py).
"""

from __future__ import annotations

import random
from collections.abc import Callable
from functools import cache
from typing import Any

import spot

SIGNALS = {name: "bool" for name in "abc"}
# ("atom", name) | ("not"|"prev", f) | ("and"|"or"|"implies", f, g) | ("F"|"G", lo, hi, f)
# | ("U"|"W"|"R"|"M", lo, hi, f, g)
# | ("once"|"historically", lo, hi, f) | ("since", lo, hi, f, g): past, timed; untimed
# with (lo, hi) = (0, None). prev (the step before) only in past_steps.
Formula = tuple[Any, ...]
BINARY = ("U", "W", "R", "M")
PAST = ("once", "historically", "since")
CONNECTIVES = {"and": "&", "or": "|", "implies": "->"}


def text(f: Formula) -> str:
    kind = f[0]
    if kind == "atom":
        return str(f[1])
    if kind in ("not", "prev"):
        return f"{'!' if kind == 'not' else 'prev '}({text(f[1])})"
    if kind in CONNECTIVES:
        return f"({text(f[1])}) {CONNECTIVES[kind]} ({text(f[2])})"
    bound = "" if f[2] is None else f"[{f[1]}ns..{f[2]}ns]"
    if kind in (*BINARY, "since"):
        return f"({text(f[3])}) {kind}{bound} ({text(f[4])})"
    return f"{kind}{bound} ({text(f[3])})"


def size(f: Formula) -> int:
    """Its operators and atoms: small enough ones stay within the 16 placeholders."""
    return 1 + sum(size(g) for g in f[1:] if isinstance(g, tuple))


def horizon(f: Formula) -> int:
    kind = f[0]
    if kind == "atom":
        return 0
    if kind in ("not", "prev"):
        return horizon(f[1])
    if kind in CONNECTIVES:
        return max(horizon(f[1]), horizon(f[2]))
    ahead = 0 if kind in PAST else int(f[2])  # a past operator looks back only
    return ahead + max(horizon(g) for g in f[3:])


def timed(f: Formula) -> int:
    """How many time-bounded operators ``f`` holds."""
    kind = f[0]
    if kind == "atom":
        return 0
    if kind in ("not", "prev"):
        return timed(f[1])
    if kind in CONNECTIVES:
        return timed(f[1]) + timed(f[2])
    return (0 if kind in PAST else 1) + sum(timed(g) for g in f[3:])


def evaluator(rows: list[tuple[str, int, bool]]) -> Callable[[Formula, int], bool]:
    """The truth of a formula at an instant, from the definitions, over the run ``rows``
    (one message a stamp; a value holds from its message until the next)."""
    at = kleene(rows, None)
    return lambda f, t: bool(at(f, t))


def kleene(rows: list[tuple[str, int, bool]], known: int | None
           ) -> Callable[[Formula, int], bool | None]:  # fmt: skip
    """Three-valued truth: a signal's value at an instant after ``known`` is unknown
    (None), and so is what it decides; None for ``known`` knows the whole run."""

    def value(name: str, t: int) -> bool | None:
        if known is not None and t > known:
            return None
        last = False
        for topic, stamp, v in rows:
            if topic == f"/{name}" and stamp <= t:
                last = v
        return last

    def some(values: Any) -> bool | None:
        out: bool | None = False
        for v in values:
            if v is True:
                return True
            if v is None:
                out = None
        return out

    def every(values: Any) -> bool | None:
        out: bool | None = True
        for v in values:
            if v is False:
                return False
            if v is None:
                out = None
        return out

    def neg(v: bool | None) -> bool | None:
        return None if v is None else not v

    @cache
    def at(f: Formula, t: int) -> bool | None:
        kind = f[0]
        if kind == "atom":
            return value(f[1], t)
        if kind == "not":
            return neg(at(f[1], t))
        if kind == "and":
            return every(at(g, t) for g in f[1:])
        if kind == "or":
            return some(at(g, t) for g in f[1:])
        if kind == "implies":
            return some([neg(at(f[1], t)), at(f[2], t)])
        if kind == "prev":
            raise ValueError("prev counts steps: past_steps evaluates it")
        if kind in PAST:  # over the instants of the run (it starts at 0)
            back = range(0 if f[2] is None else max(t - f[2], 0), t - f[1] + 1)
            if kind == "once":
                return some(at(f[3], u) for u in back)
            if kind == "historically":
                return every(at(f[3], u) for u in back)
            if f[2] is None:  # untimed, over the steps: g at one, f at every one after it
                # (the steps are the instants where something changes: f from u + 1 on)
                return some(
                    every([at(f[4], u), *(at(f[3], v) for v in range(u + 1, t + 1))]) for u in back
                )
            # g at an instant s, f at every instant of (s, t], time dense: s in [u, u + 1)
            # for a nanosecond u where g holds; (s, t] takes u's value too unless s = t
            return some(
                every([at(f[4], u), *(() if u == t else (at(f[3], v) for v in range(u, t + 1)))])
                for u in back
            )
        window = range(t + f[1], t + f[2] + 1)
        if kind in ("F", "G"):
            return (some if kind == "F" else every)(at(f[3], u) for u in window)
        lo, hi, left, right = f[1], f[2], f[3], f[4]
        if kind in ("R", "M"):  # R is !(!f U !g), M is !(!f W !g)
            dual = "U" if kind == "R" else "W"
            return neg(at((dual, lo, hi, ("not", left), ("not", right)), t))
        # edgerv's until: g at some t' of the window, f at every instant of [t, t')
        until = some(every([at(right, u), *(at(left, v) for v in range(t, u))]) for u in window)
        if kind == "W":  # or f at every instant of [t, t + hi]
            return some([until, every(at(left, v) for v in range(t, t + hi + 1))])
        return until

    return at


def random_formula(rng: random.Random, depth: int) -> Formula:
    if depth == 0 or rng.random() < 0.2:
        return ("atom", rng.choice("abc"))
    kind = rng.choice(["not", "and", "or", "F", "G", "F", "G", *BINARY, *PAST])
    if kind == "not":
        return ("not", random_formula(rng, depth - 1))
    if kind in ("and", "or"):
        return (kind, random_formula(rng, depth - 1), random_formula(rng, depth - 1))
    lo = rng.randint(0, 3)
    hi = lo + rng.randint(0, 3)
    if kind in (*BINARY, "since"):
        return (kind, lo, hi, random_formula(rng, depth - 1), random_formula(rng, depth - 1))
    return (kind, lo, hi, random_formula(rng, depth - 1))


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
    if kind in CONNECTIVES:
        op = CONNECTIVES[kind]
        return f"({propositional(f[1], names)}) {op} ({propositional(f[2], names)})"
    return names.setdefault(text(f), f"t{len(names)}")


def valid(f: Formula) -> bool:
    """True whatever its propositions: a monitor of it is satisfied at its first step."""
    return bool(spot.are_equivalent(spot.formula(propositional(f, {})), spot.formula.tt()))


def formulas(
    seed: int,
    count: int,
    keep: Callable[[Formula], bool],
    make: Callable[[random.Random], Formula] = lambda rng: random_formula(rng, 3),
) -> list[Formula]:
    """``count`` random formulas (``make``) that ``keep`` accepts, from ``seed``."""
    rng = random.Random(seed)
    out: list[Formula] = []
    while len(out) < count:
        f = make(rng)
        if keep(f):
            out.append(f)
    return out


def past_steps(f: Formula, rows: list[tuple[str, int, bool]], end: int) -> list[tuple[int, bool]]:
    """The truth of the past formula ``f`` at each step a monitor takes over ``rows`` (one
    message a stamp, each a step; signals false until their first message), up to ``end``,
    by brute force over every nanosecond from the first message (docs/semantics.md, "Past"):
    ``prev g`` is g at the step before (false at the first); untimed ``once``,
    ``historically`` and ``since`` range over the steps; timed ones over the instants from
    the first step on, each step's values held until the next. An instant without a
    message is a (clock) step where a timed operator's truth changes with every operand
    held since the last step; there everything is evaluated anew, ``prev`` included."""
    messages = {stamp: (topic[1:], value) for topic, stamp, value in rows}
    t0 = rows[0][1]
    held: dict[str, bool] = {}
    table: dict[Formula, list[bool]] = {}  # each subformula's truth at t0, t0 + 1, ...

    def evaluate(t: int, step: bool) -> dict[Formula, bool]:
        now: dict[Formula, bool] = {}

        def before(g: Formula, default: bool) -> bool:  # g's truth at the last step
            return table[g][t - 1 - t0] if t > t0 else default

        def ev(g: Formula) -> bool:
            if g in now:
                return now[g]
            kind, kids = g[0], [ev(h) for h in g[1:] if isinstance(h, tuple)]  # all of them

            def at(h: Formula, u: int) -> bool:
                return now[h] if u == t else table[h][u - t0]

            if kind == "atom":
                v = held.get(g[1], False)
            elif kind == "not":
                v = not kids[0]
            elif kind in CONNECTIVES:
                x, y = kids
                v = {"and": x and y, "or": x or y, "implies": not x or y}[kind]
            elif kind == "prev":  # held between steps
                v = before(g[1] if step else g, False)
            elif g[2] is None:  # untimed: over the steps (now, or the step before)
                if kind == "once":
                    v = kids[0] or before(g, False)
                elif kind == "historically":
                    v = kids[0] and before(g, True)
                else:
                    v = kids[1] or (kids[0] and before(g, False))
            else:  # timed: over the instants of [t - hi, t - lo] from t0 on
                back = range(max(t - g[2], t0), t - g[1] + 1)
                if kind == "once":
                    v = any(at(g[3], u) for u in back)
                elif kind == "historically":
                    v = all(at(g[3], u) for u in back)
                else:  # g at an instant of [u, u + 1), f at every one after it (as kleene)
                    v = any(
                        at(g[4], u) and (u == t or all(at(g[3], w) for w in range(u, t + 1)))
                        for u in back
                    )
            now[g] = v
            return v

        ev(f)
        return now

    out: list[tuple[int, bool]] = []
    for t in range(t0, end + 1):
        if t in messages:
            held[messages[t][0]] = messages[t][1]
        elif t > t0 and all(table[g][-1] == v for g, v in evaluate(t, step=False).items()):
            for column in table.values():  # no step: everything holds
                column.append(column[-1])
            continue
        now = evaluate(t, step=True)
        for g, v in now.items():
            table.setdefault(g, []).append(v)
        out.append((t, now[f]))
    return out
