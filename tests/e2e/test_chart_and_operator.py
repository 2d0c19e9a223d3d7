"""The operator on the real cluster: `helm install` puts the handlers on every node, the
operator (run with kopf.testing.KopfRunner) places `kubectl apply`-ed Monitor
resources on them and reports their verdicts in the resources' status.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
import urllib.error
import urllib.request
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from kopf.testing import KopfRunner
from kube import Cluster

ROOT = Path(__file__).resolve().parents[2]
CHART = ROOT / "helm" / "edgerv"
CRD = ROOT / "crds" / "monitors.edgerv.io.yaml"
TOKEN = f"e2e-{uuid.uuid4().hex}"
RELEASE = "erv"

TALKER = """
import time, rclpy
from std_msgs.msg import Float64
rclpy.init(); node = rclpy.create_node("e2e_speed")
pub = node.create_publisher(Float64, "/e2e/speed", 10)
i = 0
while True:
    m = Float64(); m.data = float(i % 100); pub.publish(m); i += 1; time.sleep(0.02)
"""


def helm() -> str:
    own = ROOT / ".cluster" / "bin" / "helm"
    found = os.environ.get("HELM") or (str(own) if own.exists() else shutil.which("helm"))
    if not found:
        pytest.skip("helm is not installed (set HELM)")
    return found


def ros_env(cluster: Cluster) -> dict[str, str]:
    env = {"ROS_DOMAIN_ID": "23", "FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}
    if cluster.link:  # the project's cluster: DDS finds the other node across the link only
        env["ROS_STATIC_PEERS"] = ";".join(cluster.link.values())
    return env


def until(what: str, check: Callable[[], Any], timeout: float = 120.0) -> Any:
    deadline = time.monotonic() + timeout
    while True:
        got = check()
        if got:
            return got
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(1.0)


def install(cluster: Cluster, release: str, ns: str, *values: str) -> None:
    """``helm install`` the chart into a new namespace, with the ROS settings of the
    cluster and ``values`` (KEY=VALUE, as ``--set``), and wait for it to be ready."""
    cluster.run("create", "namespace", ns)
    env = ros_env(cluster)
    args = [
        helm(), "install", release, str(CHART), "--namespace", ns,
        "--kubeconfig", cluster.kubeconfig, "--wait", "--timeout", "240s",
        "--set", f"handler.rosDomainId={env.pop('ROS_DOMAIN_ID')}",
    ]  # fmt: skip
    for value in values:
        args += ["--set", value]
    for key, value in env.items():
        args += ["--set-string", f"handler.extraEnv.{key}={value}"]
    done = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr + cluster.run("get", "pods", "-n", ns, "-o", "wide")


@pytest.fixture(scope="module")
def namespace(cluster: Cluster) -> Iterator[str]:
    """A namespace with the chart installed (handlers only: the test runs the operator)."""
    ns = f"edgerv-e2e-{uuid.uuid4().hex[:6]}"
    try:
        install(
            cluster,
            RELEASE,
            ns,
            "operator.enabled=false",
            f"token.value={TOKEN}",
            "handler.extraArgs={--flush-after,3600}",  # a long sort window stays full
        )
        yield ns
    finally:
        unfinalize(cluster)
        cluster.run("delete", "namespace", ns, "--wait=false", check=False)
        cluster.run("delete", "crd", "monitors.edgerv.io", "--wait=false", check=False)


def unfinalize(cluster: Cluster) -> None:
    """Take the operator's finalizer off Monitors left behind (a failed test): with no
    operator running they would keep their namespace and the CRD from going."""
    code, out, _ = cluster.attempt("get", "monitors", "-A", "-o", "json")
    for m in json.loads(out)["items"] if code == 0 else []:
        meta = m["metadata"]
        cluster.run(
            "patch", "monitor", meta["name"], "-n", meta["namespace"], "--type=merge",
            "-p", '{"metadata":{"finalizers":[]}}', check=False,
        )  # fmt: skip


@pytest.fixture(scope="module")
def operator(cluster: Cluster, namespace: str) -> Iterator[KopfRunner]:
    os.environ.update(
        KUBECONFIG=cluster.kubeconfig,
        EDGERV_TOKEN=TOKEN,
        EDGERV_NAMESPACE=namespace,
        EDGERV_HANDLER_SELECTOR=f"app.kubernetes.io/instance={RELEASE},"
        "app.kubernetes.io/component=handler",
    )
    argv = ["run", "--standalone", "--namespace", namespace, "-m", "edgerv_operator.handlers"]
    with KopfRunner(argv) as runner:
        yield runner
        # while the operator runs: it takes its finalizers off as it deletes them
        cluster.run("delete", "monitors", "--all", "-n", namespace, "--timeout=60s", check=False)
    assert runner.exception is None, runner.output


def talker_pod(cluster: Cluster) -> dict[str, Any]:
    """A pod on the edge publishing /e2e/speed: 0, 1, ... 99, 0, ... every 20 ms."""
    return {
        "apiVersion": "v1",
        "kind": "Pod",
        "metadata": {"name": "speed-talker"},
        "spec": {
            "hostNetwork": True,
            "restartPolicy": "Never",
            "nodeSelector": {"edgerv.io/tier": "edge"},
            "containers": [
                {
                    "name": "talker",
                    "image": "edgerv/handler:dev",
                    "imagePullPolicy": "IfNotPresent",
                    "command": ["python3", "-c", TALKER],
                    "env": [{"name": k, "value": v} for k, v in ros_env(cluster).items()],
                }
            ],
        },
    }


def apply(cluster: Cluster, namespace: str, doc: dict[str, Any]) -> None:
    cluster.run("apply", "-n", namespace, "-f", "-", input=json.dumps(doc))


def monitor(name: str, assertion: str, **spec: Any) -> dict[str, Any]:
    return {
        "apiVersion": "edgerv.io/v1alpha1",
        "kind": "Monitor",
        "metadata": {"name": name},
        "spec": {
            "assertion": assertion,
            "signals": {"speed": {"topic": "/e2e/speed", "type": "std_msgs/msg/Float64"}},
            "parameters": {"limit": 50},
            **spec,
        },
    }


def status(cluster: Cluster, namespace: str, name: str) -> dict[str, Any]:
    out = cluster.run("get", "monitor", name, "-n", namespace, "-o", "json", check=False)
    return dict(json.loads(out).get("status", {})) if out else {}


def handler_get(cluster: Cluster, namespace: str, tier: str, path: str) -> int:
    """The HTTP status of a GET on the handler of a tier (its node's address, port 8470)."""
    pods = json.loads(cluster.run("get", "pods", "-n", namespace, "-o", "json"))["items"]
    nodes = json.loads(cluster.run("get", "nodes", "-o", "json"))["items"]
    tiers = {n["metadata"]["name"]: n["metadata"]["labels"].get("edgerv.io/tier") for n in nodes}
    (ip,) = [
        p["status"]["hostIP"]
        for p in pods
        if "handler" in p["metadata"]["name"] and tiers.get(p["spec"]["nodeName"]) == tier
    ]
    req = urllib.request.Request(
        f"http://{ip}:8470{path}", headers={"Authorization": f"Bearer {TOKEN}"}
    )
    try:
        with urllib.request.urlopen(req, timeout=10) as answer:
            return int(answer.status)
    except urllib.error.HTTPError as exc:
        return int(exc.code)


def test_a_monitor_applied_runs_on_the_edge_and_reports_its_verdicts(
    cluster: Cluster, namespace: str, operator: KopfRunner
) -> None:
    apply(cluster, namespace, talker_pod(cluster))
    apply(cluster, namespace, monitor("speed-limit", "always (speed < limit)"))
    got = until(
        "verdicts in the Monitor's status",
        lambda: (
            (s := status(cluster, namespace, "speed-limit")).get("verdicts", {}).get("violated")
            and s
        ),
        timeout=180,
    )
    assert got["phase"] == "Running" and got["tier"] == "edge", got
    table = cluster.run("get", "monitors", "-n", namespace)
    assert "speed-limit" in table and "Running" in table
    path = f"/v1/monitors/{namespace}.speed-limit"
    assert handler_get(cluster, namespace, "cloud", path) == 200  # defined there, idle
    cluster.run("delete", "monitor", "speed-limit", "-n", namespace, "--timeout=60s")
    assert until(
        "the edge handler to forget it",
        lambda: handler_get(cluster, namespace, "edge", path) == 404,
    )


def test_a_monitor_under_pressure_moves_up_to_the_cloud(
    cluster: Cluster, namespace: str, operator: KopfRunner
) -> None:
    """Its 1,000-event sort window fills at 50 messages/s and stays over half full (the
    handlers release partial windows after an hour only): the edge handler wants it
    moved, and the operator's placement rounds hand it off to the cloud's handler."""
    apply(cluster, namespace, talker_pod(cluster))
    pressured = monitor(
        "pressured", "always (speed < limit)", sortThreshold=1000, bufferCapacity=1000
    )
    apply(cluster, namespace, pressured)
    got = until(
        "the monitor to run in the cloud",
        lambda: (
            (s := status(cluster, namespace, "pressured")).get("tier") == "cloud"
            and s.get("phase") == "Running"
            and s
        ),
        timeout=150,
    )
    assert got["handler"] and got["events"] > 0, got
    cluster.run("delete", "monitor", "pressured", "-n", namespace, "--timeout=60s")


def test_a_bad_assertion_is_reported_in_the_status(
    cluster: Cluster, namespace: str, operator: KopfRunner
) -> None:
    apply(cluster, namespace, monitor("typo", "always (speed < limt)"))
    got = until(
        "an Error phase",
        lambda: (
            status(cluster, namespace, "typo").get("phase") == "Error"
            and status(cluster, namespace, "typo")
        ),
    )
    assert "spec.assertion, column 17: unknown signal or parameter 'limt'" in got["message"], got


def test_the_api_server_checks_the_shape(cluster: Cluster, namespace: str) -> None:
    bad = monitor("shape", "always (speed < limit)", onVerdict="stop")
    code, _, err = cluster.attempt("apply", "-n", namespace, "-f", "-", input=json.dumps(bad))
    assert code != 0 and 'spec.onVerdict: Unsupported value: "stop"' in err, err


def test_helm_install_runs_the_operator_in_the_cluster(cluster: Cluster) -> None:
    """The chart as a user installs it: the operator's pod places a Monitor too (its own
    namespace and handler port, beside the release the other tests use)."""
    ns = f"edgerv-e2e-{uuid.uuid4().hex[:6]}"
    try:
        install(cluster, "erv2", ns, "handler.port=8471", f"operator.watchNamespaces={{{ns}}}")
        apply(cluster, ns, talker_pod(cluster))
        apply(cluster, ns, monitor("speed-limit", "always (speed < limit)"))
        got = until(
            "verdicts from the in-cluster operator",
            lambda: (
                (s := status(cluster, ns, "speed-limit")).get("verdicts", {}).get("violated") and s
            ),
            timeout=180,
        )
        assert got["phase"] == "Running" and got["tier"] == "edge", got
        # a new operator pod resumes the Monitor without redefining it (that would restart it)
        operator = "app.kubernetes.io/component=operator"
        cluster.run("delete", "pod", "-n", ns, "-l", operator, "--timeout=60s")
        until(
            "the new operator to resume the Monitor",
            lambda: (
                "Resuming is processed: 1 succeeded"
                in cluster.run("logs", "-n", ns, "-l", operator, "--tail=-1", check=False)
            ),
        )
        handlers = cluster.run(
            "logs", "-n", ns, "-l", "app.kubernetes.io/component=handler", "--tail=-1"
        )
        assert f"added {ns}.speed-limit" in handlers and "replaced" not in handlers, handlers
    finally:
        cluster.run("delete", "monitor", "--all", "-n", ns, "--timeout=60s", check=False)
        unfinalize(cluster)
        subprocess.run(
            [helm(), "uninstall", "erv2", "--namespace", ns, "--kubeconfig", cluster.kubeconfig],
            capture_output=True,
            timeout=120,
        )
        cluster.run("delete", "namespace", ns, "--wait=false", check=False)
