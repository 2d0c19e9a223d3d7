"""A compiled monitor: its spec, placeholders, atom functions and transition table."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from operator import eq, ge, gt, le, lt
from typing import Any

from edgerv.core.diagnostics import Diagnostic, InputError
from edgerv.core.documents import MonitorSpec
from edgerv.core.language.assertion import ParsedAssertion, parse_assertion
from edgerv.core.language.atoms import (
    CMP_FUNCS,  # the comparisons compile_atom makes: a batch applies the same ones
    Atom,
    compile_atom,
    compile_atom_columns,
)
from edgerv.core.language.past import BoolProgram, Derived, PastOp
from edgerv.core.language.synthesis import MonitorTable, SynthesisError, synthesize


@dataclass(frozen=True)
class TimedAtom:
    """``age(signal) OP duration``: placeholder ``bit``, true when ``compare(age, duration)``."""

    bit: int
    signal: int  # signal index: the age of the last message on its topic
    op: str  # < <= > >= == (!= is the negation of ==)
    duration: int  # nanoseconds


AGE_CMP: dict[str, Callable[[Any, Any], bool]] = {"<": lt, "<=": le, ">": gt, ">=": ge, "==": eq}
# For each comparison of an age with d: the instants, after the message at ``last``,
# at which its truth changes (age is d at last + d): ``age < d`` turns false at last + d.
EDGES: dict[str, tuple[int, ...]] = {"<": (0,), ">=": (0,), "<=": (1,), ">": (1,), "==": (0, 1)}


@dataclass(frozen=True)
class AtomRead:
    """An atom as a batch reads it, along its signals' updates: ``compare(values[left],
    const)``, or ``compare(values[left], values[right])`` -- compile_atom's comparison,
    applied to a column of values at once (a C loop: no Python call per value)."""

    bit: int
    left: int  # signal index
    right: int | None  # signal index, or None: compared with ``const``
    compare: Callable[[Any, Any], bool]
    const: Any = None


def _read(bit: int, atom: Atom, index_of: dict[str, int]) -> AtomRead:
    left, right = atom.lhs.signal, atom.rhs.signal
    assert left is not None  # constants go right
    compare = CMP_FUNCS[atom.op]
    if right is None:
        return AtomRead(bit, index_of[left], None, compare, atom.rhs.value)
    return AtomRead(bit, index_of[left], index_of[right], compare)


def _by_the_clock(values: list[Any]) -> bool:
    """The value function of a timed atom: never called; the clock sets its bit."""
    raise AssertionError("a timed atom is evaluated by the clock")


@dataclass(frozen=True)
class CompiledMonitor:
    spec: MonitorSpec
    parsed: ParsedAssertion
    table: MonitorTable
    signal_names: tuple[str, ...]  # signal index -> name
    atom_funcs: tuple[Callable[[list[Any]], bool], ...]  # placeholder i -> its truth value
    atoms_of_signal: tuple[tuple[int, ...], ...]  # signal index -> placeholders reading it
    atom_columns: tuple[Callable[[list[Any]], Any], ...]  # the same over columns of values
    timed: tuple[TimedAtom, ...] = ()  # the atoms time changes: age(x) < 200ms
    past: tuple[PastOp, ...] = ()  # the past operators' placeholders, inner first
    reads: tuple[AtomRead, ...] = ()  # the atoms that are not timed, as a batch reads them
    # a letter wider than the table takes: what the automaton reads of it (letter >> shift),
    # computed at each step from the atoms and past operators; None within the table
    derived: Derived | None = None

    @property
    def letter_bits(self) -> int:
        """A letter's width: the placeholders it holds (the table's, or more)."""
        return self.table.bits if self.derived is None else self.derived.bits

    @property
    def shift(self) -> int:
        """Where the placeholders the automaton reads begin in a letter (0: all of it)."""
        return 0 if self.derived is None else self.derived.shift

    @property
    def stateful(self) -> bool:
        """Its letters need more than the signal values: time, or the past."""
        return bool(self.timed or self.past)

    @property
    def clocked(self) -> bool:
        """It takes clock steps: time alone changes a placeholder."""
        return bool(self.timed) or any(op.window is not None for op in self.past)

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def warnings(self) -> tuple[Diagnostic, ...]:
        return self.parsed.warnings


def compile_monitor(spec: MonitorSpec) -> CompiledMonitor:
    """Parse, check and synthesize one monitor; raise :class:`InputError` on bad input."""
    parsed = parse_assertion(spec)
    try:
        table = synthesize(*parsed.automaton)
    except SynthesisError as exc:
        loc = spec.locate_assertion(0, len(spec.assertion))
        raise InputError([Diagnostic(loc, str(exc))]) from None
    names = tuple(spec.signals)
    index_of = {n: i for i, n in enumerate(names)}
    atoms = parsed.atoms
    funcs = tuple(_by_the_clock if a.timed else compile_atom(a, index_of) for a in atoms)
    readers = tuple(tuple(i for i, a in enumerate(atoms) if name in a.signals) for name in names)
    columns = tuple(_by_the_clock if a.timed else compile_atom_columns(a, index_of) for a in atoms)
    timed = tuple(
        TimedAtom(i, index_of[str(a.lhs.signal)], a.op, int(a.rhs.value))  # type: ignore[arg-type]
        for i, a in enumerate(atoms)
        if a.timed
    )
    reads = tuple(_read(i, a, index_of) for i, a in enumerate(atoms) if not a.timed)
    derived = None
    if parsed.abstraction is not None:
        programs = tuple(BoolProgram(part) for part in parsed.abstraction.parts)
        derived = Derived(parsed.bits, programs)
    return CompiledMonitor(
        spec, parsed, table, names, funcs, readers, columns, timed, parsed.past, reads, derived
    )


def compile_monitors(
    specs: Sequence[MonitorSpec],
) -> tuple[list[CompiledMonitor], list[Diagnostic]]:
    """Compile every monitor; collect the errors of all of them (raise if any) and the warnings."""
    compiled: list[CompiledMonitor] = []
    errors: list[Diagnostic] = []
    warnings: list[Diagnostic] = []
    for spec in specs:
        try:
            monitor = compile_monitor(spec)
        except InputError as exc:
            errors += exc.diagnostics
            continue
        compiled.append(monitor)
        warnings += monitor.warnings
    if errors:
        raise InputError(errors + warnings)
    return compiled, warnings
