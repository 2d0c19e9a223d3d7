"""The policy with the planner (issue 37): once every monitor's cost on a handler is
measured and its CPUs' headroom is known, deadline pressure moves exactly the planner's
set up in one batch, and a calm edge takes home what fits its headroom and its deadline
in one batch; without them, today's rule. And the orchestrator's rates: each monitor's
cost and the headroom from two load reports."""

from __future__ import annotations

import math

from edgerv.control.orchestrate import Counters, Target, build_reports
from edgerv.control.placement import (
    DeadlineReading,
    HandlerReport,
    MonitorLoad,
    PolicyConfig,
    PolicyMemory,
    deadline_moved,
    plan,
)
from edgerv.control.wire import LoadReport
from edgerv.core.deadline import DeadlineLoad
from edgerv.core.documents import Placement
from edgerv.core.planner import EdgeState, MonitorCost, PlannerConfig, plan_moves

CONFIG = PolicyConfig(tiers=("edge", "cloud"), tier_latency_ms={"edge": 0.0, "cloud": 40.0})
BUDGET = 0.125  # the loop's deadline, seconds


def costed(cpu: float | None, rate: float = 50.0) -> MonitorLoad:
    return MonitorLoad(active=True, events_per_second=rate, cpu=cpu)


def edge(
    p95_ms: float, monitors: dict[str, MonitorLoad], cpu: float, headroom: float | None
) -> HandlerReport:
    reading = DeadlineReading(BUDGET, p95_ms / 1000, 40)
    return HandlerReport("edge-1", "edge", cpu, 0.0, monitors, reading, headroom)


def cloud(**monitors: MonitorLoad) -> HandlerReport:
    return HandlerReport("cloud-1", "cloud", 0.1, monitors=monitors)


SIX = {f"m{i}": costed(0.02 * (i + 1), rate=10.0 * (6 - i)) for i in range(6)}  # 0.42 cores


def test_deadline_pressure_moves_the_planners_set_in_one_batch() -> None:
    handlers = [edge(160.0, SIX, cpu=0.5, headroom=0.45), cloud()]
    moves = plan(handlers, {}, CONFIG, PolicyMemory(), now=0)
    expected = plan_moves(
        [
            MonitorCost(m, "edge", load.cpu or 0.0, load.events_per_second)
            for m, load in SIX.items()
        ],
        EdgeState(0.45, BUDGET, 0.16, 40.0, handler_cpu=0.5),
        PlannerConfig(time_budget=CONFIG.planner_seconds),
    )
    assert expected.up  # (the instance asks for moves)
    assert sorted(m.monitor for m in moves) == sorted(expected.up)
    assert {(m.source, m.destination, m.reason) for m in moves} == {
        ("edge-1", "cloud-1", "deadline")
    }
    assert all(m.plan.startswith(("milp:", "greedy:", "all:")) for m in moves)
    # processor sharing: (1 - 0.5) * (1.28 / 0.95 - 1) = 0.174 cores to free
    freed = sum(SIX[m.monitor].cpu or 0.0 for m in moves)
    assert freed >= 0.5 * (160 / 125 / 0.95 - 1) - 1e-9


def test_a_cost_not_known_yet_leaves_the_move_to_todays_rule() -> None:
    monitors = {**SIX, "new": costed(None)}
    handlers = [edge(160.0, monitors, cpu=0.5, headroom=0.45), cloud()]
    moves = plan(handlers, {}, CONFIG, PolicyMemory(), now=0)
    assert moves and all(m.plan == "" and m.reason == "deadline" for m in moves)
    without_headroom = [edge(160.0, SIX, cpu=0.5, headroom=None), cloud()]
    assert all(m.plan == "" for m in plan(without_headroom, {}, CONFIG, PolicyMemory(), now=0))


def test_the_plan_never_moves_pinned_nor_latency_bound_monitors() -> None:
    placements = {
        "m5": Placement(migrate="pinned"),  # the costliest two, held
        "m4": Placement(max_latency_ms=10.0),  # the cloud is 40 ms away
    }
    handlers = [edge(200.0, SIX, cpu=0.5, headroom=0.45), cloud()]
    moves = plan(handlers, placements, CONFIG, PolicyMemory(), now=0)
    assert moves and not {"m4", "m5"} & {m.monitor for m in moves}
    assert "pinned: m5" in moves[0].plan and "m4" in moves[0].plan


