"""What each monitor costs its handler (issue 37, "costs measured, not guessed"): the
engine charges a monitor its share of each message it reads and its evaluations, and
the load report carries it (``cpuSeconds`` per monitor). The amounts are timings, so the
tests check who is charged and how the shares are split, never how much."""

from __future__ import annotations

import os

from edgerv.handler.engine import COLUMNS_FROM, Engine
from edgerv.handler.host import HostCpu, parse_stat
from edgerv.handler.reading import load_report
from kit.documents import compiled


def engine_of(every: int) -> Engine:
    """Monitors ``a1`` and ``a2`` read /a, ``b`` reads /b; ``every``: 1 in how many
    messages and rounds are timed."""
    e = Engine("edge")
    e.sample_costs(every)
    for name, signal in (("a1", "a"), ("a2", "a"), ("b", "b")):
        e.put(compiled(f"always ({signal} < 100)", {signal: "float"}, name=name), active=True)
    return e


def costs(e: Engine) -> dict[str, float]:
    return {name: slot.runtime.cost_ns for name, slot in e.slots.items() if slot.runtime}


def test_the_readers_of_a_topic_share_each_message_and_the_others_pay_nothing() -> None:
    e = engine_of(every=1)
    e.ingest([(i, "/a", [float(i)]) for i in range(1, COLUMNS_FROM // 2)])
    c = costs(e)
    assert c["a1"] > 0 and c["a1"] == c["a2"]  # one share each, the same
    assert c["b"] == 0


def test_a_monitor_is_charged_for_its_own_evaluation_only() -> None:
    """A plain monitor walks a letter that reaches no verdict as it takes it (paid for in
    the message's share); one that reaches a verdict waits for the scheduler's
    evaluation, charged to its monitor alone."""
    e = engine_of(every=1)
    e.ingest([(1, "/a", [100.0])])
    before = costs(e)
    assert sorted(v.monitor for v in e.evaluate()) == ["a1", "a2"]
    after = costs(e)
    assert after["a1"] > before["a1"] and after["a2"] > before["a2"]
    assert after["b"] == 0  # it had no letter: not evaluated


def test_a_long_batch_read_a_column_at_a_time_charges_its_readers_only() -> None:
    e = engine_of(every=1)
    e.ingest([(i, "/a", [float(i)]) for i in range(1, 4 * COLUMNS_FROM)])
    c = costs(e)
    assert c["a1"] > 0 and c["a2"] > 0
    assert c["b"] == 0


def test_messages_and_rounds_are_timed_one_in_every_at_random() -> None:
    """Sampling: the gaps between timed messages (and rounds) are those of a Bernoulli
    process of probability 1/every; one not chosen charges nothing, so the estimate costs
    only the chosen ones' clock reads."""
    e = engine_of(every=16)
    gaps = [e.cost_gap() for _ in range(4000)]
    assert min(gaps) >= 1 and 14 < sum(gaps) / len(gaps) < 18  # mean 16 (sd of it: 0.24)
    e.untimed_messages = e.untimed_rounds = 10**9  # none chosen for a long while
    e.ingest([(i, "/a", [float(i)]) for i in range(1, 10)])
    e.evaluate()
    assert set(costs(e).values()) == {0.0}
    e.untimed_messages = 1  # the next one chosen: charged 16 times its timing
    e.ingest([(10, "/a", [10.0])])
    assert costs(e)["a1"] > 0 and costs(e)["b"] == 0
    assert e.untimed_messages >= 1  # and the next gap drawn


def test_the_load_report_carries_each_monitors_cost_in_seconds() -> None:
    e = engine_of(every=1)
    e.put(compiled("always (c < 100)", {"c": "float"}, name="idle"), active=False)
    e.ingest([(1, "/a", [1.0]), (2, "/b", [2.0])])
    e.evaluate()
    monitors = load_report(e)["monitors"]
    for name in ("a1", "a2", "b"):
        assert monitors[name]["cpuSeconds"] == e.slots[name].runtime.cost_ns / 1e9 > 0  # type: ignore[union-attr]
    assert monitors["idle"]["cpuSeconds"] == 0.0  # not active here: nothing spent


def test_the_load_report_carries_the_cpu_counters_of_the_handlers_cpus() -> None:
    """The headroom the edge has left comes from the counters (/proc/stat) of the CPUs
    the handler may run on (its affinity: pinned beside the real-time task, that core)."""
    stat = (
        "cpu  100 5 50 800 20 0 5 0 0 0\n"
        "cpu0 50 2 25 400 10 0 3 0 0 0\ncpu1 50 3 25 400 10 0 2 0 0 0\nintr 1\n"
    )
    both = HostCpu(cores=2, busy_seconds=1.6, total_seconds=9.8)
    assert parse_stat(stat, 100.0, {0, 1}) == both
    assert parse_stat(stat, 100.0, {1, 7}) == HostCpu(cores=1, busy_seconds=0.8, total_seconds=4.9)
    assert parse_stat(stat, 100.0, {5}) is None
    assert parse_stat("intr 1\n", 100.0, {0}) is None
    assert parse_stat("cpu0 1 x 3 4 5\n", 100.0, {0}) is None
    host = load_report(Engine("edge"))["host"]
    assert host is not None  # this is Linux
    assert host["cores"] == len(os.sched_getaffinity(0))
    assert 0 < host["busySeconds"] <= host["totalSeconds"]
