"""The verification budget on Kubernetes (issue 37): the operator's settings for it, the
CPU quantities it reads and writes, a lever a budgeted handler pod. The chart's part:
tests/e2e/test_chart_budget.py; the resize itself, on the project's cluster:
tests/e2e/test_budget_resize.py."""

from __future__ import annotations

import re
import socket
from typing import Any

import pytest

from edgerv.control.cpu_budget import CpuBudgetError
from edgerv.control.orchestrate import Target
from edgerv.core.planner import BudgetConfig
from edgerv_operator.budget import Levers, PodCpuBudget, cpu_cores, cpu_quantity, infeasible
from edgerv_operator.config import ConfigError, OperatorConfig
from edgerv_operator.constants import (
    BUDGET_CEILING,
    BUDGET_FLOOR,
    BUDGET_HYSTERESIS,
    BUDGET_WAIT,
)
from edgerv_operator.documents import HandlerPod

ENV = {"EDGERV_TOKEN": "t", "EDGERV_NAMESPACE": "edgerv", "EDGERV_PLAIN_HTTP": "true"}


@pytest.mark.parametrize(
    ("text", "cores"),
    [("500m", 0.5), ("1", 1.0), ("1.5", 1.5), ("0.25", 0.25), ("100m", 0.1), (".5", 0.5)],
)
def test_cpu_quantities_read_as_cores(text: str, cores: float) -> None:
    assert cpu_cores(text) == pytest.approx(cores)
    assert cpu_cores(cpu_quantity(cores)) == pytest.approx(cores)


@pytest.mark.parametrize("text", ["", "m", "1Gi", "-1", "1e3", "half", "1.5.1", "10mm"])
def test_what_is_not_a_cpu_quantity_is_refused(text: str) -> None:
    with pytest.raises(ValueError, match="not a CPU quantity"):
        cpu_cores(text)


def test_a_budget_is_written_in_millicores_never_below_one() -> None:
    assert cpu_quantity(0.5) == "500m"
    assert cpu_quantity(0.1234) == "123m"
    assert cpu_quantity(0.0001) == "1m"


def test_no_budget_unless_a_tier_is_named() -> None:
    config = OperatorConfig.from_env(ENV)
    assert (config.budget_tier, config.budget) == ("", None)


def test_the_budgets_settings_and_their_defaults() -> None:
    config = OperatorConfig.from_env({**ENV, "EDGERV_BUDGET_TIER": "edge"})
    assert config.budget_tier == "edge"
    assert config.budget == BudgetConfig(
        BUDGET_FLOOR, BUDGET_CEILING, BUDGET_HYSTERESIS, BUDGET_WAIT
    )
    given = OperatorConfig.from_env(
        {
            **ENV,
            "EDGERV_BUDGET_TIER": "edge",
            "EDGERV_BUDGET_FLOOR": "0.2",
            "EDGERV_BUDGET_CEILING": "1.5",
            "EDGERV_BUDGET_HYSTERESIS": "0.05",
            "EDGERV_BUDGET_WAIT": "4",
        }
    )
    assert given.budget == BudgetConfig(0.2, 1.5, 0.05, 4.0)


@pytest.mark.parametrize(
    ("env", "error"),
    [
        ({"EDGERV_BUDGET_TIER": "fog"}, "EDGERV_BUDGET_TIER: 'fog' is not one of EDGERV_TIERS"),
        (
            {"EDGERV_BUDGET_TIER": "edge", "EDGERV_BUDGET_CEILING": "lots"},
            "EDGERV_BUDGET_CEILING: 'lots' is not a number",
        ),
        (
            {"EDGERV_BUDGET_TIER": "edge", "EDGERV_BUDGET_FLOOR": "2"},
            "floor <= ceiling",
        ),
        (
            {"EDGERV_BUDGET_TIER": "edge", "EDGERV_BUDGET_HYSTERESIS": "1"},
            "hysteresis < 1",
        ),
    ],
)
def test_a_bad_budget_setting_names_its_variable(env: dict[str, str], error: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(error)):
        OperatorConfig.from_env({**ENV, **env})


def pod(name: str, tier: str, restarts: int = 0) -> HandlerPod:
    return HandlerPod(name, tier, f"{name}:8470", f"h-{name}", f"uid-{name}/{restarts}")


