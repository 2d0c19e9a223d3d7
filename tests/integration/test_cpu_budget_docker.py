"""The edge handler's CPU budget set at run time (issue 37), on a robot without
Kubernetes: the handler's image runs as images/README.md's "docker run" says, 2,000
monitors over a topic a robot's node publishes 1,000 times a second (about a core's work
while nothing limits it), and :class:`~edgerv.control.cpu_budget.DockerCpuBudget`
lowers its CPU quota to 0.1 core, then raises it to 1 core, through the Docker SDK,
without a restart.

The container's CPU use (its cgroup's counters, read by the same budget) and the
handler's own (``cpuSeconds`` in ``GET /v1/load``) stay within each budget: a guarantee
of the kernel's CFS quota, measured over 3 s windows (MARGIN says how close). Under 0.1
core the handler says it cannot keep up, as it does today: its ingest lag in
``GET /v1/load`` reaches the planner's high mark (edgerv orchestrate's default
``lag_high``), it loses messages and its status on ``/diagnostics`` is WARN ("messages
lost before the handler took them"); under 1 core it catches up and the WARN clears.
Its monitors keep their state throughout (their steps go on from where they were; the
container's id, start and restart count do not change).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from edgerv.control.cpu_budget import CpuBudgetError, DockerCpuBudget, cores_between
from edgerv.control.placement import PolicyConfig
from kit import dockerimage
from kit.cpu_budget import (
    Diagnostics,
    HandlerContainer,
    handler_container,
    load_monitors,
    load_publisher,
)
from kit.ros import wait_for

pytestmark = pytest.mark.integration

MONITORS = 2000
RATE = 1000.0  # messages a second
LOW, HIGH = 0.1, 1.0  # cores
WINDOW = 3.0  # seconds of each measure
# The most a window may read above its budget: the kernel's CFS quota holds each 100 ms
# period, and a 3 s window cut across periods may hold up to one period's quota more at
# each end (0.1 core: 0.2/3, 7%); measured: 0.100 to 0.102 under 0.1 core.
MARGIN = 1.15
LAG_HIGH = PolicyConfig(tiers=("edge",)).lag_high  # where edgerv orchestrate sees pressure
LOST = "lost before the handler took them"


@pytest.fixture(scope="module")
def image() -> str:
    reason = dockerimage.why_no_docker()
    if reason is not None:
        pytest.skip(f"Docker cannot run here: {reason}")
    return dockerimage.handler_image()


@pytest.fixture
def loaded(
    image: str, tmp_path: Path, domain: int
) -> Iterator[tuple[HandlerContainer, Diagnostics]]:
    """The handler's container with the monitors, the robot publishing, its /diagnostics
    listened to; all stopped and removed at the end."""
    with handler_container(tmp_path, domain, image, load_monitors(MONITORS)) as handler:
        diagnostics = Diagnostics(domain)
        robot = load_publisher(domain, RATE)
        try:
            assert robot.stdout is not None
            assert robot.stdout.readline().strip() == "matched", handler.logs()
            yield handler, diagnostics
        finally:
            robot.kill()
            robot.wait()
            diagnostics.stop()


def inspect(name: str) -> dict[str, Any]:
    return json.loads(dockerimage.docker("inspect", name).stdout)[0]  # type: ignore[no-any-return]


def steps(handler: HandlerContainer) -> dict[str, int]:
    monitors = handler.get("/v1/monitors")["monitors"]
    assert all(m["active"] and m["state"] == "pending" for m in monitors), monitors[:3]
    return {m["name"]: m["step"] for m in monitors}


def measure(budget: DockerCpuBudget, handler: HandlerContainer) -> tuple[float, float, int]:
    """Over WINDOW seconds: the cores the container used (its cgroup), those the handler
    says it used (its process), and the CFS periods in which the quota ran out."""
    before, load_before = budget.use(), handler.get("/v1/load")
    time.sleep(WINDOW)
    after, load_after = budget.use(), handler.get("/v1/load")
    own = (load_after["cpuSeconds"] - load_before["cpuSeconds"]) / (
        load_after["monotonic"] - load_before["monotonic"]
    )
    throttled = after.throttled_periods - before.throttled_periods
    return cores_between(before, after), own, throttled


def lag(handler: HandlerContainer) -> float:
    return float(handler.get("/v1/load")["ingestLag"])


def lag_once(handler: HandlerContainer, high: bool, timeout: float = 30) -> float:
    """The handler's ingest lag once it is at or above LAG_HIGH (``high``), or below it,
    within ``timeout`` seconds; an AssertionError with the last reading if not."""
    seen: list[float] = []
    wait_for(lambda: seen.append(lag(handler)) or (seen[-1] >= LAG_HIGH) == high, timeout)
    assert (seen[-1] >= LAG_HIGH) == high, f"ingest lag {seen[-1]:.3f} s, high mark {LAG_HIGH} s"
    return seen[-1]


def test_the_budget_set_at_run_time_bounds_the_handlers_cpu_and_it_says_when_it_falls_behind(
    loaded: tuple[HandlerContainer, Diagnostics],
) -> None:
    handler, diagnostics = loaded
    budget = DockerCpuBudget(handler.name)
    try:
        started = inspect(handler.name)
        assert budget.cores() == budget.ceiling  # the recipe sets no limit
        assert budget.floor <= LOW < HIGH <= budget.ceiling
        wait_for(lambda: min(steps(handler).values()) > 0, timeout=30)
        free, free_own, _ = measure(budget, handler)
        before = steps(handler)

        # lowered: the kernel holds the container to it, and the handler falls behind
        assert budget.set_cores(LOW) == LOW
        low_at = time.monotonic()
        assert budget.cores() == LOW
        limits = inspect(handler.name)["HostConfig"]
        assert (limits["CpuPeriod"], limits["CpuQuota"]) == (100_000, 10_000)
        time.sleep(1.0)
        low, low_own, throttled = measure(budget, handler)
        assert throttled > 0, "the quota never ran out: the handler had no work to be held from"
        lagged = lag_once(handler, high=True)
        warned = wait_for(
            lambda: [
                s
                for s in diagnostics.between(low_at, time.monotonic())
                if s["level"] == 1 and LOST in s["message"]
            ],
            timeout=30,
        )
        assert warned, diagnostics.statuses[-5:]
        during = steps(handler)

        # raised: it uses more than the low budget, catches up, and the warning clears
        assert budget.set_cores(HIGH) == HIGH
        high_at = time.monotonic()
        assert budget.cores() == HIGH
        time.sleep(1.0)
        high, high_own, _ = measure(budget, handler)
        caught_up = lag_once(handler, high=False)
        calm = wait_for(
            lambda: [
                s for s in diagnostics.between(high_at + 1, time.monotonic()) if s["level"] == 0
            ],
            timeout=30,
        )
        assert calm, diagnostics.statuses[-5:]
        after = steps(handler)
    finally:
        budget.close()

    print(
        f"\n{MONITORS} monitors at {RATE:g} messages/s; cores used over {WINDOW:g} s "
        f"(container's cgroup / handler's own): no limit {free:.3f} / {free_own:.3f}; "
        f"budget {LOW:g}: {low:.3f} / {low_own:.3f} (ingest lag {lagged:.2f} s, "
        f"WARN '{warned[0]['message']}'); budget {HIGH:g}: {high:.3f} / {high_own:.3f} "
        f"(ingest lag back to {caught_up:.3f} s)"
    )
    assert low <= LOW * MARGIN and low_own <= LOW * MARGIN, (low, low_own)
    assert high <= HIGH * MARGIN and high_own <= HIGH * MARGIN, (high, high_own)
    assert high > 3 * LOW and high_own > 3 * LOW, (high, high_own)

    # the same container and process all along; each monitor went on from its step
    now = inspect(handler.name)
    assert now["Id"] == started["Id"] == budget.container_id
    assert now["State"]["StartedAt"] == started["State"]["StartedAt"]
    assert now["RestartCount"] == 0 and now["State"]["Pid"] == started["State"]["Pid"]
    assert set(before) == set(during) == set(after)
    assert all(before[m] < during[m] < after[m] for m in before), [
        (m, before[m], during[m], after[m]) for m in list(before)[:5]
    ]


def test_a_budget_says_what_to_do_when_it_cannot_be_set(image: str, tmp_path: Path) -> None:
    with pytest.raises(CpuBudgetError, match="no container 'edgerv-no-such-container'"):
        DockerCpuBudget("edgerv-no-such-container")
    # a container limited by --cpus: Docker changes that limit only as --cpus
    name = f"edgerv-cpus-{os.getpid()}"
    dockerimage.docker("rm", "--force", name, check=False)
    dockerimage.docker(
        "run", "--detach", "--name", name, "--network", "none", "--cpus", "0.5",
        "--entrypoint", "sleep", image, "60",
    )  # fmt: skip
    try:
        budget = DockerCpuBudget(name)
        try:
            assert budget.cores() == 0.5
            with pytest.raises(CpuBudgetError, match="started with --cpus"):
                budget.set_cores(0.2)
            assert budget.cores() == 0.5
        finally:
            budget.close()
    finally:
        dockerimage.docker("rm", "--force", name, check=False)
