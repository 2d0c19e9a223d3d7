"""Verdicts under load (outbox.py): a lane's queue is bounded, coalesces each monitor's
verdicts once full (a count, the first and the last, in their order), an exact lane
never coalesces, and the scheduler evaluates a bounded chunk at a time."""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence

from edgerv.core.pipeline import Verdict
from edgerv.handler.outbox import Burst, Lane, Outbox, VerdictQueue, split
from edgerv.handler.sinks import ViolationLines


def v(monitor: str, step: int) -> Verdict:
    return Verdict(monitor, "violated", step * 10, step)


def key(x: Verdict) -> str:
    return x.monitor


def test_a_queue_under_its_capacity_keeps_every_verdict_in_order() -> None:
    q: VerdictQueue[Verdict] = VerdictQueue(key, capacity=10)
    items = [v(f"m{i % 3}", i) for i in range(10)]
    assert q.put(items) == 0
    assert q.take(100) == items
    assert len(q) == 0


def test_a_full_queue_coalesces_each_monitor_into_one_burst_its_first_and_last() -> None:
    q: VerdictQueue[Verdict] = VerdictQueue(key, capacity=4)
    q.put([v("a", 1), v("b", 1), v("a", 2), v("b", 2)])  # full now
    coalesced = q.put([v("a", s) for s in range(3, 1003)] + [v("b", 3)])
    assert coalesced == 999  # a's 1000 after the first: all but the first joined its burst
    assert len(q) == 4 + 2  # bounded: its capacity, and one burst per monitor
    items = q.take(100)
    assert items[:4] == [v("a", 1), v("b", 1), v("a", 2), v("b", 2)]
    a, b = items[4], items[5]
    assert isinstance(a, Burst) and isinstance(b, Burst)
    assert (a.monitor, a.first, a.last, a.count, a.between) == (
        "a",
        v("a", 3),
        v("a", 1002),
        1000,
        998,
    )
    assert (b.first, b.last, b.count, b.ends) == (v("b", 3), v("b", 3), 1, [v("b", 3)])


def test_a_burst_taken_is_closed_and_the_monitors_next_verdicts_queue_anew() -> None:
    q: VerdictQueue[Verdict] = VerdictQueue(key, capacity=1)
    q.put([v("a", 1), v("a", 2), v("a", 3)])
    first = q.take(1)
    assert first == [v("a", 1)]
    q.put([v("a", 4)])  # the burst of 2..3 is still queued: 4 joins it (order kept)
    burst = q.take(1)[0]
    assert isinstance(burst, Burst) and (burst.first.step, burst.last.step, burst.count) == (
        2,
        4,
        3,
    )
    q.put([v("a", 5)])
    assert q.take(5) == [v("a", 5)]


def test_per_monitor_order_holds_across_many_monitors_and_takes() -> None:
    q: VerdictQueue[Verdict] = VerdictQueue(key, capacity=50)
    seen: dict[str, list[int]] = {}
    counted: dict[str, int] = {}
    step = 0
    for round_ in range(200):
        batch = []
        for i in range(30):
            step += 1
            batch.append(v(f"m{(i * 7 + round_) % 40}", step))
        q.put(batch)
        assert len(q) <= 50 + 40  # capacity plus one burst per monitor
        singles, bursts = split(q.take(37))
        for s in singles:
            seen.setdefault(s.monitor, []).append(s.step)
            counted[s.monitor] = counted.get(s.monitor, 0) + 1
        for b in bursts:
            seen.setdefault(b.monitor, []).extend(x.step for x in b.ends)
            counted[b.monitor] = counted.get(b.monitor, 0) + b.count
    singles, bursts = split(q.take(10_000))
    for s in singles:
        seen.setdefault(s.monitor, []).append(s.step)
        counted[s.monitor] = counted.get(s.monitor, 0) + 1
    for b in bursts:
        seen.setdefault(b.monitor, []).extend(x.step for x in b.ends)
        counted[b.monitor] = counted.get(b.monitor, 0) + b.count
    assert sum(counted.values()) == step  # every verdict given, one by one or counted
    for steps in seen.values():
        assert steps == sorted(steps)


