"""The placement policy over a fleet (issue 36): a robot's instance runs on its robot's
handlers and the shared ones only (edgerv.core.robots.may_host), wherever the policy
starts, sheds or brings it home; a monitor of no robot goes anywhere, as before. The
policy without robots: tests/unit/test_placement.py."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

from hypothesis import given
from hypothesis import strategies as st

from edgerv.control.orchestrate import Target, build_reports
from edgerv.control.placement import (
    DeadlineReading,
    HandlerReport,
    MonitorLoad,
    Move,
    PolicyConfig,
    PolicyMemory,
    plan,
    start_on,
)
from edgerv.control.wire import parse_load
from edgerv.core.documents import Placement
from edgerv.core.robots import may_host
from kit.counts import props

CONFIG = PolicyConfig(
    tiers=("edge", "cloud"),
    tier_latency_ms={"edge": 0.0, "cloud": 40.0},
    max_moves_down=10,  # every monitor that may come home comes in one round here
)
OFF = MonitorLoad(active=False)
# a's instances, b's, and a monitor of no robot (a cluster without robots)
PLACEMENTS = {
    "a1": Placement(robot="a"),
    "a2": Placement(robot="a"),
    "b1": Placement(robot="b"),
    "b2": Placement(robot="b"),
    "free": Placement(),
}


def handler(
    name: str, tier: str, cpu: float, robot: str | None, **monitors: MonitorLoad
) -> HandlerReport:
    return HandlerReport(name, tier, cpu, monitors=monitors, robot=robot)


def busy(rate: float) -> MonitorLoad:
    return MonitorLoad(active=True, events_per_second=rate)


def moves_of(moves: list[Move]) -> list[tuple[str, str, str, str]]:
    return [(m.monitor, m.source, m.destination, m.reason) for m in moves]


def hosts(
    moves: list[Move], handlers: list[HandlerReport], placements: Mapping[str, Placement]
) -> None:
    """Every move puts a monitor on a handler that may run it."""
    robot = {h.name: h.robot for h in handlers}
    for m in moves:
        p = placements.get(m.monitor, Placement())
        assert may_host(p.robot, robot[m.destination]), (m, p.robot, robot[m.destination])


# -- start ----------------------------------------------------------------------------------


def test_start_on_never_picks_another_robots_handler() -> None:
    edge_a = handler("edge-a", "edge", 0.6, "a")
    edge_b = handler("edge-b", "edge", 0.0, "b")  # the least loaded of the edge
    cloud = handler("cloud", "cloud", 0.0, None)
    both = [edge_a, edge_b, cloud]
    assert start_on(Placement(robot="a"), both, CONFIG) is edge_a
    assert start_on(Placement(robot="b"), both, CONFIG) is edge_b
    assert start_on(Placement(), both, CONFIG) is edge_b  # no robot: the least loaded
    # a pressured own edge is still its robot's: the other robot's never is
    hot_a = handler("edge-a", "edge", 0.99, "a")
    assert start_on(Placement(robot="a"), [hot_a, edge_b, cloud], CONFIG) is hot_a
    # no handler of its own on its home tier: the shared one above, never b's
    assert start_on(Placement(robot="a"), [edge_b, cloud], CONFIG) is cloud
    assert start_on(Placement(robot="c"), both, CONFIG) is cloud
    assert start_on(Placement(robot="a", max_latency_ms=5.0), [edge_b, cloud], CONFIG) is None
    assert start_on(Placement(robot="a"), [edge_b], CONFIG) is None
    # a shared handler on the edge runs any robot's instance
    shared_edge = handler("edge-shared", "edge", 0.3, None)
    assert start_on(Placement(robot="a"), [edge_b, shared_edge, cloud], CONFIG) is shared_edge
    # ... and the robot's own one, when less loaded
    assert start_on(Placement(robot="a"), [shared_edge, edge_a, cloud], CONFIG) is shared_edge
    idle_a = handler("edge-a", "edge", 0.1, "a")
    assert start_on(Placement(robot="a"), [shared_edge, idle_a], CONFIG) is idle_a
    # of a higher home tier: its robot's there, or a shared one
    cloud_b = handler("cloud-b", "cloud", 0.0, "b")
    busy_cloud = handler("cloud", "cloud", 0.5, None)
    assert start_on(Placement("cloud", robot="a"), [edge_a, cloud_b, busy_cloud], CONFIG) is (
        busy_cloud
    )
    assert start_on(Placement("cloud", robot="b"), [edge_a, cloud_b, busy_cloud], CONFIG) is (
        cloud_b
    )


def test_a_round_starts_each_instance_on_its_robots_edge() -> None:
    defined = {m: OFF for m in PLACEMENTS}
    handlers = [
        handler("edge-a", "edge", 0.4, "a", **defined),
        handler("edge-b", "edge", 0.1, "b", **defined),
        handler("cloud", "cloud", 0.0, None, **defined),
    ]
    moves = plan(handlers, PLACEMENTS, CONFIG, PolicyMemory(), now=0)
    assert moves_of(moves) == [
        ("a1", "", "edge-a", "start"),
        ("a2", "", "edge-a", "start"),
        ("b1", "", "edge-b", "start"),
        ("b2", "", "edge-b", "start"),
        ("free", "", "edge-b", "start"),  # no robot: the least loaded edge
    ]
    # defined only on the other robot's edge and the cloud: it starts on the cloud
    handlers = [
        handler("edge-b", "edge", 0.1, "b", a1=OFF),
        handler("cloud", "cloud", 0.5, None, a1=OFF),
    ]
    assert moves_of(plan(handlers, PLACEMENTS, CONFIG, PolicyMemory(), now=0)) == [
        ("a1", "", "cloud", "start")
    ]


def test_a_pinned_instance_goes_home_to_its_own_robots_edge() -> None:
    pinned = {"a1": Placement("edge", "pinned", robot="a")}
    cloud = handler("cloud", "cloud", 0.1, None, a1=busy(5))
    edge_b = handler("edge-b", "edge", 0.0, "b", a1=OFF)
    assert plan([cloud, edge_b], pinned, CONFIG, PolicyMemory(), now=0) == []
    edge_a = handler("edge-a", "edge", 0.3, "a", a1=OFF)
    moves = plan([cloud, edge_b, edge_a], pinned, CONFIG, PolicyMemory(), now=0)
    assert moves_of(moves) == [("a1", "cloud", "edge-a", "pinned home")]


# -- up: pressure on one robot's edge -------------------------------------------------------


def two_robots(
    cpu_a: float, cpu_b: float, deadline_a: DeadlineReading | None = None
) -> list[HandlerReport]:
    """Robot a's edge (a1, a2 and the robotless free), robot b's (b1, b2), a shared cloud."""
    return [
        HandlerReport(
            "edge-a",
            "edge",
            cpu_a,
            monitors={"a1": busy(600), "a2": busy(300), "free": busy(100)},
            deadline=deadline_a,
            robot="a",
        ),
        handler("edge-b", "edge", cpu_b, "b", b1=busy(600), b2=busy(300)),
        handler("cloud", "cloud", 0.1, None),
    ]


def test_cpu_pressure_on_one_robots_edge_moves_only_its_monitors() -> None:
    handlers = two_robots(cpu_a=0.95, cpu_b=0.3)
    moves = plan(handlers, PLACEMENTS, CONFIG, PolicyMemory(), now=0)
    # (0.95 - 0.7) / 0.95 = 26% of 1000 events/s: a1 alone
    assert moves_of(moves) == [("a1", "edge-a", "cloud", "pressure")]
    both = plan(two_robots(0.95, 0.95), PLACEMENTS, CONFIG, PolicyMemory(), now=0)
    assert moves_of(both) == [
        ("a1", "edge-a", "cloud", "pressure"),
        ("b1", "edge-b", "cloud", "pressure"),
    ]


def test_deadline_pressure_on_one_robots_edge_moves_only_its_monitors() -> None:
    at_risk = DeadlineReading(budget=0.125, p95=0.2, count=40)
    moves = plan(two_robots(0.3, 0.3, at_risk), PLACEMENTS, CONFIG, PolicyMemory(), now=0)
    # at least half its movable load, busiest first: a1 (600 of 1000)
    assert moves_of(moves) == [("a1", "edge-a", "cloud", "deadline")]
    # a robotless monitor sheds with the robot's: it may run anywhere
    pinned = Placement(robot="a", migrate="pinned")
    only_free = {**PLACEMENTS, "a1": pinned, "a2": pinned}
    moves = plan(two_robots(0.3, 0.3, at_risk), only_free, CONFIG, PolicyMemory(), now=0)
    assert moves_of(moves) == [("free", "edge-a", "cloud", "deadline")]


def test_up_goes_to_a_shared_handler_or_the_robots_own_never_another_robots() -> None:
    hot_a = handler("edge-a", "edge", 0.95, "a", a1=busy(600), a2=busy(300))
    cloud_b = handler("cloud-b", "cloud", 0.0, "b")  # the least loaded above: b's
    shared = handler("cloud", "cloud", 0.4, None)
    moves = plan([hot_a, cloud_b, shared], PLACEMENTS, CONFIG, PolicyMemory(), now=0)
    assert moves_of(moves) == [("a1", "edge-a", "cloud", "pressure")]
    # only b's above: nothing moves (the pressure stays, b's handler never takes a's)
    assert plan([hot_a, cloud_b], PLACEMENTS, CONFIG, PolicyMemory(), now=0) == []
    # a's own handler above, less loaded than the shared one: there
    cloud_a = handler("cloud-a", "cloud", 0.0, "a")
    moves = plan([hot_a, cloud_b, shared, cloud_a], PLACEMENTS, CONFIG, PolicyMemory(), now=0)
    assert moves_of(moves) == [("a1", "edge-a", "cloud-a", "pressure")]


def test_a_stray_instance_is_never_shed_to_a_handler_of_the_wrong_robot() -> None:
    """b's instance found on a's edge (the node relabelled under it, say): a's edge sheds
    to a's own handler above, which may not run b's; b's stays rather than go there."""
    hot_a = handler("edge-a", "edge", 0.95, "a", b1=busy(900), a1=busy(100))
    cloud_a = handler("cloud-a", "cloud", 0.0, "a")
    shared = handler("cloud", "cloud", 0.5, None)
    handlers = [hot_a, cloud_a, shared]
    moves = plan(handlers, PLACEMENTS, CONFIG, PolicyMemory(), now=0)
    hosts(moves, handlers, PLACEMENTS)
    assert moves_of(moves) == [("a1", "edge-a", "cloud-a", "pressure")]


