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


MAX_TABLE_BITS = 16  # an operand reading placeholders p0..p15 only is a truth table
# A letter's raw bits: atoms, past operators, and the automaton's derived placeholders
# (edgerv.core.language.synthesis.abstract), in one signed 64-bit integer (NumPy's int64
# in the column path, array typecode 'q'): bits 0..62.
MAX_LETTER_BITS = 63


def check_bit(bit: int) -> None:
    """Raise :class:`PastError` when placeholder ``bit`` is past a letter's width (the
    atoms and past operators before it take the rest)."""
    if bit >= MAX_LETTER_BITS - 1:  # (and one at least for what the automaton reads)
        raise PastError(
            f"more than {MAX_LETTER_BITS - 1} atoms and past or time-bounded operators in "
            f"one assertion (a letter holds {MAX_LETTER_BITS} bits: docs/semantics.md, "
            "Limits): split it into several monitors"
        )


def compile_boolean(formula: Any) -> BitsFunction:
    """A Spot boolean formula over placeholders ``p<i>`` as a function of the bits: a
    lookup in its truth table over the bits up to the highest it reads, or, past
    :data:`MAX_TABLE_BITS`, a :class:`BoolProgram` (no table of 2^17 entries or more).

    The table is built bottom-up over Spot's tree with an explicit stack, as integers
    of one bit per letter, so an operand nested thousands deep is no deeper a
    computation (no recursion, no generated source); raises :class:`PastError` for a
    formula that is not boolean over placeholders."""
    if not formula.is_boolean():
        raise PastError(f"'{formula}' is not a boolean formula")
    if _highest(formula) >= MAX_TABLE_BITS:
        return BoolProgram(formula)
    table = _truth_table(str(formula))
    mask = len(table) - 1
    function = lambda b: table[b & mask]  # noqa: E731 (it carries its table: Past reads it)
    function.table, function.mask = table, mask  # type: ignore[attr-defined]
    return function


@lru_cache(maxsize=1024)
def _truth_table(text: str) -> tuple[bool, ...]:
    """The truth of the boolean formula ``text`` for each letter ``0 .. 2^n - 1``, n one
    more than the highest placeholder it reads (monitors with one operand share it)."""
    formula = spot.formula(text)
    highest = _highest(formula)
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


def _placeholder(ap: Any) -> int:
    """The bit of placeholder ``p<i>`` (raises :class:`PastError` for another name)."""
    name = ap.ap_name()
    if not (name.startswith("p") and name[1:].isdigit()):
        raise PastError(f"unknown proposition '{name}'")
    bit = int(name[1:])
    if bit >= MAX_LETTER_BITS:
        raise PastError(f"placeholder '{name}' is past a letter's {MAX_LETTER_BITS} bits")
    return bit


def _highest(formula: Any) -> int:
    """The highest placeholder bit ``formula`` reads (-1: none)."""
    return max((_placeholder(ap) for ap in spot.atomic_prop_collect(formula)), default=-1)


# BoolProgram's instructions, each writing one register (its index in the program)
_VAR, _NOT, _AND, _OR, _XOR, _EQUIV, _CONST = range(7)