class SlowSink:
    """A sink that takes 20 ms a batch, and records what it got."""

    def __init__(self) -> None:
        self.got: list[Verdict] = []
        self.bursts: list[Burst[Verdict]] = []
        self.gate = threading.Event()

    def write(self, handler: str, verdicts: Sequence[Verdict]) -> None:
        self.gate.wait()
        self.got.extend(verdicts)

    def write_bursts(self, handler: str, bursts: Sequence[Burst[Verdict]]) -> None:
        self.bursts.extend(bursts)


def test_a_lane_that_falls_behind_coalesces_and_the_producer_never_waits() -> None:
    sink = SlowSink()
    outbox = Outbox("h", capacity=100)
    lane = outbox.add("slow", sink)
    for step in range(1, 10_001):
        outbox.write("h", [v("a", step), v("b", step)])  # never blocks: the sink is held
    assert lane.queued() <= 100 + 2
    sink.gate.set()
    outbox.close(time.monotonic() + 30)
    total = len(sink.got) + sum(b.count for b in sink.bursts)
    assert total == 20_000 and lane.unwritten == 0
    assert lane.coalesced == total - len(sink.got) - len(sink.bursts)


def test_an_exact_lane_never_coalesces_it_waits_for_room() -> None:
    sink = SlowSink()
    sink.gate.set()
    lane: Lane[Verdict] = Lane("log", lambda s, b: sink.write("h", s), key, exact=True, capacity=10)
    for step in range(1, 2001):
        lane.put([v("a", step)])
    assert lane.flush(time.monotonic() + 30)
    assert [x.step for x in sink.got] == list(range(1, 2001)) and lane.coalesced == 0
    lane.close(time.monotonic() + 1)


def test_an_exact_lane_stops_waiting_at_its_deadline_and_counts_what_it_did_not_write() -> None:
    sink = SlowSink()  # held: never writes
    lane: Lane[Verdict] = Lane("log", lambda s, b: sink.write("h", s), key, exact=True, capacity=10)
    lane.put([v("a", s) for s in range(50)], until=time.monotonic() + 0.2)
    assert lane.unwritten >= 50 - 20  # at most 10 queued and 10 being written: the rest counted
    assert len(lane.queue) <= 10
    started = time.monotonic()
    left = lane.close(time.monotonic() + 0.2)
    sink.gate.set()
    assert time.monotonic() - started < 10  # behaviour: a close has a deadline
    assert lane.unwritten >= left


def test_a_failing_sink_does_not_stop_its_lane() -> None:
    got: list[Verdict] = []

    def write(singles: Sequence[Verdict], bursts: Sequence[Burst[Verdict]]) -> None:
        if singles and singles[0].step == 1:
            raise RuntimeError("boom")
        got.extend(singles)

    lane: Lane[Verdict] = Lane("f", write, key, batch=1)
    lane.put([v("a", 1), v("a", 2)])
    assert lane.flush(time.monotonic() + 30)
    assert got == [v("a", 2)] and lane.failed == 1
    lane.close(time.monotonic() + 1)


def test_violation_lines_count_a_bursts_middle_as_held_back() -> None:
    lines: list[str] = []

    class Log:
        def warning(self, fmt: str, *args: object) -> None:
            lines.append(fmt % args)

    now = [0.0]
    sink = ViolationLines(lambda m: ("/t",), clock=lambda: now[0], log=Log())  # type: ignore[arg-type]
    sink.write_bursts("h", [Burst("a", v("a", 1), v("a", 100), 100)])
    now[0] = 5.0
    sink.write("h", [v("a", 101)])
    assert "a violated at step 1 " in lines[0]
    assert "(99 more violations since its last line)" in lines[-1]  # 98 between + the last
