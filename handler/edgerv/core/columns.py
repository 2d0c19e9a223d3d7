"""A monitor's letters for a chunk of a check, a column at a time (NumPy).

What :meth:`MonitorRuntime._compress_one <edgerv.core.pipeline.MonitorRuntime>`
does event by event, for a chunk of events whose field values came as arrays (an
MCAP bag read column-wise): each signal's value after each event is its column,
forward-filled from its updates; each placeholder is its comparison over the
columns; a timed atom's truth comes from the time of the last message on its
topic, forward-filled the same way; and the clock steps between two events are
the instants at which a timed atom's truth changes (docs/semantics.md, "Time").
One letter per event and per clock step, in order: the letters and stamps of the
scalar path, exactly (``tests/unit/test_columns.py`` checks them side by side).

Only where NumPy computes what Python does: a comparison whose operands NumPy
holds exactly (a float column with a float, or an integer of at most 2^53; an
integer column with an integer in its range; a bool with a bool; any column of
Python objects), times within +-2^62 ns, and a monitor that takes its events as
they come with every signal valued and no past operator. Anything else gets
None, and the caller takes the scalar path.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from edgerv.core.monitor import AGE_CMP, EDGES, CompiledMonitor

_TIME = 1 << 62  # stamps, ages and durations within it: sums stay in int64
_FLOAT_INT = 1 << 53  # integers a float64 holds exactly

Change = tuple[npt.NDArray[np.int64], Any]  # positions (ascending) and the values given there


class Letters(NamedTuple):
    """What a chunk leaves: its letters and their stamps (events and clock steps, in
    order), and the state after its last event."""

    letters: npt.NDArray[np.int64]
    stamps: npt.NDArray[np.int64]
    values: list[Any]  # each signal's value after the chunk (Python values)
    last: list[int | None]  # each signal's last message time (a clocked monitor's)


def compress(
    monitor: CompiledMonitor,
    stamps: npt.NDArray[np.int64],
    changes: Sequence[Change],
    before: Sequence[Any],
    valuation: int,
    now: int | None,
    last: Sequence[int | None],
) -> Letters | None:
    """The letters of a chunk's events (``stamps``; ``changes``: per signal, its updates)
    for a monitor whose signals all have a value (``before``) and whose last letter was
    ``valuation``; ``now`` and ``last``: its clock (None, [] without timed atoms). None
    where this path does not give exactly the scalar path's letters."""
    n = len(stamps)
    if monitor.past or not n:
        return None
    changes = [(np.asarray(p, np.int64), v) for p, v in changes]  # () where none
    columns: dict[int, Any] = {}

    def column(signal: int) -> Any:
        if signal not in columns:
            columns[signal] = _column(changes[signal], before[signal], n)
        return columns[signal]

    bits = np.zeros(n, np.int64)
    with np.errstate(all="ignore"):  # NaN compares false, as in Python
        for read in monitor.reads:
            left = column(read.left)
            if left is None:
                return None
            if read.right is None:
                if not _exact(left, read.const):
                    return None
                truth = read.compare(left, read.const)
            else:
                right = column(read.right)
                if right is None or not (
                    left.dtype.hasobject or right.dtype.hasobject or left.dtype == right.dtype
                ):
                    return None
                truth = read.compare(left, right)
            bits |= np.asarray(truth, dtype=bool).astype(np.int64) << read.bit
    values = list(before)
    for signal, (positions, given) in enumerate(changes):
        if len(positions):
            value = given[-1]
            values[signal] = value.item() if isinstance(value, np.generic) else value
    if not monitor.timed:
        got: Letters | None = Letters(bits, stamps, values, list(last))
    else:
        got = _timed(monitor, stamps, changes, bits, valuation, now, last, values)
    if got is None or monitor.derived is None:
        return got
    # a wide letter: the placeholders the automaton reads, from the atoms' (a clock step's
    # too: its letter's are computed again, as the scalar path's)
    return got._replace(letters=monitor.derived.columns(got.letters))


def _column(change: Change, before: Any, n: int) -> Any:
    """A signal's value after each of ``n`` events: ``before`` until its first update.
    None when ``before`` has no exact place among the column's values."""
    positions, given = change
    if len(positions) == n:
        return given
    given = np.asarray(given)
    source = np.empty(len(given) + 1, given.dtype if len(given) else object)
    source[: len(given)] = given
    source[-1] = before
    held = source[-1]
    if source.dtype != object and not (held == before or before != before):
        source = np.array([*given.tolist(), before], dtype=object)
    if not len(positions):
        return np.full(n, source[-1], source.dtype)
    index = np.full(n, -1, np.int64)
    index[positions] = np.arange(len(positions))
    np.maximum.accumulate(index, out=index)
    return source[index]


def _exact(column: Any, const: Any) -> bool:
    """Whether NumPy compares ``column``'s values with ``const`` as Python does."""
    kind = column.dtype
    if kind.hasobject:
        return True
    if kind == np.bool_:
        return type(const) is bool
    if type(const) is bool or not isinstance(const, int | float):
        return False
    if kind == np.float64:
        return isinstance(const, float) or -_FLOAT_INT <= const <= _FLOAT_INT
    if kind == np.int64:
        if isinstance(const, int):
            return -(1 << 63) <= const < (1 << 63)
        return not len(column) or int(np.abs(column).max()) <= _FLOAT_INT
    if kind == np.uint64:
        return isinstance(const, int) and 0 <= const < (1 << 64)
    return False


