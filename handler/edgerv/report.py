"""Output of ``edgerv check``: the exact JSON document, or a readable table."""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import TextIO

from edgerv.core.checker import MonitorResult

MAX_LISTED = 20


def to_json(results: Sequence[MonitorResult]) -> str:
    """``json.dumps({"monitors": [r.as_dict() for r in results]})``, each verdict written
    out directly as json.dumps writes its dict: a check can have a verdict at each of
    100,000 steps, and making a dict of each to print it took a tenth of the check."""
    monitors = []
    for r in results:
        verdicts = ", ".join(
            [
                f'{{"verdict": "{v.verdict}", "stamp": {v.stamp}, "step": {v.step}}}'
                for v in r.verdicts
            ]
        )
        name, state = json.dumps(r.name), json.dumps(r.state)
        monitors.append(f'{{"name": {name}, "verdicts": [{verdicts}], "state": {state}}}')
    return f'{{"monitors": [{", ".join(monitors)}]}}'


def format_stamp(ns: int) -> str:
    sec, frac = divmod(ns, 1_000_000_000)
    return f"{sec}.{frac:09d}"


def print_table(results: Sequence[MonitorResult], out: TextIO) -> None:
    from rich.console import Console  # here: --json does without it (60 ms less to start)
    from rich.table import Table

    console = Console(file=out, highlight=False, width=None if out.isatty() else 120)
    table = Table(title="edgerv check", title_justify="left")
    table.add_column("monitor")
    table.add_column("state")
    table.add_column("steps", justify="right")
    table.add_column("violated", justify="right")
    table.add_column("satisfied", justify="right")
    table.add_column("first verdict (step @ stamp)")
    styles = {"violated": "bold red", "satisfied": "green", "pending": "yellow", "halted": "cyan"}
    for r in results:
        violated = sum(v.verdict == "violated" for v in r.verdicts)
        first = r.verdicts[0] if r.verdicts else None
        table.add_row(
            r.name,
            f"[{styles[r.state]}]{r.state}[/]",
            str(r.steps),
            str(violated),
            str(len(r.verdicts) - violated),
            f"{first.verdict} at step {first.step} @ {format_stamp(first.stamp)}" if first else "-",
        )
    console.print(table)
    for r in results:
        if len(r.verdicts) < 2:
            continue
        console.print(f"[bold]{r.name}[/]: {len(r.verdicts)} verdicts")
        for v in r.verdicts[:MAX_LISTED]:
            console.print(f"  {v.verdict:9} step {v.step:>8} @ {format_stamp(v.stamp)}")
        if len(r.verdicts) > MAX_LISTED:
            console.print(f"  ... {len(r.verdicts) - MAX_LISTED} more (--json lists all)")
    late = [r for r in results if r.late_events]
    for r in late:
        console.print(
            f"[yellow]note[/]: {r.name}: {r.late_events} events arrived after newer ones beyond "
            "its sortThreshold window and were evaluated in arrival order"
        )
