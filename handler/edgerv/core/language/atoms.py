"""Atoms: the propositions over signal values that become a letter's placeholders.

An atom is a bool signal, or a comparison between a signal and a signal, a parameter
or a literal (``speed < limit``), or ``age(signal)`` with a duration. The parser reads
them (edgerv.core.language.comparisons); here is what they are, the letters that can
occur (:func:`feasible_letters`: atoms over one signal are not independent) and the
functions that compute them from signal values.
"""

from __future__ import annotations

import itertools
import math
import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import spot

from edgerv.core.documents import MonitorSpec, Value
from edgerv.core.msgtypes import ValueKind

CmpOp = Literal["<", "<=", ">", ">=", "==", "!="]

CMP_FUNCS: dict[str, Callable[[Any, Any], bool]] = {
    "<": operator.lt,
    "<=": operator.le,
    ">": operator.gt,
    ">=": operator.ge,
    "==": operator.eq,
    "!=": operator.ne,
}
FLIP: dict[str, CmpOp] = {"<": ">", "<=": ">=", ">": "<", ">=": "<=", "==": "==", "!=": "!="}


@dataclass(frozen=True)
class Operand:
    """One side of a comparison: a signal (by name), ``age(signal)``, or a constant (a
    duration is a constant in integer nanoseconds)."""

    signal: str | None
    value: Value | None = None
    age: bool = False  # age(signal): the time since the last message on its topic

    def describe(self) -> str:
        if self.signal is not None:
            return f"age({self.signal})" if self.age else self.signal
        return repr(self.value)


@dataclass(frozen=True)
class Atom:
    """A proposition over signal values; ``placeholder`` is its bit in a letter."""

    lhs: Operand
    op: CmpOp
    rhs: Operand
    text: str  # as the user wrote it, for messages

    @property
    def signals(self) -> tuple[str, ...]:
        """The signals whose values it reads (an age atom reads none: it reads the time)."""
        return tuple(
            dict.fromkeys(o.signal for o in (self.lhs, self.rhs) if o.signal and not o.age)
        )

    @property
    def timed(self) -> bool:
        """``age(x) OP duration``: its truth changes as time passes, without a message."""
        return self.lhs.age

    def key(self) -> tuple[Any, ...]:
        def k(o: Operand) -> tuple[Any, ...]:
            if o.signal is not None:
                return ("a" if o.age else "s", o.signal)
            return ("c", type(o.value), o.value)

        return (k(self.lhs), self.op, k(self.rhs))


def _samples(kind: ValueKind, constants: list[Value]) -> list[Value]:
    """Values covering every region that comparisons with ``constants`` can tell apart."""
    if kind == "bool":
        return [False, True]
    if kind == "string":
        strs = [c for c in constants if isinstance(c, str)]
        return [*strs, "\x00" + "".join(strs)]
    numbers = [c for c in constants if isinstance(c, int | float) and not isinstance(c, bool)]
    if kind == "int":  # exact: an integer constant may be beyond a float's range
        points: set[Value] = {0}
        for c in numbers:
            if isinstance(c, int):
                points |= {c - 1, c, c + 1}
            elif math.isfinite(c):  # an infinite or NaN one compares alike with every int
                points |= {math.floor(c) - 1, math.floor(c), math.ceil(c), math.ceil(c) + 1}
        return sorted(points)
    nums = sorted({f for f in map(_nearest_float, numbers) if not math.isnan(f)})
    points_f: set[float] = {0.0, -math.inf, math.inf}
    for a, b in itertools.pairwise(nums):
        middle = (a + b) / 2
        if not math.isfinite(middle):  # a + b overflowed, or an infinity is a bound
            middle = a / 2 + b / 2
        if math.isfinite(middle):
            points_f.add(middle)
    for c in nums:  # each side of it, also where adding 1.0 changes nothing
        points_f |= {c, c - 1.0, c + 1.0, math.nextafter(c, -math.inf), math.nextafter(c, math.inf)}
    return [*sorted(points_f), math.nan]


def _nearest_float(c: int | float) -> float:
    """``c`` as a float; an integer beyond a float's range as the infinity of its sign."""
    try:
        return float(c)
    except OverflowError:
        return math.inf if c > 0 else -math.inf


def feasible_letters(spec: MonitorSpec, atoms: Sequence[Atom]) -> Any:
    """A boolean formula over the placeholders true of exactly the letters that can occur.

    Atoms that read the same single signal are not independent (``speed < 50`` and
    ``speed > 100`` are never both true). Monitoring over the letters that can occur
    gives the exact verdicts of the assertion over signal values: a prefix is bad
    when no continuation of *possible* letters satisfies the formula.
    """
    by_signal: dict[tuple[str, bool], list[int]] = {}
    for i, a in enumerate(atoms):
        if a.rhs.signal is None and a.lhs.signal is not None:
            by_signal.setdefault((a.lhs.signal, a.lhs.age), []).append(i)
    parts = []
    for (name, age), idxs in by_signal.items():
        if len(idxs) < 2 and (age or spec.signals[name].kind != "float"):
            continue
        consts = [atoms[i].rhs.value for i in idxs if atoms[i].rhs.value is not None]
        if age:  # nanoseconds, never negative; infinite before the topic's first message
            ints = _samples("int", consts)  # type: ignore[arg-type]
            samples: list[Any] = [v for v in ints if isinstance(v, int) and v >= 0] + [math.inf]
        else:
            samples = _samples(spec.signals[name].kind, consts)  # type: ignore[arg-type]
        rows = set()
        for v in samples:
            rows.add(tuple(_compare(v, atoms[i].op, atoms[i].rhs.value) for i in idxs))
        if len(rows) == 2 ** len(idxs):
            continue
        disjuncts = [
            spot.formula.And(
                [
                    spot.formula.ap(f"p{i}") if bit else spot.formula.Not(spot.formula.ap(f"p{i}"))
                    for i, bit in zip(idxs, row, strict=True)
                ]
            )
            for row in sorted(rows)
        ]
        parts.append(spot.formula.Or(disjuncts))
    return spot.formula.And(parts) if parts else spot.formula.tt()


def _compare(value: Any, op: str, const: Any) -> bool:
    try:
        return bool(CMP_FUNCS[op](value, const))
    except TypeError:
        return False


def compile_atom_columns(atom: Atom, index_of: dict[str, int]) -> Callable[[list[Any]], Any]:
    """The atom over columns of values (one array per signal): an array of truth values.

    The same comparison as :func:`compile_atom`, applied elementwise (the columns are
    NumPy object arrays, so each element is compared as the Python values it holds).
    """
    func = CMP_FUNCS[atom.op]
    if atom.lhs.signal is None or atom.timed:  # timed atoms are the clock's (pipeline.Clock)
        raise ValueError(atom)
    li = index_of[atom.lhs.signal]
    if atom.rhs.signal is not None:
        ri = index_of[atom.rhs.signal]
        return lambda cols: func(cols[li], cols[ri])
    const = atom.rhs.value
    return lambda cols: func(cols[li], const)


def compile_atom(atom: Atom, index_of: dict[str, int]) -> Callable[[list[Any]], bool]:
    """A function from the signal values (by index) to the atom's truth value."""
    func = CMP_FUNCS[atom.op]
    if atom.lhs.signal is None or atom.timed:  # never: constants go right; timed: the clock's
        raise ValueError(atom)
    li = index_of[atom.lhs.signal]
    if atom.rhs.signal is not None:
        ri = index_of[atom.rhs.signal]
        return lambda values: bool(func(values[li], values[ri]))
    const = atom.rhs.value
    return lambda values: bool(func(values[li], const))
