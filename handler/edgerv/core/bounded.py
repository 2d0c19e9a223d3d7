"""Time-bounded future operators as past formulas (docs/semantics.md, "Time").

An obligation with a time bound, ``P -> F[a..b] Q`` under ``always``, is judged by a
past formula that is false exactly at the instants at which some obligation's failure
is certain and shown there: its deadline passed with no Q, or (for ``until``) R broke
before Q came. Spot then builds an automaton for ``always`` of that formula over the
placeholders, and the pipeline computes the past operators step by step
(edgerv.core.past), clock steps included, so verdicts come at the instant a failure
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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import spot

from edgerv.core.past import PastOp, compile_boolean

BoundedKind = Literal["F", "G", "U", "W"]


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