class BoolProgram:
    """A boolean formula over placeholders as data: a list of instructions over the bits
    of a letter, evaluated in order, no truth table (any of a letter's 63 bits), no
    generated source. Conjunctions and disjunctions test their literal operands with two
    masks at once (``a & !b & c``: one test); the others read registers.

    Called with a letter (an int) it gives the formula's truth there; :meth:`columns`
    gives it for a NumPy array of letters at once (the column path)."""

    __slots__ = ("code", "reads")

    def __init__(self, formula: Any) -> None:
        if not formula.is_boolean():
            raise PastError(f"'{formula}' is not a boolean formula")
        code: list[tuple[Any, ...]] = []
        reg: dict[int, int] = {}  # a subformula's id: its register
        reads = 0
        stack = [(formula, False)]
        while stack:  # leaves first, each shared subformula once, without recursion
            f, expanded = stack.pop()
            if f.id() in reg:
                continue
            k = f.kind()
            kids = [g for g in f if not (k in (spot.op_And, spot.op_Or) and _literal(g))]
            if not expanded and kids:
                stack.append((f, True))
                stack.extend((g, False) for g in kids if g.id() not in reg)
                continue
            if k == spot.op_ap:
                bit = _placeholder(f)
                reads |= 1 << bit
                code.append((_VAR, bit))
            elif k in (spot.op_tt, spot.op_ff):
                code.append((_CONST, k == spot.op_tt))
            elif k == spot.op_Not:
                code.append((_NOT, reg[f[0].id()]))
            elif k in (spot.op_And, spot.op_Or):
                pos = neg = 0
                for g in f:
                    if _literal(g):
                        bit = _placeholder(g if g.kind() == spot.op_ap else g[0])
                        reads |= 1 << bit
                        if g.kind() == spot.op_ap:
                            pos |= 1 << bit
                        else:
                            neg |= 1 << bit
                regs = tuple(reg[g.id()] for g in kids)
                code.append((_AND if k == spot.op_And else _OR, pos, neg, regs))
            elif k in (spot.op_Xor, spot.op_Equiv):
                code.append((_XOR if k == spot.op_Xor else _EQUIV, reg[f[0].id()], reg[f[1].id()]))
            elif k == spot.op_Implies:  # !a | b
                code.append((_NOT, reg[f[0].id()]))
                code.append((_OR, 0, 0, (len(code) - 1, reg[f[1].id()])))
            else:
                raise PastError(f"'{f}' is not a boolean formula")
            reg[f.id()] = len(code) - 1
        self.code = tuple(code)
        self.reads = reads  # the bits it reads

    def __call__(self, bits: int) -> bool:
        regs: list[bool] = []
        put = regs.append
        for ins in self.code:
            op = ins[0]
            if op == _AND:
                _, pos, neg, kids = ins
                put(bits & pos == pos and not bits & neg and all(regs[k] for k in kids))
            elif op == _OR:
                _, pos, neg, kids = ins
                put(bool(bits & pos) or bool(~bits & neg) or any(regs[k] for k in kids))
            elif op == _VAR:
                put(bool(bits >> ins[1] & 1))
            elif op == _NOT:
                put(not regs[ins[1]])
            elif op == _XOR:
                put(regs[ins[1]] != regs[ins[2]])
            elif op == _EQUIV:
                put(regs[ins[1]] == regs[ins[2]])
            else:
                put(ins[1])
        return regs[-1]

    def columns(self, letters: Any) -> Any:
        """The truth for each letter of an int64 NumPy array: a bool array."""
        import numpy as np  # here: only the column path takes it

        regs: list[Any] = []
        put = regs.append
        for ins in self.code:
            op = ins[0]
            if op in (_AND, _OR):
                _, pos, neg, kids = ins
                if op == _AND:
                    out = ((letters & pos) == pos) & ((letters & neg) == 0)
                    for k in kids:
                        out = out & regs[k]
                else:
                    out = ((letters & pos) != 0) | ((~letters & neg) != 0)
                    for k in kids:
                        out = out | regs[k]
                put(out)
            elif op == _VAR:
                put((letters >> ins[1] & 1) != 0)
            elif op == _NOT:
                put(~regs[ins[1]])
            elif op == _XOR:
                put(regs[ins[1]] ^ regs[ins[2]])
            elif op == _EQUIV:
                put(~(regs[ins[1]] ^ regs[ins[2]]))
            else:
                put(np.full(len(letters), ins[1], bool))
        return regs[-1]


def _literal(g: Any) -> bool:
    """A placeholder or its negation: a conjunction or disjunction tests it by its mask."""
    return bool(g.kind() == spot.op_ap or (g.kind() == spot.op_Not and g[0].kind() == spot.op_ap))


@dataclass(frozen=True)
class Derived:
    """The placeholders an automaton reads when its assertion's letter is wider than its
    table takes (edgerv.core.language.synthesis.abstract): placeholder ``shift + j`` is
    ``programs[j]`` of the bits below ``shift`` (the atoms' and the past operators'),
    computed at every step after them. The automaton reads ``letter >> shift``."""

    shift: int
    programs: tuple[BoolProgram, ...]

    @property
    def bits(self) -> int:
        """The letter's whole width: the raw bits and the derived ones."""
        return self.shift + len(self.programs)

    def __call__(self, bits: int) -> int:
        """``bits`` with the derived placeholders set from the bits below ``shift``."""
        bits &= (1 << self.shift) - 1
        one = 1 << self.shift
        for program in self.programs:
            if program(bits):
                bits |= one
            one <<= 1
        return bits

    def columns(self, letters: Any) -> Any:
        """The same over an int64 NumPy array of letters (a new array)."""
        import numpy as np

        out = letters & ((1 << self.shift) - 1)
        for j, program in enumerate(self.programs):
            out |= program.columns(out).astype(np.int64) << (self.shift + j)
        return out


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
        """The first instant after ``now`` at which :meth:`once` may change its answer:
        a run's start plus ``lo`` or its end plus ``hi``, the first of either after now
        (the runs are in order, starts and ends ascending; the ongoing one, last, has no
        end)."""
        best = None
        for start, _ in self.runs:
            if start + lo > now:  # type: ignore[operator]
                best = start + lo  # type: ignore[operator]
                break
        for _, end in self.runs:
            if end is None:
                break
            if end + hi > now:
                if best is None or end + hi < best:
                    best = end + hi
                break
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