def _timed(
    monitor: CompiledMonitor,
    stamps: npt.NDArray[np.int64],
    changes: Sequence[Change],
    bits: npt.NDArray[np.int64],
    valuation: int,
    now: int | None,
    last: Sequence[int | None],
    values: list[Any],
) -> Letters | None:
    """The letters of a monitor with timed atoms: each event's ages, and the clock steps
    between two events (and between the step before the chunk and its first event)."""
    n = len(stamps)
    if bool(np.any(stamps[1:] < stamps[:-1])):
        return None  # late events: the scalar path
    lo, hi = int(stamps[0]), int(stamps[-1])  # (in order)
    known_last = [t for t in last if t is not None]
    if (
        lo < -_TIME
        or hi > _TIME
        or any(abs(t) > _TIME for t in known_last)
        or any(a.duration > _TIME for a in monitor.timed)
        or (now is not None and lo < now)
    ):
        return None  # far times, or before the clock: the scalar path
    mask = 0
    # per timed signal: the time of its last message after each event (and before the
    # chunk, at index -1 of ``after``), and whether there is one
    lasts: dict[int, tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]] = {}
    out_last = list(last)
    for atom in monitor.timed:
        mask |= 1 << atom.bit
        s = atom.signal
        if s in lasts:
            continue
        positions = changes[s][0]
        if len(positions) == n:  # a message of it at every event (its own topic's field)
            lasts[s] = (stamps, np.ones(n, bool))
            continue
        index = np.full(n, -1, np.int64)
        index[positions] = positions
        np.maximum.accumulate(index, out=index)
        prior = last[s]
        times = np.where(index >= 0, stamps[np.maximum(index, 0)], 0 if prior is None else prior)
        known = (index >= 0) | (prior is not None)
        lasts[s] = (times, known)
    for s, (positions, _) in enumerate(changes):  # every signal's, as the clock keeps them
        if len(positions):
            out_last[s] = int(stamps[positions[-1]])
    event_bits = (bits & ~mask) | _aged(monitor, stamps, lasts)
    # the gaps: before event j (j = 0..n-1), after the step before it
    before_now = np.empty(n, np.int64)
    before_now[1:] = stamps[:-1]
    before_now[0] = now if now is not None else 0
    gap_ok = np.ones(n, bool)
    if now is None:
        gap_ok[0] = False  # no step yet: no time has passed for the monitor
    instants = []
    for atom in monitor.timed:
        times, known = lasts[atom.signal]
        prev_t = np.empty(n, np.int64)
        prev_k = np.empty(n, bool)
        prev_t[1:], prev_k[1:] = times[:-1], known[:-1]
        prior = last[atom.signal]
        prev_t[0], prev_k[0] = (0, False) if prior is None else (prior, True)
        for edge in EDGES[atom.op]:
            at = prev_t + (atom.duration + edge)
            ok = gap_ok & prev_k & (at > before_now) & (at < stamps)
            instants.append(at[ok])
    steps = np.unique(np.concatenate(instants)) if instants else np.zeros(0, np.int64)
    if not len(steps):
        return Letters(event_bits, stamps, values, out_last)
    gap = np.searchsorted(stamps, steps, side="right")  # the event each step comes before
    previous = gap - 1  # the event before it, -1: the step before the chunk
    base = np.where(previous >= 0, event_bits[np.maximum(previous, 0)], valuation)
    step_lasts = {}
    for s, (times, known) in lasts.items():
        prior = last[s]
        t = np.where(previous >= 0, times[np.maximum(previous, 0)], 0 if prior is None else prior)
        k = np.where(previous >= 0, known[np.maximum(previous, 0)], prior is not None)
        step_lasts[s] = (t, k)
    step_bits = (base & ~mask) | _aged(monitor, steps, step_lasts)
    total = n + len(steps)
    letters = np.empty(total, np.int64)
    out_stamps = np.empty(total, np.int64)
    event_at = np.arange(n) + np.searchsorted(gap, np.arange(n), side="right")
    step_at = gap + np.arange(len(steps))
    letters[event_at], out_stamps[event_at] = event_bits, stamps
    letters[step_at], out_stamps[step_at] = step_bits, steps
    return Letters(letters, out_stamps, values, out_last)


def _aged(
    monitor: CompiledMonitor,
    at: npt.NDArray[np.int64],
    lasts: dict[int, tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]],
) -> npt.NDArray[np.int64]:
    """The timed atoms' bits at the instants ``at``, each signal's last message time
    (and whether it has one) given at each."""
    out = np.zeros(len(at), np.int64)
    for atom in monitor.timed:
        times, known = lasts[atom.signal]
        truth: Any = AGE_CMP[atom.op](at - times, atom.duration)
        # an infinite age (no message yet) is more than any duration
        truth = truth | ~known if atom.op in (">", ">=") else truth & known
        out |= np.asarray(truth, dtype=bool).astype(np.int64) << atom.bit
    return out
