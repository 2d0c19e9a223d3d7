"""Offline verification of a recorded run: the live pipeline, fed from a trace."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from edgerv.core.arrivals import (
    Binding,
    Column,
    arrivals,
    column_arrivals,
    positions_by_topic,
    rows_column,
)
from edgerv.core.diagnostics import Diagnostic, InputError
from edgerv.core.monitor import CompiledMonitor
from edgerv.core.pipeline import (
    MonitorRuntime,
    MonitorState,
    Router,
    TopicRoute,
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
        monitor handed its events column by column (:meth:`MonitorRuntime.offer_arrivals`,
        which takes a field without a value, ABSENT, out of a monitor's updates).
        A message that lacks a field or holds a value of another kind sends the chunk
        through :meth:`_feed_events`, which stops at it with its place."""
        if chunk.columns is not None:
            self._feed_columns(chunk)
            return
        columns: dict[str, Column] = {}
        rows = chunk.rows
        for topic, indexes in positions_by_topic(chunk.topics, self.router.routes).items():
            if rows is not None:  # read from CDR by the topic's fields: of their types
                columns[topic] = rows_column(indexes, rows)
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
            if here and runtime.offer_arrivals(arrivals(chunk.stamps, here, len(runtime.values))):
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
                arrived = column_arrivals(chunk.stamps, here, len(runtime.values))
                if runtime.offer_arrivals(arrived):
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
                    else _past_the_end(route, event.msg)
                    if isinstance(exc, IndexError)
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


def _past_the_end(route: TopicRoute, msg: Any) -> str:
    """What an index past the end of an array or sequence of ``msg`` is: the field read
    through it (an empty optional is no error: its field has no value)."""
    for path, get in zip(route.fields, route.getters, strict=True):
        try:
            get(msg)
        except IndexError:
            return f"field '{path}': an index past the end of an array or sequence"
        except Exception:  # another field's error: said by the one looked for
            continue
    return "an index past the end of an array or sequence"
