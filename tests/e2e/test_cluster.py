"""The cluster itself: tiered nodes, the project's image in pods, ROS 2 across the nodes' link."""

from __future__ import annotations

import json
import time
import uuid

import pytest

from kit.kube import Cluster

pytestmark = pytest.mark.e2e

TIERS = ("edge", "cloud")


def pod(name: str, tier: str, args: list[str], command: list[str] | None = None,
        env: dict[str, str] | None = None) -> str:  # fmt: skip
    container: dict[str, object] = {
        "name": "edgerv",
        "image": "edgerv/handler:dev",
        "imagePullPolicy": "Never",
        "args": args,
        "env": [{"name": k, "value": v} for k, v in (env or {}).items()],
    }
    if command:
        container["command"] = command
    return json.dumps(
        {
            "apiVersion": "v1",
            "kind": "Pod",
            "metadata": {"name": name, "labels": {"app.kubernetes.io/part-of": "edgerv-e2e"}},
            "spec": {
                "nodeSelector": {"edgerv.io/tier": tier},
                "hostNetwork": True,
                "restartPolicy": "Never",
                "terminationGracePeriodSeconds": 1,
                "containers": [container],
            },
        }
    )


def apply(cluster: Cluster, manifest: str) -> None:
    path = f"/tmp/edgerv-e2e-{uuid.uuid4().hex}.json"
    with open(path, "w") as f:
        f.write(manifest)
    cluster.run("apply", "-f", path)


def wait_phase(cluster: Cluster, name: str, timeout: float = 180) -> str:
    deadline = time.monotonic() + timeout
    phase = ""
    while time.monotonic() < deadline:
        phase = cluster.run("get", "pod", name, "-o", "jsonpath={.status.phase}", check=False)
        if phase in ("Succeeded", "Failed"):
            return phase
        time.sleep(1)
    return phase


def test_nodes_are_ready_with_their_tiers(cluster: Cluster) -> None:
    nodes = json.loads(cluster.run("get", "nodes", "-o", "json"))["items"]
    tiers = {}
    for n in nodes:
        ready = [c["status"] for c in n["status"]["conditions"] if c["type"] == "Ready"]
        assert ready == ["True"], n["metadata"]["name"]
        tiers[n["metadata"]["labels"].get("edgerv.io/tier")] = n["metadata"]["name"]
    assert set(TIERS) <= set(tiers)


@pytest.mark.parametrize("tier", TIERS)
def test_the_handler_image_runs_on_every_node(cluster: Cluster, tier: str) -> None:
    name = f"version-{tier}-{uuid.uuid4().hex[:6]}"
    apply(cluster, pod(name, tier, ["--version"]))
    try:
        assert wait_phase(cluster, name) == "Succeeded"
        assert cluster.run("logs", name).startswith("edgerv ")
        node = cluster.run("get", "pod", name, "-o", "jsonpath={.spec.nodeName}")
        labels = json.loads(cluster.run("get", "node", node, "-o", "json"))["metadata"]["labels"]
        assert labels["edgerv.io/tier"] == tier
    finally:
        cluster.run("delete", "pod", name, "--wait=false", check=False)


TALKER = """
import sys, time, rclpy
from std_msgs.msg import String
rclpy.init(); node = rclpy.create_node("e2e_talker")
pub = node.create_publisher(String, "/e2e/hello", 10)
for i in range(600):
    m = String(); m.data = f"hello from the edge {i}"; pub.publish(m); time.sleep(0.2)
"""

LISTENER = """
import sys, time, rclpy
from std_msgs.msg import String
rclpy.init(); node = rclpy.create_node("e2e_listener")
got = []
node.create_subscription(String, "/e2e/hello", lambda m: got.append(m.data), 10)
deadline = time.monotonic() + 90
while not got and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.2)
print(got[0] if got else "nothing", flush=True)
sys.exit(0 if got else 1)
"""


def test_pods_on_two_nodes_exchange_a_ros_message_across_the_link(cluster: Cluster) -> None:
    suffix = uuid.uuid4().hex[:6]
    env = {"ROS_DOMAIN_ID": "17", "FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}
    if cluster.link:  # the project's cluster: DDS finds the other node across the link only
        env["ROS_STATIC_PEERS"] = ";".join(cluster.link.values())
    talker, listener = f"talker-{suffix}", f"listener-{suffix}"
    apply(cluster, pod(talker, "edge", ["-c", TALKER], ["python3"], env))
    apply(cluster, pod(listener, "cloud", ["-c", LISTENER], ["python3"], env))
    try:
        assert wait_phase(cluster, listener) == "Succeeded", cluster.run(
            "logs", listener, check=False
        )
        assert cluster.run("logs", listener).startswith("hello from the edge")
    finally:
        cluster.run("delete", "pod", talker, listener, "--wait=false", check=False)


def test_each_node_keeps_its_pods_logs_where_the_other_cannot_remove_them(
    cluster: Cluster,
) -> None:
    """The project's cluster runs both kubelets on one host: each must have its own pod
    log directory, since a kubelet's garbage collection removes the log directories of
    every pod it does not run (the other node's pods' logs vanished before their
    ``kubectl logs``). Read from the running kubelets' own configuration."""
    if not cluster.link:
        pytest.skip("a cluster of yours: its nodes are separate machines")
    dirs = {}
    for node in cluster.link:
        configz = json.loads(cluster.run("get", "--raw", f"/api/v1/nodes/{node}/proxy/configz"))
        config = configz["kubeletconfig"]
        dirs[node] = (config["podLogsDir"], config["volumePluginDir"])
        assert config["podLogsDir"] != "/var/log/pods", node
    assert len(set(dirs.values())) == len(dirs), dirs
