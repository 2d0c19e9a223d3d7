"""The deadline planner (issue 37): the time to plan 450 monitors (the case study's
edge: 200 monitors at the robot's rates and 250 at the IMU's 200 Hz) and 10,000 (that mix
twenty-two times over), with the solver (SciPy's HiGHS milp, proven optimum) against the
greedy rule it falls back to (largest cost first up, smallest first home).

Each monitor's cost on the edge is its rate times a cost per event drawn around 3.5 us
(lognormal, sigma 0.5: small and large automata), seeded, so every run plans the same
instances. Up: all run on the edge, the p95 at 130% of the deadline, the headroom
leaving 60% of verification (40% to free). Home: all on the cloud, the p95 at 50%, room
for 40% of them. Each also with its topics' ingestion charged (each monitor reads its
rate's topic, /imu to /battery; a topic's ingestion its rate times 250 us, freed with its
last reader, paid with its first: ``EdgeState.topic_costs``). The plan's time is the
whole of ``plan_moves`` (best of ROUNDS, SciPy imported before); ``(monitors,
events/s)`` is what each moved.

``python bench/planner.py``: prints the table and the rows (bench/run_all.py's format).
"""

from __future__ import annotations

import itertools
import random
import time
from typing import Any

from edgerv.core.planner import (
    MICRO,
    EdgeState,
    MonitorCost,
    Plan,
    PlannerConfig,
    Tier,
    plan_moves,
)

ROUNDS = 3
SIZES = (450, 10_000)
RATES = (200.0, 50.0, 20.0, 8.0, 1.0)  # the robot's topics: /imu, /odom, /scan, camera, ...
TOPICS = {200.0: "/imu", 50.0: "/odom", 20.0: "/scan", 8.0: "/camera/image", 1.0: "/battery"}
# a topic's ingestion on the edge, whatever number of monitors read it: its rate times the
# CPU a message took besides the monitors in the demo's edge handler (about 250 us)
INGEST_PER_MESSAGE = 250e-6
CHARGES = {topic: rate * INGEST_PER_MESSAGE for rate, topic in TOPICS.items()}
BUDGET = 60.0  # seconds: time enough for the solver to prove its optimum
DEFAULT = PlannerConfig().time_budget


def fleet(n: int, tier: Tier, seed: int = 37) -> list[MonitorCost]:
    """``n`` monitors: 4 in 9 at the robot's rates, 5 in 9 at the IMU's 200 Hz."""
    rng = random.Random(seed)
    monitors = []
    for i in range(n):
        rate = rng.choice(RATES) if i % 9 < 4 else 200.0
        per_event = rng.lognormvariate(0, 0.5) * 3.5e-6  # seconds of CPU an event
        topics = (TOPICS[rate],)
        monitors.append(MonitorCost(f"m{i:05d}", tier, rate * per_event, rate, topics=topics))
    return monitors


def timed(monitors: list[MonitorCost], edge: EdgeState, budget: float) -> tuple[Plan, float]:
    best, plan = float("inf"), None
    for _ in range(ROUNDS):
        start = time.perf_counter()
        plan = plan_moves(monitors, edge, PlannerConfig(time_budget=budget))
        best = min(best, time.perf_counter() - start)
    assert plan is not None
    return plan, best


def moved(p: Plan) -> str:
    return f"{p.objective[0]} monitors, {p.events_milli / 1000:,.0f} events/s"


def main() -> list[dict[str, Any]]:
    plan_moves(fleet(9, "edge"), EdgeState(0.0, 0.1, 0.2, 40.0))  # import SciPy first
    rows: list[dict[str, Any]] = []
    table = [
        "| monitors | direction | greedy rule | milp (proven) | milp within the default "
        f"{DEFAULT:g} s |",
        "|---|---|---|---|---|",
    ]
    for n, direction, charged in itertools.product(SIZES, ("up", "home"), (False, True)):
        topics = CHARGES if charged else {}
        if direction == "up":
            monitors = fleet(n, "edge")
            total = sum(m.cost for m in monitors) + sum(topics.values())
            edge = EdgeState(0.6 * total / 0.9, 0.1, 0.13, 40.0, topic_costs=topics)
        else:
            monitors = fleet(n, "cloud")
            total = sum(m.cost for m in monitors) + sum(topics.values())
            edge = EdgeState(0.4 * total / 0.9, 0.1, 0.05, 40.0, topic_costs=topics)
        greedy, greedy_s = timed(monitors, edge, 0.0)
        exact, exact_s = timed(monitors, edge, BUDGET)
        default, default_s = timed(monitors, edge, DEFAULT)
        kind = f"{direction}, topics charged" if charged else direction
        table.append(
            f"| {n:,} | {kind} | {greedy_s * 1e3:,.1f} ms ({moved(greedy)}) "
            f"| {exact_s * 1e3:,.1f} ms, {exact.method} ({moved(exact)}) "
            f"| {default_s * 1e3:,.1f} ms, {default.method} ({moved(default)}) |"
        )
        rows.append(
            {
                "name": f"deadline planner, {n:,} monitors {kind}",
                "detail": f"{total:.3g} cores of verification, target "
                f"{exact.target_microcores / MICRO:.3g} cores (bench/planner.py); best of "
                f"{ROUNDS}; the default budget {DEFAULT:g} s: {default.method} in "
                f"{default_s * 1e3:,.0f} ms",
                "baseline": f"greedy rule {greedy_s * 1e3:,.1f} ms ({moved(greedy)})",
                "measured": f"milp {exact_s * 1e3:,.1f} ms, {exact.method} ({moved(exact)})",
                "ratio": f"{exact_s / greedy_s:,.0f}x the time; "
                f"{exact.events_milli / max(1, greedy.events_milli):.3f}x the events/s",
            }
        )
    print("\n".join(table))
    return rows


if __name__ == "__main__":
    for row in main():
        print(row)
