"""An assertion, parsed and compiled: its formula over placeholders, ready for synthesis.

The stages (each a module of this package): the lexer's tokens; the parser's typed
syntax tree (atoms read as comparisons over signals, each given its placeholder
``p<i>`` in the order atoms first appear, as in the paper's section IV; PSL's keyword
operators as Spot's); the lowering to Spot's formula (past operators as derived
placeholders, time-bounded ones cut out); their reading by past formulas (timed).
Then the warnings: an assertion no run can satisfy, or none can violate.

=================  =====================================  ==========================
PSL                Spot                                   binding
=================  =====================================  ==========================
``always f``       ``G(f)``                               up to the end of the group
``never f``        ``G!(f)``                              up to the end of the group
``eventually! f``  ``F(f)``                               up to the end of the group
``next f``         ``X f`` (``next!``, ``next[n]`` alike) like ``X``
``next_e[i..j] f`` ``F[i..j] f``                          like ``F``
``next_a[i..j] f`` ``G[i..j] f``                          like ``G``
``a until b``      ``a W b``                              like ``W``
``a until! b``     ``a U b``                              like ``U``
``a until_ b``     ``a W (a & b)``                        like ``W``
``a until!_ b``    ``a U (a & b)``                        like ``U``
``a before b``     ``a R !b``                             like ``R``
``a before! b``    ``a M !b``                             like ``M``
``a before_ b``    ``!b W a``                             like ``W``
``a before!_ b``   ``!b U a``                             like ``U``
=================  =====================================  ==========================
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import spot

from edgerv.core.diagnostics import Diagnostic, InputError
from edgerv.core.documents import MonitorSpec
from edgerv.core.language.atoms import Atom, feasible_letters
from edgerv.core.language.comparisons import AtomReader
from edgerv.core.language.formula import Lowering
from edgerv.core.language.lexer import Fail, check_size, tokenize
from edgerv.core.language.parser import Parser
from edgerv.core.language.past import MAX_LETTER_BITS, PastOp
from edgerv.core.language.spot_worker import BudgetExceeded, worker
from edgerv.core.language.synthesis import (
    MAX_PLACEHOLDERS,
    Abstraction,
    SynthesisError,
    abstract,
)
from edgerv.core.language.timed import TimedReading
from edgerv.core.language.tree import Node, Prop, postorder


@dataclass(frozen=True)
class ParsedAssertion:
    spec: MonitorSpec
    formula: Any  # spot.formula over p0..p{n-1}
    atoms: tuple[Atom, ...]  # atoms[i] is placeholder p<i>
    spot_text: str  # the formula as Spot prints it
    constraint: Any  # spot.formula: the letters that can occur (see feasible_letters)
    warnings: tuple[Diagnostic, ...]
    past: tuple[PastOp, ...] = ()  # derived placeholders p<len(atoms)>..., inner first
    # past MAX_PLACEHOLDERS: what the automaton reads of a letter (its placeholders
    # p<bits>... computed from the ones below); None within it
    abstraction: Abstraction | None = None

    @property
    def bits(self) -> int:
        """Placeholders in a letter: the atoms', then the past operators'."""
        return len(self.atoms) + len(self.past)

    @property
    def automaton(self) -> tuple[Any, Any, int]:
        """The formula the automaton is built for, its constraint and its letter width."""
        a = self.abstraction
        if a is None:
            return self.formula, self.constraint, self.bits
        return a.formula, a.constraint, a.bits


def parse_assertion(spec: MonitorSpec) -> ParsedAssertion:
    """The assertion of ``spec``, compiled to a formula over placeholders; raises
    InputError with every error located in the assertion's text."""
    diagnostics: list[Diagnostic] = []

    def fail(start: int, length: int, message: str, hint: str | None = None) -> None:
        diagnostics.append(Diagnostic(spec.locate_assertion(start, length), message, hint=hint))

    def stop_on_errors() -> None:
        if diagnostics:
            raise InputError(diagnostics)

    tokens = tokenize(spec.assertion, fail)
    check_size(tokens, fail)
    stop_on_errors()
    reader = AtomReader(spec, fail)
    tree = Parser(reader, fail).parse(tokens)
    stop_on_errors()
    assert tree is not None  # no error: a tree
    atoms = tuple(reader.atoms)
    if len(atoms) >= MAX_LETTER_BITS - 1:
        _too_many_atoms(tree, fail)
        stop_on_errors()
    lowering = Lowering(spec.assertion, fail, len(atoms))
    formula = lowering.lower(tree)
    stop_on_errors()
    reading = TimedReading(lowering)
    if lowering.cuts:
        formula = reading.read(formula)
        stop_on_errors()
    constraint = feasible_letters(spec, atoms)
    past = tuple(lowering.past)
    abstraction = None
    if len(atoms) + len(past) > MAX_PLACEHOLDERS:  # what the automaton reads of its letters
        abstraction = _abstract(spec, formula, constraint, len(atoms) + len(past))
    # past placeholders range free; over an abstraction's, the same letters can occur
    seen = (formula, constraint) if abstraction is None else abstraction.automaton
    warnings = _vacuity_warnings(spec, *seen)
    if reading.anchored and spec.on_verdict == "reset":
        warnings.append(
            Diagnostic(
                spec.locate_assertion(0, len(spec.assertion.rstrip())),
                "this assertion is read at the run's first instant (a time-bounded operator "
                "outside always): after its verdict, reset reads it again at each step, "
                "its window long past",
                "warning",
                "write onVerdict: halt for its one verdict, or put it under always",
            )
        )
    return ParsedAssertion(
        spec, formula, atoms, str(formula), constraint, tuple(warnings), past, abstraction
    )


