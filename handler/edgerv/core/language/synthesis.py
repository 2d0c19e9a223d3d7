"""Synthesis of three-valued (LTL3) monitors as compact transition tables.

For a formula f over placeholders p0..p(k-1) and the constraint C on the letters
that can occur, Spot builds two deterministic *bad-prefix* monitors
(``translate(g, 'monitor', 'det')``: a word prefix has a run iff it is not bad):

* M+ for ``G C & f``: a prefix without a run is a bad prefix of f -> ``violated``
* M- for ``G C & !f``: a prefix without a run is a good prefix of f -> ``satisfied``

Their product, minimized, is a deterministic automaton whose whole state is one
integer. It is compiled to a flat table ``table[(state << k) | letter]``, where a
letter is the bit vector of the placeholders (bit i is p<i>). States
``0 .. live-1`` are undecided (0 is initial); ``live`` is VIOLATED and
``live + 1`` is SATISFIED. The rows of the two verdict states are copies of the
initial row, so with ``onVerdict: reset`` the next letter starts afresh with no
special case in the evaluation loop.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import spot
from spot import buddy

from edgerv.core.language.bounded import substitute
from edgerv.core.language.spot_worker import BudgetExceeded, worker

MAX_PLACEHOLDERS = 16  # the automaton's letter: a table row has 2^16 columns at most
MAX_TABLE_ENTRIES = 1 << 22


class SynthesisError(Exception):
    pass


@dataclass(frozen=True)
class MonitorTable:
    bits: int  # letter width: the number of placeholders
    live: int  # undecided states are 0 .. live-1; 0 is initial
    table: tuple[int, ...]  # table[(state << bits) | letter] -> next state

    @property
    def violated(self) -> int:
        return self.live

    @property
    def satisfied(self) -> int:
        return self.live + 1

    @property
    def states(self) -> int:
        return self.live + 2

    def step(self, state: int, letter: int) -> int:
        return self.table[(state << self.bits) | letter]


class _Successors:
    """Letter -> successor of a deterministic Spot monitor (-1: no run, a bad prefix)."""

    def __init__(self, aut: Any, bits: int) -> None:
        self.aut = aut
        d = aut.get_dict()
        known = {str(ap): d.varnum(ap) for ap in aut.ap()}  # APs Spot simplified away are absent
        variables = [known.get(f"p{i}", -1) for i in range(bits)]
        self.letters = []
        for letter in range(1 << bits):
            cube = buddy.bddtrue
            for i, var in enumerate(variables):
                if var >= 0:
                    lit = buddy.bdd_ithvar(var) if letter >> i & 1 else buddy.bdd_nithvar(var)
                    cube = cube & lit
            self.letters.append(cube)
        self.edges = [[(e.cond, e.dst) for e in aut.out(s)] for s in range(aut.num_states())]
        self.initial = aut.get_init_state_number() if aut.num_states() else -1
        self.cache: dict[int, list[int]] = {}

    def row(self, state: int) -> list[int]:
        if state < 0:
            return [-1] * len(self.letters)
        if state not in self.cache:
            row = []
            for cube in self.letters:
                dst = -1
                for cond, target in self.edges[state]:
                    if (cond & cube) != buddy.bddfalse:
                        dst = target
                        break
                row.append(dst)
            self.cache[state] = row
        return self.cache[state]


def _bad_prefix_monitor(f: Any) -> Any:
    aut = spot.translate(f, "monitor", "det")
    if not aut.is_deterministic():  # Spot's 'det' monitors are deterministic; make sure
        raise SynthesisError(f"Spot returned a nondeterministic monitor for {f}")
    return aut


@lru_cache(maxsize=4096)
def _synthesize_cached(formula_text: str, constraint_text: str, bits: int) -> MonitorTable:
    f = spot.formula(formula_text)
    g = spot.formula.G(spot.formula(constraint_text))
    pos = _Successors(_bad_prefix_monitor(spot.formula.And([g, f])), bits)
    neg = _Successors(_bad_prefix_monitor(spot.formula.And([g, spot.formula.Not(f)])), bits)
    n_letters = 1 << bits

    # Breadth-first product; verdicts are the absorbing classes -1 (violated), -2 (satisfied).
    start = (pos.initial, neg.initial)
    index = {start: 0}
    order = [start]
    rows: list[list[int]] = []
    queue = deque([start])
    while queue:
        a, b = queue.popleft()
        ra, rb = pos.row(a), neg.row(b)
        row = []
        for letter in range(n_letters):
            na, nb = ra[letter], rb[letter]
            if na < 0 or a < 0:
                row.append(-1)
            elif nb < 0 or b < 0:
                row.append(-2)
            else:
                key = (na, nb)
                if key not in index:
                    index[key] = len(order)
                    order.append(key)
                    queue.append(key)
                row.append(index[key])
        rows.append(row)
        if len(order) * n_letters > MAX_TABLE_ENTRIES:
            raise SynthesisError(
                f"the monitor needs more than {MAX_TABLE_ENTRIES} table entries; "
                "split the assertion into several monitors"
            )
    # The start state itself may already be decided (f unsatisfiable or valid over C).
    if start[0] < 0:
        rows[0] = [-1] * n_letters
    elif start[1] < 0:
        rows[0] = [-2] * n_letters
    return _minimize(rows, bits)


def _minimize(rows: list[list[int]], bits: int) -> MonitorTable:
    """Moore partition refinement; verdicts (-1, -2) are fixed classes of their own."""
    n = len(rows)
    cls = [0] * n
    while True:
        sigs: dict[tuple[int, ...], int] = {}
        new = [
            sigs.setdefault((cls[s], *(t if t < 0 else cls[t] for t in rows[s])), len(sigs))
            for s in range(n)
        ]
        if len(sigs) == len(set(cls)):
            break
        cls = new
    # Renumber classes breadth-first from the initial state so that it is 0.
    number: dict[int, int] = {cls[0]: 0}
    rep: list[int] = [0]
    queue = deque([0])
    while queue:
        s = queue.popleft()
        for t in rows[s]:
            if t >= 0 and cls[t] not in number:
                number[cls[t]] = len(rep)
                rep.append(t)
                queue.append(t)
    live = len(rep)
    verdict = {-1: live, -2: live + 1}
    table: list[int] = []
    for s in rep:
        table += [verdict[t] if t < 0 else number[cls[t]] for t in rows[s]]
    initial_row = table[: 1 << bits]
    table += initial_row + initial_row  # VIOLATED and SATISFIED restart like the initial state
    return MonitorTable(bits=bits, live=live, table=tuple(table))


def synthesize(formula: Any, constraint: Any, bits: int) -> MonitorTable:
    """The LTL3 monitor table of ``formula`` over ``bits`` placeholders under ``constraint``."""
    if bits > MAX_PLACEHOLDERS:
        raise SynthesisError(
            f"the automaton reads {bits} placeholders (docs/semantics.md, Limits); at "
            f"most {MAX_PLACEHOLDERS} are supported: split it into several monitors"
        )
    try:
        return worker.call(_synthesize_cached, str(formula), str(constraint), bits)
    except BudgetExceeded as exc:
        raise SynthesisError(f"{exc}; {exc.hint}") from None


# -- propositional abstraction: what the automaton reads of a wide letter -----------------


@dataclass(frozen=True)
class Abstraction:
    """A formula over more placeholders than a table takes, as the automaton reads it:
    each maximal boolean subformula under its temporal operators (the boolean operands
    of one conjunction or disjunction together) is one placeholder ``p<j>`` of
    ``formula``, whose truth is ``parts[j]`` over the letter's placeholders (computed at
    every step: edgerv.core.language.past.Derived); ``constraint`` says which of its
    letters can occur: those with a letter of the assertion's own placeholders that the
    assertion's constraint admits (an existential projection, so the automaton's
    verdicts are those of the formula over its own placeholders)."""

    formula: Any
    constraint: Any
    parts: tuple[Any, ...]

    @property
    def bits(self) -> int:
        return len(self.parts)

    @property
    def automaton(self) -> tuple[Any, Any]:
        return self.formula, self.constraint


def abstract(formula: Any, constraint: Any) -> Abstraction:
    """``formula`` (under ``constraint``) with each maximal boolean subformula as one
    placeholder; raises :class:`SynthesisError` if the automaton would still read more
    than :data:`MAX_PLACEHOLDERS` (distinct ones: a subformula and its negation share
    one). Walks Spot's tree with an explicit stack."""
    f = spot.formula
    parts: list[Any] = []
    index: dict[int, int] = {}

    def placeholder(g: Any) -> Any:
        negated = g.kind() == spot.op_Not
        h = g[0] if negated else g
        if h.id() not in index:
            index[h.id()] = len(parts)
            parts.append(h)
        ap = f.ap(f"p{index[h.id()]}")
        return f.Not(ap) if negated else ap

    built: dict[int, Any] = {}
    stack = [(formula, False)]
    while stack:
        g, expanded = stack.pop()
        if g.id() in built:
            continue
        if g.kind() in (spot.op_tt, spot.op_ff):
            built[g.id()] = g
            continue
        if g.is_boolean():
            built[g.id()] = placeholder(g)
            continue
        junction = g.kind() in (spot.op_And, spot.op_Or)
        kids = [h for h in g if not (junction and h.is_boolean())]
        if not expanded:
            stack.append((g, True))
            stack.extend((h, False) for h in kids)
            continue
        if junction:
            booleans = [h for h in g if h.is_boolean()]
            join = f.And if g.kind() == spot.op_And else f.Or
            rest = [built[h.id()] for h in kids]
            if booleans:
                rest.insert(0, placeholder(join(booleans)))
            built[g.id()] = join(rest)
        else:
            built[g.id()] = g.map(lambda h: built[h.id()])
    if len(parts) > MAX_PLACEHOLDERS:
        raise SynthesisError(
            f"the automaton reads {len(parts)} boolean subformulas under temporal operators "
            f"(each one placeholder of its letter); at most {MAX_PLACEHOLDERS} are "
            "supported (docs/semantics.md, Limits): split the assertion into several "
            "monitors"
        )
    texts = tuple(str(p) for p in parts)
    try:
        projected = worker.call(_projected, str(constraint), texts)
    except BudgetExceeded as exc:
        raise SynthesisError(f"{exc}; {exc.hint}") from None
    return Abstraction(built[formula.id()], spot.formula(projected), tuple(parts))


