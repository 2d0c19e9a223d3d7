"""The verification budget set at run time on Kubernetes (issue 37): the operator, in the
cluster with the chart's rights, has the planner set the edge handler's CPU budget each
placement round, and a budget that changes resizes the handler's pod in place: the
kubelet changes its container's CFS quota, the container is not restarted, and its
monitors keep their state (their steps go on from where they were).

The planner's reading here is the robot's deadline: the edge handler measures a
real-time task's outputs (``--deadline /e2e/cmd=100ms``), a pod whose commands come 140
ms after the capture their stamps say for a while (past the deadline), then 50 ms after.
While it is late the planner lowers the handler's budget from its 1 core to the floor
(edgerv.core.planner.handler_budget: "the deadline is at risk", the monitor pinned so
that moving it is no way out); once it is on time it raises it again ("the deadline is
met"). The rule's numbers are tested without a cluster (tests/unit/test_budget_lever.py)
and with Docker (tests/integration/test_cpu_budget_docker.py).

A release of its own, its operator watching its namespace only, on a port of its own.
"""

from __future__ import annotations

import subprocess
import uuid
from typing import Any

from edgerv.control.client import HandlerClient
from edgerv_operator.constants import HANDLER_CONTAINER
from kit.chart import (
    TOKEN,
    apply,
    handler_pod,
    handler_tls,
    helm,
    install,
    monitor,
    never_refused,
    rights,
    talker_pod,
    task_pod,
    unfinalize,
    until,
)
from kit.kube import Cluster

RELEASE, PORT = "ervb", 8474
TASK_TOPIC = "/e2e/cmd"  # the real-time task's outputs, whose makespans the edge measures
EDGE_NODE = {"edgerv.io/tier": "edge"}
LATE = 40  # seconds the task's outputs come past the deadline
CRDS = ("monitors.edgerv.io", "kopfpeerings.kopf.dev", "clusterkopfpeerings.kopf.dev")


