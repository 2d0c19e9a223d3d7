"""Random assertions, events and runs of the side-by-side tests (a way of computing held
against the way it replaced, on the same random input): over the signals
:data:`SIGNALS` (a, b, x, y on /a, /b, /x, /y, and z: x's topic too)."""

from __future__ import annotations

import math
import random
import re
from typing import Any

from edgerv.core.diagnostics import Location
from edgerv.core.traces import TraceEvent

MS = 1_000_000
SIGNALS: dict[str, Any] = {
    "a": {"topic": "/a", "type": "std_msgs/msg/Bool"},
    "b": {"topic": "/b", "type": "std_msgs/msg/Bool", "initial": False},
    "x": {"topic": "/x", "type": "std_msgs/msg/Float64"},
    "y": {"topic": "/y", "type": "std_msgs/msg/Float64", "initial": 1.0},
    "z": {"topic": "/x", "type": "std_msgs/msg/Float64", "field": "data"},  # x's topic too
}
ATOMS = ["a", "b", "x < 2", "x >= y", "z == 3", "age(a) < 15ms", "age(x) >= 7ms", "!b"]
SHAPES = [
    "always {f}",
    "always (a -> {f})",
    "{f}",
    "always (b -> F[0..30ms] x < 2) && always {f}",
    "always (a -> (b U[5ms..20ms] x >= y))",
    "always (x < 2 -> G[0..10ms] !a) && always {f}",
]


def random_assertion(rng: random.Random) -> str:
    """A formula of past operators (timed or not, nested) over random atoms, in a shape."""
    formula = re.sub(
        r"\b[ab]\b", lambda _: f"({rng.choice(ATOMS)})", random_mixed(rng, rng.randint(0, 3))
    )
    return rng.choice(SHAPES).format(f=formula)


def random_events(rng: random.Random, n: int) -> list[TraceEvent]:
    """Messages on /a, /b, /x, /y: long runs of one value (a run of equal letters), ties,
    gaps that let timed operators change by the clock alone, now and then one late."""
    stamp, out = 0, []
    held = {"/a": False, "/b": True, "/x": 1.0, "/y": 2.0}
    for i in range(n):
        stamp += rng.choice([0, 1, 2 * MS, 2 * MS, 5 * MS, 11 * MS, 40 * MS])
        late = stamp - rng.randint(1, 20 * MS) if rng.random() < 0.04 else stamp
        topic = rng.choice(["/a", "/b", "/x", "/x", "/y"])
        if rng.random() < 0.2:  # a new value; else the one held
            held[topic] = (
                rng.random() < 0.5
                if topic in ("/a", "/b")
                else rng.choice([0.0, 1.0, 2.0, 3.0, math.nan, 5])
            )
        out.append(TraceEvent(topic, late, {"data": held[topic]}, Location("t", i + 1)))
    return out


AGES = [
    f"age({s}) {op} {d}ms" for s in "axy" for op in ("<", "<=", ">", ">=", "==") for d in (0, 2, 7)
]
UNTIMED = ["a", "b", "!a", "x < 2", "x >= y", "z == 3", "y != 1", "x > -0.5", "y <= 2"]


def random_untimed_past_free(rng: random.Random) -> str:
    """An assertion of future operators over random atoms, ages among them."""
    atoms = [rng.choice(AGES if rng.random() < 0.4 else UNTIMED) for _ in range(rng.randint(1, 4))]
    body = f" {rng.choice(['&', '|', '->'])} ".join(f"({a})" for a in atoms)
    return rng.choice(
        [
            "always ({f})",
            "always ((a) -> ({f}))",
            "eventually! ({f})",
            "always ((b) -> F[0..30ms] ({f}))",
            "always (({f}) -> next (x < 2))",
        ]
    ).format(f=body)


def random_run(rng: random.Random, n: int, late: float) -> list[TraceEvent]:
    stamp, out = rng.randint(0, 3) * MS, []
    held: dict[str, Any] = {"/a": False, "/b": True, "/x": 1.0, "/y": 2.0}
    for i in range(n):
        stamp += rng.choice([0, 1, MS, 2 * MS, 2 * MS - 1, 7 * MS, 7 * MS + 1, 11 * MS, 40 * MS])
        at = stamp - rng.randint(1, 20 * MS) if rng.random() < late else stamp
        topic = rng.choice(["/a", "/b", "/x", "/x", "/y"])
        if rng.random() < 0.3:
            held[topic] = (
                rng.random() < 0.5
                if topic in ("/a", "/b")
                else rng.choice([0.0, 1.0, 2.0, 3.0, math.nan, 5.0, -1.0])
            )
        out.append(TraceEvent(topic, at, {"data": held[topic]}, Location("t", i + 1)))
    return out


def random_mixed(rng: random.Random, depth: int) -> str:
    """Every operator, timed or not, nested at random."""
    if depth == 0 or rng.random() < 0.2:
        return rng.choice("ab")
    kind = rng.choice(["not", "and", "or", "once", "hist", "since", "prev", "once_t", "hist_t",
                       "once_t", "hist_t", "since_t", "since_t"])  # fmt: skip
    x = random_mixed(rng, depth - 1)
    if kind == "since_t":
        lo = rng.choice([0, 0, 10, 20]) * MS
        hi = lo + rng.choice([5, 20, 40]) * MS
        return f"({x} since[{lo}ns..{hi}ns] {random_mixed(rng, depth - 1)})"
    if kind in ("and", "or", "since"):
        op = {"and": "&", "or": "|", "since": "since"}[kind]
        return f"({x} {op} {random_mixed(rng, depth - 1)})"
    if kind == "not":
        return f"(!{x})"
    word = {"once": "once", "hist": "historically", "prev": "prev"}.get(kind)
    if word:
        return f"({word} {x})"
    lo = rng.choice([0, 0, 10, 20]) * MS
    hi = lo + rng.choice([5, 20, 40]) * MS
    return f"({'once' if kind == 'once_t' else 'historically'}[{lo}ns..{hi}ns] {x})"
