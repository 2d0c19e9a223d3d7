"""The budget lever (issue 37): the edge handler's CPU budget from its reading
(:func:`edgerv.core.planner.handler_budget`, by its properties), the flags of
``edgerv orchestrate --budget-container``, and the orchestrator setting a budget each
round through an object of edgerv's :class:`~edgerv.control.cpu_budget.CpuBudget`
protocol (tests/integration/test_cpu_budget_docker.py sets one on a real daemon)."""

from __future__ import annotations

import argparse
import sys
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from edgerv.control.client import HandlerClient
from edgerv.control.cpu_budget import CpuBudget, CpuBudgetError
from edgerv.control.orchestrate import BudgetLever, Orchestrator, Target
from edgerv.control.orchestrate_command import (
    add_arguments,
    budget_lever,
    config_from,
    parse_budget_container,
    parse_handlers,
    run,
)
from edgerv.control.placement import PolicyConfig
from edgerv.control.wire import LoadReport, parse_load
from edgerv.core.diagnostics import InputError
from edgerv.core.planner import BudgetConfig, EdgeState, PlannerConfig, handler_budget
from kit.counts import props

C = PlannerConfig()  # high 1.0, low 0.95, margin 0.1


def reading(ratio: float | None, h: float | None = 0.3, headroom: float = 1.0) -> EdgeState:
    return EdgeState(
        headroom=headroom,
        deadline=0.1,
        p95=None if ratio is None else ratio * 0.1,
        cloud_latency_ms=0.0,
        handler_cpu=h,
    )


@st.composite
def cases(draw: st.DrawFn) -> tuple[EdgeState, float, BudgetConfig, float]:
    """A reading, the budget in force, the bounds, the monitors' cores in the headroom."""
    floor = draw(st.floats(0.01, 1.0))
    bounds = BudgetConfig(
        floor=floor,
        ceiling=draw(st.floats(floor, 4.0)),
        hysteresis=draw(st.sampled_from([0.0, 0.1, 0.3])),
    )
    h = draw(st.floats(0.0, 1.0))
    state = reading(draw(st.floats(0.0, 2.0)), h, draw(st.floats(0.0, 4.0)))
    return state, draw(st.floats(0.001, 5.0)), bounds, draw(st.floats(0.0, h))


def held(current: float, b: BudgetConfig) -> float:
    return min(max(current, b.floor), b.ceiling)


@props(300)
@given(cases())
def test_the_budget_stays_within_its_bounds(
    case: tuple[EdgeState, float, BudgetConfig, float],
) -> None:
    state, current, bounds, verification = case
    decided = handler_budget(state, current, bounds, C, verification)
    assert bounds.floor <= decided.cores <= bounds.ceiling
    assert decided.previous == current
    if current == held(current, bounds) and decided.changed:  # beyond the hysteresis only
        assert abs(decided.cores - current) > bounds.hysteresis * current


@props(300)
@given(cases())
def test_at_risk_the_budget_is_lowered_to_the_calm_mark_never_raised(
    case: tuple[EdgeState, float, BudgetConfig, float],
) -> None:
    state, current, bounds, verification = case
    ratio, h = state.ratio, state.handler_cpu
    assert ratio is not None and h is not None
    if ratio < C.high:
        state = reading(C.high + ratio / 2, h, state.headroom)
        ratio = state.ratio
        assert ratio is not None
    was = held(current, bounds)
    decided = handler_budget(state, was, bounds, C, verification)
    assert decided.cores <= was
    calm_mark = 1 - (1 - h) * ratio / C.low  # processor sharing: the p95 at the calm mark
    if max(bounds.floor, calm_mark) < was * (1 - bounds.hysteresis):
        assert decided.cores == pytest.approx(max(bounds.floor, calm_mark))
        assert decided.cores < was


