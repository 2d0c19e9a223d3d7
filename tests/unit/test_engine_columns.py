"""The live handler's long batches, ingested a column at a time, against the same messages
ingested one at a time: the same verdicts, state, counts and drops.

:meth:`Engine.ingest` hands each monitor its messages of a long batch as arrays
(:func:`edgerv.core.arrivals.column_arrivals`), which :func:`edgerv.core.columns.compress`
turns into letters where NumPy computes what Python does, and the list path elsewhere
(past operators, sort windows with events waiting, late events, a handoff holding). A
monitor's capacity is tested where its letters are made (MonitorRuntime.take_arrivals).
Each engine here is held against one fed a message at a time (the path every message
took before), on random monitors, runs and batch sizes.
"""

from __future__ import annotations

import random
from typing import Any

import pytest

from edgerv.core import columns
from edgerv.handler import engine as engine_module
from kit.documents import compiled
from kit.randomruns import SIGNALS, random_assertion, random_run, random_untimed_past_free
from kit.sidebyside import engine_with, messages, run_side_by_side

MS = 1_000_000


@pytest.mark.parametrize("seed", range(120))
def test_long_batches_give_what_one_message_at_a_time_gives(seed: int) -> None:
    """One to three random monitors (past operators timed or not, ages, two signals
    compared, one topic read for two signals, sort windows, halting), random runs with
    ties and late messages, cut into batches of random sizes; some buffers too small for
    a batch, so that they drop what does not fit."""
    rng = random.Random(seed)
    monitors = []
    for i in range(rng.randint(1, 3)):
        text = random_untimed_past_free(rng) if rng.random() < 0.6 else random_assertion(rng)
        threshold = rng.choice([1, 1, 2, 3, 7])
        capacity = rng.choice([4096, 4096, max(threshold, 40), max(threshold, 150)])
        monitors.append(
            compiled(
                text,
                SIGNALS,
                name=f"m{i}",
                sortThreshold=threshold,
                bufferCapacity=capacity,
                onVerdict="halt" if rng.random() < 0.2 else "reset",
            )
        )
    events = random_run(rng, rng.randint(1, 700), late=0.0 if seed % 2 else 0.03)
    sizes = [rng.choice([1, 3, 15, 16, 40, 64, 200, 700]) for _ in range(700)]
    run_side_by_side(monitors, messages(events), sizes)


def test_the_column_path_is_taken_and_numpy_values_never_reach_a_monitor() -> None:
    """A monitor of ages and comparisons on an in-order run: its long batches are
    compressed by columns.compress (the side-by-side test would pass if it never were),
    and its signal values stay Python values (a NumPy scalar would not serialize in a
    handoff's snapshot)."""
    m = compiled("always (age(x) < 7ms & x < 2)", SIGNALS)
    events = random_run(random.Random(1), 400, late=0.0)
    called = []
    real = columns.compress

    def spy(*args: Any) -> Any:
        got = real(*args)
        called.append(got is not None)
        return got

    columns.compress = spy  # type: ignore[assignment]
    try:
        run_side_by_side([m], messages(events), [100] * 4)
    finally:
        columns.compress = real  # type: ignore[assignment]
    assert called and all(called[1:]), called  # the first batch: signals without a value yet
    e, _ = engine_with([m])
    e.ingest(messages(events), now=0.0)
    rt = e.slots["m"].runtime
    assert rt is not None
    assert {type(v) for v in rt.values} <= {bool, float}, rt.values


def test_short_batches_take_the_path_of_one_message_at_a_time() -> None:
    """Below COLUMNS_FROM messages, no column is built (it would cost more than it saves)."""
    m = compiled("always (x < 2)", SIGNALS)
    events = random_run(random.Random(2), engine_module.COLUMNS_FROM - 1, late=0.0)
    called = []
    real = columns.compress
    columns.compress = lambda *a: called.append(a) or real(*a)  # type: ignore[assignment]
    try:
        e, _ = engine_with([m])
        e.ingest(messages(events), now=0.0)
    finally:
        columns.compress = real  # type: ignore[assignment]
    assert not called
