"""The orchestration policy: up under pressure, down when calm, no flapping, constraints."""

from __future__ import annotations

import pytest

from edgerv.control.placement import (
    DeadlineReading,
    HandlerReport,
    MonitorLoad,
    Move,
    PolicyConfig,
    PolicyConfigError,
    PolicyMemory,
    plan,
)
from edgerv.core.documents import Placement

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


def test_at_most_max_moves_down_come_down_a_round() -> None:
    config = PolicyConfig(tiers=("edge", "cloud"), calm_seconds=0, cooldown_seconds=0)
    up = {name: busy(10) for name in "abcde"}
    below = [edge(0.2), idle("cloud", "cloud-1", **up)]
    assert [m.monitor for m in plan(below, {}, config, PolicyMemory(), now=1)] == ["a"]
    config = PolicyConfig(
        tiers=("edge", "cloud"), calm_seconds=0, cooldown_seconds=0, max_moves_down=3
    )
    assert [m.monitor for m in plan(below, {}, config, PolicyMemory(), now=1)] == ["a", "b", "c"]
    with pytest.raises(PolicyConfigError, match="max_moves_down"):
        PolicyConfig(tiers=("edge",), max_moves_down=0)


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


def test_a_pinned_monitor_started_above_its_home_tier_goes_home_once_it_can() -> None:
    """Its home tier had no handler when it started: it runs above until a lower tier
    where it would start now defines it, then moves there in one move (from cloud to
    edge, past fog, when both are there), and never up; an auto monitor above its home
    waits for calm instead."""
    off = MonitorLoad(active=False)
    pinned = {"a": Placement(tier="edge", migrate="pinned"), "b": Placement(tier="edge")}

    def moved(handlers: list[HandlerReport]) -> list[tuple[str, str, str, str]]:
        moves = plan(handlers, pinned, CONFIG, PolicyMemory(), now=0)
        return [(m.monitor, m.source, m.destination, m.reason) for m in moves]

    cloud = idle("cloud", "cloud-1", a=busy(1), b=busy(1))
    assert moved([cloud]) == []  # nowhere lower
    fog = idle("fog", "fog-1", a=off)
    assert moved([cloud, fog]) == [("a", "cloud-1", "fog-1", "pinned home")]
    # the edge's handler came up, under pressure (b waits for calm): a goes home anyway
    assert moved([cloud, fog, edge(0.95, a=off, b=off)]) == [
        ("a", "cloud-1", "edge-1", "pinned home")
    ]
    assert moved([edge(0.95, a=busy(1)), idle("cloud", "cloud-1", a=off)]) == []  # never up
    moving = MonitorLoad(active=True, in_handoff=True)
    assert moved([idle("cloud", "cloud-1", a=moving), edge(0.3, a=off)]) == []  # (moving)
    # in a handoff that another handler reports (its receiver, holding it): not moved
    # again before that handoff is settled, as no plan moves a monitor any handler moves
    receiving = MonitorLoad(active=False, in_handoff=True)
    assert moved([cloud, fog, edge(0.3, a=receiving, b=off)]) == []


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


# -- deadline pressure (docs/protocol.md, "Deadline pressure") ----------------------------


def timed(
    cpu: float, p95_ms: float | None, count: int = 40, misses: int = 0, **monitors: MonitorLoad
) -> HandlerReport:
    """The edge handler with a --deadline of 125 ms whose window reads ``p95_ms``."""
    reading = DeadlineReading(0.125, None if p95_ms is None else p95_ms / 1000, count, misses)
    return HandlerReport("edge-1", "edge", cpu, monitors=monitors, deadline=reading)


def moved(moves: list[Move]) -> list[tuple[str, str, str]]:
    return [(m.monitor, m.destination, m.reason) for m in moves]


def test_deadline_pressure_sheds_half_the_movable_load_busiest_first() -> None:
    mon = {"m100": busy(100), "m400": busy(400), "m200": busy(200), "m300": busy(300)}
    handlers = [timed(0.3, p95_ms=140, **mon), idle("fog", "fog-1")]
    # 1000 events/s movable: at least 500 go, busiest first: 400 + 300
    assert moved(plan(handlers, {}, CONFIG, PolicyMemory(), now=0)) == [
        ("m400", "fog-1", "deadline"),
        ("m300", "fog-1", "deadline"),
    ]
    # at the budget exactly (p95 / budget = deadline_high = 1.0) is pressure too
    handlers = [timed(0.3, p95_ms=125, **mon), idle("fog", "fog-1")]
    assert [m.monitor for m in plan(handlers, {}, CONFIG, PolicyMemory(), now=0)] == [
        "m400",
        "m300",
    ]
    handlers = [timed(0.3, p95_ms=124, **mon), idle("fog", "fog-1")]
    assert plan(handlers, {}, CONFIG, PolicyMemory(), now=0) == []