def test_a_shared_handler_under_pressure_sheds_each_robots_monitors_to_a_shared_one() -> None:
    config = PolicyConfig(tiers=("edge", "fog", "cloud"), max_moves_down=10)
    fog = handler("fog", "fog", 0.99, None, a1=busy(400), b1=busy(400), free=busy(200))
    cloud_a = handler("cloud-a", "cloud", 0.0, "a")
    cloud = handler("cloud", "cloud", 0.3, None)
    handlers = [fog, cloud_a, cloud]
    moves = plan(handlers, PLACEMENTS, config, PolicyMemory(), now=0)
    assert moves and all(m.destination == "cloud" for m in moves), moves
    hosts(moves, handlers, PLACEMENTS)


# -- down: home to each one's own robot's edge ----------------------------------------------


def test_coming_home_each_monitor_goes_to_its_own_robots_edge() -> None:
    memory = PolicyMemory()
    up = plan(two_robots(0.95, 0.95), PLACEMENTS, CONFIG, memory, now=0)
    assert {m.monitor for m in up} == {"a1", "b1"}
    # both edges calm now; b's the less loaded, the monitors on the shared cloud
    calm = [
        handler("edge-a", "edge", 0.3, "a", a2=busy(300), free=busy(100)),
        handler("edge-b", "edge", 0.05, "b", b2=busy(300)),
        handler("cloud", "cloud", 0.2, None, a1=busy(600), b1=busy(600), x=busy(10)),
    ]
    placements = {**PLACEMENTS, "x": Placement()}
    for now in (1.0, 20.0):  # calm since 1 s, for 30 s first
        assert plan(calm, placements, CONFIG, memory, now=now) == []
    # x never moved: down at once; a1 and b1 moved at 0: after their cooldown (60 s)
    moves = plan(calm, placements, CONFIG, memory, now=40.0)
    assert moves_of(moves) == [("x", "cloud", "edge-b", "calm below")]  # the least loaded
    calm[1] = handler("edge-b", "edge", 0.05, "b", b2=busy(300), x=busy(10))
    calm[2] = handler("cloud", "cloud", 0.2, None, a1=busy(600), b1=busy(600))
    assert plan(calm, placements, CONFIG, memory, now=50.0) == []
    moves = plan(calm, placements, CONFIG, memory, now=61.0)
    assert moves_of(moves) == [
        ("a1", "cloud", "edge-a", "calm below"),  # not b's, less loaded as it is
        ("b1", "cloud", "edge-b", "calm below"),
    ]
    hosts(moves, calm, placements)


