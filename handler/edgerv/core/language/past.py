"""Past-time operators as derived placeholders, computed step by step (Havelund and Rosu).

Each application of a past operator in an assertion (``once f``, ``historically f``,
``f since g``, ``prev f``, and ``once[a..b] f``, ``historically[a..b] f``) becomes a
placeholder of its own, like an atom: Spot sees a proposition, and the pipeline
computes its truth at every step from its operands' truth at that step and a little
state (one bit for the untimed operators, the intervals in which the operand held
for the timed ones). Operands are boolean formulas over the other placeholders,
inner past operators first. docs/semantics.md ("Past") says what each one means.

Timed ones change their truth as time passes: :meth:`Past.next_change` gives the
next instant at which one does, and the monitor takes a clock step there.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Literal

import spot

PastKind = Literal["prev", "once", "historically", "since", "until"]
BitsFunction = Callable[[int], bool]


class PastError(Exception):
    """An operand that is not a boolean formula over the placeholders."""


@dataclass(frozen=True)
class PastOp:
    """One past operator: placeholder ``bit`` over ``operands`` (``(f,)``, or ``(f, g)``
    for ``f since g``), each a function of the letter's bits; ``window`` the closed
    interval ``[lo, hi]`` in nanoseconds of a timed one."""

    kind: PastKind
    bit: int
    operands: tuple[BitsFunction, ...]
    window: tuple[int, int] | None = None
    text: str = ""
    delay: int = 0  # "until" only: it reads ``f U[lo..hi] g`` this long ago


MAX_TABLE_BITS = 16  # an operand reads placeholders p0..p15 at most (synthesis' limit)


def compile_boolean(formula: Any) -> BitsFunction:
    """A Spot boolean formula over placeholders ``p<i>`` as a function of the bits: a
    lookup in its truth table over the bits up to the highest it reads.

    The table is built bottom-up over Spot's tree with an explicit stack, as integers
    of one bit per letter, so an operand nested thousands deep is no deeper a
    computation (no recursion, no generated source); raises :class:`PastError` for a
    formula that is not boolean over placeholders, or reads more than
    :data:`MAX_TABLE_BITS` of them."""
    if not formula.is_boolean():
        raise PastError(f"'{formula}' is not a boolean formula")
    table = _truth_table(str(formula))
    mask = len(table) - 1
    return lambda b: table[b & mask]


@lru_cache(maxsize=1024)
def _truth_table(text: str) -> tuple[bool, ...]:
    """The truth of the boolean formula ``text`` for each letter ``0 .. 2^n - 1``, n one
    more than the highest placeholder it reads (monitors with one operand share it)."""
    formula = spot.formula(text)
    highest = -1
    for ap in spot.atomic_prop_collect(formula):
        name = ap.ap_name()
        if not (name.startswith("p") and name[1:].isdigit()):
            raise PastError(f"unknown proposition '{name}'")
        highest = max(highest, int(name[1:]))
    if highest >= MAX_TABLE_BITS:
        raise PastError(
            f"it reads placeholder p{highest}: at most {MAX_TABLE_BITS} atoms and past or "
            "time-bounded operators are supported"
        )
    size = 1 << (highest + 1)
    ones = (1 << size) - 1
    value: dict[int, int] = {}  # a subformula's id: its truth table (bit j: letter j)
    stack = [(formula, False)]
    while stack:
        f, children_done = stack.pop()
        if f.id() in value:
            continue
        kids = list(f)
        if not children_done and kids:
            stack.append((f, True))
            stack.extend((g, False) for g in kids if g.id() not in value)
            continue
        value[f.id()] = _combine(f, [value[g.id()] for g in kids], size, ones)
    table = value[formula.id()]
    bits = format(table, f"0{size}b")[::-1]  # bit j of the table is letter j
    return tuple(c == "1" for c in bits)


def _combine(f: Any, parts: list[int], size: int, ones: int) -> int:
    """The truth table of ``f`` from its children's (``parts``) over ``size`` letters."""
    k = f.kind()
    if k == spot.op_tt:
        return ones
    if k == spot.op_ff:
        return 0
    if k == spot.op_ap:
        i = int(f.ap_name()[1:])
        period = 1 << (i + 1)  # letters with bit i set: the upper half of each period
        block = ((1 << (1 << i)) - 1) << (1 << i)
        return block * (ones // ((1 << period) - 1))
    if k == spot.op_Not:
        return ones ^ parts[0]
    if k == spot.op_And:
        out = ones
        for part in parts:
            out &= part
        return out
    if k == spot.op_Or:
        out = 0
        for part in parts:
            out |= part
        return out
    if k == spot.op_Xor:
        return parts[0] ^ parts[1]
    if k == spot.op_Implies:
        return (ones ^ parts[0]) | parts[1]
    if k == spot.op_Equiv:
        return ones ^ (parts[0] ^ parts[1])
    raise PastError(f"'{f}' is not a boolean formula")


@dataclass
class _Runs:
    """The time intervals ``[start, end)`` in which an operand held, oldest first; the
    last one's end is None while it still holds. Those that can no longer matter to a
    window reaching ``hi`` back are dropped."""

    runs: list[list[int | None]] = field(default_factory=list)

    def step(self, now: int, holds: bool) -> None:
        runs = self.runs
        ongoing = bool(runs) and runs[-1][1] is None
        if holds and not ongoing:
            runs.append([now, None])
        elif not holds and ongoing:
            runs[-1][1] = now

    def prune(self, now: int, hi: int) -> None:
        runs = self.runs
        while runs and runs[0][1] is not None and runs[0][1] + hi <= now:
            del runs[0]

    def once(self, now: int, lo: int, hi: int) -> bool:
        """Did it hold at some instant of ``[now - hi, now - lo]``? After :meth:`prune`
        every run left ends after ``now - hi``: the oldest one tells."""
        return bool(self.runs) and self.runs[0][0] + lo <= now  # type: ignore[operator]

    def next_change(self, now: int, lo: int, hi: int) -> int | None:
        """The first instant after ``now`` at which :meth:`once` may change its answer."""
        best = None
        for start, end in self.runs:
            for at in (start + lo, None if end is None else end + hi):  # type: ignore[operator]
                if at is not None and at > now and (best is None or at < best):
                    best = at
        return best


@dataclass
class _SinceRuns:
    """``f since[lo..hi] g``: the runs of g since f's current run began (an instant of g
    counts only if f held at every instant after it, up to now). While f is false only
    the present instant can count (nothing after it): then it holds where g does, if
    ``lo`` is 0."""

    runs: _Runs = field(default_factory=_Runs)
    live: bool = False  # f holds now: ``runs`` are the candidates
    g: bool = False  # g now, while f does not hold

    def step(self, now: int, f: bool, g: bool) -> None:
        if not f:
            self.runs, self.live, self.g = _Runs(), False, g
            return
        if not self.live:  # f's run begins: instants of g before it no longer count
            self.runs, self.live = _Runs(), True
        self.runs.step(now, g)

    def holds(self, now: int, lo: int, hi: int) -> bool:
        if self.live:
            self.runs.prune(now, hi)
            return self.runs.once(now, lo, hi)
        return lo == 0 and self.g

    def next_change(self, now: int, lo: int, hi: int) -> int | None:
        return self.runs.next_change(now, lo, hi) if self.live else None


@dataclass
class _UntilRuns:
    """``f U[lo..hi] g`` read ``delay`` ago (a time-bounded until read late, as
    edgerv.core.language.bounded makes it; ``delay`` >= hi): at t, with s = t - delay, g holds at
    some instant t' of ``[s + lo, s + hi]`` and f at every instant of ``[s, t')``. From
    the runs of f and of g up to t; an ongoing run holds on (no new step)."""

    f: _Runs = field(default_factory=_Runs)
    g: _Runs = field(default_factory=_Runs)

    def step(self, now: int, f: bool, g: bool) -> None:
        self.f.step(now, f)
        self.g.step(now, g)

    def prune(self, now: int, delay: int) -> None:
        self.f.prune(now, delay)  # a run that ended by s no longer matters
        self.g.prune(now, delay)

    def holds(self, now: int, lo: int, hi: int, delay: int) -> bool:
        s = now - delay
        last: int | None = s  # the first instant from s on at which f fails (None: never)
        for start, end in self.f.runs:
            if start <= s and (end is None or end > s):  # type: ignore[operator]
                last = end
                break
        first, until = s + lo, s + hi if last is None else min(s + hi, last)
        if first > until:
            return False
        return any(
            start <= until and (end is None or end > first)  # type: ignore[operator]
            for start, end in self.g.runs
        )

    def next_change(self, now: int, lo: int, hi: int, delay: int) -> int | None:
        """An instant after ``now`` at or before the first one at which :meth:`holds`
        may change: where s, s + lo or s + hi meets a run's bound, or passes it."""
        best = None
        for runs in (self.f.runs, self.g.runs):
            for start, end in runs:
                for edge in (start, end):
                    if edge is None:
                        continue
                    for offset in (delay, delay - lo, delay - hi):
                        for at in (edge + offset, edge + offset + 1):
                            if at > now and (best is None or at < best):
                                best = at
        return best


class Past:
    """The derived placeholders of one monitor and their state. Not thread-safe."""

    def __init__(self, ops: Sequence[PastOp]) -> None:
        self.ops = tuple(ops)
        # per op: prev: [the operand at the last step]; untimed: [its value]; timed: runs
        self.state: list[Any] = [self._initial(op) for op in self.ops]
        self._prevs = [
            (i, op.bit) for i, op in enumerate(self.ops) if op.window is None and op.kind == "prev"
        ]

    @staticmethod
    def _initial(op: PastOp) -> Any:
        if op.kind == "until":
            return _UntilRuns()
        if op.window is not None:
            return _SinceRuns() if op.kind == "since" else _Runs()
        return [op.kind == "historically"]  # once, since, prev: False; historically: True

    def step(self, now: int, bits: int) -> int:
        """Take a step at ``now`` whose atoms are ``bits``: the letter with the derived
        placeholders set, inner ones first (an outer one reads their new bits)."""
        for op, state in zip(self.ops, self.state, strict=True):
            f = op.operands[0](bits)
            if op.kind == "until":
                assert op.window is not None
                state.step(now, f, op.operands[1](bits))
                state.prune(now, op.delay)
                value = state.holds(now, *op.window, op.delay)
            elif op.window is not None and op.kind == "since":
                state.step(now, f, op.operands[1](bits))
                value = state.holds(now, *op.window)
            elif op.window is not None:
                lo, hi = op.window
                value = self._timed(state, now, lo, hi, f if op.kind == "once" else not f)
                if op.kind == "historically":
                    value = not value
            elif op.kind == "prev":  # the operand at the step before (none: false)
                value, state[0] = state[0], f
            elif op.kind == "once":
                value = state[0] = state[0] or f
            elif op.kind == "historically":
                value = state[0] = state[0] and f
            else:  # f since g: g now, or f now and (f since g) at the step before
                g = op.operands[1](bits)
                value = state[0] = g or (f and state[0])
            bits = bits | (1 << op.bit) if value else bits & ~(1 << op.bit)
        return bits

    @staticmethod
    def _timed(runs: _Runs, now: int, lo: int, hi: int, holds: bool) -> bool:
        runs.step(now, holds)
        runs.prune(now, hi)
        return runs.once(now, lo, hi)

    def settled(self, bits: int) -> bool:
        """Would a step with the atoms of ``bits`` (the last step's letter) at the same
        instant give ``bits`` again and leave the state as it is? Then so does every
        later step with the same atoms, up to the first instant at which a timed one
        may change (:meth:`next_change`): a run of equal messages is a run of equal
        letters, and a batch takes it whole.

        Only ``prev`` can answer no: it gives the operand of the step before, which the
        next step replaces by the last one. ``once``, ``historically`` and ``since``
        already hold what a repeated operand gives them, and a timed one's runs do not
        change while its operand does not (its truth then changes with time only).
        """
        state = self.state
        return all(state[i][0] == bool(bits >> bit & 1) for i, bit in self._prevs)

    def prune(self, now: int) -> None:
        """Forget the runs no window reaching back from ``now`` can see, as a step at
        ``now`` does (a batch that takes a run of equal letters whole prunes once)."""
        for op, state in zip(self.ops, self.state, strict=True):
            if op.window is None:
                continue
            if op.kind == "until":
                state.prune(now, op.delay)
            elif op.kind != "since":
                state.prune(now, op.window[1])
            elif state.live:
                state.runs.prune(now, op.window[1])

    def time_changes(self, now: int, bits: int) -> bool:
        """Does a timed one's truth at ``now`` differ from its bit in ``bits`` (the
        last step's letter), every operand held since that step? Then time alone
        changed it, and a clock step is due at ``now``."""
        for op, state in zip(self.ops, self.state, strict=True):
            if op.window is not None:
                lo, hi = op.window
                if op.kind == "until":
                    state.prune(now, op.delay)
                    value = state.holds(now, lo, hi, op.delay)
                elif op.kind == "since":
                    value = state.holds(now, lo, hi)
                else:
                    state.prune(now, hi)
                    value = state.once(now, lo, hi) != (op.kind == "historically")
                if value != bool(bits >> op.bit & 1):
                    return True
        return False

    def next_change(self, now: int) -> int | None:
        """The first instant after ``now`` at which a timed one may change its truth
        with no new step; None if none can."""
        best = None
        for op, state in zip(self.ops, self.state, strict=True):
            if op.window is None:
                continue
            if op.kind == "until":
                at = state.next_change(now, *op.window, op.delay)
            else:
                at = state.next_change(now, *op.window)
            if at is not None and (best is None or at < best):
                best = at
        return best

    def save(self) -> Any:
        """The state, as plain JSON values (a handoff snapshot carries it)."""
        out: list[Any] = []
        for s in self.state:
            if isinstance(s, _UntilRuns):
                out.append({"f": s.f.runs, "g": s.g.runs})
            elif isinstance(s, _SinceRuns):
                out.append({"runs": s.runs.runs, "live": s.live, "g": s.g})
            else:
                out.append(s.runs if isinstance(s, _Runs) else s)
        return out

    def load(self, ops: Any) -> None:
        """The state :meth:`save` gave (checked: raises ValueError if it does not fit)."""
        if not isinstance(ops, list) or len(ops) != len(self.ops):
            raise ValueError("the past operators' state does not fit")
        state: list[Any] = []
        for op, s in zip(self.ops, ops, strict=True):
            if op.kind == "until":
                if not isinstance(s, dict):
                    raise ValueError("a time-bounded until's state does not fit")
                state.append(_UntilRuns(_Runs(_runs(s.get("f"))), _Runs(_runs(s.get("g")))))
            elif op.window is not None and op.kind == "since":
                if not isinstance(s, dict) or not all(
                    isinstance(s.get(k), bool) for k in ("live", "g")
                ):
                    raise ValueError("a timed since's state does not fit")
                state.append(_SinceRuns(_Runs(_runs(s.get("runs"))), s["live"], s["g"]))
            elif op.window is not None:
                state.append(_Runs(_runs(s)))
            else:
                (value,) = s
                if not isinstance(value, bool):
                    raise ValueError("a past operator's value is not a bool")
                state.append([value])
        self.state = state


def _runs(value: Any) -> list[list[int | None]]:
    """Runs from their JSON form (raises ValueError or TypeError if they do not fit)."""
    if not isinstance(value, list):
        raise ValueError("a timed operator's runs are not a list")
    return [[int(a), None if b is None else int(b)] for a, b in value]
