"""A batch of messages split into each monitor's :class:`~edgerv.core.pipeline.Arrivals`:
the one way a chunk of a trace (``edgerv check``) and a batch the live handler took
(:meth:`edgerv.handler.engine.Engine.ingest`) reach the monitors a column at a time.

A batch is its messages' stamps and topics, in arrival order, and per topic its
*column*: the positions of the topic's messages in the batch and, per field the
topic's route reads, their values. A monitor's arrivals are its own messages among
them (those of the topics it reads), in the same order, with the values its signals
take: :meth:`MonitorRuntime.offer_arrivals` gives them the letters that offering each
message in turn gives (docs/semantics.md, section 3: how, not what).
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from itertools import chain, compress, count, repeat
from operator import eq
from typing import Any

from edgerv.core.pipeline import Arrivals

Binding = tuple[tuple[int, int], ...]  # (signal index in the monitor, field index) pairs
# a topic's messages in a batch: their positions, and its fields' values (one list each;
# or NumPy arrays: a batch read column-wise)
Column = tuple[Any, Sequence[Any]]
FEW_TOPICS = 6  # up to this many topics, a batch is split by one pass over it for each


def positions_by_topic(topics: Sequence[str], wanted: Collection[str]) -> dict[str, list[int]]:
    """The positions in ``topics`` of each wanted topic present."""
    if len(wanted) <= FEW_TOPICS:  # a C loop over the batch per topic
        found = {t: list(compress(range(len(topics)), map(eq, topics, repeat(t)))) for t in wanted}
        return {t: i for t, i in found.items() if i}
    out: dict[str, list[int]] = {}
    for i, topic in enumerate(topics):
        if topic in wanted:
            out.setdefault(topic, []).append(i)
    return out


def rows_column(positions: list[int], rows: Sequence[Sequence[Any]]) -> Column:
    """A topic's column from the field values of each message of the batch (``rows``,
    indexed by batch position; the messages at ``positions`` are the topic's)."""
    mine = map(rows.__getitem__, positions)
    return positions, list(map(list, zip(*mine, strict=True)))


def array_column(positions: list[int], rows: Sequence[Sequence[Any]]) -> Column:
    """:func:`rows_column` in NumPy arrays: positions of int64, each field's values in
    the array NumPy makes of them (bool, int64, float64; Python objects where NumPy
    cannot hold them exactly, e.g. strings and integers beyond int64)."""
    return as_arrays(rows_column(positions, rows))


def as_arrays(column: Column) -> Column:
    """A column of lists (:func:`rows_column`) in NumPy arrays, as :func:`array_column`
    makes them."""
    import numpy as np

    positions, values = column
    return np.array(positions, np.int64), [_array(v) for v in values]


def _array(values: Sequence[Any]) -> Any:
    import numpy as np

    try:
        out = np.array(values)
    except (OverflowError, ValueError):
        out = None
    if out is None or out.dtype.kind not in "bif":
        out = np.empty(len(values), object)
        out[:] = values
    return out


def arrivals(
    stamps: Sequence[int], reads: Sequence[tuple[Column, Binding]], signals: int
) -> Arrivals:
    """A monitor's arrivals in a batch stamped ``stamps``, from the columns of the topics
    it reads there (each with the binding of its signals to the topic's fields)."""
    keys, positions = _positions([at for (at, _), _ in reads], len(stamps))
    mine = stamps if len(keys) == len(stamps) else list(map(stamps.__getitem__, keys))
    return Arrivals(mine, *updates(reads, positions, signals))


def column_arrivals(stamps: Any, reads: Sequence[tuple[Column, Binding]], signals: int) -> Arrivals:
    """:func:`arrivals` for a batch read column-wise: positions, stamps and values in
    NumPy arrays."""
    import numpy as np  # (a batch read column-wise comes with NumPy loaded)

    indexes: list[Any] = [at for (at, _), _ in reads]
    keys: Any
    if len(indexes) == 1:
        keys, positions = indexes[0], [np.arange(len(indexes[0]))]
    elif sum(map(len, indexes)) == len(stamps):
        keys, positions = None, indexes
    else:  # the monitor's messages among the batch's, and each one's rank among them
        taken = np.zeros(len(stamps), bool)
        for at in indexes:
            taken[at] = True
        keys = np.flatnonzero(taken)
        rank = np.cumsum(taken) - 1
        positions = [rank[at] for at in indexes]
    mine = stamps if keys is None else stamps[keys]
    return Arrivals(mine, *updates(reads, positions, signals), columnar=True)


def updates(
    reads: Sequence[tuple[Column, Binding]], positions: list[Any], signals: int
) -> tuple[list[tuple[Any, Any]], list[tuple[Any, tuple[int, ...]]]]:
    """A monitor's changes and groups (:class:`Arrivals`): each topic's messages at
    ``positions`` among the monitor's, with the values of the fields its signals read."""
    changes: list[tuple[Any, Any]] = [((), ())] * signals
    groups: list[tuple[Any, tuple[int, ...]]] = []
    for ((_, values), binding), at in zip(reads, positions, strict=True):
        for s, f in binding:
            changes[s] = (at, values[f])
        groups.append((at, tuple(s for s, _ in binding)))
    return changes, groups


def _positions(indexes: list[Sequence[int]], size: int) -> tuple[Sequence[int], list[Any]]:
    """The batch positions of a monitor's messages, in order, and where the messages of
    each of its topics (at these batch positions) stand among them."""
    if len(indexes) == 1:  # one topic: its messages are the monitor's, in order
        return indexes[0], [range(len(indexes[0]))]
    if sum(map(len, indexes)) == size:  # every message of the batch is the monitor's
        return range(size), list(indexes)
    keys = sorted(chain.from_iterable(indexes))
    rank = dict(zip(keys, count()))
    return keys, [list(map(rank.__getitem__, mine)) for mine in indexes]
