"""When a verdict is reported against the earliest instant it is certain (docs/semantics.md,
section 6, "When each construct reports").

The earliest certain instant comes from a brute-force reference that tries every instant:
the first T at which the run up to T (every signal unknown after it) decides the formula,
by three-valued evaluation of the definitions (tests/kit/dense.py). Kleene's logic can leave
undecided what a cleverer reading would decide (``x | !x``); the formulas here are ones
whose verdict it decides in time. The contract checked: a nested formula's verdict comes
at most its horizon H after that instant, never before it. ``python
tests/unit/test_verdict_delay.py`` prints the table of measured delays the docs give.
"""

from __future__ import annotations

import random
import statistics
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from kit.checks import events, run, verdicts
from kit.dense import (
    SIGNALS,
    Formula,
    evaluator,
    horizon,
    kleene,
    random_formula,
    random_run,
    size,
    text,
    timed,
)
from kit.documents import compiled

Case = tuple[str, Formula, list[tuple[str, int, bool]]]


def certain_violation(body: Formula, rows: list[tuple[str, int, bool]], end: int) -> int | None:
    """The first instant T at which the run up to T makes ``always (body)`` fail."""
    for known in range(0, end + 1):
        at = kleene(rows, known)
        if any(at(body, t) is False for t in range(0, known + 1)):
            return known
    return None


def certain_verdict(f: Formula, rows: list[tuple[str, int, bool]], end: int) -> int | None:
    """The first instant T at which the run up to T decides ``f`` at the first instant."""
    for known in range(0, end + 1):
        if kleene(rows, known)(f, 0) is not None:
            return known
    return None


def cases(seed: int, count: int) -> list[Case]:
    """("always", body, run) whose body fails on its run; ("top", f, run) decided on it."""
    rng = random.Random(seed)
    out: list[Case] = []
    while len(out) < count:
        f = random_formula(rng, 3)
        if timed(f) < 2 or horizon(f) > 8 or size(f) > 11:
            continue
        rows = random_run(rng, 24)
        where = "top" if f[0] in ("F", "G", "U", "W", "R", "M") and rng.random() < 0.4 else (
            "always")  # fmt: skip
        at = evaluator(rows)
        if (where == "always" and any(not at(f, t) for t in range(0, 24 - horizon(f) + 1))) or (
            where == "top" and horizon(f) <= 24
        ):
            out.append((where, f, rows))
    return out


def delay(case: Case) -> tuple[int, int, int]:
    """(reported, earliest certain, horizon) of the case's verdict, in ns."""
    where, f, rows = case
    h, end = horizon(f), rows[-1][1]
    assertion = f"always ({text(f)})" if where == "always" else text(f)
    (result,) = run([compiled(assertion, SIGNALS, onVerdict="halt")], events(rows))
    ((_, _, reported),) = verdicts(result)
    earliest = (certain_violation if where == "always" else certain_verdict)(f, rows, end)
    assert earliest is not None
    return reported, earliest, h


CASES = cases(21, 60)


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"{c[0]} {text(c[1])}")
def test_a_verdict_comes_at_most_its_horizon_after_it_is_certain(case: Case) -> None:
    reported, earliest, h = delay(case)
    assert earliest <= reported <= earliest + h, (case, reported, earliest, h)


def table() -> str:
    rows = []
    for where in ("always", "top"):
        measured = [delay(c) for c in CASES if c[0] == where]
        late = [r - e for r, e, _ in measured]
        share = [(r - e) / h for r, e, h in measured if h]
        rows.append(
            f"| {where} | {len(measured)} | {sum(d == 0 for d in late)} | "
            f"{statistics.mean(share):.2f} | {max(share):.2f} |"
        )
    head = "| where | formulas | at the earliest instant | mean delay / H | largest delay / H |"
    return "\n".join([head, "|---|---|---|---|---|", *rows])


if __name__ == "__main__":
    print(table())