# What Past.step does for each operator, by code (the most frequent first): its program
# holds one tuple per operator, its operands as truth tables (no call per operand)
_TIMED_ONCE, _TIMED_HISTORICALLY, _TIMED_SINCE, _UNTIL = range(4)  # (once 0: `if code` below)
_PREV, _ONCE, _HISTORICALLY, _SINCE = range(4, 8)
_TIMED_CODES = {"once": _TIMED_ONCE, "historically": _TIMED_HISTORICALLY, "since": _TIMED_SINCE}
_UNTIMED_CODES = {"prev": _PREV, "once": _ONCE, "historically": _HISTORICALLY, "since": _SINCE}
# (code, its bit, the other bits, f's table and mask, g's (or none), lo, hi, delay)
_Instruction = tuple[int, int, int, Any, int, Any, int, int, int, int]


class _Calls:
    """An operand that is not :func:`compile_boolean`'s, read as a table: ``calls[bits]``
    is its value (its mask is -1: every bit)."""

    __slots__ = ("function",)

    def __init__(self, function: BitsFunction) -> None:
        self.function = function

    def __getitem__(self, bits: int) -> bool:
        return self.function(bits)


def _table(operand: BitsFunction) -> tuple[Any, int]:
    """An operand as its truth table and the mask of the bits it reads."""
    table = getattr(operand, "table", None)
    if table is None:
        return _Calls(operand), -1
    return table, operand.mask  # type: ignore[attr-defined]


def _instruction(op: PastOp) -> _Instruction:
    if op.kind == "until":
        code = _UNTIL
    elif op.window is not None:
        if op.kind not in _TIMED_CODES:
            raise PastError(f"'{op.kind}' takes no time bound")
        code = _TIMED_CODES[op.kind]
    else:
        code = _UNTIMED_CODES[op.kind]
    f_table, f_mask = _table(op.operands[0])
    g_table, g_mask = _table(op.operands[1]) if len(op.operands) > 1 else ((), 0)
    lo, hi = (0, 0) if op.window is None else op.window
    one = 1 << op.bit
    return code, one, ~one, f_table, f_mask, g_table, g_mask, lo, hi, op.delay


