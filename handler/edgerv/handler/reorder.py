"""The handler's reorder window: one timestamp order across topics before the pipeline.

Each topic is delivered in order, but topics travel apart: under load a message
can reach the handler after a later-stamped one of another topic. The window
holds what was taken until it is ``window`` older (by stamp) than the newest
message taken, or has waited ``window`` seconds, and releases it in timestamp
order (equal stamps in arrival order). So messages of different topics that
arrive less than ``window`` apart out of order are still evaluated in order;
the price is up to ``window`` more latency.
"""

from __future__ import annotations

from bisect import bisect_right
from operator import itemgetter
from typing import Any, Generic, TypeVar

Item = TypeVar("Item", bound=tuple[Any, ...])  # (stamp ns, topic, field values, ...)
_STAMP = itemgetter(0)


class ReorderWindow(Generic[Item]):
    def __init__(self, window: float) -> None:
        self.window = window
        self.window_ns = int(window * 1e9)
        self.pending: list[Item] = []
        self.newest: int | None = None
        self.since: float | None = None  # when the oldest pending item was taken

    def add(self, batch: list[Item], now: float) -> list[Item]:
        """Take a batch; return what leaves the window, in timestamp order."""
        if not batch:
            return []
        # stable: equal stamps keep their arrival order; sorted runs merge in linear time
        self.pending = sorted(self.pending + batch, key=_STAMP)
        newest = self.pending[-1][0]
        if self.newest is None or newest > self.newest:
            self.newest = newest
        if self.since is None:
            self.since = now
        cut = bisect_right(self.pending, self.newest - self.window_ns, key=_STAMP)
        released, self.pending = self.pending[:cut], self.pending[cut:]
        if not self.pending:
            self.since = None
        return released

    def due(self, now: float) -> list[Item]:
        """Everything, once the oldest pending item has waited ``window`` seconds."""
        if self.since is not None and now - self.since >= self.window:
            return self.drain()
        return []

    def drain(self) -> list[Item]:
        released, self.pending, self.since = self.pending, [], None
        return released
