"""A shared handler's room filled least-served robot first (edgerv.core.fair_share), and
the placement policy sharing a cloud handler between robots under pressure (issue 36:
"the cloud handler's load is shared fairly between robots")."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from edgerv.control.placement import (
    DeadlineReading,
    HandlerReport,
    MonitorLoad,
    PolicyConfig,
    PolicyMemory,
    plan,
)
from edgerv.core.documents import Placement
from edgerv.core.fair_share import fill

costs = st.floats(min_value=0.0, max_value=1.0, allow_nan=False)
robots = st.sampled_from(["amr-a", "amr-b", "amr-c", "amr-d"])
asks = st.dictionaries(
    robots,
    st.lists(st.tuples(st.sampled_from("pqrstuvw"), costs), unique_by=lambda i: i[0]),
    min_size=1,
)


@given(costs.map(lambda c: 2 * c), st.dictionaries(robots, costs), asks)
@settings(max_examples=400, deadline=None)
def test_the_room_is_never_passed_nor_left_to_waste(
    room: float, running: dict[str, float], asked: dict[str, list[tuple[str, float]]]
) -> None:
    kept = fill(room, running, asked)
    total = sum(c for items in asked.values() for _, c in items)
    if kept is None:  # the room holds all: nobody is held back
        assert total <= room
        return
    assert total > room
    assert set(kept) == set(asked)
    used = 0.0
    for r, names in kept.items():
        cost = dict(asked[r])
        assert names == [n for n, _ in asked[r] if n in names]  # in the order asked
        used += sum(cost[n] for n in names)
    assert used <= room + 1e-9
    # work-conserving: no monitor held back would still fit in what is left
    for r, items in asked.items():
        for n, c in items:
            if n not in kept[r]:
                assert c > room - used - 1e-9


@given(st.integers(1, 12), st.integers(1, 12), st.sampled_from([0.0625, 0.125, 0.25, 0.5]))
def test_robots_asking_alike_get_alike_within_one_monitor(n_a: int, n_b: int, c: float) -> None:
    asked = {
        "amr-a": [(f"a{i}", c) for i in range(n_a)],
        "amr-b": [(f"b{i}", c) for i in range(n_b)],
    }
    room = c * ((n_a + n_b) // 2)  # (exact in binary: no rounding decides a fit)
    kept = fill(room, {}, asked)
    if kept is None:
        assert n_a + n_b == 0
        return
    a, b = len(kept["amr-a"]), len(kept["amr-b"])
    assert a + b == (n_a + n_b) // 2  # the room, all of it
    # an even split, but for a robot that asked for less than its half
    assert abs(a - b) <= 1 or a == n_a or b == n_b


def test_what_a_robot_runs_there_already_counts_in_its_share() -> None:
    asked = {"amr-a": [("a1", 0.2), ("a2", 0.2)], "amr-b": [("b1", 0.2), ("b2", 0.2)]}
    # a runs 0.4 there already: b is served first and takes the room
    assert fill(0.4, {"amr-a": 0.4}, asked) == {"amr-a": [], "amr-b": ["b1", "b2"]}
    # nobody there: one each
    assert fill(0.4, {}, asked) == {"amr-a": ["a1"], "amr-b": ["b1"]}


def test_each_robot_sends_its_cheapest_first_so_that_more_robots_get_relief() -> None:
    asked = {"amr-a": [("small", 0.0625), ("big", 0.25)], "amr-b": [("b1", 0.5)]}
    # a's small, then b's one (b is served least), and a's big no longer fits
    assert fill(0.625, {}, asked) == {"amr-a": ["small"], "amr-b": ["b1"]}
    # room for a's two but not for b's: a's two (nothing fits of b's)
    assert fill(0.375, {}, asked) == {"amr-a": ["small", "big"], "amr-b": []}


# -- the policy: two robots under deadline pressure, one cloud --------------------------------

CONFIG = PolicyConfig(tiers=("edge", "cloud"), tier_latency_ms={"edge": 0.0, "cloud": 40.0})
LATE = DeadlineReading(budget=0.125, p95=0.25, count=40, misses=40)
# six instances on each robot's edge; a6 and a7 are a's, run in the cloud in one test
PLACEMENTS = {f"{r}{i}": Placement(robot=r) for r in ("a", "b") for i in range(8)}


def edge(robot: str, cost: float) -> HandlerReport:
    """A robot's edge missing its deadline, its six monitors each measured at ``cost``."""
    monitors = {
        f"{robot}{i}": MonitorLoad(active=True, events_per_second=100.0, cpu=cost) for i in range(6)
    }
    return HandlerReport(
        f"edge-{robot}", "edge", 0.3, monitors=monitors, deadline=LATE, robot=robot
    )


def cloud(cpu: float, **monitors: MonitorLoad) -> HandlerReport:
    return HandlerReport("cloud", "cloud", cpu, monitors=monitors)


def up_by_robot(handlers: list[HandlerReport]) -> dict[str, int]:
    config = PolicyConfig(tiers=CONFIG.tiers, tier_latency_ms=CONFIG.tier_latency_ms, planner=False)
    moves = plan(handlers, PLACEMENTS, config, PolicyMemory(), now=0.0)
    assert all(m.destination == "cloud" and m.reason == "deadline" for m in moves), moves
    counts = {"a": 0, "b": 0}
    for m in moves:
        counts[m.monitor[0]] += 1
    return counts


def test_two_robots_late_at_once_share_the_clouds_room() -> None:
    # each would shed half its movable load (3 of 6 at 0.05 cores: 0.15); the cloud's room
    # below its target (0.7) is 0.21: two each, not three for the first and one for the other
    assert up_by_robot([edge("a", 0.05), edge("b", 0.05), cloud(0.49)]) == {"a": 2, "b": 2}
    # room for both: as before
    assert up_by_robot([edge("a", 0.05), edge("b", 0.05), cloud(0.1)]) == {"a": 3, "b": 3}
    # one robot alone takes what it must shed: its deadline before the cloud's target
    assert up_by_robot([edge("a", 0.05), cloud(0.6)]) == {"a": 3, "b": 0}


def test_a_robot_that_holds_the_cloud_already_waits_while_the_other_is_served() -> None:
    held = {f"a{i}": MonitorLoad(active=True, events_per_second=100.0, cpu=0.05) for i in (6, 7)}
    # room 0.16 below the target; a runs 0.1 there already: b is served first, b two, a one
    assert up_by_robot([edge("a", 0.05), edge("b", 0.05), cloud(0.54, **held)]) == {
        "a": 1,
        "b": 2,
    }


def test_costs_not_measured_yet_are_not_shared() -> None:
    """Before the monitors' costs are measured the rule's shed goes up as before."""
    unmeasured = [
        HandlerReport(
            h.name,
            h.tier,
            h.cpu,
            monitors={m: MonitorLoad(active=True, events_per_second=100.0) for m in h.monitors},
            deadline=h.deadline,
            robot=h.robot,
        )
        for h in (edge("a", 0.05), edge("b", 0.05))
    ]
    assert up_by_robot([*unmeasured, cloud(0.69)]) == {"a": 3, "b": 3}
