"""The tree to Spot's formula over placeholders (one walk, leaves first, no recursion).

Atoms are ``p0..p<n-1>``. Each past operator over booleans becomes a derived
placeholder of its own (``p<n>``, ...: edgerv.core.language.past computes it step by
step). Each time-bounded operator, and each past operator over one, is taken out as
a **cut**: a proposition ``fut<k>`` stands for it, and edgerv.core.language.timed
reads the formula with them (edgerv.core.language.bounded). Whatever cannot be built
is refused at its operator's place: an untimed future operator inside a past or a
time-bounded one, a SERE operator over a non-boolean where Spot needs a boolean,
more cuts or placeholders than the limits.
"""

from __future__ import annotations

from typing import Any

import spot

from edgerv.core.language.bounded import UNTIMED, Cut, CutKind
from edgerv.core.language.lexer import Fail
from edgerv.core.language.past import PastError, PastKind, PastOp, check_bit, compile_boolean
from edgerv.core.language.tree import (
    UNBOUNDED,
    Binary,
    Closure,
    Const,
    FirstMatch,
    Node,
    Not,
    Past,
    Prop,
    Repeat,
    Sere,
    Steps,
    Suffix,
    Timed,
    Until,
    postorder,
)

MAX_CUTS = 64  # time-bounded operators, and past ones over them: Delays nests a call each
MAX_UNFOLDED = 20_000  # nodes of the formula as a tree, shared operands counted each time

f = spot.formula
_STRONG_X = spot.formula("X[!] p").kind()  # Spot's Python names no op_strong_X
_BOOL = {"&": lambda a, b: f.And([a, b]), "|": lambda a, b: f.Or([a, b]), "^": f.Xor,
         "->": f.Implies, "<->": f.Equiv}  # fmt: skip
_SERE = {";": lambda a, b: f.Concat([a, b]), ":": lambda a, b: f.Fusion([a, b]),
         "|": lambda a, b: f.OrRat([a, b]), "&": lambda a, b: f.AndNLM([a, b]),
         "&&": lambda a, b: f.AndRat([a, b]), "^": f.Xor, "->": f.Implies,
         "<->": f.Equiv}  # fmt: skip
_UNTIL = {"U": f.U, "W": f.W, "R": f.R, "M": f.M}