class Past:
    """The derived placeholders of one monitor and their state. Not thread-safe."""

    def __init__(self, ops: Sequence[PastOp]) -> None:
        self.ops = tuple(ops)
        # per op: prev: [the operand at the last step]; untimed: [its value]; timed: runs
        self.state: list[Any] = [self._initial(op) for op in self.ops]
        self._prevs = [
            (i, op.bit) for i, op in enumerate(self.ops) if op.window is None and op.kind == "prev"
        ]
        self.always_settled = not self._prevs  # settled() is True whatever the letter
        self._program = tuple(_instruction(op) for op in self.ops)
        self._timed = tuple(i for i, op in enumerate(self.ops) if op.window is not None)

    @staticmethod
    def _initial(op: PastOp) -> Any:
        if op.kind == "until":
            return _UntilRuns()
        if op.window is not None:
            return _SinceRuns() if op.kind == "since" else _Runs()
        return [op.kind == "historically"]  # once, since, prev: False; historically: True

    def step(self, now: int, bits: int) -> int:
        """Take a step at ``now`` whose atoms are ``bits``: the letter with the derived
        placeholders set, inner ones first (an outer one reads their new bits).

        The timed once and historically (the runs of their operand, :class:`_Runs`) are
        stepped here, not by calls: what :meth:`_Runs.step`, :meth:`_Runs.prune` and
        :meth:`_Runs.once` do, in that order."""
        for (code, one, off, ft, fm, gt, gm, lo, hi, delay), state in zip(
            self._program, self.state, strict=True
        ):
            if code <= _TIMED_HISTORICALLY:  # once[lo..hi] f; historically: not once !f
                holds = ft[bits & fm]
                if code:  # historically
                    holds = not holds
                runs = state.runs
                if not runs:
                    if holds:
                        runs.append([now, None])
                        value = lo == 0
                    else:
                        value = False
                else:
                    last = runs[-1]
                    if last[1] is None:
                        if not holds:
                            last[1] = now
                    elif holds:
                        runs.append([now, None])
                    while runs and (end := runs[0][1]) is not None and end + hi <= now:
                        del runs[0]
                    value = bool(runs) and runs[0][0] + lo <= now
                if code:  # historically
                    value = not value
            elif code == _TIMED_SINCE:
                state.step(now, ft[bits & fm], gt[bits & gm])
                value = state.holds(now, lo, hi)
            elif code == _UNTIL:
                state.step(now, ft[bits & fm], gt[bits & gm])
                state.prune(now, delay)
                value = state.holds(now, lo, hi, delay)
            elif code == _PREV:  # the operand at the step before (none: false)
                value, state[0] = state[0], ft[bits & fm]
            elif code == _ONCE:
                value = state[0] = state[0] or ft[bits & fm]
            elif code == _HISTORICALLY:
                value = state[0] = state[0] and ft[bits & fm]
            else:  # f since g: g now, or f now and (f since g) at the step before
                value = state[0] = gt[bits & gm] or (ft[bits & fm] and state[0])
            bits = bits | one if value else bits & off
        return bits

    def settled(self, bits: int) -> bool:
        """Would a step with the atoms of ``bits`` (the last step's letter) at the same
        instant give ``bits`` again and leave the state as it is? Then so does every
        later step with the same atoms, up to the first instant at which a timed one
        may change (:meth:`next_change`): a run of equal messages is a run of equal
        letters, and a batch takes it whole.

        Only ``prev`` can answer no (:attr:`always_settled` where there is none): it
        gives the operand of the step before, which the next step replaces by the last
        one. ``once``, ``historically`` and ``since`` already hold what a repeated
        operand gives them, and a timed one's runs do not change while its operand does
        not (its truth then changes with time only, and what a step would forget of
        them, a run that ends out of its window, waits for an instant at or after
        :meth:`next_change`: a step before it forgets nothing).
        """
        state = self.state
        return all(state[i][0] == bool(bits >> bit & 1) for i, bit in self._prevs)

    def prune(self, now: int) -> None:
        """Forget the runs no window reaching back from ``now`` can see, as a step at
        ``now`` does (a batch that takes a run of equal letters whole prunes once)."""
        program, state = self._program, self.state
        for i in self._timed:
            code, hi, delay = program[i][0], program[i][8], program[i][9]
            s = state[i]
            if code == _UNTIL:
                s.prune(now, delay)
            elif code != _TIMED_SINCE:
                s.prune(now, hi)
            elif s.live:
                s.runs.prune(now, hi)

    def time_changes(self, now: int, bits: int) -> bool:
        """Does a timed one's truth at ``now`` differ from its bit in ``bits`` (the
        last step's letter), every operand held since that step? Then time alone
        changed it, and a clock step is due at ``now``."""
        program, state = self._program, self.state
        for i in self._timed:
            code, one, _, _, _, _, _, lo, hi, delay = program[i]
            s = state[i]
            if code == _UNTIL:
                s.prune(now, delay)
                value = s.holds(now, lo, hi, delay)
            elif code == _TIMED_SINCE:
                value = s.holds(now, lo, hi)
            else:
                s.prune(now, hi)
                value = s.once(now, lo, hi) != (code == _TIMED_HISTORICALLY)
            if value != bool(bits & one):
                return True
        return False

    def next_change(self, now: int) -> int | None:
        """The first instant after ``now`` at which a timed one may change its truth
        with no new step; None if none can."""
        best = None
        program, state = self._program, self.state
        for i in self._timed:
            code, lo, hi, delay = program[i][0], program[i][7], program[i][8], program[i][9]
            if code == _UNTIL:
                at = state[i].next_change(now, lo, hi, delay)
            else:
                at = state[i].next_change(now, lo, hi)
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
