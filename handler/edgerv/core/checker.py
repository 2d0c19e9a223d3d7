"""Offline verification of a recorded run: the live pipeline, fed from a trace."""

from __future__ import annotations

from collections.abc import Collection, Iterable, Sequence
from dataclasses import dataclass, field
from itertools import chain, compress, count, repeat
from operator import eq
from typing import Any

from edgerv.core.diagnostics import Diagnostic, InputError
from edgerv.core.monitor import CompiledMonitor
from edgerv.core.pipeline import (
    Arrivals,
    MonitorRuntime,
    MonitorState,
    Router,
    ValueTypeError,
    Verdict,
)
from edgerv.core.traces import EventChunk, TraceEvent, TraceEvents, chunks_of

EVALUATE_BATCH = 1024  # letters a monitor collects before the check evaluates them


@dataclass
class MonitorResult:
    name: str
    verdicts: list[Verdict] = field(default_factory=list)
    state: MonitorState = "pending"
    steps: int = 0
    late_events: int = 0

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "verdicts": [v.as_dict() for v in self.verdicts],
            "state": self.state,
        }


@dataclass
class CheckRun:
    """A check in progress: feed events, then :meth:`finish`. Keeps results on bad input."""

    monitors: Sequence[CompiledMonitor]
    results: dict[str, MonitorResult] = field(init=False)
    router: Router = field(init=False)
    # each monitor's topics, and which field each of its signals reads there (the routes
    # are fixed for the whole check)
    reads: dict[str, list[tuple[str, Binding]]] = field(init=False)

    def __post_init__(self) -> None:
        self.router = Router(MonitorRuntime(m) for m in self.monitors)
        self.results = {m.name: MonitorResult(m.name) for m in self.monitors}
        self.reads = {}
        for topic, route in self.router.routes.items():
            for runtime, b in route.readers:
                self.reads.setdefault(runtime.name, []).append((topic, route.bindings[b]))

    @property
    def topics(self) -> set[str]:
        return set(self.router.routes)

    @property
    def clocked(self) -> bool:
        """Some monitor takes clock steps: the end of the trace's time matters (finish)."""
        return any(rt.clock is not None for rt in self.router.runtimes.values())

    def fields(self) -> dict[str, list[str]]:
        """Each monitored topic's fields, as its route reads them (in its values' order)."""
        return {topic: list(route.fields) for topic, route in self.router.routes.items()}

    def readers(self) -> dict[str, list[str]]:
        """Each monitored topic, and the monitors reading it."""
        return {
            topic: [runtime.name for runtime, _ in route.readers]
            for topic, route in self.router.routes.items()
        }

    def feed(self, events: Iterable[TraceEvent]) -> None:
        """Check these events, a chunk at a time (a trace's own chunks when they come from
        :meth:`Trace.events`)."""
        chunks = events.chunks() if isinstance(events, TraceEvents) else chunks_of(events)
        for chunk in chunks:
            self.feed_chunk(chunk)

    def feed_chunk(self, chunk: EventChunk) -> None:
        """Check a chunk of events: each topic's fields read for the whole chunk, each
        monitor handed its events column by column (:meth:`MonitorRuntime.offer_arrivals`).
        A message that lacks a field or holds a value of another kind sends the chunk
        through :meth:`_feed_events`, which stops at it with its place."""
        if chunk.columns is not None:
            self._feed_columns(chunk)
            return
        columns: dict[str, tuple[list[int], list[list[Any]]]] = {}
        rows = chunk.rows
        for topic, indexes in _indexes_by_topic(chunk.topics, self.router.routes).items():
            if rows is not None:  # read from CDR by the topic's fields: of their types
                mine = map(rows.__getitem__, indexes)
                columns[topic] = (indexes, list(map(list, zip(*mine, strict=True))))
                continue
            msgs = list(map(chunk.msgs.__getitem__, indexes))
            values = self.router.routes[topic].extract_all(msgs, chunk.parsed_json)
            if values is None:
                self._feed_events(chunk)
                return
            columns[topic] = (indexes, values)
        self.router.seq += len(chunk)
        for name, reads in self.reads.items():
            runtime = self.router.runtimes[name]
            here = [(columns[t], binding) for t, binding in reads if t in columns]
            if here and runtime.offer_arrivals(_arrivals(chunk, here, len(runtime.values))):
                self.results[name].verdicts += runtime.evaluate()

    def _feed_columns(self, chunk: EventChunk) -> None:
        """:meth:`feed_chunk` for a chunk read column-wise: each monitor handed its events
        in arrays."""
        columns = chunk.columns
        assert columns is not None
        self.router.seq += len(chunk)
        for name, reads in self.reads.items():
            runtime = self.router.runtimes[name]
            here = [(columns[t], binding) for t, binding in reads if t in columns]
            if here and not runtime.halted:
                arrivals = _column_arrivals(chunk.stamps, here, len(runtime.values))
                if runtime.offer_arrivals(arrivals):
                    self.results[name].verdicts += runtime.evaluate()

    def _feed_events(self, events: Iterable[TraceEvent]) -> None:
        """Check these events one by one."""
        for event in events:
            try:
                ready = self.router.dispatch(event.topic, event.stamp, event.msg)
            except (LookupError, AttributeError, TypeError, ValueTypeError) as exc:
                route = self.router.routes[event.topic]
                readers = ", ".join(rt.name for rt, _ in route.readers)
                message = (
                    str(exc)
                    if isinstance(exc, ValueTypeError)
                    else f"no field {exc} in the message"
                )
                raise InputError(
                    [
                        Diagnostic(
                            event.where,
                            f"message on {event.topic}: {message}",
                            hint=f"monitors reading {event.topic} ({readers}) expect "
                            f"{route.msg_type} with fields {', '.join(route.fields)}",
                        )
                    ]
                ) from None
            for runtime in ready:  # evaluated in batches: the same verdicts, fewer calls
                if len(runtime.letters) >= EVALUATE_BATCH:
                    self.results[runtime.name].verdicts += runtime.evaluate()

    def finish(self, end: int | None = None) -> list[MonitorResult]:
        """Flush the partial event buffers (the run is over) and report in input order.

        ``end``: the latest time the trace shows as passed (:attr:`Trace.end`); monitors
        with timed atoms take their clock steps up to it.
        """
        for runtime in self.router.runtimes.values():
            runtime.flush()
            if end is not None:
                runtime.advance(end)
            self.results[runtime.name].verdicts += runtime.evaluate()
        out = []
        for m in self.monitors:
            runtime = self.router.runtimes[m.name]
            result = self.results[m.name]
            result.state, result.steps = runtime.status, runtime.step
            result.late_events = runtime.late_events
            out.append(result)
        return out


