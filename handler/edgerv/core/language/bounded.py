"""Time-bounded future operators as past formulas (docs/semantics.md, "Time").

An obligation with a time bound, ``P -> F[a..b] Q`` under ``always``, is judged by a
past formula that is false exactly at the instants at which some obligation's failure
is certain and shown there: its deadline passed with no Q, or (for ``until``) R broke
before Q came. Spot then builds an automaton for ``always`` of that formula over the
placeholders, and the pipeline computes the past operators step by step
(edgerv.core.language.past), clock steps included, so verdicts come at the instant a failure
became certain, live and offline alike.

Each obligation opened at an instant t where P holds (signals hold their values
between messages, so P holds over intervals and every instant of them opens one):

=========================  ==========================================================
``F[a..b] Q``              Q at some instant of [t+a, t+b]
``G[a..b] Q``              Q at every instant of [t+a, t+b]
``R U[a..b] Q``            Q at some instant t' of [t+a, t+b], R at every instant of
                           [t, t') (a Q before t+a does not count; R need not hold
                           where Q comes, as a state that turns from busy to done at
                           one message)
``R W[a..b] Q``            ``R U[a..b] Q``, or R at every instant of [t, t+b]: R
                           until Q, or for the whole window if Q does not come
=========================  ==========================================================

The past forms, with ``once``/``since`` over closed windows of integer nanoseconds:

* F: ``once[b..b] P -> once[0..b-a] Q``: P held b ago and Q not since b-a ago.
* G: ``once[a..b] P -> Q``.
* R breaks (U and W): ``!R & (once[0..a-1ns] P | (!Q since[0..b-a] (once[a..a] P & !Q)))``
  is true at u when R fails at u while an obligation is open with no Q in its window
  up to u: opened less than a ago (its window has not begun), or opened at some
  t = s - a with no Q from s = t + a to u. U is F's form and this one (Q must come);
  W is this one alone.

Every other nesting (:class:`Delays`): a formula of time-bounded operators, boolean
connectives and past operators over them is read its horizon H late (Maler, Nickovic and
Pnueli's rewriting of bounded future into past): true at t where the formula is true at
t - H, each operator a past one with its window shifted by the delay (U, W, R and M by
``until``, edgerv.core.language.past's placeholder that reads ``f U[a..b] g`` late from the runs
of f and g). Under ``always`` it is read from the instant the run is H old; at the top,
one operator over atoms is read at the run's first instant as soon as it is certain
(:func:`first_instant`), a nested one when the run is H old.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import spot

from edgerv.core.language.past import PastKind, PastOp, check_bit, compile_boolean

BoundedKind = Literal["F", "G", "U", "W", "R", "M"]


@dataclass(frozen=True)
class Obligation:
    """One time-bounded operator in its shape: ``P -> R op[lo..hi] Q`` (R for U and W
    only), each a Spot boolean formula over the placeholders; ``text`` its source."""

    kind: BoundedKind
    window: tuple[int, int]
    p: Any
    q: Any
    r: Any = None
    text: str = ""


def as_past(ob: Obligation, first_bit: int) -> tuple[Any, list[PastOp]]:
    """The boolean formula that is false exactly where one of ``ob``'s obligations is
    certain to fail, and the past operators it reads (placeholders ``first_bit`` on,
    inner ones first)."""
    lo, hi = ob.window
    f = spot.formula
    ops: list[PastOp] = []

    def past(kind: Any, operands: tuple[Any, ...], window: tuple[int, int], what: str) -> Any:
        bit = first_bit + len(ops)
        check_bit(bit)
        funcs = tuple(compile_boolean(o) for o in operands)
        ops.append(PastOp(kind, bit, funcs, window, what))
        return f.ap(f"p{bit}")

    if ob.kind == "G":
        return f.Implies(past("once", (ob.p,), (lo, hi), f"the antecedent of {ob.text}"), ob.q), ops
    parts = []
    if ob.kind in ("F", "U"):  # Q must come: missed once the deadline passed
        opened = past("once", (ob.p,), (hi, hi), f"the antecedent of {ob.text}")
        parts.append(f.Implies(opened, past("once", (ob.q,), (0, hi - lo), ob.text)))
    if ob.kind in ("U", "W"):  # R must hold until Q comes
        not_q = f.Not(ob.q)
        started = ob.p if lo == 0 else past("once", (ob.p,), (lo, lo), f"{ob.text}: window")
        waiting = past(
            "since", (not_q, f.And([started, not_q])), (0, hi - lo), f"{ob.text}: waiting"
        )
        if lo > 0:
            early = past("once", (ob.p,), (0, lo - 1), f"{ob.text}: before the window")
            waiting = f.Or([early, waiting])
        parts.append(f.Not(f.And([f.Not(ob.r), waiting])))
    return f.And(parts), ops


# -- any nesting, read late: time-bounded operators, past ones over them ----------------

# a time-bounded operator, or a past operator over one (read late with it)
CutKind = Literal["F", "G", "U", "W", "R", "M", "once", "historically", "since"]
NewPast = Callable[[PastKind, tuple[Any, ...], tuple[int, int] | None, str, int], Any]


@dataclass(frozen=True)
class Cut:
    """A time-bounded operator, or a past operator over one, taken out of the assertion:
    its proposition ``name`` (``fut<k>``) stands for it; ``operands`` are Spot boolean
    formulas over the placeholders and the names of the operators nested in them
    (``(Q,)``, ``(R, Q)``)."""

    name: str
    kind: CutKind
    window: tuple[int, int]  # an untimed past operator's: [0, MAX_WINDOW]
    operands: tuple[Any, ...]
    text: str


class Delays:
    """Time-bounded formulas read as past formulas with a delay (Maler, Nickovic and
    Pnueli): :meth:`at` gives, for a boolean formula ``f`` over placeholders and nested
    time-bounded operators, a formula over placeholders true at an instant t exactly
    where ``f`` is true at ``t - delay``, for any delay of at least ``f``'s horizon
    (how far ahead its truth looks). Each past operator it needs is made by
    ``new_past`` (which numbers it and returns its proposition), once per operand and
    window. Walks the formulas with explicit stacks: any depth."""

    def __init__(self, cuts: dict[str, Cut], new_past: NewPast) -> None:
        self.cuts = cuts
        self.new_past = new_past
        self._made: dict[tuple[str, str, tuple[int, int] | None, int], Any] = {}
        self._horizons: dict[str, int] = {}

    def past(
        self,
        kind: PastKind,
        operand: Any,
        window: tuple[int, int] | None,
        text: str,
        *,
        other: Any = None,
        delay: int = 0,
    ) -> Any:
        """The proposition of ``kind[window] operand`` (``operand U other`` read
        ``delay`` ago for "until"), made once."""
        operands = (operand,) if other is None else (operand, other)
        key = (kind, " ; ".join(map(str, operands)), window, delay)
        if key not in self._made:
            self._made[key] = self.new_past(kind, operands, window, text, delay)
        return self._made[key]

    def names(self, f: Any) -> list[str]:
        return sorted(
            n for n in (ap.ap_name() for ap in spot.atomic_prop_collect(f)) if n in self.cuts
        )

    def horizon(self, f: Any) -> int:
        """How far ahead of an instant ``f``'s truth there looks (ns)."""
        return max((self.cut_horizon(n) for n in self.names(f)), default=0)

    def cut_horizon(self, name: str) -> int:
        """The horizon of a time-bounded operator: its window's end plus its operands'."""
        todo = [name]
        while todo:  # inner ones first, without recursion
            n = todo[-1]
            inner = [m for o in self.cuts[n].operands for m in self.names(o)]
            missing = [m for m in inner if m not in self._horizons]
            if missing:
                todo.extend(missing)
                continue
            todo.pop()
            cut = self.cuts[n]
            ahead = cut.window[1] if cut.kind in FUTURE else 0  # a past one looks back only
            self._horizons[n] = ahead + max((self._horizons[m] for m in inner), default=0)
        return self._horizons[name]

    def started(self, age: int) -> Any:
        """True from the instant the monitor's run is ``age`` old (its first step then)."""
        if age == 0:
            return spot.formula.tt()
        return self.past("once", spot.formula.tt(), (age, MAX_WINDOW), f"the run {age} ns old")

    def at(self, f: Any, delay: int) -> Any:
        """``f`` read ``delay`` ago (``delay`` >= :meth:`horizon` of ``f``)."""

        def leaf(g: Any) -> Any:
            if g.kind() == spot.op_ap and g.ap_name() in self.cuts:
                return self._cut_at(g.ap_name(), delay)
            if not self.names(g):  # read whole, one placeholder for all of it
                return g if delay == 0 else self.past("once", g, (delay, delay), str(g))
            return None

        return rebuild(f, leaf)

    def _cut_at(self, name: str, delay: int) -> Any:
        cut = self.cuts[name]
        lo, hi = cut.window
        inner = max(self.horizon(o) for o in cut.operands)
        *r, q = (self.at(o, inner) for o in cut.operands)
        late = delay - inner  # how long ago the operator's own instant is, read `inner` late
        if cut.kind not in FUTURE:
            return self._past_at(cut, inner, late, [*r, q])
        window = (late - hi, late - lo)
        if cut.kind in ("F", "G"):
            if window == (0, 0):
                return q
            kind: PastKind = "once" if cut.kind == "F" else "historically"
            return self.past(kind, q, window, cut.text)
        f = spot.formula
        if cut.kind in ("R", "M"):  # R is !(!r U !q), M is !(!r W !q)
            r, q = [f.Not(r[0])], f.Not(q)
        until = self.past("until", r[0], (lo, hi), cut.text, other=q, delay=late)
        if cut.kind in ("W", "M"):  # or r at every instant of [t, t + hi]
            until = f.Or([until, self.past("historically", r[0], (late - hi, late), cut.text)])
        return f.Not(until) if cut.kind in ("R", "M") else until

    def _past_at(self, cut: Cut, inner: int, late: int, operands: list[Any]) -> Any:
        """A past operator over operands read ``inner`` late, read ``late`` more. Instants
        before the run (its operands read late there say nothing) do not count: no
        witness for once and since, no failure for historically."""
        f = spot.formula
        lo, hi = cut.window
        real = self.started(inner)
        if cut.kind == "since":  # untimed: over steps, so a junction is a witness
            left, right = operands
            window = None if cut.window == UNTIMED else cut.window
            since = self.past("since", left, window, cut.text, other=f.And([real, right]))
            return since if late == 0 else self.past("once", since, (late, late), cut.text)
        (q,) = operands
        window = (lo + late, min(hi + late, MAX_WINDOW))
        if cut.kind == "once":
            return self.past("once", f.And([real, q]), window, cut.text)
        return self.past("historically", f.Or([f.Not(real), q]), window, cut.text)

    def ltl(self, f: Any, delay: int) -> Any:
        """``f``, with untimed temporal operators over time-bounded ones, over letters
        read ``delay`` late: each boolean subformula under its temporal operators read
        so (:meth:`at`), the operators kept. True at a step at t where ``f`` is true
        read at t - delay, its untimed operators ranging over the steps from there."""

        def leaf(g: Any) -> Any:
            if not g.is_boolean():
                return None
            return g if g.kind() in (spot.op_tt, spot.op_ff) else self.at(g, delay)

        return rebuild(f, leaf)