def handler(pod: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """The handler container's spec and status in ``pod``."""
    (spec,) = [c for c in pod["spec"]["containers"] if c["name"] == HANDLER_CONTAINER]
    (state,) = [c for c in pod["status"]["containerStatuses"] if c["name"] == HANDLER_CONTAINER]
    return spec, state


def quota(cluster: Cluster, ns: str, pod: str) -> float:
    """The CFS quota in force in the container's own cgroup, in cores (cgroup v1 or v2)."""
    read = (
        "import os\n"
        "if os.path.exists('/sys/fs/cgroup/cpu.max'):\n"
        "    q, p = open('/sys/fs/cgroup/cpu.max').read().split()\n"
        "else:\n"
        "    q = open('/sys/fs/cgroup/cpu/cpu.cfs_quota_us').read()\n"
        "    p = open('/sys/fs/cgroup/cpu/cpu.cfs_period_us').read()\n"
        "print(int(q) / int(p))\n"
    )
    out = cluster.run("exec", "-n", ns, pod, "-c", HANDLER_CONTAINER, "--", "python3", "-c", read)
    return float(out.strip())


def test_the_planner_resizes_the_edge_handler_in_place_and_its_monitors_keep_their_state(
    cluster: Cluster,
) -> None:
    ns = f"edgerv-budget-{uuid.uuid4().hex[:6]}"
    until(  # a CRD an earlier module deleted (--wait=false) must be gone to be made again
        "the CRDs of an earlier release to go",
        lambda: not any(cluster.attempt("get", "crd", crd)[0] == 0 for crd in CRDS),
    )
    try:
        install(
            cluster,
            RELEASE,
            ns,
            f"handler.port={PORT}",
            f"token.value={TOKEN}",
            f"operator.watchNamespaces={{{ns}}}",
            "operator.placementSeconds=2",
            "operator.budget.tier=edge",
            "operator.budget.floor=0.1",
            "operator.budget.ceiling=1",
            "handler.tiers.edge.resources.limits.cpu=1",  # where the budget starts
            "handler.tiers.edge.extraArgs[0]=--deadline",
            f"handler.tiers.edge.extraArgs[1]={TASK_TOPIC}=100ms",
        )
        before = handler_pod(cluster, ns, "edge")
        spec, state = handler(before)
        assert spec["resources"]["limits"]["cpu"] == "1", spec
        assert spec["resizePolicy"] == [{"resourceName": "cpu", "restartPolicy": "NotRequired"}]
        name = before["metadata"]["name"]
        apply(cluster, ns, talker_pod(cluster, period=0.01))
        pinned = {"migrate": "pinned"}  # (the budget is the planner's only lever here)
        apply(cluster, ns, monitor("budgeted", "always (speed < limit)", placement=pinned))
        edge = HandlerClient(
            f"{before['status']['hostIP']}:{PORT}", TOKEN, handler_tls(cluster, ns, RELEASE)
        )

        def stepping() -> dict[str, Any] | None:
            report = edge.monitor(f"{ns}.budgeted", timeout=5.0)
            return dict(report) if report and report["active"] and report["step"] > 0 else None

        first = until("the monitor to step on the edge handler", stepping, timeout=180)

        def limit(pod: dict[str, Any]) -> tuple[str | None, str | None]:
            """The CPU limit asked for, and the one the kubelet applied."""
            spec, state = handler(pod)
            wanted = spec["resources"].get("limits", {}).get("cpu")
            return wanted, (state.get("resources") or {}).get("limits", {}).get("cpu")

        assert limit(handler_pod(cluster, ns, "edge")) == ("1", "1")  # no deadline reading yet
        apply(cluster, ns, task_pod(cluster, "task", TASK_TOPIC, EDGE_NODE, late=LATE))

        def resized() -> dict[str, Any] | None:
            pod = handler_pod(cluster, ns, "edge")
            return pod if limit(pod) == ("100m", "100m") else None

        after = until("the handler's pod resized to the floor by the planner", resized, timeout=120)
        spec_after, state_after = handler(after)
        # in place: the same pod, the same container, no restart
        assert after["metadata"]["uid"] == before["metadata"]["uid"]
        assert state_after["containerID"] == state["containerID"], (state, state_after)
        assert state_after["restartCount"] == state["restartCount"]
        assert spec_after["resources"]["requests"] == spec["resources"]["requests"]
        assert quota(cluster, ns, name) == 0.1  # the kubelet set the container's quota
        # the monitors keep their state: the steps go on from where they were
        later = until(
            "the monitor to step on", lambda: (r := stepping()) and r["step"] > first["step"] and r
        )
        assert later["active"] and later["epoch"] == first["epoch"]  # no handoff, no restart

        # once the task is on time again, the budget is raised again, in place
        def raised() -> dict[str, Any] | None:
            pod = handler_pod(cluster, ns, "edge")
            wanted, applied = limit(pod)
            return pod if wanted not in (None, "100m") and applied == wanted else None

        again = until("the budget raised once the task is on time", raised, timeout=LATE + 120)
        assert again["metadata"]["uid"] == before["metadata"]["uid"]
        assert handler(again)[1]["restartCount"] == state["restartCount"]
        # the operator said why, and needed no right the chart does not give it
        logs = cluster.run(
            "logs", "-n", ns, "-l", "app.kubernetes.io/component=operator", "--tail=-1"
        )
        assert "'budget': 0.1" in logs and "the deadline is at risk" in logs, logs
        assert "the deadline is met" in logs, logs
        never_refused(cluster, ns)
        got = rights(
            cluster,
            f"{ns}/{RELEASE}-operator",
            [
                ("get", "pods", "-n", ns, "--subresource=resize"),
                ("patch", "pods", "-n", ns, "--subresource=resize"),
                ("patch", "pods", "-n", ns),
                ("update", "pods", "-n", ns, "--subresource=resize"),
                ("patch", "pods", "-n", "default", "--subresource=resize"),
            ],
        )
        assert {q for q, yes in got.items() if yes} == {
            f"get pods -n {ns} --subresource=resize",
            f"patch pods -n {ns} --subresource=resize",
        }, got
    finally:
        cluster.run("delete", "monitors", "--all", "-n", ns, "--timeout=60s", check=False)
        unfinalize(cluster)
        subprocess.run(
            [helm(), "uninstall", RELEASE, "--namespace", ns, "--kubeconfig", cluster.kubeconfig],
            capture_output=True,
            timeout=180,
        )
        cluster.run("delete", "namespace", ns, "--wait=false", check=False)
        for crd in CRDS:  # made by this test
            cluster.run("delete", "crd", crd, "--wait=false", check=False)