@props(300)
@given(cases())
def test_calm_with_headroom_raises_it_up_to_what_the_tasks_leave_less_the_margin(
    case: tuple[EdgeState, float, BudgetConfig, float],
) -> None:
    state, current, bounds, verification = case
    ratio, h = state.ratio, state.handler_cpu
    assert ratio is not None and h is not None
    if ratio > C.low:
        state = reading(ratio * C.low / 2, h, state.headroom)
        ratio = state.ratio
        assert ratio is not None
    was = held(current, bounds)
    decided = handler_budget(state, was, bounds, C, verification)
    share = (state.headroom + h - verification) * (1 - C.margin)  # what the tasks leave
    keeps = h + (1 - h) * (1 - ratio / C.low) * (1 - C.margin)  # the p95 under the mark
    target = min(bounds.ceiling, max(bounds.floor, h, min(share, keeps)))
    if decided.changed:
        assert decided.cores == pytest.approx(target, abs=1e-6)
        assert decided.cores >= min(max(h, bounds.floor), bounds.ceiling)  # never throttled
    if target > was * (1 + bounds.hysteresis) + 1e-6:
        assert decided.cores > was


@props(200)
@given(cases(), st.floats(0.0, 1.99))
def test_in_the_band_without_a_reading_or_within_the_wait_it_stays(
    case: tuple[EdgeState, float, BudgetConfig, float], since: float
) -> None:
    state, current, bounds, verification = case
    was = held(current, bounds)
    band = reading((C.low + C.high) / 2, state.handler_cpu, state.headroom)
    for edge in (band, None, reading(None), reading(1.5, h=None)):
        assert not handler_budget(edge, was, bounds, C, verification).changed
    assert not handler_budget(state, was, bounds, C, verification, since_change=since).changed


def test_a_budget_outside_the_bounds_is_brought_in_at_once() -> None:
    bounds = BudgetConfig(floor=0.1, ceiling=1.0)
    decided = handler_budget(None, 2.0, bounds, C, since_change=0.0)  # no quota: the machine's
    assert (decided.cores, decided.previous, decided.changed) == (1.0, 2.0, True)
    assert "outside [0.1, 1]" in decided.reason
    assert handler_budget(None, 0.01, bounds, C).cores == 0.1


def test_the_paper_numbers() -> None:
    """The handler at 0.3 cores and the p95 at 110% of its deadline: 0.189 cores bring it
    to 95% (0.7 * 1.1 / 0.95 = 0.81 of the CPU left to the task); calm at 70% and 0.15
    cores, it may rise to 0.351 (what keeps the p95 under 95%, less the margin)."""
    bounds = BudgetConfig(floor=0.05, ceiling=2.0)
    down = handler_budget(reading(1.1, h=0.3), 2.0, bounds, C, 0.2)
    assert down.cores == pytest.approx(1 - 0.7 * 1.1 / 0.95) and "at risk" in down.reason
    up = handler_budget(reading(0.7, h=0.15), down.cores, bounds, C, 0.2)
    assert up.cores == pytest.approx(0.15 + 0.85 * (1 - 0.7 / 0.95) * 0.9, abs=1e-6)
    assert "met" in up.reason and "->" in up.reason
    starved = handler_budget(reading(1.5, h=0.1), 1.0, bounds, C)  # even 0 would not do
    assert starved.cores == 0.05 and "floor 0.05" in starved.reason


def test_bounds_out_of_range_are_refused() -> None:
    for floor, ceiling, hysteresis, wait in [
        (0.0, 1.0, 0.1, 2.0),
        (2.0, 1.0, 0.1, 2.0),
        (0.1, float("inf"), 0.1, 2.0),
        (0.1, 1.0, 1.0, 2.0),
        (0.1, 1.0, 0.1, -1.0),
    ]:
        with pytest.raises(ValueError, match="need"):
            BudgetConfig(floor, ceiling, hysteresis, wait)


class Quota:
    """A CPU budget as edgerv's protocol has it, held in memory: what a cgroup's quota
    would be (``refuse``: the error its daemon would give, raised by set_cores)."""

    def __init__(self, floor: float = 0.05, ceiling: float = 2.0, cores: float = 2.0) -> None:
        self._floor, self._ceiling, self.now = floor, ceiling, cores
        self.refuse = ""
        self.made: list[tuple[str, float]] = []

    @property
    def floor(self) -> float:
        return self._floor

    @property
    def ceiling(self) -> float:
        return self._ceiling

    def cores(self) -> float:
        return self.now

    def set_cores(self, cores: float) -> float:
        if self.refuse:
            raise CpuBudgetError(self.refuse)
        self.now = round(min(max(cores, self._floor), self._ceiling), 5)  # a quota's rounding
        return self.now


