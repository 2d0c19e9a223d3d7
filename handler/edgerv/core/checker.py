"""Offline verification of a recorded run: the live pipeline, fed from a trace."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from edgerv.core.diagnostics import Diagnostic, InputError
from edgerv.core.monitor import CompiledMonitor
from edgerv.core.pipeline import MonitorRuntime, MonitorState, Router, ValueTypeError, Verdict
from edgerv.core.traces import TraceEvent

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

    def __post_init__(self) -> None:
        self.router = Router(MonitorRuntime(m) for m in self.monitors)
        self.results = {m.name: MonitorResult(m.name) for m in self.monitors}

    @property
    def topics(self) -> set[str]:
        return set(self.router.routes)

    def feed(self, events: Iterable[TraceEvent]) -> None:
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