def check_types(monitors: Sequence[CompiledMonitor], msgtypes: dict[str, str]) -> list[Diagnostic]:
    """Errors for topics a bag records with another type than a monitor declares."""
    errors = []
    for m in monitors:
        for sig in m.spec.signals.values():
            recorded = msgtypes.get(sig.topic)
            if recorded is not None and recorded != sig.msg_type:
                errors.append(
                    Diagnostic(
                        sig.location,
                        f"monitor '{m.name}' signal '{sig.name}' reads {sig.topic} as "
                        f"{sig.msg_type}, but the bag records it as {recorded}",
                    )
                )
    return errors


Binding = tuple[tuple[int, int], ...]  # (signal index in the monitor, field index) pairs
Column = tuple[list[int], list[list[Any]]]  # a topic's events in a chunk, its fields' values
FEW_TOPICS = 6  # up to this many topics, a chunk is split by one pass over it for each


def _indexes_by_topic(topics: list[str], wanted: Collection[str]) -> dict[str, list[int]]:
    """The positions in ``topics`` of each wanted topic present."""
    if len(wanted) <= FEW_TOPICS:  # a C loop over the chunk per topic
        found = {t: list(compress(range(len(topics)), map(eq, topics, repeat(t)))) for t in wanted}
        return {t: i for t, i in found.items() if i}
    out: dict[str, list[int]] = {}
    for i, topic in enumerate(topics):
        if topic in wanted:
            out.setdefault(topic, []).append(i)
    return out


def _arrivals(chunk: EventChunk, reads: list[tuple[Column, Binding]], signals: int) -> Arrivals:
    """A monitor's events of the chunk, from the columns of the topics it reads."""
    keys, positions = _positions([indexes for (indexes, _), _ in reads], len(chunk))
    stamps = chunk.stamps if len(keys) == len(chunk) else list(map(chunk.stamps.__getitem__, keys))
    return Arrivals(stamps, *_updates(reads, positions, signals))


def _updates(
    reads: list[tuple[Any, Binding]], positions: list[Any], signals: int
) -> tuple[list[tuple[Any, Any]], list[tuple[Any, tuple[int, ...]]]]:
    """A monitor's changes and groups (:class:`Arrivals`): each topic's events at
    ``positions`` among the monitor's, with the values of the fields its signals read."""
    changes: list[tuple[Any, Any]] = [((), ())] * signals
    groups: list[tuple[Any, tuple[int, ...]]] = []
    for ((_, values), binding), at in zip(reads, positions, strict=True):
        for s, f in binding:
            changes[s] = (at, values[f])
        groups.append((at, tuple(s for s, _ in binding)))
    return changes, groups


def _positions(indexes: list[list[int]], chunk: int) -> tuple[Sequence[int], list[Sequence[int]]]:
    """The chunk positions of a monitor's events, in order, and where the events of each
    of its topics (at these chunk positions) stand among them."""
    if len(indexes) == 1:  # one topic: its events are the monitor's, in order
        return indexes[0], [range(len(indexes[0]))]
    if sum(map(len, indexes)) == chunk:  # every event of the chunk is the monitor's
        return range(chunk), list(indexes)
    keys = sorted(chain.from_iterable(indexes))
    rank = dict(zip(keys, count()))
    return keys, [list(map(rank.__getitem__, mine)) for mine in indexes]


def _column_arrivals(stamps: Any, reads: list[tuple[Any, Binding]], signals: int) -> Arrivals:
    """:func:`_arrivals` for a chunk read column-wise: the same, in arrays."""
    import numpy as np  # (a chunk read column-wise comes with NumPy loaded)

    indexes = [at for (at, _), _ in reads]
    if len(indexes) == 1:
        keys, positions = indexes[0], [np.arange(len(indexes[0]))]
    elif sum(map(len, indexes)) == len(stamps):
        keys, positions = None, indexes
    else:  # the monitor's events among the chunk's, and each one's rank among them
        mine = np.zeros(len(stamps), bool)
        for at in indexes:
            mine[at] = True
        keys = np.flatnonzero(mine)
        rank = np.cumsum(mine) - 1
        positions = [rank[at] for at in indexes]
    mine = stamps if keys is None else stamps[keys]
    return Arrivals(mine, *_updates(reads, positions, signals), columnar=True)