def test_a_calm_edge_takes_home_what_fits_in_one_batch_at_what_it_cost_there() -> None:
    memory = PolicyMemory(costs={f"m{i}": {"edge": 0.05} for i in range(6)})
    away = {f"m{i}": costed(0.01) for i in range(6)}  # cheaper in the cloud: not the measure
    config = PolicyConfig(
        tiers=("edge", "cloud"), tier_latency_ms={"cloud": 40.0}, calm_seconds=0, cooldown_seconds=0
    )
    calm = edge(60.0, {}, cpu=0.1, headroom=0.9)
    plan([calm, cloud(**away)], {}, config, memory, now=0)  # calm from now
    moves = plan([calm, cloud(**away)], {}, config, memory, now=1)
    # the headroom allows 0.81, the deadline (1 - 0.1) * (1 - 0.48 / 0.95) * 0.9 = 0.401:
    # 8 at 0.05 would fit; all 6 away come home, in one batch (max_moves_down is 1)
    room = 0.9 * (1 - 60 / 125 / 0.95) * 0.9
    assert math.floor(room / 0.05) >= 6
    assert len(moves) == 6 and {m.reason for m in moves} == {"calm below"}
    tight = edge(110.0, {}, cpu=0.1, headroom=0.9)  # 88%: room for (0.9)(0.074)(0.9) = 0.06
    memory = PolicyMemory(costs={f"m{i}": {"edge": 0.05} for i in range(6)})
    plan([tight, cloud(**away)], {}, config, memory, now=0)
    assert len(plan([tight, cloud(**away)], {}, config, memory, now=1)) == 1


def test_coming_home_a_monitor_counts_at_the_larger_of_its_cost_there_and_now() -> None:
    """What a monitor cost on the edge was last read while the edge was overloaded (the
    reason it moved): a handler that falls behind takes its messages in long batches,
    each message far cheaper than one at a time (bench/RESULTS.md: 5x at batch 100), so
    that under-reads what it costs at the robot's rates once the edge is calm. Where it
    runs now its handler keeps up. Home, it counts at the larger of the two (`make
    demo`: 233 planned home at 0.07 cores took the loop to 201% of its deadline, and
    went back up 4.8 s later)."""
    config = PolicyConfig(
        tiers=("edge", "cloud"), tier_latency_ms={"cloud": 40.0}, calm_seconds=0, cooldown_seconds=0
    )
    tight = edge(110.0, {}, cpu=0.1, headroom=0.9)  # 88%: room for (0.9)(0.074)(0.9) = 0.06
    for there, now, fit in ((0.01, 0.05, 1), (0.05, 0.01, 1), (0.01, 0.01, 5)):
        memory = PolicyMemory(costs={f"m{i}": {"edge": there} for i in range(6)})
        away = {f"m{i}": costed(now) for i in range(6)}
        plan([tight, cloud(**away)], {}, config, memory, now=0)
        assert len(plan([tight, cloud(**away)], {}, config, memory, now=1)) == fit, (there, now)


def test_what_comes_home_lets_the_deadlines_window_refill_before_it_counts() -> None:
    """Monitors brought home to the edge weigh on its deadline while their handoff
    settles (taking them over, subscribing again, the events held for them): the p95
    right after reads that, not what they cost. For one deadline_wait to settle and one
    for the window to refill, the edge's deadline does not send them up."""
    memory = PolicyMemory(costs={f"m{i}": {"edge": 0.05} for i in range(6)})
    away = {f"m{i}": costed(0.01) for i in range(6)}
    config = PolicyConfig(
        tiers=("edge", "cloud"), tier_latency_ms={"cloud": 40.0}, calm_seconds=0, cooldown_seconds=0
    )
    calm = edge(60.0, {}, cpu=0.1, headroom=0.9)
    plan([calm, cloud(**away)], {}, config, memory, now=0)
    assert len(plan([calm, cloud(**away)], {}, config, memory, now=1)) == 6
    wait = config.deadline_wait
    assert memory.deadline_moved["edge-1"] == 1 + wait
    home = {f"m{i}": costed(0.05) for i in range(6)}
    transient = edge(160.0, home, cpu=0.4, headroom=0.5)  # the handoff's own work, in the p95
    assert plan([transient, cloud()], {}, config, memory, now=1 + wait) == []
    assert plan([transient, cloud()], {}, config, memory, now=1 + 2 * wait - 0.1) == []
    assert len(plan([transient, cloud()], {}, config, memory, now=1 + 2 * wait)) > 0