def test_a_lever_for_each_handler_of_the_budgeted_tier_kept_while_its_pod_runs() -> None:
    made: list[object] = []

    def make_api() -> object:
        made.append(object())  # (a CoreV1Api: no call is made by choosing the levers)
        return made[-1]

    bounds = BudgetConfig(0.1, 1.0)
    levers = Levers("edge", bounds, "ns", make_api, lambda p: Target(p.tier or "", p.address))
    assert levers.of([pod("cloud", "cloud")]) == [] and made == []  # no API until needed
    first = levers.of([pod("a", "edge"), pod("b", "edge"), pod("cloud", "cloud")])
    assert [lever.handler for lever in first] == [
        Target("edge", "a:8470"),
        Target("edge", "b:8470"),
    ]
    assert all(isinstance(lever.budget, PodCpuBudget) for lever in first)
    assert [lever.budget.pod for lever in first] == ["h-a", "h-b"]  # type: ignore[attr-defined]
    assert all(lever.bounds == bounds for lever in first) and len(made) == 1
    first[0].changed_at = 12.0  # its history: when the planner last changed it
    again = levers.of([pod("a", "edge"), pod("b", "edge", restarts=1)])
    assert again[0] is first[0] and again[0].changed_at == 12.0
    assert again[1] is not first[1]  # a restarted handler: a lever of its own
    assert levers.of([]) == []


def handler_pod_with(limits: dict[str, str] | None, name: str = "handler") -> Any:
    """A pod as the API client gives it (kubernetes.client's own types)."""
    from kubernetes import client

    resources = client.V1ResourceRequirements(requests={"cpu": "100m"}, limits=limits)
    container = client.V1Container(name=name, image="edgerv/handler:dev", resources=resources)
    return client.V1Pod(spec=client.V1PodSpec(containers=[container]))


def test_the_budget_read_is_the_handler_containers_cpu_limit_as_it_is() -> None:
    budget = PodCpuBudget(None, "ns", "h-a", 0.1, 0.5)
    assert budget._limit(handler_pod_with({"cpu": "250m", "memory": "1Gi"})) == 0.25
    # above the ceiling as it is (the planner brings it within), none: the ceiling
    assert budget._limit(handler_pod_with({"cpu": "1"})) == 1.0
    assert budget._limit(handler_pod_with({"memory": "1Gi"})) == 0.5
    assert budget._limit(handler_pod_with(None)) == 0.5
    with pytest.raises(CpuBudgetError, match="no container 'handler'"):
        budget._limit(handler_pod_with({"cpu": "1"}, name="sidecar"))
    with pytest.raises(CpuBudgetError, match="'lots' is not a CPU quantity"):
        budget._limit(handler_pod_with({"cpu": "lots"}))


def test_an_infeasible_resize_reads_as_the_limit_in_force_and_says_why() -> None:
    """The kubelet refuses a resize for good (PodResizePending, Infeasible: the node has
    not the CPU): the spec says 2 cores, the container runs with 0.5; the budget read is
    the 0.5 in force, and why is said. Deferred is the kubelet's to finish."""
    from kubernetes import client

    pod = handler_pod_with({"cpu": "2"})
    running = client.V1ContainerStatus(
        name="handler",
        image="edgerv/handler:dev",
        image_id="",
        ready=True,
        restart_count=0,
        resources=client.V1ResourceRequirements(limits={"cpu": "500m"}),
    )
    pending = client.V1PodCondition(
        type="PodResizePending",
        status="True",
        reason="Infeasible",
        message="Node didn't have enough capacity: cpu, requested: 2000, capacity: 1000",
    )
    pod.status = client.V1PodStatus(conditions=[pending], container_statuses=[running])
    budget = PodCpuBudget(None, "ns", "h-a", 0.1, 4.0)
    assert infeasible(pod) == pending.message
    assert budget._in_force(pod) == 0.5 and budget._limit(pod) == 2.0
    pending.reason = "Deferred"
    assert infeasible(pod) is None
    pod.status.container_statuses = None  # (a kubelet that does not say): the spec's
    assert budget._in_force(pod) == 2.0


def test_an_api_server_that_does_not_answer_is_a_budget_error_not_a_crash() -> None:
    """The kubernetes client's own errors (a refused connection) become the CpuBudgetError
    the orchestrator reports as a record, and its rounds go on."""
    from kubernetes import client

    with socket.socket() as s:  # a port nothing listens on, on loopback
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    config = client.Configuration()
    config.host = f"http://127.0.0.1:{port}"
    config.retries = 0
    budget = PodCpuBudget(client.CoreV1Api(client.ApiClient(config)), "ns", "h-a", 0.1, 0.5)
    with pytest.raises(CpuBudgetError, match="the API server did not answer"):
        budget.cores()
    with pytest.raises(CpuBudgetError, match="the API server did not answer"):
        budget.set_cores(0.3)
