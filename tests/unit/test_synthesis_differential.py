"""Synthesized monitors against the independent reference (tests/kit/reference.py).

Formulas: Spot's pattern families (DAC, EH, SB) and random LTL. Each is written
as an assertion over bool signals, goes through edgerv's front end and
synthesis, and its letters go through the real evaluation loop
(:meth:`MonitorRuntime.evaluate`). The reference reads the *original* Spot
formula over the signal names, so the front end is covered too.
"""

from __future__ import annotations

import random

import pytest
import spot
import spot.gen as sg

from edgerv.core.monitor import CompiledMonitor
from edgerv.core.pipeline import MonitorRuntime
from kit.documents import compiled
from kit.reference import ReferenceMonitor

NAMES = "abcdefghij"


def family(code: int) -> list[str]:
    return [
        str(spot.relabel(f, spot.Abc)) for f in sg.ltl_patterns((code, 1, sg.ltl_pattern_max(code)))
    ]


def random_formulas(count: int, seed: int) -> list[str]:
    gen = spot.randltl(["a", "b", "c"], seed=seed, tree_size=(5, 20), simplify=0)
    out: list[str] = []
    while len(out) < count:
        f = next(gen)
        if len(spot.atomic_prop_collect(f)) > 0:
            out.append(str(f))
    return out


def edgerv_verdicts(m: CompiledMonitor, letters: list[int]) -> list[tuple[str, int]]:
    rt = MonitorRuntime(m)
    rt.letters.extend(letters)
    rt.stamps.extend(range(len(letters)))
    return [(v.verdict, v.step) for v in rt.evaluate()]


def compare(formula: str, seed: int, halt: bool = False, runs: int = 12, length: int = 30) -> None:
    aps = sorted(str(a) for a in spot.atomic_prop_collect(spot.formula(formula)))
    on_verdict = "halt" if halt else "reset"
    m = compiled(formula, {a: "bool" for a in aps}, onVerdict=on_verdict)
    names = [atom.text for atom in m.parsed.atoms]  # bit i of a letter is this signal
    ref = ReferenceMonitor(spot.formula(formula), names, halt=halt)
    rng = random.Random(seed)
    for _ in range(runs):
        # biased letters reach deep states more often than uniform ones
        bias = [rng.random() for _ in names]
        letters = [
            sum(1 << i for i, p in enumerate(bias) if rng.random() < p) for _ in range(length)
        ]
        assert edgerv_verdicts(m, letters) == ref.run(letters), (formula, letters)


@pytest.mark.parametrize("formula", family(sg.LTL_DAC_PATTERNS))
def test_dac_patterns(formula: str) -> None:
    compare(formula, seed=1)


@pytest.mark.parametrize("formula", family(sg.LTL_EH_PATTERNS) + family(sg.LTL_SB_PATTERNS))
def test_eh_and_sb_patterns(formula: str) -> None:
    compare(formula, seed=2)


@pytest.mark.parametrize("formula", random_formulas(120, seed=7))
def test_random_formulas(formula: str) -> None:
    compare(formula, seed=3)


@pytest.mark.parametrize("formula", random_formulas(30, seed=11))
def test_random_formulas_halt(formula: str) -> None:
    compare(formula, seed=4, halt=True)


def test_the_table_is_minimal_and_one_integer() -> None:
    m = compiled("always (a -> (b until c))", {"a": "bool", "b": "bool", "c": "bool"})
    table = m.table
    assert (table.live, table.bits) == (2, 3)  # the paper's Fig. 2 automaton has 2 live states
    assert len(table.table) == table.states << table.bits


def test_liveness_reports_good_prefixes() -> None:
    m = compiled("eventually! a", {"a": "bool"})
    assert edgerv_verdicts(m, [0, 0, 1, 0]) == [("satisfied", 3)]


def test_unsatisfiable_formula_is_violated_at_every_step() -> None:
    m = compiled("a & !a", {"a": "bool"})
    assert edgerv_verdicts(m, [0, 1]) == [("violated", 1), ("violated", 2)]