def test_the_backlog_a_move_leaves_drains_before_the_deadline_counts_again() -> None:
    """A move for the deadline leaves outputs queued behind late ones; they drain after
    it, late, and fill the window. Once a poll reads the loop caught up (its newest
    makespan within the budget) the deadline waits deadline_wait after that, so the
    drained backlog's p95 sends nothing more up (make demo's orchestrated phase moved
    its last 196 monitors on it, 1.2 s after the loop was back on time). A loop never
    read caught up counts again after the first wait: the move was not enough."""
    wait = CONFIG.deadline_wait

    def late(p95_ms: float, last_ms: float, monitors: dict[str, MonitorLoad]) -> HandlerReport:
        reading = DeadlineReading(BUDGET, p95_ms / 1000, 40, 20, last_ms / 1000)
        return HandlerReport("edge-1", "edge", 0.5, 0.0, monitors, reading, 0.45)

    for caught_up in (True, False):
        memory = PolicyMemory()
        first = plan([late(160.0, 170.0, SIX), cloud()], {}, CONFIG, memory, now=0)
        assert first and len(first) < len(SIX)
        rest = {m: load for m, load in SIX.items() if m not in {mv.monitor for mv in first}}
        # the orchestrator: the handoff ended at 0.5
        deadline_moved(memory, "edge-1", 0.5)
        last = 110.0 if caught_up else 180.0
        assert plan([late(200.0, last, rest), cloud()], {}, CONFIG, memory, now=1.0) == []
        draining = late(190.0, 112.0 if caught_up else 175.0, rest)
        again = plan([draining, cloud()], {}, CONFIG, memory, now=0.5 + wait)
        assert bool(again) is not caught_up, caught_up
        if caught_up:
            assert plan([draining, cloud()], {}, CONFIG, memory, now=1.0 + wait - 0.1) == []
            assert plan([draining, cloud()], {}, CONFIG, memory, now=1.0 + wait)


def test_inside_the_band_nothing_moves_either_way() -> None:
    config = PolicyConfig(tiers=("edge", "cloud"), calm_seconds=0, cooldown_seconds=0)
    memory = PolicyMemory(costs={"a": {"edge": 0.05}})
    band = edge(122.0, SIX, cpu=0.5, headroom=0.45)  # 97.6%: between 95% and 100%
    assert plan([band, cloud(a=costed(0.05))], {}, config, memory, now=0) == []
    assert plan([band, cloud(a=costed(0.05))], {}, config, memory, now=5) == []


def load(
    t: float,
    cpu: float,
    monitors: dict[str, float],
    busy: float,
    total: float,
    outputs: int | None = None,
    taking: dict[str, float] | None = None,
) -> LoadReport:
    deadline: DeadlineLoad | None = None
    if outputs is not None:  # the deadline topic's messages so far, and a window's reading
        deadline = {
            "topic": "/cmd_vel", "budgetMs": 125.0, "windowSeconds": 2.0, "count": 16,
            "misses": 0, "p50Ms": 100.0, "p95Ms": 110.0, "maxMs": 112.0, "lastMs": 100.0,
            "missesTotal": 0, "messagesTotal": outputs,
        }  # fmt: skip
    return {
        "handler": "edge-1",
        "monotonic": t,
        "cpuSeconds": cpu,
        "host": {"cores": 2, "busySeconds": busy, "totalSeconds": total},
        "ingestLag": 0.0,
        "reachMs": None,
        "deadline": deadline,
        "topics": {t: {"messages": 0, "cpuSeconds": v} for t, v in (taking or {}).items()},
        "monitors": {
            m: {
                "active": True,
                "handoff": None,
                "epoch": 0,
                "peer": None,
                "events": 0,
                "cpuSeconds": s,
                "migrationWanted": False,
                "placement": {"tier": None, "migrate": "auto", "maxLatencyMs": None},
                "topics": ["/imu"] if m == "a" else ["/odom"],
            }
            for m, s in monitors.items()
        },
    }


