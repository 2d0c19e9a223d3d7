"""The orchestration policy: up under pressure, down when calm, no flapping, constraints."""

from __future__ import annotations

import pytest

from edgerv.core.placement import (
    HandlerReport,
    MonitorLoad,
    Placement,
    PolicyConfig,
    PolicyMemory,
    plan,
)

CONFIG = PolicyConfig(
    tiers=("edge", "fog", "cloud"), tier_latency_ms={"edge": 0.0, "fog": 5.0, "cloud": 40.0}
)


def edge(cpu: float, **monitors: MonitorLoad) -> HandlerReport:
    return HandlerReport("edge-1", "edge", cpu, monitors=monitors)


def idle(tier: str, name: str, cpu: float = 0.1, **monitors: MonitorLoad) -> HandlerReport:
    return HandlerReport(name, tier, cpu, monitors=monitors)


def busy(rate: float, wanted: bool = False) -> MonitorLoad:
    return MonitorLoad(active=True, events_per_second=rate, migration_wanted=wanted)


def test_nothing_moves_without_pressure() -> None:
    handlers = [edge(0.6, a=busy(100)), idle("fog", "fog-1")]
    assert plan(handlers, {}, CONFIG, PolicyMemory(), now=0) == []


def test_a_monitor_that_wants_to_migrate_goes_one_tier_up() -> None:
    handlers = [
        edge(0.6, a=busy(10, wanted=True), b=busy(500)),
        idle("fog", "fog-1", cpu=0.3),
        idle("fog", "fog-2", cpu=0.2),
        idle("cloud", "cloud-1"),
    ]
    moves = plan(handlers, {}, CONFIG, PolicyMemory(), now=0)
    assert [(m.monitor, m.source, m.destination) for m in moves] == [("a", "edge-1", "fog-2")]


def test_cpu_pressure_sheds_the_busiest_until_the_target() -> None:
    monitors = {"small": busy(10), "big": busy(600), "mid": busy(300), "tiny": busy(1)}
    handlers = [edge(0.95, **monitors), idle("fog", "fog-1")]
    moves = plan(handlers, {}, CONFIG, PolicyMemory(), now=0)
    # excess (0.95 - 0.7) / 0.95 = 26% of 911 events/s: the 600 alone covers it
    assert [m.monitor for m in moves] == ["big"]


def test_pinned_and_latency_budget_stay() -> None:
    handlers = [edge(0.95, a=busy(600), b=busy(300), c=busy(100)), idle("fog", "fog-1")]
    placements = {"a": Placement(migrate="pinned"), "b": Placement(max_latency_ms=2.0)}
    moves = plan(handlers, placements, CONFIG, PolicyMemory(), now=0)
    assert [m.monitor for m in moves] == ["c"]


def test_no_destination_no_move() -> None:
    handlers = [edge(0.95, a=busy(600)), idle("fog", "fog-1", cpu=0.9)]
    assert plan(handlers, {}, CONFIG, PolicyMemory(), now=0) == []


def test_back_down_only_after_calm_and_cooldown() -> None:
    memory = PolicyMemory()
    hot = [edge(0.95, a=busy(600)), idle("fog", "fog-1")]
    assert [m.monitor for m in plan(hot, {}, CONFIG, memory, now=0)] == ["a"]
    calm = [edge(0.2), idle("fog", "fog-1", a=busy(600))]
    for now in (1, 20, 40):  # calm for 39 s by t=40, but a moved at t=0: cooldown 60 s
        assert plan(calm, {}, CONFIG, memory, now=now) == []
    moves = plan(calm, {}, CONFIG, memory, now=61)
    assert [(m.monitor, m.destination, m.reason) for m in moves] == [("a", "edge-1", "calm below")]


def test_a_monitor_stays_at_its_home_tier() -> None:
    memory = PolicyMemory()
    calm = [edge(0.1), idle("fog", "fog-1", a=busy(10))]
    plan(calm, {"a": Placement(tier="fog")}, CONFIG, memory, now=0)
    assert plan(calm, {"a": Placement(tier="fog")}, CONFIG, memory, now=1000) == []


def test_no_flapping_under_oscillating_load() -> None:
    """Load swinging every few seconds: up moves stay immediate, descents thin out."""
    memory = PolicyMemory()
    where = "edge"
    downs, ups = [], []
    for now in range(0, 900, 2):
        hot = (now // 6) % 2 == 0
        mon = {"a": busy(600)}
        edge_cpu = 0.95 if hot and where == "edge" else 0.3
        handlers = [
            edge(edge_cpu, **(mon if where == "edge" else {})),
            idle("fog", "fog-1", **(mon if where == "fog" else {})),
        ]
        for move in plan(handlers, {}, CONFIG, memory, now=now):
            where = "fog" if move.destination == "fog-1" else "edge"
            (ups if where == "fog" else downs).append(now)
    assert ups[0] == 0
    # each bounce doubles the wait before the next descent: 60, 120, 240, ... seconds
    waits = [d - u for u, d in zip(ups, downs, strict=False)]
    assert waits == sorted(waits) and waits[1] >= 2 * CONFIG.cooldown_seconds, (ups, downs)
    assert len(downs) <= 3, (ups, downs)  # not one round trip per swing (150 swings here)


def test_bad_configuration_is_refused() -> None:
    with pytest.raises(ValueError, match="tiers must be distinct"):
        PolicyConfig(tiers=("edge", "edge"))
    with pytest.raises(ValueError, match="cpu_low < cpu_target < cpu_high"):
        PolicyConfig(tiers=("edge",), cpu_low=0.9)
    with pytest.raises(ValueError, match="reports tier 'moon'"):
        plan([HandlerReport("x", "moon", 0.1)], {}, CONFIG, PolicyMemory(), now=0)


def test_a_monitor_running_nowhere_starts_on_its_home_tier() -> None:
    off = MonitorLoad(active=False)
    handlers = [
        edge(0.3, a=off, b=off, c=off, d=off),
        idle("fog", "fog-1", a=off, b=off, c=off, d=off),
        idle("cloud", "cloud-1", a=off, b=off, c=off, d=MonitorLoad(active=False, in_handoff=True)),
    ]
    placements = {
        "b": Placement(tier="cloud"),
        "c": Placement(tier="edge", max_latency_ms=1.0),
    }
    moves = plan(handlers, placements, CONFIG, PolicyMemory(), now=0)
    assert [(m.monitor, m.source, m.destination, m.reason) for m in moves] == [
        ("a", "", "edge-1", "start"),  # no tier given: the lowest
        ("b", "", "cloud-1", "start"),
        ("c", "", "edge-1", "start"),
        # d is being handed off: placed already
    ]
    running = [edge(0.3, a=busy(1)), idle("cloud", "cloud-1", a=off)]
    assert plan(running, {}, CONFIG, PolicyMemory(), now=0) == []
    # no handler on the home tier: the nearest one above that allows it
    only_cloud = [idle("cloud", "cloud-1", a=off, c=off)]
    moves = plan(only_cloud, placements, CONFIG, PolicyMemory(), now=0)
    assert [(m.monitor, m.destination) for m in moves] == [("a", "cloud-1")]  # c: 40 ms > 1