@lru_cache(maxsize=1024)
def _projected(constraint_text: str, parts: tuple[str, ...]) -> str:
    """The letters over ``p0..p<k-1>`` (``p<j>`` the truth of ``parts[j]``) that some
    letter satisfying ``constraint_text`` gives: exists the assertion's placeholders,
    with BDDs."""
    d = spot.make_bdd_dict()
    owner = spot.make_twa_graph(d)
    fresh = [spot.formula.ap(f"q{j}") for j in range(len(parts))]
    relation = spot.formula.And(
        [spot.formula(constraint_text)]
        + [spot.formula.Equiv(q, spot.formula(p)) for q, p in zip(fresh, parts, strict=True)]
    )
    whole = spot.formula_to_bdd(relation, d, owner)  # (registers every proposition)
    keep = buddy.bddtrue
    for q in fresh:  # each q<j> is in it: parts[j] is no constant
        keep = keep & buddy.bdd_ithvar(d.varnum(q))
    image = spot.bdd_to_formula(buddy.bdd_existcomp(whole, keep), d)
    d.unregister_all_my_variables(owner)  # (Spot crashes at exit otherwise)
    names = {f"q{j}": spot.formula.ap(f"p{j}") for j in range(len(parts))}
    return str(substitute(image, lambda ap: names.get(ap.ap_name())))