def test_an_instance_waits_for_its_own_robots_edge_to_be_calm() -> None:
    memory = PolicyMemory()
    handlers = [
        handler("edge-a", "edge", 0.7, "a"),  # between the marks: not calm
        handler("edge-b", "edge", 0.05, "b"),
        handler("cloud", "cloud", 0.2, None, a1=busy(60), b1=busy(60)),
    ]
    plan(handlers, PLACEMENTS, CONFIG, memory, now=0)
    moves = plan(handlers, PLACEMENTS, CONFIG, memory, now=100)
    assert moves_of(moves) == [("b1", "cloud", "edge-b", "calm below")]
    handlers[1:] = [
        handler("edge-b", "edge", 0.05, "b", b1=busy(60)),
        handler("cloud", "cloud", 0.2, None, a1=busy(60)),
    ]
    for now in (200, 1000):
        assert plan(handlers, PLACEMENTS, CONFIG, memory, now=now) == []  # a1 waits, up there
    # ... and with no edge of its own at all it stays up, whoever is calm below
    alone = [handlers[1], handlers[2]]
    memory = PolicyMemory()
    plan(alone, PLACEMENTS, CONFIG, memory, now=0)
    assert plan(alone, PLACEMENTS, CONFIG, memory, now=100) == []


def test_coming_home_counts_against_one_budget_across_robots() -> None:
    config = PolicyConfig(tiers=("edge", "cloud"), calm_seconds=0, cooldown_seconds=0)
    handlers = [
        handler("edge-a", "edge", 0.1, "a"),
        handler("edge-b", "edge", 0.1, "b"),
        handler("cloud", "cloud", 0.2, None, a1=busy(60), b1=busy(60), b2=busy(60)),
    ]
    moves = plan(handlers, PLACEMENTS, config, PolicyMemory(), now=1)
    assert moves_of(moves) == [("a1", "cloud", "edge-a", "calm below")]  # max_moves_down: 1


