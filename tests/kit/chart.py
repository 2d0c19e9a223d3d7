"""The chart on a real cluster, for the e2e tier: ``helm`` itself, the chart installed into
a namespace of its own (:func:`install`, :func:`installed`), the operator run beside it
(:func:`running_operator`), Monitor resources applied and read back (:func:`monitor`,
:func:`apply`, :func:`status`), a talker pod, the release's TLS, and what a
ServiceAccount may do (:func:`rights`)."""

from __future__ import annotations

import base64
import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from kopf.testing import KopfRunner

from edgerv.control.tls import ClientTls
from kit.kube import Cluster

ROOT = Path(__file__).resolve().parents[2]

CHART = ROOT / "helm" / "edgerv"

TOKEN = f"e2e-{uuid.uuid4().hex}"

RELEASE = "erv"

TALKER = """
import sys, time, rclpy
from std_msgs.msg import Float64
topic, period, top = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
rclpy.init(); node = rclpy.create_node("e2e_speed")
pub = node.create_publisher(Float64, topic, 10)
i = 0
while True:
    m = Float64(); m.data = float(i % top); pub.publish(m); i += 1; time.sleep(period)
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


def talker_pod(
    cluster: Cluster,
    name: str = "speed-talker",
    topic: str = "/e2e/speed",
    node: dict[str, str] | None = None,
    period: float = 0.02,
    top: int = 100,
) -> dict[str, Any]:
    """A pod publishing ``topic`` (std_msgs/Float64): 0, 1, ... top-1, 0, ... every
    ``period`` seconds, on the node ``node`` selects (default: the edge tier's)."""
    return {
        "apiVersion": "v1",
        "kind": "Pod",
        "metadata": {"name": name},
        "spec": {
            "hostNetwork": True,
            "restartPolicy": "Never",
            "nodeSelector": node or {"edgerv.io/tier": "edge"},
            "containers": [
                {
                    "name": "talker",
                    "image": "edgerv/handler:dev",
                    "imagePullPolicy": "IfNotPresent",
                    "command": ["python3", "-c", TALKER, topic, str(period), str(top)],
                    "env": [{"name": k, "value": v} for k, v in cluster_ros_env(cluster).items()],
                }
            ],
        },
    }


COUNTER = """
import json, sys, time, rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64
topic, count = sys.argv[1], int(sys.argv[2])
rclpy.init(); node = rclpy.create_node("e2e_counter")
qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
pub = node.create_publisher(Float64, topic, qos)
while pub.get_subscription_count() < 1:  # the edge handler's: every message reaches it
    time.sleep(0.1)
print(json.dumps({"subscribers": pub.get_subscription_count()}), flush=True)
for i in range(count):
    m = Float64(); m.data = float(i % 100); pub.publish(m); time.sleep(0.02)
print(json.dumps({"published": count}), flush=True)
while True:  # then quiet values: no more violations, the last ones evaluated
    m = Float64(); m.data = 0.0; pub.publish(m); time.sleep(0.02)
"""
COUNT = 2500  # 50 s at 50 messages/s: the moves happen meanwhile


def counter_pod(
    cluster: Cluster,
    name: str,
    topic: str = "/e2e/count",
    node: dict[str, str] | None = None,
    count: int = COUNT,
) -> dict[str, Any]:
    """A pod publishing ``topic`` reliably once a handler subscribes: 0, 1, ... 99, 0, ...
    ``count`` messages every 20 ms, then 0s (on the node ``node`` selects; default: the
    edge tier's)."""
    pod = talker_pod(cluster, name=name, node=node)
    pod["spec"]["containers"][0]["command"] = ["python3", "-c", COUNTER, topic, str(count)]
    return pod


TASK = """
import sys, time, rclpy
from geometry_msgs.msg import TwistStamped
topic, late = sys.argv[1], float(sys.argv[2])
rclpy.init(); node = rclpy.create_node("e2e_task")
pub = node.create_publisher(TwistStamped, topic, 10)
start = time.monotonic()
while True:  # each output stamped with its input's capture: 140 ms old while late
    age = 0.140 if time.monotonic() - start < late else 0.050
    m = TwistStamped(); m.header.frame_id = "camera"
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(time.time_ns() - int(age * 1e9), 10**9)
    pub.publish(m); time.sleep(0.05)
"""


def task_pod(cluster: Cluster, name: str, topic: str, node: dict[str, str], late: float) -> Any:
    """A robot's real-time task: its outputs on ``topic`` (geometry_msgs/TwistStamped,
    every 50 ms), each published 140 ms after the capture its stamp says for ``late``
    seconds (past a 100 ms deadline), then 50 ms after (on time)."""
    pod = talker_pod(cluster, name=name, node=node)
    pod["spec"]["containers"][0]["command"] = ["python3", "-c", TASK, topic, str(late)]
    return pod


def counting_monitor(name: str) -> dict[str, Any]:
    """Violated by each message of value 50 or more: COUNT / 2 times, the last at step COUNT
    (the step of every verdict shifts if one message is lost or evaluated twice)."""
    doc = monitor(name, "always (count < limit)", placement={"tier": "edge"})
    doc["spec"]["signals"] = {
        "count": {
            "topic": "/e2e/count",
            "type": "std_msgs/msg/Float64",
            "qos": {"reliability": "reliable", "depth": 1000},
        }
    }
    return doc


def expected_verdicts(tmp: Path, count: int = COUNT) -> tuple[int, int]:
    """``edgerv check`` on the ``count`` messages the counter publishes first:
    (violations, the last one's step)."""
    trace = tmp / "count.jsonl"
    trace.write_text(
        "".join(
            json.dumps({"topic": "/e2e/count", "stamp": i * 20_000_000, "msg": {"data": i % 100}})
            + "\n"
            for i in range(count)
        )
    )
    spec = counting_monitor("offline")["spec"]
    doc = tmp / "monitor.yaml"
    doc.write_text(json.dumps({"apiVersion": "edgerv.io/v1alpha1", "kind": "Monitor",
                               "metadata": {"name": "offline"}, "spec": spec}))  # fmt: skip
    done = subprocess.run(
        [str(Path(sys.executable).with_name("edgerv")), "check", str(doc), str(trace), "--json"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 1, done.stderr
    (result,) = json.loads(done.stdout)["monitors"]
    violated = [v for v in result["verdicts"] if v["verdict"] == "violated"]
    return len(violated), violated[-1]["step"]


def handler_pod(cluster: Cluster, namespace: str, tier: str) -> dict[str, Any]:
    """The one live handler pod on the node of a tier (not one being deleted)."""
    pods = json.loads(
        cluster.run(
            "get",
            "pods",
            "-n",
            namespace,
            "-l",
            "app.kubernetes.io/component=handler",
            "-o",
            "json",
        )
    )["items"]
    nodes = json.loads(cluster.run("get", "nodes", "-o", "json"))["items"]
    tiers = {n["metadata"]["name"]: n["metadata"]["labels"].get("edgerv.io/tier") for n in nodes}
    (pod,) = [
        p
        for p in pods
        if tiers.get(p["spec"]["nodeName"]) == tier and not p["metadata"].get("deletionTimestamp")
    ]
    return dict(pod)


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


@contextlib.contextmanager
def installed(cluster: Cluster, *values: str) -> Iterator[str]:
    """A namespace with the chart installed (handlers only: the test runs the operator,
    :func:`running_operator`), and ``values`` set; everything the release made goes after."""
    ns = f"edgerv-e2e-{uuid.uuid4().hex[:6]}"
    try:
        install(
            cluster,
            RELEASE,
            ns,
            "operator.enabled=false",
            f"token.value={TOKEN}",
            "handler.extraArgs={--flush-after,3600}",  # a long sort window stays full
            *values,
        )
        yield ns
    finally:
        unfinalize(cluster)
        subprocess.run(  # its cluster-wide objects too (roles), also after a failed test
            [helm(), "uninstall", RELEASE, "--namespace", ns, "--kubeconfig", cluster.kubeconfig],
            capture_output=True,
            timeout=300,
        )
        cluster.run("delete", "namespace", ns, "--wait=false", check=False)
        # the CRDs the release made and kept (crds.keep): the next run installs them anew
        for crd in ("monitors.edgerv.io", "kopfpeerings.kopf.dev", "clusterkopfpeerings.kopf.dev"):
            cluster.run("delete", "crd", crd, "--wait=false", check=False)


def release_ca(cluster: Cluster, ns: str, release: str = RELEASE) -> Path:
    """The CA the chart made for a release (its Secret's ca.crt), in a file."""
    secret = json.loads(cluster.run("get", "secret", f"{release}-tls", "-n", ns, "-o", "json"))
    path = Path(tempfile.mkdtemp(prefix="edgerv-e2e-")) / "ca.crt"
    path.write_bytes(base64.b64decode(secret["data"]["ca.crt"]))
    return path


def handler_tls(cluster: Cluster, ns: str, release: str = RELEASE) -> ClientTls:
    """How a caller verifies a release's handlers: its CA, the name the chart gave them."""
    return ClientTls(str(release_ca(cluster, ns, release)), f"{release}-handler.{ns}.svc")


@contextlib.contextmanager
def running_operator(cluster: Cluster, namespace: str) -> Iterator[KopfRunner]:
    """The operator (kopf.testing.KopfRunner, in this process) for the release installed
    in ``namespace``; at the end the Monitors there are deleted while it still runs (it
    takes its finalizers off)."""
    os.environ.update(
        KUBECONFIG=cluster.kubeconfig,
        EDGERV_TOKEN=TOKEN,
        EDGERV_TLS_CA_FILE=str(release_ca(cluster, namespace)),  # HTTPS, as the chart's
        EDGERV_TLS_SERVER_NAME=f"{RELEASE}-handler.{namespace}.svc",
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
