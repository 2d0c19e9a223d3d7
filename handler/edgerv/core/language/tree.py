"""The typed syntax tree of an assertion: what the parser makes and every rewriting walks.

Each node keeps where it was written (``span``: offsets into the assertion's text,
``at``: its operator's own token) so that whatever refuses it later names the place.
Leaves are the atoms' placeholders (``Prop``: the atom's index, given in the order the
atoms first appear) and the constants. PSL's keyword operators are already Spot's
operators here (the parser builds ``a until_ b`` as ``a W (a & b)``, sharing ``a``):
the tree is what the assertion means, in the fewest kinds of node.

Trees are walked without recursion (:func:`postorder`): an assertion may nest as deep
as the parser's limits allow.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Literal, TypeVar

Span = tuple[int, int]  # [start, end) in the assertion's text

BoolOp = Literal["&", "|", "^", "->", "<->"]
UntilOp = Literal["U", "W", "R", "M"]
SereOp = Literal[";", ":", "|", "&", "&&", "^", "->", "<->"]
RepeatOp = Literal["[*", "[:*", "[=", "[->"]
PastName = Literal["once", "historically", "prev", "since"]
TimedOp = Literal["F", "G", "U", "W", "R", "M"]
UNBOUNDED = -1  # a repetition's or a step range's open end


@dataclass(frozen=True, eq=False)
class Node:
    span: Span
    at: Span  # the operator's own token (for a leaf, the leaf)

    @property
    def children(self) -> tuple[Node, ...]:
        return ()


@dataclass(frozen=True, eq=False)
class Const(Node):
    value: bool


@dataclass(frozen=True, eq=False)
class Prop(Node):
    """An atom's placeholder ``p<index>``."""

    index: int


@dataclass(frozen=True, eq=False)
class Not(Node):
    operand: Node

    @property
    def children(self) -> tuple[Node, ...]:
        return (self.operand,)


@dataclass(frozen=True, eq=False)
class Binary(Node):
    """A boolean connective between formulas."""

    op: BoolOp
    left: Node
    right: Node

    @property
    def children(self) -> tuple[Node, ...]:
        return (self.left, self.right)


@dataclass(frozen=True, eq=False)
class Steps(Node):
    """``X``, ``F`` or ``G``, untimed; with a step range for ``X[n]``, ``F[i..j]``,
    ``G[i..j]`` (``hi`` may be :data:`UNBOUNDED`); ``strong`` for ``X[!]``."""

    op: Literal["X", "F", "G"]
    operand: Node
    lo: int | None = None  # None: no range (F f, G f, X f)
    hi: int | None = None
    strong: bool = False

    @property
    def children(self) -> tuple[Node, ...]:
        return (self.operand,)


@dataclass(frozen=True, eq=False)
class Until(Node):
    op: UntilOp
    left: Node
    right: Node

    @property
    def children(self) -> tuple[Node, ...]:
        return (self.left, self.right)


@dataclass(frozen=True, eq=False)
class Timed(Node):
    """A time-bounded ``F``/``G`` (one operand) or ``U``/``W``/``R``/``M`` (two), its
    window ``[lo, hi]`` in nanoseconds."""

    op: TimedOp
    window: tuple[int, int]
    operands: tuple[Node, ...]

    @property
    def children(self) -> tuple[Node, ...]:
        return self.operands


@dataclass(frozen=True, eq=False)
class Past(Node):
    """``once``, ``historically``, ``prev`` (one operand) or ``since`` (two), timed with
    a window in nanoseconds or not (None)."""

    op: PastName
    window: tuple[int, int] | None
    operands: tuple[Node, ...]

    @property
    def children(self) -> tuple[Node, ...]:
        return self.operands


@dataclass(frozen=True, eq=False)
class Sere(Node):
    """A SERE's binary operator (``&&`` is length-matching, ``&`` not: Spot's and PSL's
    reading)."""

    op: SereOp
    left: Node
    right: Node

    @property
    def children(self) -> tuple[Node, ...]:
        return (self.left, self.right)


@dataclass(frozen=True, eq=False)
class Repeat(Node):
    """``r[*i..j]``, ``r[:*i..j]``, ``b[=i..j]``, ``b[->i..j]`` (``hi`` may be
    :data:`UNBOUNDED`); ``operand`` None for a lone ``[*]``, which repeats ``true``."""

    op: RepeatOp
    operand: Node | None
    lo: int
    hi: int

    @property
    def children(self) -> tuple[Node, ...]:
        return () if self.operand is None else (self.operand,)


@dataclass(frozen=True, eq=False)
class FirstMatch(Node):
    operand: Node

    @property
    def children(self) -> tuple[Node, ...]:
        return (self.operand,)


@dataclass(frozen=True, eq=False)
class Closure(Node):
    """A braced SERE as a formula: ``{r}`` (weak), ``{r}!`` (strong)."""

    sere: Node
    strong: bool

    @property
    def children(self) -> tuple[Node, ...]:
        return (self.sere,)


@dataclass(frozen=True, eq=False)
class Suffix(Node):
    """``{r} []-> f`` (``|->``, ``{r}(f)``) or ``{r} <>-> f``; ``[]=>``, ``<>=>`` and
    ``|=>`` are these over ``{r;1}``."""

    universal: bool
    sere: Node
    formula: Node

    @property
    def children(self) -> tuple[Node, ...]:
        return (self.sere, self.formula)


N = TypeVar("N")


def postorder(root: Node) -> Iterator[Node]:
    """Every node below ``root`` and itself, children first, each shared node once."""
    seen: set[int] = set()
    stack: list[tuple[Node, bool]] = [(root, False)]
    while stack:
        node, expanded = stack.pop()
        if expanded:
            yield node
            continue
        if id(node) in seen:
            continue
        seen.add(id(node))
        stack.append((node, True))
        stack.extend((c, False) for c in reversed(node.children))


def fold(root: Node, combine: Callable[[Node, list[N]], N]) -> N:
    """``combine(node, values of its children)`` from the leaves up, without recursion
    (a shared node is combined once)."""
    value: dict[int, N] = {}
    for node in postorder(root):
        value[id(node)] = combine(node, [value[id(c)] for c in node.children])
    return value[id(root)]


def contains(root: Node, kinds: tuple[type[Node], ...]) -> Node | None:
    """The first node of one of ``kinds`` below ``root`` (or itself), children first."""
    return next((n for n in postorder(root) if isinstance(n, kinds)), None)