def test_planned_homecoming_brings_each_instance_to_its_own_robots_edge() -> None:
    """The planner's path (each edge's headroom and deadline known, every cost known):
    one planned batch per destination, each a robot's own edge."""
    calm_reading = DeadlineReading(budget=0.125, p95=0.04, count=40)

    def edge(name: str, robot: str, cpu: float) -> HandlerReport:
        return HandlerReport(
            name, "edge", cpu, deadline=calm_reading, headroom=3.0, task_work=0.001, robot=robot
        )

    cost = MonitorLoad(active=True, events_per_second=50, cpu=0.05)
    handlers = [
        edge("edge-a", "a", 0.2),
        edge("edge-b", "b", 0.1),
        handler("cloud", "cloud", 0.2, None, a1=cost, a2=cost, b1=cost),
    ]
    memory = PolicyMemory()
    plan(handlers, PLACEMENTS, CONFIG, memory, now=0)
    moves = plan(handlers, PLACEMENTS, CONFIG, memory, now=100)
    assert sorted((m.monitor, m.destination) for m in moves) == [
        ("a1", "edge-a"),
        ("a2", "edge-a"),
        ("b1", "edge-b"),
    ]
    assert all(m.plan for m in moves), moves  # planned, not the rule's


# -- the invariant, over random fleets and rounds ------------------------------------------

ROBOTS = st.sampled_from([None, "a", "b"])
TIERS = ("edge", "fog", "cloud")
CPUS = st.sampled_from([0.05, 0.05, 0.3, 0.7, 0.95])
READINGS = st.sampled_from(
    [None, None, DeadlineReading(0.1, 0.05, 40), DeadlineReading(0.1, 0.2, 40)]
)