def _too_many_atoms(tree: Node, fail: Fail) -> None:
    """Refuse an assertion with more distinct atoms than a letter holds, at the first
    atom past the limit."""
    limit = MAX_LETTER_BITS - 1
    first = next(n for n in postorder(tree) if isinstance(n, Prop) and n.index >= limit - 1)
    start, end = first.at
    fail(start, max(1, end - start), f"more than {limit - 1} distinct atoms in one assertion "
         f"(a letter holds {MAX_LETTER_BITS} bits, one at least for what its automaton "
         "reads: docs/semantics.md, Limits)", "split it into several monitors")  # fmt: skip


def _abstract(spec: MonitorSpec, formula: Any, constraint: Any, raw: int) -> Abstraction:
    """What the automaton reads of a letter wider than its table takes (synthesis.abstract),
    refused where it reads more than the table or the letter holds."""
    loc = spec.locate_assertion(0, len(spec.assertion.rstrip()))
    try:
        abstraction = abstract(formula, constraint)
    except SynthesisError as exc:
        raise InputError([Diagnostic(loc, str(exc))]) from None
    if raw + abstraction.bits > MAX_LETTER_BITS:
        raise InputError([Diagnostic(
            loc, f"a letter of this assertion needs {raw + abstraction.bits} bits: {raw} for "
            f"its atoms and past or time-bounded operators, {abstraction.bits} for what its "
            f"automaton reads; at most {MAX_LETTER_BITS} (docs/semantics.md, Limits)",
            hint="split the assertion into several monitors")])  # fmt: skip
    return abstraction


@lru_cache(maxsize=4096)
def _vacuity(formula_text: str, constraint_text: str) -> str | None:
    """'unsatisfiable', 'valid' or None for a formula over the letters that can occur."""
    f, g = spot.formula(formula_text), spot.formula.G(spot.formula(constraint_text))
    if spot.translate(spot.formula.And([g, f])).is_empty():
        return "unsatisfiable"
    if spot.translate(spot.formula.And([g, spot.formula.Not(f)])).is_empty():
        return "valid"
    return None


def _vacuity_warnings(spec: MonitorSpec, formula: Any, constraint: Any) -> list[Diagnostic]:
    loc = spec.locate_assertion(0, len(spec.assertion.rstrip()))
    try:
        kind = worker.call(_vacuity, str(formula), str(constraint))
    except BudgetExceeded as exc:
        raise InputError([Diagnostic(loc, str(exc), hint=exc.hint)]) from None
    if kind == "unsatisfiable":
        return [
            Diagnostic(
                loc,
                "the assertion can never hold: every run violates it at step 1",
                "warning",
                "check the comparisons and the temporal operators",
            )
        ]
    if kind == "valid":
        return [
            Diagnostic(
                loc,
                "the assertion always holds: no run can violate it",
                "warning",
                "a monitor that cannot fail checks nothing; check the formula",
            )
        ]
    return []
