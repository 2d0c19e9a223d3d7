"""A check's chunks read column-wise (NumPy arrays, as an MCAP bag is read) against one
event at a time: the same letters, verdicts, state and clock.

:func:`edgerv.core.columns.compress` computes a chunk's letters a column at a time, the
clock steps between its events included, where NumPy holds the values exactly; elsewhere
the runtime takes the list path. Both are held here against the scalar path, event by
event, on random monitors and runs (ages of every comparison, two signals compared, one
topic read for two signals, values with and without an initial one, NaN, late events,
ties, gaps that the clock steps through).
"""

from __future__ import annotations

import random
from typing import Any

import numpy as np
import pytest

from edgerv.core import columns
from edgerv.core.checker import CheckRun
from edgerv.core.monitor import CompiledMonitor
from edgerv.core.traces import EventChunk, TraceEvent, chunks_of
from kit.documents import compiled
from kit.randomruns import SIGNALS, random_assertion, random_run, random_untimed_past_free
from kit.sidebyside import outcome, state_of

MS = 1_000_000
TOPICS = ["/a", "/b", "/x", "/y"]


def column_chunk(events: list[TraceEvent], first: int) -> EventChunk:
    """The events as a bag's chunk read column-wise: each topic's positions and values."""
    cols: dict[str, tuple[Any, list[Any]]] = {}
    for topic in TOPICS:
        at = [i for i, e in enumerate(events) if e.topic == topic]
        if at:
            dtype = bool if topic in ("/a", "/b") else np.float64
            data = np.array([events[i].msg["data"] for i in at], dtype=dtype)
            cols[topic] = (np.array(at, np.int64), [data])
    stamps = np.array([e.stamp for e in events], np.int64)
    return EventChunk("t", stamps=stamps, columns=cols, first=first)


def check_side_by_side(
    m: CompiledMonitor, events: list[TraceEvent], sizes: list[int], arrays: bool = True
) -> None:
    """Chunks of ``sizes`` (read column-wise, or with ``arrays`` False as a JSON trace's
    chunks of messages) against one event at a time."""
    batched, single = CheckRun([m]), CheckRun([m])
    fed = 0
    for size in sizes:
        part = events[fed : fed + size]
        if not part:
            break
        if arrays:
            batched.feed_chunk(column_chunk(part, fed + 1))
        else:
            (chunk,) = chunks_of(part, len(part))
            batched.feed_chunk(chunk)
        single._feed_events(part)
        fed += len(part)
        (b_rt,), (s_rt,) = batched.router.runtimes.values(), single.router.runtimes.values()
        single.results["m"].verdicts += s_rt.evaluate()
        if not b_rt.halted:
            assert state_of(b_rt) == state_of(s_rt), fed
    ends = [max(e.stamp for e in events) + d for d in (0, 50 * MS)]
    (b,), (s,) = batched.finish(ends[1]), single.finish(ends[1])
    assert outcome(b, late=True) == outcome(s, late=True)


@pytest.mark.parametrize("seed", range(150))
def test_column_chunks_give_what_one_event_at_a_time_gives(seed: int) -> None:
    rng = random.Random(seed)
    text = random_untimed_past_free(rng) if seed % 3 else random_assertion(rng)
    halt = rng.random() < 0.2
    threshold = rng.choice([1, 1, 2, 3, 7])
    m = compiled(text, SIGNALS, onVerdict="halt" if halt else "reset", sortThreshold=threshold)
    events = random_run(rng, rng.randint(1, 300), late=0.0 if seed % 2 else 0.03)
    sizes = [rng.choice([1, 2, 5, 17, 64, 300]) for _ in range(300)]
    check_side_by_side(m, events, sizes)


@pytest.mark.parametrize("seed", range(40))
def test_a_sort_window_over_json_chunks_gives_what_one_event_at_a_time_gives(seed: int) -> None:
    """A JSON trace's long chunks, for a monitor with a sort window: compressed a column at
    a time (values as the Python objects they are) where the events come in order."""
    rng = random.Random(seed)
    m = compiled(random_untimed_past_free(rng), SIGNALS, sortThreshold=rng.choice([2, 3, 7]))
    events = random_run(rng, rng.randint(100, 600), late=0.0 if seed % 2 else 0.02)
    check_side_by_side(m, events, [rng.choice([130, 200, 333]) for _ in range(10)], arrays=False)


@pytest.mark.parametrize("threshold", [1, 3])
def test_the_column_path_is_taken(threshold: int) -> None:
    """A monitor of ages and comparisons on an in-order run: its chunks are compressed by
    columns.compress (the side-by-side tests above would pass if it never were), with a
    sort window too (its whole windows; the rest waits in the buffer)."""
    m = compiled("always (age(x) < 7ms & x < 2)", SIGNALS, sortThreshold=threshold)
    rng = random.Random(1)
    events = random_run(rng, 200, late=0.0)
    called = []
    real = columns.compress

    def spy(*args: Any) -> Any:
        got = real(*args)
        called.append(got is not None)
        return got

    columns.compress = spy  # type: ignore[assignment]
    try:
        check_side_by_side(m, events, [50] * 4)
    finally:
        columns.compress = real  # type: ignore[assignment]
    assert called and all(called[1:]), called  # the first chunk: signals without a value yet


@pytest.mark.parametrize(
    ("dtype", "const", "exact"),
    [
        (np.float64, 2, True),
        (np.float64, 2.5, True),
        (np.float64, 2**60 + 1, False),  # a float64 cannot hold it: compared in Python
        (np.int64, 3, True),
        (np.int64, 2.5, True),  # small values: exact as floats
        (np.uint64, -1, False),
        (np.bool_, True, True),
        (np.bool_, 1, False),
        (object, "AUTO", True),
    ],
)
def test_what_numpy_compares_exactly(dtype: Any, const: Any, exact: bool) -> None:
    column = np.array([1, 0, 1], dtype=dtype)
    assert columns._exact(column, const) is exact
