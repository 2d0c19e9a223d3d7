"""How each time-bounded operator of an assertion is read (docs/semantics.md, section 6).

The lowering (edgerv.core.language.formula) leaves a proposition ``fut<k>`` for each
time-bounded operator (and each past operator over one). Here the formula is
rewritten without them, by past formulas (edgerv.core.language.bounded):

- under a top-level ``always``, ``always (P -> op)`` (alone or in a conjunction, P
  boolean, op over atoms) as the obligations it opens, each reported the instant its
  failure is certain;
- any other combination, nested in one another, under untimed operators or over
  past ones, read its horizon late (Maler, Nickovic and Pnueli);
- outside ``always``, at the run's first instant: as soon as it is certain where
  the operator's operands hold no other, else its horizon late.
"""

from __future__ import annotations

from typing import Any, cast

import spot

from edgerv.core.language.bounded import (
    BoundedKind,
    Delays,
    Obligation,
    as_past,
    cut_formula,
    first_instant,
    substitute,
)
from edgerv.core.language.formula import Lowering
from edgerv.core.language.past import PastError, compile_boolean
from edgerv.core.language.tree import Timed


class TimedReading:
    def __init__(self, lowering: Lowering) -> None:
        self.low = lowering
        self.delays = Delays(lowering.cuts, lowering.new_past)
        self.anchored = False  # a time-bounded operator read at the run's first instant

    def read(self, formula: Any) -> Any:
        """The formula with its time-bounded operators read by past formulas, or None
        on an error (reported)."""
        f = spot.formula
        if formula.kind() == spot.op_And:
            parts = [self.read(g) for g in formula]
            return None if any(g is None for g in parts) else f.And(parts)
        if not _futures(formula):
            return formula
        if formula.is_boolean():
            return self._at_first_instant(formula)
        if formula.kind() != spot.op_G:
            return self._late(formula)
        pieces = []
        for part in _conjuncts(formula[0]):
            names = _futures(part)
            if not names or part.kind() == spot.op_G:  # always (x & always y): y as well
                pieces.append(self.read(part) if names else part)
                continue
            shape = _antecedent(part, names[0])
            cut = self.delays.cuts[names[0]]
            simple = (
                not self.delays.names(cut_formula(cut))
                and cut.kind in ("F", "G", "U", "W")
                and isinstance(self.low.where[names[0]], Timed)
            )
            if len(names) == 1 and shape is not None and shape.is_boolean() and simple:
                pieces.append(self._judged(names[0], shape))
            else:
                pieces.append(self._delayed(part))
        return None if any(x is None for x in pieces) else f.G(f.And(pieces))

    def _error(self, name: str, message: str, hint: str | None = None) -> None:
        self.low.error(self.low.where[name], message, hint)

    def _delayed(self, part: Any) -> Any:
        """``always (part)``'s piece: ``part`` read its horizon late, from the instant
        the run is that old (no obligation opens before the run)."""
        if not part.is_boolean() and not self._steps_free(part):
            return None
        d = self.delays
        horizon = d.horizon(part)
        try:
            read = d.at(part, horizon) if part.is_boolean() else d.ltl(part, horizon)
            return spot.formula.Implies(d.started(horizon), read)
        except PastError as exc:
            self._error(d.names(part)[0], str(exc))
            return None

    def _at_first_instant(self, formula: Any) -> Any:
        """A boolean combination of time-bounded operators at the top of the assertion,
        each read at the run's first instant: as soon as it is certain when its operands
        hold no other (:func:`bounded.first_instant`), else its horizon late."""
        d = self.delays

        def read(ap: Any) -> Any:
            name = ap.ap_name()
            if name not in d.cuts:
                return None
            cut = d.cuts[name]
            if not d.names(cut_formula(cut)):
                return first_instant(cut, d)
            h = d.horizon(ap)
            ready = d.started(h)
            late = spot.formula.And([ready, d.at(ap, h)])
            return spot.formula.U(spot.formula.Not(ready), late)

        self.anchored = True
        try:
            return substitute(formula, read)
        except PastError as exc:
            self._error(d.names(formula)[0], str(exc))
            return None

    def _steps_free(self, formula: Any) -> bool:
        """Untimed operators over time-bounded ones range over the instants their
        operands change at, read late: X, a step count (F[1..3]) or a SERE, which count
        steps, have no such reading. Refused at the time-bounded operator; False then."""
        if formula.is_syntactic_stutter_invariant():
            return True
        name = _futures(formula)[0]
        kind = self.delays.cuts[name].kind
        self._error(name, f"a time-bounded {kind} beside X, a step count or a SERE, which "
                    "count steps: not supported",
                    "bound the step in time instead: X f as F[0..100ms] f, or split the "
                    "assertion into several monitors")  # fmt: skip
        return False

    def _late(self, formula: Any) -> Any:
        """An assertion whose untimed temporal operators hold time-bounded ones, not
        under a top-level always: its letters read its horizon H late, from the instant
        the run is H old (so its first step is the run's first instant, read late)."""
        if not self._steps_free(formula):
            return None
        self.anchored = True
        d = self.delays
        horizon = d.horizon(formula)
        try:
            ready = d.started(horizon)
            late = spot.formula.And([ready, d.ltl(formula, horizon)])
            return spot.formula.U(spot.formula.Not(ready), late)
        except PastError as exc:
            self._error(d.names(formula)[0], str(exc))
            return None

    def _judged(self, name: str, shape: Any) -> Any:
        """The past formula judging ``always (shape -> op)``'s obligations, ``op`` the
        time-bounded operator ``name`` stands for."""
        cut = self.delays.cuts[name]
        try:
            compile_boolean(shape)  # its placeholders within the table's width
        except PastError as exc:
            self._error(name, str(exc))
            return None
        *r, q = cut.operands
        kind = cast(BoundedKind, cut.kind)
        ob = Obligation(kind, cut.window, shape, q, r[0] if r else None, cut.text)
        try:
            piece, ops = as_past(ob, self.low.next_bit)
        except PastError as exc:  # too many placeholders
            self._error(name, str(exc))
            return None
        self.low.past.extend(ops)
        return piece


def _futures(formula: Any) -> list[str]:
    """The time-bounded operators' propositions (``fut<k>``) in ``formula``."""
    names = (ap.ap_name() for ap in spot.atomic_prop_collect(formula))
    return sorted(n for n in names if n.startswith("fut"))


def _conjuncts(body: Any) -> list[Any]:
    """``body`` as a conjunction's parts, ``P -> (A & B)`` as ``P -> A`` and ``P -> B``."""
    if body.kind() == spot.op_And:
        return [part for g in body for part in _conjuncts(g)]
    if body.kind() == spot.op_Implies and body[1].kind() == spot.op_And:
        return [part for g in body[1] for part in _conjuncts(spot.formula.Implies(body[0], g))]
    return [body]


def _antecedent(part: Any, name: str) -> Any:
    """P when ``part`` is ``P -> fut``, ``fut`` (P true) or ``!P | fut``; else None."""
    fut = spot.formula.ap(name)
    if part == fut:
        return spot.formula.tt()
    if part.kind() == spot.op_Implies and part[1] == fut:
        return part[0]
    if part.kind() == spot.op_Or and fut in list(part):
        return spot.formula.Not(spot.formula.Or([g for g in part if g != fut]))
    return None
