"""The chart on a real cluster, for the e2e tier: ``helm`` itself, the chart installed into
a namespace of its own (:func:`install`), Monitor resources applied and read back
(:func:`monitor`, :func:`apply`, :func:`status`), a talker pod, and what a ServiceAccount
may do (:func:`rights`)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from kit.kube import Cluster

ROOT = Path(__file__).resolve().parents[2]

CHART = ROOT / "helm" / "edgerv"

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


def cluster_ros_env(cluster: Cluster) -> dict[str, str]:
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
    env = cluster_ros_env(cluster)
    args = [
        helm(), "install", release, str(CHART), "--namespace", ns,
        "--kubeconfig", cluster.kubeconfig, "--wait", "--timeout", "240s",
        "--set", f"handler.rosDomainId={env['ROS_DOMAIN_ID']}",
        "--set", f"handler.ros.transports={env['FASTDDS_BUILTIN_TRANSPORTS']}",
    ]  # fmt: skip
    if "ROS_STATIC_PEERS" in env:  # the chart's value, as a user sets it
        peers = env["ROS_STATIC_PEERS"].replace(";", ",")
        args += ["--set", f"handler.ros.staticPeers={{{peers}}}"]
    for value in values:
        args += ["--set", value]
    done = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr + cluster.run("get", "pods", "-n", ns, "-o", "wide")
    assert f"helm test {release} --namespace {ns} --logs" in done.stdout, done.stdout  # NOTES
    # helm's --wait takes a DaemonSet with all but maxUnavailable (1) of its pods Ready:
    # the tests place monitors by tier, so every handler must be up (a DaemonSet a tier)
    for tier in ("edge", "cloud"):
        code, out, err = cluster.attempt(
            "rollout", "status", f"daemonset/{release}-handler-{tier}", "-n", ns,
            "--timeout=240s", timeout=260,
        )  # fmt: skip
        assert code == 0, out + err + cluster.run("get", "pods", "-n", ns, "-o", "wide")


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
                    "env": [{"name": k, "value": v} for k, v in cluster_ros_env(cluster).items()],
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


def can_i(cluster: Cluster, account: str, verb: str, what: str, *where: str) -> bool:
    """`kubectl auth can-i` as a ServiceAccount (namespace/name): the API server's RBAC
    authorizer's answer (a SubjectAccessReview)."""
    ns, name = account.split("/")
    _, out, err = cluster.attempt(
        "auth", "can-i", verb, what, *where, f"--as=system:serviceaccount:{ns}:{name}"
    )
    assert out.strip() in ("yes", "no"), out + err
    return out.strip() == "yes"


def rights(cluster: Cluster, account: str, asked: list[tuple[str, ...]]) -> dict[str, bool]:
    """Each (verb, resource, flags...) asked: whether the account may."""
    return {" ".join(q): can_i(cluster, account, *q) for q in asked}


def never_refused(cluster: Cluster, ns: str) -> None:
    """The operator's pods logged no refusal by the API server: nothing Kopf or the
    operator did needed a right the chart does not grant."""
    logs = cluster.run("logs", "-n", ns, "-l", "app.kubernetes.io/component=operator", "--tail=-1")
    for refusal in ("Forbidden", "forbidden", "Not enough permissions"):
        assert refusal not in logs, logs