_QUOTA_IS_A_BUDGET: type[CpuBudget] = Quota  # (mypy checks the protocol is kept)


class LoadReports(HandlerClient):
    """A handler's API as the orchestrator reads it: the load reports given, in turn."""

    def __init__(self, answers: list[LoadReport]) -> None:
        super().__init__("http://e", None)
        self.answers = answers

    def get(self, path: str, timeout: float = 10.0) -> object:
        return self.answers.pop(0)


def edge_load(t: float, cpu: float, busy: float, monitor_cpu: float, p95_ms: float) -> LoadReport:
    """The edge handler's load report: its CPU and its monitor's, its machine's (2 cores),
    its deadline (100 ms, 40 makespans)."""
    return parse_load(
        {
            "handler": "edge-1",
            "monotonic": t,
            "cpuSeconds": cpu,
            "monitors": {
                "m": {
                    "active": True,
                    "handoff": None,
                    "migrationWanted": False,
                    "events": int(t * 100),
                    "cpuSeconds": monitor_cpu,
                    "placement": {"migrate": "pinned"},
                }
            },
            "host": {"cores": 2, "busySeconds": busy, "totalSeconds": t * 2},
            "deadline": {"budgetMs": 100.0, "count": 40, "p95Ms": p95_ms},
        }
    )


def lever_round(wait: float, quota: Quota, loads: list[LoadReport]) -> tuple[Orchestrator, Target]:
    edge = Target("edge", "e:1")
    config = PolicyConfig(tiers=("edge", "cloud"), deadline_wait=wait)
    lever = BudgetLever(quota, edge, BudgetConfig(0.05, 2.0, wait=wait), "edgerv-edge")
    o = Orchestrator([edge], config, token=None, levers=[lever], on_idle=lambda idle: None)
    o.clients = {edge: LoadReports(loads)}
    return o, edge


def test_the_orchestrator_lowers_the_budget_at_risk_waits_then_raises_it_when_calm() -> None:
    quota = Quota()
    loads = [
        edge_load(10.0, 5.0, 10.0, 1.0, 110.0),
        # 2 s later: the handler 0.3 cores, its monitor 0.2; its CPUs 60% busy: 0.8 idle
        edge_load(12.0, 5.6, 12.4, 1.4, 110.0),
        edge_load(12.5, 5.7, 13.0, 1.5, 110.0),
    ]
    o, _ = lever_round(2.0, quota, loads)
    assert o.round() == []  # the first poll: no headroom known yet, the budget stays
    (lowered,) = o.round()
    assert lowered["budget"] == pytest.approx(1 - 0.7 * 1.1 / 0.95, abs=1e-4)
    assert (lowered["from"], lowered["handler"], lowered["container"]) == (
        2.0,
        "edge-1",
        "edgerv-edge",
    )
    assert lowered["ok"] and "at risk" in lowered["reason"] and lowered["at"] > 0
    assert list(lowered)[:4] == ["at", "budget", "from", "handler"]
    assert o.round() == []  # still at risk, but its window must refill first (2 s)
    assert quota.now == pytest.approx(lowered["budget"], abs=1e-4)

    quota = Quota(cores=0.19)
    loads = [
        edge_load(10.0, 5.0, 10.0, 1.0, 70.0),
        edge_load(12.0, 5.3, 12.4, 1.4, 70.0),  # calm at 70%: the handler 0.15 cores
    ]
    o, _ = lever_round(0.0, quota, loads)
    assert o.round() == []
    (raised,) = o.round()
    assert raised["budget"] == pytest.approx(0.15 + 0.85 * (1 - 0.7 / 0.95) * 0.9, abs=1e-4)
    assert raised["from"] == 0.19 and "met" in raised["reason"]