def test_the_orchestrator_reads_each_monitors_cost_and_the_headroom_from_two_reports() -> None:
    target, previous = Target("edge", "e:1"), dict[Target, Counters]()
    first, _, _ = build_reports({target: load(10.0, 5.0, {"a": 1.0, "b": 2.0}, 100, 400)}, previous)
    assert first[0].headroom is None and first[0].monitors["a"].cpu is None  # one reading
    # 2 s later: a spent 0.2 s (0.1 core), b's counter restarted (it moved back: unknown);
    # the two CPUs were busy 1.0 of their 4.0 s: 1.5 cores idle, plus a's 0.1
    second, _, _ = build_reports(
        {target: load(12.0, 5.6, {"a": 1.2, "b": 0.1}, 101, 404)}, previous
    )
    report = second[0]
    assert math.isclose(report.monitors["a"].cpu or 0.0, 0.1)
    assert report.monitors["b"].cpu is None
    assert report.headroom is not None and math.isclose(report.headroom, 1.5 + 0.1)
    assert math.isclose(report.cpu, 0.3)


def test_a_topics_ingestion_is_the_handlers_cpu_besides_its_monitors_by_what_taking_it_cost() -> (
    None
):
    """Two reports 2 s apart: the handler spent 0.3 cores, its monitors 0.1 and 0.05: the
    0.15 besides them is its topics' ingestion, shared by what taking each cost (/imu
    0.03 CPU seconds, /odom 0.01): 0.1125 and 0.0375 cores; counted in the headroom."""
    target, previous = Target("edge", "e:1"), dict[Target, Counters]()
    taken = {"/imu": 1.0, "/odom": 0.5}
    build_reports({target: load(10.0, 5.0, {"a": 1.0, "b": 2.0}, 100, 400, taking=taken)}, previous)
    assert previous[target].taking == taken
    later = {"/imu": 1.03, "/odom": 0.51}
    second, _, _ = build_reports(
        {target: load(12.0, 5.6, {"a": 1.2, "b": 2.1}, 101, 404, taking=later)}, previous
    )
    report = second[0]
    assert report.monitors["a"].topics == ("/imu",)
    assert report.topics.keys() == {"/imu", "/odom"}
    assert math.isclose(report.topics["/imu"], 0.1125)
    assert math.isclose(report.topics["/odom"], 0.0375)
    assert report.headroom is not None and math.isclose(report.headroom, 1.5 + 0.3)
    # a monitor's cost unknown (its counter restarted): what is besides them is not known
    third, _, _ = build_reports(
        {target: load(14.0, 6.2, {"a": 1.4, "b": 0.0}, 102, 408, taking=later)}, previous
    )
    assert third[0].topics == {}


def test_the_real_time_tasks_work_per_output_is_what_its_cpus_did_besides_the_handler() -> None:
    """With --deadline: the CPUs' busy cores less the handler's, per message of the
    deadline topic (its outputs), over the same two reports."""
    target, previous = Target("edge", "e:1"), dict[Target, Counters]()
    build_reports({target: load(10.0, 5.0, {"a": 1.0}, 100, 400, outputs=80)}, previous)
    # 2 s: busy 3.0 of 4.0 CPU seconds (1.5 cores), the handler 0.3 cores; 16 outputs: 8/s
    second, _, _ = build_reports(
        {target: load(12.0, 5.6, {"a": 1.2}, 103, 404, outputs=96)}, previous
    )
    assert second[0].task_work is not None
    assert math.isclose(second[0].task_work, (1.5 - 0.3) / 8)
    none, _, _ = build_reports({target: load(14.0, 6.0, {"a": 1.4}, 104, 408)}, previous)
    assert none[0].task_work is None  # no deadline measured


def test_a_monitor_in_a_handoff_is_not_planned_home() -> None:
    """The planner's batch home is made of monitors that run where they are: one that a
    handoff is moving (another driver's, the operator's) stays out of it."""
    memory = PolicyMemory(costs={f"m{i}": {"edge": 0.01} for i in range(4)})
    away = {f"m{i}": costed(0.01) for i in range(4)}
    away["m0"] = MonitorLoad(active=True, events_per_second=50.0, cpu=0.01, in_handoff=True)
    config = PolicyConfig(
        tiers=("edge", "cloud"), tier_latency_ms={"cloud": 40.0}, calm_seconds=0, cooldown_seconds=0
    )
    calm = edge(60.0, {}, cpu=0.1, headroom=0.9)
    plan([calm, cloud(**away)], {}, config, memory, now=0)  # calm from now
    moves = plan([calm, cloud(**away)], {}, config, memory, now=1)
    assert sorted(m.monitor for m in moves) == ["m1", "m2", "m3"]
    assert all(m.plan for m in moves)  # planned, not today's rule
