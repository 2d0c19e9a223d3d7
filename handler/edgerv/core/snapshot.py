"""A monitor's state at a handoff's cut, as an object (docs/protocol.md).

The sender's runtime makes it (:meth:`MonitorRuntime.snapshot
<edgerv.core.pipeline.MonitorRuntime.snapshot>`), the receiver's is made from it
(:meth:`MonitorRuntime.restored <edgerv.core.pipeline.MonitorRuntime.restored>`), and
:mod:`edgerv.core.handoff` carries it over the wire. Here: its type, its error, and the
letters' run-length form both sides use.
"""

from __future__ import annotations

from array import array
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from edgerv.core.monitor import CompiledMonitor


class HandoffError(Exception):
    """A snapshot that cannot be used: what is wrong with it."""


@dataclass(frozen=True)
class Snapshot:
    monitor: str
    epoch: int  # fences stale handoffs: a handler ignores an epoch it has seen
    cut: int
    state: int
    step: int
    halted: bool
    values: tuple[Any, ...]  # per signal, None for "no value yet"
    valuation: int
    last_released: int | None
    late_events: int
    bits: int
    letters: array  # type: ignore[type-arg]  # the letter typecode of ``bits``
    stamps: Mapping[int, int]  # letter index -> stamp, only where a verdict can be reported
    # a monitor with timed atoms: its clock (the time of its last step, and of the last
    # message on each signal's topic); None for one without
    clock: tuple[int | None, tuple[int | None, ...]] | None = None
    past: Any = None  # its past operators' state (Past.save), None for a monitor without
    # a monitor whose letter is wider than its table's (more than 16 placeholders: the
    # automaton reads its top, edgerv.core.language.past.Derived): that width, which
    # ``valuation`` has, while ``letters`` are what the automaton reads of each, ``bits``
    # wide; 0 for any other (its letters are its valuations' width)
    wide: int = 0
    # the letters' runs (runs_of), when the sender computed them already
    runs: Any = field(default=None, compare=False, repr=False)


def deciding_steps(monitor: CompiledMonitor, state: int, runs: tuple[Any, Any, Any]) -> list[int]:
    """The indices of the letters that take the automaton to a verdict, from ``state``.

    Walks the letters' runs (:func:`runs_of`) run by run: within a run of one letter,
    once a step leaves a state that is not a verdict unchanged, the rest of the run
    stays there.
    """
    table = monitor.table
    rows, bits, live = table.table, table.bits, table.live
    found = []
    starts, values, lengths = runs
    for start, letter, length in zip(
        starts.tolist(), values.tolist(), lengths.tolist(), strict=True
    ):
        for j in range(length):
            nxt = rows[(state << bits) | letter]
            if nxt >= live:
                found.append(start + j)
            elif nxt == state:
                break  # a loop on this letter: no verdict in the rest of the run
            state = nxt
    return found


def runs_of(letters: Sequence[int]) -> tuple[Any, Any, Any]:
    """Run-length form of the letters: the start, letter and length of each run (arrays)."""
    import numpy as np  # here: the pipeline imports this module, a check without a handoff

    # (most) does without NumPy
    arr = (
        np.frombuffer(letters, dtype=letters.typecode)
        if isinstance(letters, array)
        else np.asarray(letters, dtype=np.int64)
    )
    starts = np.flatnonzero(arr[1:] != arr[:-1]) + 1
    if len(arr):
        starts = np.concatenate((np.zeros(1, starts.dtype), starts))
    return starts, arr[starts], np.diff(starts, append=len(arr))
