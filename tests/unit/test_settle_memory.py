"""The handler's cycle collector (main.settle_memory): what exists once the monitors are
loaded is frozen out of its scans, it runs less often than Python's default, and it still
reclaims the cycles made afterwards (bench/scale.py: each full collection of a /diagnostics
update of 10,000 monitors stalled every thread)."""

from __future__ import annotations

import gc
import weakref
from collections.abc import Iterator

import pytest

from edgerv.handler.main import GC_YOUNG, settle_memory


@pytest.fixture
def collector() -> Iterator[None]:
    threshold = gc.get_threshold()
    yield
    gc.unfreeze()
    gc.set_threshold(*threshold)


class Node:
    def __init__(self) -> None:
        self.other: Node | None = None


def test_the_loaded_objects_are_frozen_and_young_collections_come_less_often(
    collector: None,
) -> None:
    before = gc.get_threshold()
    settle_memory()
    assert gc.get_freeze_count() > 0
    assert gc.get_threshold() == (max(before[0], GC_YOUNG), *before[1:])
    assert GC_YOUNG > 700  # Python's default


def test_a_cycle_made_afterwards_is_still_reclaimed(collector: None) -> None:
    settle_memory()
    a, b = Node(), Node()
    a.other, b.other = b, a
    gone = weakref.ref(a)
    del a, b
    gc.collect()
    assert gone() is None