def test_deadline_shed_counts_only_movable_monitors_and_the_cpu_rule_applies_when_larger() -> None:
    mon = {"pinned": busy(1000), "a": busy(100), "b": busy(100), "far": busy(900)}
    placements = {"pinned": Placement(migrate="pinned"), "far": Placement(max_latency_ms=1.0)}
    handlers = [timed(0.3, p95_ms=200, **mon), idle("fog", "fog-1")]
    # movable: a and b, 200 events/s; half of it is one of them
    assert moved(plan(handlers, placements, CONFIG, PolicyMemory(), now=0)) == [
        ("a", "fog-1", "deadline")
    ]
    ten = {f"m{i}": busy(100) for i in range(10)}
    small_shed = PolicyConfig(tiers=("edge", "fog"), deadline_shed=0.1)
    handlers = [timed(0.95, p95_ms=200, **ten), idle("fog", "fog-1")]
    # the deadline asks for 10% (one monitor), the CPU for (0.95 - 0.7) / 0.95 = 26%: three
    assert [m.reason for m in plan(handlers, {}, small_shed, PolicyMemory(), now=0)] == [
        "deadline"
    ] * 3


def test_after_a_deadline_shed_the_deadline_waits_for_its_window_to_refill() -> None:
    memory = PolicyMemory()
    mon = {"a": busy(400), "b": busy(300), "c": busy(200), "d": busy(100)}
    assert len(plan([timed(0.3, 150, **mon), idle("fog", "fog-1")], {}, CONFIG, memory, 0)) == 2
    left = {"c": busy(200), "d": busy(100)}
    # the window still holds makespans from before the move: not acted on for 2 s
    for now in (0.5, 1.0, 1.99):
        assert plan([timed(0.3, 150, **left), idle("fog", "fog-1")], {}, CONFIG, memory, now) == []
    # load pressure meanwhile is not delayed (and says so: it is not the deadline's move)
    hot = plan([timed(0.95, 150, **left), idle("fog", "fog-1")], {}, CONFIG, memory, now=1.5)
    assert moved(hot) == [("c", "fog-1", "pressure")]
    # once the wait is over, a deadline still at risk sheds again
    again = plan([timed(0.3, 150, d=busy(100)), idle("fog", "fog-1")], {}, CONFIG, memory, now=2.0)
    assert moved(again) == [("d", "fog-1", "deadline")]


def test_too_few_makespans_are_no_information() -> None:
    mon = {"a": busy(400), "b": busy(300)}
    few = [timed(0.3, p95_ms=500, count=3, **mon), idle("fog", "fog-1")]
    assert plan(few, {}, CONFIG, PolicyMemory(), now=0) == []  # no pressure
    enough = [timed(0.3, p95_ms=500, count=4, **mon), idle("fog", "fog-1")]
    assert [m.reason for m in plan(enough, {}, CONFIG, PolicyMemory(), now=0)] == ["deadline"]
    empty = [timed(0.3, p95_ms=None, count=0, **mon), idle("fog", "fog-1")]
    assert plan(empty, {}, CONFIG, PolicyMemory(), now=0) == []
    # fewer, but every one missed: two or more are information (were the p95 within the
    # budget, two misses in a row would come at most 0.25% of the time); one is not
    for count, misses, pressed in [(2, 2, True), (3, 3, True), (3, 2, False), (1, 1, False)]:
        window = [timed(0.3, 500, count, misses, **mon), idle("fog", "fog-1")]
        reasons = [m.reason for m in plan(window, {}, CONFIG, PolicyMemory(), now=0)]
        assert reasons == (["deadline"] if pressed else []), (count, misses)
    # ... and they do not block calm: a monitor comes back down as without a reading
    memory = PolicyMemory()
    below = [timed(0.2, p95_ms=500, count=3), idle("fog", "fog-1", a=busy(10))]
    assert plan(below, {}, CONFIG, memory, now=0) == []
    assert moved(plan(below, {}, CONFIG, memory, now=61)) == [("a", "edge-1", "calm below")]