@st.composite
def fleets(draw: st.DrawFn) -> tuple[list[HandlerReport], dict[str, Placement]]:
    """Handlers of random robots, tiers and loads; monitors of random robots, each active
    on a handler that may run it (or defined, inactive, where it may not: a start)."""
    specs = [
        (f"{tier}-{i}", tier, draw(ROBOTS))
        for tier in TIERS
        for i in range(draw(st.integers(0 if tier == "fog" else 1, 2)))
    ]
    placements: dict[str, Placement] = {}
    monitors: dict[str, dict[str, MonitorLoad]] = {name: {} for name, _, _ in specs}
    for j in range(draw(st.integers(1, 8))):
        m = f"m{j}"
        robot = draw(ROBOTS)
        placements[m] = Placement(
            draw(st.sampled_from([None, *TIERS])),
            draw(st.sampled_from(["auto", "auto", "auto", "auto", "pinned"])),
            draw(st.sampled_from([None, None, 10.0])),
            robot,
        )
        fit = [name for name, _, r in specs if may_host(robot, r)]
        runs = bool(fit) and draw(st.integers(0, 4)) > 0  # mostly: it runs somewhere
        running = draw(st.sampled_from(fit)) if runs else None
        for name, _, _ in specs:
            if name == running:
                monitors[name][m] = MonitorLoad(
                    active=True,
                    events_per_second=draw(st.sampled_from([0.0, 10.0, 300.0])),
                    migration_wanted=draw(st.integers(0, 4)) == 0,
                    cpu=draw(st.sampled_from([None, 0.05])),
                )
            elif draw(st.integers(0, 3)):
                monitors[name][m] = OFF
    handlers = [
        HandlerReport(
            name,
            tier,
            draw(CPUS),
            monitors=monitors[name],
            deadline=draw(READINGS),
            headroom=draw(st.sampled_from([None, 2.0])),
            robot=robot,
        )
        for name, tier, robot in specs
    ]
    return handlers, placements


def made(handlers: list[HandlerReport], moves: list[Move]) -> list[HandlerReport]:
    """The reports after the moves: each monitor active on its destination only."""
    load = {m: d for h in handlers for m, d in h.monitors.items() if d.active}
    out = []
    for h in handlers:
        monitors = dict(h.monitors)
        for move in moves:
            if move.source == h.name:
                monitors[move.monitor] = OFF
            if move.destination == h.name:
                monitors[move.monitor] = load.get(move.monitor, busy(10.0))
        out.append(dataclasses.replace(h, monitors=monitors))
    return out


@props(80)
@given(fleets(), st.data())
def test_no_round_ever_puts_an_instance_on_another_robots_handler(
    fleet: tuple[list[HandlerReport], dict[str, Placement]], data: st.DataObject
) -> None:
    handlers, placements = fleet
    config = PolicyConfig(
        tiers=TIERS,
        tier_latency_ms={"edge": 0.0, "fog": 5.0, "cloud": 40.0},
        calm_seconds=10.0,
        cooldown_seconds=30.0,
        max_moves_down=5,
        planner_seconds=0,  # the planner's greedy rule: fast
    )
    memory = PolicyMemory()
    now = 0.0
    for _ in range(data.draw(st.integers(1, 4))):
        moves = plan(handlers, placements, config, memory, now=now)
        hosts(moves, handlers, placements)
        assert len({m.monitor for m in moves}) == len(moves), moves  # one move each
        handlers = made(handlers, moves)
        for h in handlers:  # what runs where is always allowed
            for m in h.active():
                assert may_host(placements[m].robot, h.robot), (m, h)
        now += data.draw(st.sampled_from([1.0, 40.0, 100.0]))
        if data.draw(st.booleans()):  # the load changes, or stays
            handlers = [
                dataclasses.replace(h, cpu=data.draw(CPUS), deadline=data.draw(READINGS))
                for h in handlers
            ]


# -- the orchestrator: a target's robot is its report's -------------------------------------


def test_a_targets_robot_and_its_monitors_robots_reach_the_policy() -> None:
    load = parse_load(
        {
            "handler": "h-edge-a",
            "monotonic": 1.0,
            "cpuSeconds": 0.5,
            "monitors": {
                "ns.m.a": {
                    "active": True,
                    "events": 3,
                    "migrationWanted": False,
                    "placement": {"tier": "edge", "robot": "a"},
                },
                "ns.n": {"active": False, "events": 0, "migrationWanted": False},
            },
        }
    )
    target = Target("edge", "10.0.0.1:8470", "a")
    (report,), placements, where = build_reports({target: load}, {})
    assert report.robot == "a" and report.tier == "edge"
    assert placements == {"ns.m.a": Placement("edge", robot="a"), "ns.n": Placement()}
    assert where == {"h-edge-a": target}
    (shared,), _, _ = build_reports({Target("cloud", "10.0.0.2:8470"): load}, {})
    assert shared.robot is None