FUTURE = ("F", "G", "U", "W", "R", "M")


def cut_formula(cut: Cut) -> Any:
    """Its operands in one formula (to look for operators nested in them)."""
    return spot.formula.And(list(cut.operands))


MAX_WINDOW = 2**63 - 1  # ns: a window reaching back to the run's first step
UNTIMED = (0, MAX_WINDOW)  # an untimed past operator's window, as a cut


def rebuild(f: Any, leaf: Callable[[Any], Any]) -> Any:
    """``f`` with each subformula g for which ``leaf(g)`` is not None replaced by that,
    the nodes above rebuilt; a node without children that ``leaf`` keeps stays. Walks
    Spot's tree with an explicit stack (any depth), each shared subformula once."""
    built: dict[int, Any] = {}
    stack = [(f, False)]
    while stack:
        g, expanded = stack.pop()
        if g.id() in built:
            continue
        if expanded:
            built[g.id()] = g.map(lambda h: built[h.id()])
            continue
        new = leaf(g)
        if new is not None or g.size() == 0:
            built[g.id()] = g if new is None else new
            continue
        stack.append((g, True))
        stack.extend((h, False) for h in g)
    return built[f.id()]


def substitute(f: Any, replace: Callable[[Any], Any]) -> Any:
    """``f`` with each atomic proposition ``ap`` for which ``replace(ap)`` is not None
    replaced by that."""
    return rebuild(f, lambda g: replace(g) if g.kind() == spot.op_ap else None)