def test_calm_needs_the_deadline_below_its_low_mark() -> None:
    def descents(p95_ms: float | None, count: int = 40) -> list[Move]:
        memory = PolicyMemory()
        below = [timed(0.2, p95_ms, count), idle("fog", "fog-1", a=busy(10))]
        plan(below, {}, CONFIG, memory, now=0)
        return plan(below, {}, CONFIG, memory, now=61)

    # between the marks (0.95 and 1.0 of 125 ms): neither pressure nor calm
    assert descents(p95_ms=122) == []
    assert moved(descents(p95_ms=118)) == [("a", "edge-1", "calm below")]  # 0.944
    assert moved(descents(p95_ms=None, count=0)) == [("a", "edge-1", "calm below")]
    no_reading = [edge(0.2), idle("fog", "fog-1", a=busy(10))]
    memory = PolicyMemory()
    plan(no_reading, {}, CONFIG, memory, now=0)
    assert moved(plan(no_reading, {}, CONFIG, memory, now=61)) == [("a", "edge-1", "calm below")]


def test_the_deadline_alone_moves_nothing_before_rates_are_known() -> None:
    """The orchestrator's first poll knows the window but no event rates yet."""
    mon = {"a": busy(0), "b": busy(0)}
    assert plan([timed(0.0, 300, **mon), idle("fog", "fog-1")], {}, CONFIG, PolicyMemory(), 0) == []


def test_a_handler_whose_deadline_is_at_risk_receives_no_monitors() -> None:
    hot_fog = HandlerReport(
        "fog-1", "fog", 0.1, deadline=DeadlineReading(0.1, 0.2, 40)
    )  # its own robot's task
    handlers = [edge(0.95, a=busy(600)), hot_fog]
    assert plan(handlers, {}, CONFIG, PolicyMemory(), now=0) == []
    off = MonitorLoad(active=False)
    starts = [timed(0.1, 300, a=off), idle("edge", "edge-2", cpu=0.5, a=off)]
    assert moved(plan(starts, {}, CONFIG, PolicyMemory(), now=0)) == [("a", "edge-2", "start")]


def test_bad_deadline_settings_are_refused() -> None:
    with pytest.raises(PolicyConfigError, match="deadline_low < deadline_high") as exc:
        PolicyConfig(tiers=("edge",), deadline_low=1.0)
    assert exc.value.setting == "deadline_low"
    with pytest.raises(PolicyConfigError, match="deadline_shed <= 1"):
        PolicyConfig(tiers=("edge",), deadline_shed=0.0)
    with pytest.raises(PolicyConfigError, match="deadline_wait >= 0"):
        PolicyConfig(tiers=("edge",), deadline_wait=-1)


def test_an_ingest_that_lags_with_cpu_to_spare_sheds_half_then_lets_its_backlog_drain() -> None:
    """Under a CPU budget it cannot keep up with, a handler's CPU reads below the target
    while its ingest lags (docs/protocol.md, "The budget lever"): the lag moves monitors,
    busiest first, at least deadline_shed of the movable load, and is not acted on again
    until deadline_wait has passed (its backlog drains meanwhile)."""
    memory = PolicyMemory()
    mon = {"m100": busy(100), "m400": busy(400), "m200": busy(200), "m300": busy(300)}

    def lagging(lag: float, **monitors: MonitorLoad) -> list[HandlerReport]:
        return [HandlerReport("edge-1", "edge", 0.1, lag, monitors), idle("fog", "fog-1")]

    assert moved(plan(lagging(1.0, **mon), {}, CONFIG, memory, now=0)) == [
        ("m400", "fog-1", "pressure"),
        ("m300", "fog-1", "pressure"),
    ]
    left = {"m100": busy(100), "m200": busy(200)}
    for now in (0.5, 1.99):  # the backlog of before the move still drains
        assert plan(lagging(0.8, **left), {}, CONFIG, memory, now) == []
    assert moved(plan(lagging(0.8, **left), {}, CONFIG, memory, now=2.0)) == [
        ("m200", "fog-1", "pressure")
    ]
    assert plan(lagging(0.4, **left), {}, CONFIG, PolicyMemory(), now=0) == []  # under lag_high


def test_a_monitor_in_a_handoff_is_neither_shed_nor_brought_home_by_the_rule() -> None:
    moving = MonitorLoad(active=True, events_per_second=600, in_handoff=True)
    hot = [edge(0.95, a=moving, b=busy(300)), idle("fog", "fog-1")]
    assert [m.monitor for m in plan(hot, {}, CONFIG, PolicyMemory(), now=0)] == ["b"]
    away = {"a": MonitorLoad(active=True, events_per_second=10, in_handoff=True), "b": busy(10)}
    below = [edge(0.2), idle("cloud", "cloud-1", **away)]
    config = PolicyConfig(
        tiers=("edge", "cloud"), calm_seconds=0, cooldown_seconds=0, max_moves_down=5
    )
    assert [m.monitor for m in plan(below, {}, config, PolicyMemory(), now=1)] == ["b"]