def test_a_budget_the_daemon_refuses_is_a_record_once_and_the_rounds_go_on() -> None:
    quota = Quota()
    quota.refuse = "the Docker daemon at x refused to set the CPU quota: no such cgroup"
    loads = [
        edge_load(10.0 + 2 * i, 5.0 + 0.6 * i, 10.0 + 2.4 * i, 1.0 + 0.4 * i, 110.0)
        for i in range(4)
    ]
    o, _ = lever_round(0.0, quota, loads)
    assert o.round() == []
    (failed,) = o.round()
    assert (failed["ok"], failed["error"], failed["handler"]) == (False, quota.refuse, "edge-1")
    assert o.round() == []  # the same error: said once
    quota.refuse = ""
    (lowered,) = o.round()
    assert lowered["ok"] and lowered["budget"] < 2.0


def orchestrate_args(*argv: str, handlers: str = "edge=e:1,cloud=c:1") -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_arguments(p)
    return p.parse_args(["--handlers", handlers, *argv])


def test_the_budget_container_names_its_handler() -> None:
    targets = parse_handlers("edge=e:1,cloud=c:1")
    assert parse_budget_container("edgerv-edge", targets, "edge") == ("edgerv-edge", targets[0])
    assert parse_budget_container("up = c:1", targets, "edge") == ("up", targets[1])
    for text, said in [
        ("x=z:9", "z:9 is not one of --handlers \\(e:1, c:1\\)"),
        ("=e:1", "'=e:1' is not CONTAINER or CONTAINER=HOST:PORT"),
        ("x=", "'x=' is not CONTAINER"),
    ]:
        with pytest.raises(InputError, match=f"--budget-container: error: {said}"):
            parse_budget_container(text, targets, "edge")
    two = parse_handlers("edge=e:1,edge=f:1,cloud=c:1")
    with pytest.raises(InputError, match="the lowest tier, edge, has 2 handlers \\(e:1, f:1\\)"):
        parse_budget_container("x", two, "edge")


def lever_of(*argv: str) -> BudgetLever | None:
    args = orchestrate_args(*argv)
    targets = parse_handlers(args.handlers)
    made: list[Quota] = []

    def budget_of(container: str, floor: float) -> CpuBudget:
        made.append(Quota(floor=floor, ceiling=2.0))
        return made[-1]

    return budget_lever(args, targets, config_from(args, targets), budget_of)


def test_the_budget_flags_set_the_bounds() -> None:
    assert lever_of() is None
    lever = lever_of("--budget-container", "edgerv-edge", "--deadline-wait", "3")
    assert lever is not None and lever.container == "edgerv-edge"
    assert lever.handler == Target("edge", "e:1")
    assert lever.bounds == BudgetConfig(floor=0.05, ceiling=2.0, hysteresis=0.1, wait=3.0)
    lever = lever_of(
        "--budget-container", "b", "--budget-floor", "0.2", "--budget-ceiling", "8",
        "--budget-hysteresis", "0.25",
    )  # fmt: skip
    assert lever is not None and lever.budget.floor == 0.2
    assert lever.bounds == BudgetConfig(floor=0.2, ceiling=2.0, hysteresis=0.25, wait=2.0)
    with pytest.raises(InputError, match="--budget-floor: error: needs --budget-container"):
        lever_of("--budget-floor", "0.2")
    with pytest.raises(InputError, match="--budget-ceiling: error: need 0 < floor <= ceiling"):
        lever_of("--budget-container", "b", "--budget-floor", "0.5", "--budget-ceiling", "0.2")
    with pytest.raises(SystemExit):  # argparse: not a fraction below 1
        orchestrate_args("--budget-hysteresis", "1.5x")


def test_without_the_docker_sdk_it_says_how_to_install_it(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setitem(sys.modules, "docker", None)  # (what an absent package imports as)
    assert run(orchestrate_args("--budget-container", "edgerv-edge", "--once")) == 2
    err = capsys.readouterr().err
    assert "--budget-container: error: the Docker SDK for Python is not installed" in err
    assert "pip install 'edgerv[planner]'" in err and "Traceback" not in err


def test_a_daemon_that_does_not_answer_is_an_input_error_at_start(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Any
) -> None:
    monkeypatch.setenv("DOCKER_HOST", f"unix://{tmp_path}/nobody.sock")
    assert run(orchestrate_args("--budget-container", "edgerv-edge", "--once")) == 2
    err = capsys.readouterr().err
    assert "--budget-container: error: the Docker daemon at unix://" in err
    assert "does not answer" in err and "Traceback" not in err