def first_instant(cut: Cut, delays: Delays) -> Any:
    """An LTL formula over placeholders true at a run's first step exactly where ``cut``
    holds at the run's first instant, decided as early as it is certain: a time-bounded
    operator at the top of an assertion, as STL reads it. Its operands hold no other
    time-bounded operator (those take :meth:`Delays.at`, read when the run is their
    horizon old)."""
    f = spot.formula
    lo, hi = cut.window
    *r, q = cut.operands
    if cut.kind in ("R", "M"):  # R is !(!r U !q), M is !(!r W !q)
        dual: BoundedKind = "U" if cut.kind == "R" else "W"
        negated = tuple(f.Not(o) for o in cut.operands)
        return f.Not(first_instant(Cut(cut.name, dual, cut.window, negated, cut.text), delays))
    opened = delays.started(lo)
    if cut.kind == "F":  # Q by the deadline (a Q at the deadline's instant counts)
        return f.U(f.Not(delays.started(hi)), f.And([opened, q]))
    if cut.kind == "G":  # Q from lo to hi, both included: decided 1 ns after hi
        return f.W(f.Implies(opened, q), delays.started(hi + 1))
    if cut.kind == "U":  # R until Q, Q within the window
        return f.U(f.And([r[0], f.Not(delays.started(hi))]), f.And([opened, q]))
    # W: as U, or R all the way through hi
    return f.W(r[0], f.Or([f.And([opened, q]), delays.started(hi + 1)]))