def test_a_tiers_measured_latency_holds_where_it_passes_what_is_said() -> None:
    """The fog said 5 ms from the robot; its handler measures 12 (its reach): a monitor
    of maxLatencyMs 10 may not go there, one of 20 may; measured below what is said, what
    is said holds."""
    placements = {"near": Placement(max_latency_ms=10.0), "far": Placement(max_latency_ms=20.0)}
    hot = edge(0.95, near=busy(600), far=busy(500))
    fog = HandlerReport("fog-1", "fog", 0.1, reach_ms=12.0)
    moves = plan([hot, fog], placements, CONFIG, PolicyMemory(), now=0)
    assert [m.monitor for m in moves] == ["far"]
    quick = HandlerReport("fog-1", "fog", 0.1, reach_ms=1.0)  # 5 ms said: the near still fits
    moves = plan([hot, quick], placements, CONFIG, PolicyMemory(), now=0)
    assert [m.monitor for m in moves] == ["near"]


def test_a_monitor_whose_tier_grew_too_far_comes_down_at_once() -> None:
    """A monitor went up to the fog when it was 5 ms away; the fog now measures 30 ms,
    past its maxLatencyMs of 10: it comes down where it would start now, in one move, with
    no calm or cooldown to wait for (reason latency); one with no maxLatencyMs stays, and
    nothing moves while no tier below may take it."""
    placements = {"near": Placement(max_latency_ms=10.0)}
    fog = HandlerReport(
        "fog-1", "fog", 0.3, monitors={"near": busy(50), "any": busy(50)}, reach_ms=30.0
    )
    below = edge(0.8, near=MonitorLoad(active=False), any=MonitorLoad(active=False))
    moves = plan([below, fog], placements, CONFIG, PolicyMemory(), now=0)
    assert moves == [Move("near", "fog-1", "edge-1", "latency")]
    alone = plan([fog], placements, CONFIG, PolicyMemory(), now=0)
    assert alone == []


@pytest.mark.parametrize("seed", range(40))
def test_no_move_takes_a_monitor_where_the_tier_is_farther_than_its_max_latency(
    seed: int,
) -> None:
    """Random handlers (loaded, calm, late, each tier's latency said and measured) and
    monitors (some with maxLatencyMs, some pinned, some running nowhere): a few rounds of
    the policy; no move goes to a tier whose latency (the larger of said and measured)
    passes the monitor's maxLatencyMs."""
    import random

    rng = random.Random(seed)
    config = PolicyConfig(
        tiers=("edge", "fog", "cloud"),
        tier_latency_ms={"fog": rng.choice([0.0, 5.0]), "cloud": rng.choice([0.0, 40.0])},
        calm_seconds=0.0,
        cooldown_seconds=0.0,
    )
    names = [f"m{i}" for i in range(8)]
    placements = {
        m: Placement(
            tier=rng.choice([None, "edge", "fog"]),
            migrate=rng.choice(["auto", "auto", "pinned"]),  # type: ignore[arg-type]
            max_latency_ms=rng.choice([None, 3.0, 10.0, 30.0]),
        )
        for m in names
    }
    memory = PolicyMemory()
    for round_ in range(4):
        handlers = []
        for tier, name in (("edge", "edge-1"), ("fog", "fog-1"), ("cloud", "cloud-1")):
            monitors = {
                m: MonitorLoad(
                    active=rng.random() < 0.4,
                    events_per_second=rng.choice([0.0, 10.0, 500.0]),
                    migration_wanted=rng.random() < 0.2,
                )
                for m in names
            }
            deadline = None
            if tier == "edge" and rng.random() < 0.5:
                deadline = DeadlineReading(0.1, rng.choice([0.05, 0.2]), 10, 5)
            handlers.append(
                HandlerReport(
                    name,
                    tier,
                    rng.choice([0.2, 0.6, 0.95]),
                    monitors=monitors,
                    deadline=deadline,
                    reach_ms=rng.choice([None, 1.0, 8.0, 25.0, 60.0]),
                )
            )
        latency = dict(config.tier_latency_ms)
        for h in handlers:
            if h.reach_ms is not None:
                latency[h.tier] = max(latency.get(h.tier, 0.0), h.reach_ms)
        tiers = {h.name: h.tier for h in handlers}
        for move in plan(handlers, placements, config, memory, now=10.0 * round_):
            most = placements[move.monitor].max_latency_ms
            there = latency.get(tiers[move.destination], 0.0)
            assert most is None or there <= most, (move, there, most)