class Lowering:
    """Lowers trees of one assertion: :attr:`past` and :attr:`cuts` grow as it goes,
    numbered after the ``atoms`` placeholders."""

    def __init__(self, text: str, fail: Fail, atoms: int) -> None:
        self.text = text
        self.fail = fail
        self.atoms = atoms
        self.past: list[PastOp] = []
        self.cuts: dict[str, Cut] = {}
        self.where: dict[str, Node] = {}  # each cut's node, for its errors

    @property
    def next_bit(self) -> int:
        return self.atoms + len(self.past)

    def new_past(
        self,
        kind: PastKind,
        operands: tuple[Any, ...],
        window: tuple[int, int] | None,
        text: str,
        delay: int = 0,
    ) -> Any:
        """A derived placeholder for a past operator over boolean ``operands``: its
        proposition (raises PastError for an operand it cannot compute)."""
        bit = self.next_bit
        check_bit(bit)
        funcs = tuple(compile_boolean(o) for o in operands)
        self.past.append(PastOp(kind, bit, funcs, window, text, delay))
        return f.ap(f"p{bit}")

    def source(self, node: Node) -> str:
        return self.text[node.span[0] : node.span[1]]

    def error(self, node: Node, message: str, hint: str | None = None) -> None:
        start, end = node.at
        self.fail(start, max(1, end - start), message, hint)

    def lower(self, root: Node) -> Any:
        """Spot's formula for the tree, or None after an error (reported)."""
        made: dict[int, Any] = {}
        late: set[int] = set()  # nodes that hold a cut
        size: dict[int, int] = {}  # each node's operators and leaves, its shared ones counted
        for node in postorder(root):  # as often as they occur (as Spot prints and reads it)
            size[id(node)] = min(1 + sum(size[id(c)] for c in node.children), MAX_UNFOLDED + 1)
            if size[id(node)] > MAX_UNFOLDED:
                self.error(node, f"the assertion unfolds to more than {MAX_UNFOLDED:,} "
                           "operators and atoms here (until_ and until!_ repeat their left "
                           "operand)", "write it with W and U (a until_ b is a W (a & b)), "
                           "or split the assertion into several monitors")  # fmt: skip
                return None
            kids = [made[id(c)] for c in node.children]
            if isinstance(node, Timed) or any(id(c) in late for c in node.children):
                late.add(id(node))
            formula = self._one(node, kids, late)
            if formula is None:
                return None
            made[id(node)] = formula
        return made[id(root)]

    def _one(self, node: Node, kids: list[Any], late: set[int]) -> Any:
        if isinstance(node, Const):
            return f.tt() if node.value else f.ff()
        if isinstance(node, Prop):
            return f.ap(f"p{node.index}")
        if isinstance(node, Not):
            if _sere_only(kids[0]):
                return self._not_boolean(node, "'!'")
            return f.Not(kids[0])
        if isinstance(node, Binary):
            return _BOOL[node.op](*kids)
        if isinstance(node, Until):
            return _UNTIL[node.op](*kids)
        if isinstance(node, Steps):
            return _steps(node, kids[0])
        if isinstance(node, Sere):
            if node.op in ("^", "<->") and not all(k.is_boolean() for k in kids):
                return self._not_boolean(node, f"'{node.op}'")
            if node.op == "->" and not kids[0].is_boolean():
                return self._not_boolean(node, "'->' (on its left)")
            return _SERE[node.op](*kids)
        if isinstance(node, Repeat):
            return self._repeat(node, kids)
        if isinstance(node, FirstMatch):
            return f.first_match(kids[0])
        if isinstance(node, Closure):
            return f.EConcat(kids[0], f.tt()) if node.strong else f.Closure(kids[0])
        if isinstance(node, Suffix):
            return (f.UConcat if node.universal else f.EConcat)(kids[0], kids[1])
        if isinstance(node, Timed):
            return self._cut(node, node.op, node.window, kids)
        if isinstance(node, Past):
            if id(node) in late:  # over a time-bounded operator: read late with it
                if node.op == "prev":
                    self.error(node, "prev over a time-bounded operator: not supported (prev "
                               "counts steps, which a late reading does not keep)",
                               "write once[a..b] for a time before now")  # fmt: skip
                    return None
                return self._cut(node, node.op, node.window or UNTIMED, kids)
            return self._past(node, kids)
        raise AssertionError(f"a node the lowering does not know: {node!r}")

    def _past(self, node: Past, kids: list[Any]) -> Any:
        if not all(k.is_boolean() for k in kids):
            self.error(node, f"'{node.op}' needs a formula without future operators",
                       "past operators look back: their operands are atoms, boolean "
                       "operators and other past operators")  # fmt: skip
            return None
        try:
            return self.new_past(node.op, tuple(kids), node.window, self.source(node))
        except PastError as exc:
            self.error(node, str(exc))
            return None

    def _cut(self, node: Node, kind: CutKind, window: tuple[int, int], kids: list[Any]) -> Any:
        name = f"fut{len(self.cuts)}"
        if len(self.cuts) >= MAX_CUTS:  # each takes a placeholder or more: far past the limit
            self.error(node, f"more than {MAX_CUTS} time-bounded operators (and past operators "
                       "over them) in one assertion",
                       "split the assertion into several monitors")  # fmt: skip
            return None
        if not all(k.is_boolean() for k in kids):
            self.error(node, f"an untimed future operator inside the operand of {kind}",
                       "the operands of a time-bounded operator are atoms, boolean "
                       "operators, past operators and time-bounded operators")  # fmt: skip
            return None
        self.cuts[name] = Cut(name, kind, window, tuple(kids), self.source(node))
        self.where[name] = node
        return f.ap(name)

    def _repeat(self, node: Repeat, kids: list[Any]) -> Any:
        operand = kids[0] if kids else f.tt()
        hi = f.unbounded() if node.hi == UNBOUNDED else node.hi
        if node.op in ("[=", "[->") and not operand.is_boolean():
            return self._not_boolean(node, node.op + "]")
        if node.op == "[*":
            return f.Star(operand, node.lo, hi)
        if node.op == "[:*":
            return f.FStar(operand, node.lo, hi)
        if node.op == "[=":
            return f.sugar_equal(operand, node.lo, hi)
        return f.sugar_goto(operand, node.lo, hi)

    def _not_boolean(self, node: Node, what: str) -> None:
        self.error(node, f"not a boolean expression: in a SERE {what} applies to booleans "
                   "only", "write the SERE's steps as booleans: {a ; !b ; c}")  # fmt: skip


def _sere_only(g: Any) -> bool:
    """A SERE that is not a boolean (``a;b``, ``a[*]``): no formula's operand."""
    return bool(g.is_sere_formula() and not g.is_boolean() and not g.is_ltl_formula())


def _steps(node: Steps, operand: Any) -> Any:
    if node.lo is None or node.hi is None:
        if node.op == "X":
            return f.unop(_STRONG_X, operand) if node.strong else f.X(operand)
        return f.F(operand) if node.op == "F" else f.G(operand)
    hi = f.unbounded() if node.hi == UNBOUNDED else node.hi
    x = _STRONG_X if node.strong else spot.op_X
    if node.op == "X":
        return f.nested_unop_range(x, spot.op_Or, node.lo, node.hi, operand)
    join = spot.op_Or if node.op == "F" else spot.op_And
    return f.nested_unop_range(x, join, node.lo, hi, operand)
