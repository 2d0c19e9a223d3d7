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
from typing import Any, Generic, TypeVar

Item = TypeVar("Item", bound=tuple[Any, ...])  # (stamp ns, topic, field values, ...)


def _stamp_of(pair: tuple[Any, float]) -> int:
    """An (item, time taken) pair's stamp: the key pending is kept sorted by."""
    return int(pair[0][0])


class ReorderWindow(Generic[Item]):
    def __init__(self, window: float) -> None:
        self.window = window
        self.window_ns = int(window * 1e9)
        self.pending: list[Item] = []
        self._taken: list[float] = []  # when each pending item was taken (pending's order)
        self.newest: int | None = None
        self.since: float | None = None  # when the pending item taken first was taken

    def add(self, batch: list[Item], now: float) -> list[Item]:
        """Take a batch; return what leaves the window, in timestamp order."""
        if not batch:
            return []
        # stable: equal stamps keep their arrival order; sorted runs merge in linear time
        pairs = sorted(
            zip(self.pending + batch, self._taken + [now] * len(batch), strict=True),
            key=_stamp_of,
        )
        newest = pairs[-1][0][0]
        if self.newest is None or newest > self.newest:
            self.newest = newest
        cut = bisect_right(pairs, self.newest - self.window_ns, key=_stamp_of)
        released = [item for item, _ in pairs[:cut]]
        self.pending = [item for item, _ in pairs[cut:]]
        self._taken = [taken for _, taken in pairs[cut:]]
        # (not the first item's time: under steady traffic the window never empties, and
        # the time of an item released long ago made due() release everything at once)
        self.since = min(self._taken) if self._taken else None
        return released

    def due(self, now: float) -> list[Item]:
        """Everything, once the oldest pending item has waited ``window`` seconds."""
        if self.since is not None and now - self.since >= self.window:
            return self.drain()
        return []

    def drain(self) -> list[Item]:
        released, self.pending, self._taken, self.since = self.pending, [], [], None
        return released
