"""The chart's part of the verification budget (issue 37): the budgeted tier's handlers
get a CPU limit to resize and a resize policy that restarts nothing, the operator the
settings and exactly the right it needs (pods/resize: get, patch), and nothing of it
without a budget. Offline: `helm template` only (helm as tests/cluster/build.sh builds
it, or $HELM)."""

from __future__ import annotations

import subprocess
from typing import Any

import yaml

from edgerv_operator.constants import HANDLER_CONTAINER
from kit.chart import CHART, helm


def template(*values: str) -> list[dict[str, Any]]:
    args = [helm(), "template", "r", str(CHART)]
    for value in values:
        args += ["--set", value]
    done = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return [d for d in yaml.safe_load_all(done.stdout) if d]


def handler_containers(docs: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    return {
        d["metadata"]["name"].rsplit("-", 1)[-1]: d["spec"]["template"]["spec"]["containers"][0]
        for d in docs
        if d["kind"] == "DaemonSet"
    }


def pod_rules(docs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    (role,) = [
        d for d in docs if d["kind"] == "Role" and d["metadata"]["name"] == "r-operator-pods"
    ]
    return list(role["rules"])


def test_the_chart_gives_the_budgeted_tier_a_limit_to_resize_and_the_operator_the_right() -> None:
    docs = template("operator.budget.tier=edge", "operator.budget.ceiling=0.75")
    containers = handler_containers(docs)
    edge, cloud = containers["edge"], containers["cloud"]
    assert edge["name"] == HANDLER_CONTAINER
    assert edge["resources"]["limits"]["cpu"] == "0.75"
    assert edge["resizePolicy"] == [{"resourceName": "cpu", "restartPolicy": "NotRequired"}]
    assert "cpu" not in cloud["resources"].get("limits", {}) and "resizePolicy" not in cloud
    assert {"apiGroups": [""], "resources": ["pods/resize"], "verbs": ["get", "patch"]} in (
        pod_rules(docs)
    )
    (operator,) = [d for d in docs if d["kind"] == "Deployment"]
    env = {
        e["name"]: e.get("value")
        for e in operator["spec"]["template"]["spec"]["containers"][0]["env"]
    }
    assert env["EDGERV_BUDGET_TIER"] == "edge" and env["EDGERV_BUDGET_CEILING"] == "0.75"
    # a limit the user gives the tier is where the budget starts
    given = handler_containers(
        template("operator.budget.tier=edge", "handler.tiers.edge.resources.limits.cpu=2")
    )
    assert given["edge"]["resources"]["limits"]["cpu"] == 2


def test_without_a_budget_no_limit_no_resize_and_no_right_to_it() -> None:
    docs = template()
    for container in handler_containers(docs).values():
        assert "cpu" not in container["resources"].get("limits", {})
        assert "resizePolicy" not in container
    assert all("pods/resize" not in r["resources"] for r in pod_rules(docs))
    (operator,) = [d for d in docs if d["kind"] == "Deployment"]
    names = {e["name"] for e in operator["spec"]["template"]["spec"]["containers"][0]["env"]}
    assert not any(n.startswith("EDGERV_BUDGET_") for n in names)


def test_the_values_schema_refuses_a_budget_that_is_not_a_number() -> None:
    args = [helm(), "template", "r", str(CHART), "--set", "operator.budget.ceiling=lots"]
    done = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert done.returncode != 0 and "ceiling" in done.stderr
