"""Prometheus metrics of a handler, rendered from the engine's reading at scrape time
(:mod:`edgerv.handler.reading`; no hot-path cost)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

from prometheus_client import CollectorRegistry, ProcessCollector
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from edgerv.handler.budget import MemoryBudget
from edgerv.handler.engine import Engine
from edgerv.handler.outbox import Outbox
from edgerv.handler.reading import read


class EngineCollector(Collector):
    def __init__(
        self,
        engine: Engine,
        qos_problems: Callable[[], dict[str, int]],
        outbox: Outbox | None = None,
        budget: MemoryBudget | None = None,
    ) -> None:
        self.engine = engine
        self.qos_problems = qos_problems  # topic -> publishers with incompatible QoS
        self.outbox = outbox
        self.budget = budget

    def collect(self) -> Iterator[Metric]:
        events = CounterMetricFamily(
            "edgerv_events", "Events offered to a monitor", labels=["monitor"]
        )
        dropped = CounterMetricFamily(
            "edgerv_events_dropped",
            "Events a monitor lost because its buffer was full",
            labels=["monitor"],
        )
        late = CounterMetricFamily(
            "edgerv_late_events",
            "Events released after newer ones (beyond the sort window)",
            labels=["monitor"],
        )
        verdicts = CounterMetricFamily(
            "edgerv_verdicts", "Verdicts reported", labels=["monitor", "verdict"]
        )
        buf = GaugeMetricFamily(
            "edgerv_buffer_events",
            "Events buffered by a monitor (event buffer plus letters)",
            labels=["monitor"],
        )
        cap = GaugeMetricFamily(
            "edgerv_buffer_capacity", "A monitor's bufferCapacity", labels=["monitor"]
        )
        active = GaugeMetricFamily(
            "edgerv_monitor_active", "1 when the monitor runs here", labels=["monitor"]
        )
        wanted = GaugeMetricFamily(
            "edgerv_migration_wanted",
            "1 when a monitor's buffer stays full: move it up a tier",
            labels=["monitor"],
        )
        reading = read(self.engine)
        for m in reading.monitors:
            name = [m.name]
            events.add_metric(name, m.events)
            dropped.add_metric(name, m.dropped)
            late.add_metric(name, m.late)
            verdicts.add_metric([m.name, "violated"], m.violations)
            verdicts.add_metric([m.name, "satisfied"], m.satisfactions)
            buf.add_metric(name, m.buffered)
            cap.add_metric(name, m.capacity)
            active.add_metric(name, 1 if m.active else 0)
            wanted.add_metric(name, 1 if m.migration_wanted else 0)
        msgs = CounterMetricFamily(
            "edgerv_messages", "Messages received per topic", labels=["topic"]
        )
        for topic, n in reading.messages.items():
            msgs.add_metric([topic], n)
        gone = CounterMetricFamily(
            "edgerv_messages_lost",
            "Messages lost before the handler took them (gaps in a single publisher's "
            "sequence numbers: a subscription queue that overflowed, best-effort delivery)",
            labels=["topic"],
        )
        for topic, n in reading.lost.items():
            gone.add_metric([topic], n)
        qos = GaugeMetricFamily(
            "edgerv_qos_incompatible_publishers",
            "Publishers whose QoS cannot match the handler's subscription",
            labels=["topic"],
        )
        for topic, n in self.qos_problems().items():
            qos.add_metric([topic], n)
        yield from (events, dropped, late, verdicts, buf, cap, active, wanted, msgs, gone, qos)
        yield GaugeMetricFamily(
            "edgerv_ingest_lag_seconds",
            "Publication to ingestion delay of the last messages taken",
            value=reading.ingest_lag,
        )
        yield from self.deadline()
        yield from self.sinks()
        yield from self.memory()

    def sinks(self) -> Iterator[Metric]:
        """The verdict lanes (outbox.py): what each sink got only as a count."""
        if self.outbox is None:
            return
        coalesced = CounterMetricFamily(
            "edgerv_verdicts_coalesced",
            "Verdicts a sink got only as a burst's count (it fell behind: each monitor's "
            "first and last verdict of the burst went out)",
            labels=["sink"],
        )
        queued = GaugeMetricFamily(
            "edgerv_verdict_queue", "Items waiting in a sink's queue", labels=["sink"]
        )
        unwritten = CounterMetricFamily(
            "edgerv_verdicts_unwritten",
            "Verdicts still queued for a sink when the handler's stop time ran out",
            labels=["sink"],
        )
        for sink, (c, q, u) in self.outbox.counts().items():
            coalesced.add_metric([sink], c)
            queued.add_metric([sink], q)
            unwritten.add_metric([sink], u)
        yield from (coalesced, queued, unwritten)

    def memory(self) -> Iterator[Metric]:
        """--memory-budget: the budget, what is committed of it, and the refusals."""
        b = self.budget
        if b is None:
            return
        yield GaugeMetricFamily(
            "edgerv_memory_budget_bytes", "The handler's memory budget", value=b.total
        )
        yield GaugeMetricFamily(
            "edgerv_memory_committed_bytes",
            "The budget committed: the process at start, the verdict queues, request "
            "bodies, a bundle, and the monitors' buffers as they will fill",
            value=b.committed(),
        )
        yield CounterMetricFamily(
            "edgerv_monitors_refused_budget",
            "Monitors refused because they would pass the memory budget",
            value=b.refused,
        )

    def deadline(self) -> Iterator[Metric]:
        """--deadline: the robot's real-time task (nothing without the option)."""
        window = self.engine.deadline
        if window is None:
            return
        reading = window.report(time.monotonic_ns())
        topic = [reading["topic"]]
        budget = GaugeMetricFamily(
            "edgerv_deadline_budget_seconds",
            "The real-time task's deadline (--deadline)",
            labels=["topic"],
        )
        budget.add_metric(topic, reading["budgetMs"] / 1e3)
        p95 = GaugeMetricFamily(
            "edgerv_deadline_makespan_p95_seconds",
            "95th percentile of the task's makespan (publication minus header.stamp) over "
            "the window; absent while the window is empty",
            labels=["topic"],
        )
        if reading["p95Ms"] is not None:
            p95.add_metric(topic, reading["p95Ms"] / 1e3)
        misses = CounterMetricFamily(
            "edgerv_deadline_misses",
            "Outputs of the task whose makespan exceeded the deadline",
            labels=["topic"],
        )
        misses.add_metric(topic, reading["missesTotal"])
        measured = CounterMetricFamily(
            "edgerv_deadline_messages",
            "Outputs of the task whose makespan was measured",
            labels=["topic"],
        )
        measured.add_metric(topic, reading["messagesTotal"])
        yield from (budget, p95, misses, measured)


def build_registry(
    engine: Engine,
    qos_problems: Callable[[], dict[str, int]],
    outbox: Outbox | None = None,
    budget: MemoryBudget | None = None,
) -> CollectorRegistry:
    registry = CollectorRegistry()
    registry.register(EngineCollector(engine, qos_problems, outbox, budget))
    ProcessCollector(namespace="edgerv", registry=registry)  # edgerv_process_cpu_seconds_total
    return registry
