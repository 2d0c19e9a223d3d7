"""The operator on the real cluster: `helm install` puts the handlers on every node, the
operator (run with kopf.testing.KopfRunner) places `kubectl apply`-ed Monitor
resources on them and reports their verdicts in the resources' status.
"""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from kopf.testing import KopfRunner

from edgerv.control.client import ApiError, HandlerClient, Untrusted, WrongScheme
from edgerv.control.migrate import migrate
from edgerv.control.tls import ClientTls
from kit.chart import (
    CHART,
    RELEASE,
    ROOT,
    TOKEN,
    apply,
    counter_pod,
    counting_monitor,
    expected_verdicts,
    handler_pod,
    handler_tls,
    helm,
    install,
    installed,
    monitor,
    never_refused,
    release_ca,
    rights,
    running_operator,
    status,
    talker_pod,
    unfinalize,
    until,
)
from kit.kube import Cluster

CRD = ROOT / "crds" / "monitors.edgerv.io.yaml"  # the chart's Monitor CRD (files/crds/ links here)


@pytest.fixture(scope="module")
def namespace(cluster: Cluster) -> Iterator[str]:
    """A namespace with the chart installed (handlers only: the test runs the operator)."""
    with installed(cluster) as ns:
        yield ns


@pytest.fixture(scope="module")
def operator(cluster: Cluster, namespace: str) -> Iterator[KopfRunner]:
    with running_operator(cluster, namespace) as runner:
        yield runner


def set_tier(cluster: Cluster, namespace: str, name: str, tier: str) -> None:
    """`kubectl patch` of a Monitor's spec.placement.tier, as a user edits it."""
    cluster.run(
        "patch", "monitor", name, "-n", namespace, "--type=merge",
        "-p", json.dumps({"spec": {"placement": {"tier": tier}}}),
    )  # fmt: skip


def handler_get(cluster: Cluster, namespace: str, tier: str, path: str) -> int:
    """The HTTP status of a GET on the handler of a tier (its node's address, port 8470,
    over HTTPS verified with the release's CA)."""
    ip = handler_pod(cluster, namespace, tier)["status"]["hostIP"]
    client = HandlerClient(f"{ip}:8470", TOKEN, handler_tls(cluster, namespace))
    status, _ = client.call(path, method="GET", timeout=10.0)
    return status


def test_the_handlers_serve_https_only_to_callers_that_trust_the_release_ca(
    cluster: Cluster, namespace: str, tmp_path: Path
) -> None:
    """The chart's handlers serve HTTPS with the certificate it made: a caller with the
    release's CA and the name the chart gave them is served; a caller with another CA
    is refused before it sends anything, and a plain-HTTP caller gets no answer."""
    ip = handler_pod(cluster, namespace, "edge")["status"]["hostIP"]
    assert handler_get(cluster, namespace, "edge", "/v1/monitors") == 200
    key, other = tmp_path / "other.key", tmp_path / "other.crt"
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key),
         "-out", str(other), "-days", "1", "-subj", "/CN=another CA"],
        check=True, capture_output=True,
    )  # fmt: skip
    stranger = ClientTls(str(other), f"{RELEASE}-handler.{namespace}.svc")
    with pytest.raises(Untrusted, match="its certificate is not trusted"):
        HandlerClient(f"{ip}:8470", TOKEN, stranger).monitors(timeout=10.0)
    wrong_name = ClientTls(str(release_ca(cluster, namespace)), "erv-handler.other.svc")
    with pytest.raises(Untrusted, match="its certificate is not trusted"):
        HandlerClient(f"{ip}:8470", TOKEN, wrong_name).monitors(timeout=10.0)
    with pytest.raises(WrongScheme, match="speaks HTTPS"):
        HandlerClient(f"http://{ip}:8470", TOKEN).monitors(timeout=10.0)


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
    story = [(e["reason"], e["message"]) for e in events_of(cluster, namespace, "speed-limit")]
    assert got["phase"] == "Running" and got["tier"] == "edge", (got, story)
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


# What a process in a pod may do, seen from inside it (the kernel's word, not the spec's).
PRIVILEGES = """
import json, os
lines = open("/proc/self/status").read().splitlines()
status = dict(l.split(":\\t", 1) for l in lines if ":\\t" in l)
try:
    open("/written-by-the-probe", "w").close(); root = "writable"
except OSError:
    root = "read-only"
print(json.dumps({
    "uid": os.getuid(), "gid": os.getgid(), "root": root,
    "token": os.path.exists("/var/run/secrets/kubernetes.io/serviceaccount/token"),
    "capEff": status["CapEff"].strip(), "noNewPrivs": status["NoNewPrivs"].strip(),
    "seccomp": status["Seccomp"].strip(),
}))
"""


# A deadline plan in the operator's image (tests/unit/test_planner.py's instance where the
# solver's answer is not the greedy rule's: two monitors are the fewest, c and d of them
# the fewest events); "greedy" without SciPy.
PLANS = """
import json
from edgerv.core.planner import EdgeState, MonitorCost, PlannerConfig, plan_moves
costs = [("a", 0.20, 900), ("b", 0.20, 100), ("c", 0.15, 50), ("d", 0.10, 10), ("e", 0.05, 1)]
ms = [MonitorCost(n, "edge", cost, rate, None, False, False) for n, cost, rate in costs]
p = plan_moves(ms, EdgeState(0.5, 0.1, 0.12, 40.0, None, None, {}), PlannerConfig(time_budget=5.0))
print(json.dumps({"up": list(p.up), "method": p.method}))
"""


def privileges(cluster: Cluster, ns: str, selector: str) -> list[dict[str, Any]]:
    """What the processes of each pod ``selector`` picks in ``ns`` may do."""
    pods = json.loads(cluster.run("get", "pods", "-n", ns, "-l", selector, "-o", "json"))["items"]
    assert pods, selector
    return [
        json.loads(
            cluster.run("exec", "-n", ns, p["metadata"]["name"], "--", "python3", "-c", PRIVILEGES)
        )
        for p in pods
    ]


HARDENED = {  # the chart's default securityContext, as the kernel applies it
    "uid": 10001,
    "gid": 10001,
    "root": "read-only",
    "capEff": "0000000000000000",  # no capability
    "noNewPrivs": "1",  # allowPrivilegeEscalation: false
    "seccomp": "2",  # a filter: the runtime's default profile
}


def test_the_handlers_run_unprivileged_with_no_api_token(cluster: Cluster, namespace: str) -> None:
    seen = privileges(cluster, namespace, "app.kubernetes.io/component=handler")
    assert len(seen) == 2  # one per node
    for got in seen:
        assert got == HARDENED | {"token": False}, got


def test_helm_install_runs_the_operator_in_the_cluster(cluster: Cluster) -> None:
    """The chart as a user installs it: the operator's pods place a Monitor too (its own
    namespace and handler port, beside the release the other tests use). Two operator
    replicas: one acts, the other waits (Kopf peering), so the Monitor is defined once and
    a tier edit moves it by one handoff (the handlers' records). The operator restarted
    while a handoff is half done (adopted, never committed): it settles it, one copy.
    The token's Secret rotated: handlers and operator follow it, with no restart."""
    ns = f"edgerv-e2e-{uuid.uuid4().hex[:6]}"
    operator = "app.kubernetes.io/component=operator"

    def acting() -> tuple[str, list[str], dict[str, int]]:
        """The replica of highest priority in the peering object (its pod's name: POD_ID),
        the pods whose logs show work on the Monitor, and every replica's priority."""
        pods = json.loads(cluster.run("get", "pods", "-n", ns, "-l", operator, "-o", "json"))
        names = [p["metadata"]["name"] for p in pods["items"]]
        logs = {n: cluster.run("logs", "-n", ns, n, "--tail=-1", check=False) for n in names}
        peering = json.loads(
            cluster.run("get", "kopfpeering", "erv2-operator", "-n", ns, "-o", "json")
        )
        peers = {k: int(v["priority"]) for k, v in peering.get("status", {}).items()}
        assert set(peers) == set(names), (peers, names)  # both met in the peering object
        worked = [n for n, text in logs.items() if f"[{ns}/speed-limit]" in text]
        return max(peers, key=lambda k: peers[k]), worked, peers

    try:
        install(
            cluster, "erv2", ns, "handler.port=8471", f"operator.watchNamespaces={{{ns}}}",
            "operator.replicas=2", f"token.value={TOKEN}",
            "crds.install=false",  # the first release owns the cluster's CRDs
        )  # fmt: skip
        tested = subprocess.run(  # `helm test`: every handler answers as the operator calls
            [helm(), "test", "erv2", "--namespace", ns, "--logs", "--timeout", "120s",
             "--kubeconfig", cluster.kubeconfig],
            capture_output=True, text=True, timeout=180,
        )  # fmt: skip
        assert tested.returncode == 0, tested.stdout + tested.stderr
        assert "2 of 2 handlers answered" in tested.stdout, tested.stdout
        assert tested.stdout.count("(https://") == 2, tested.stdout
        apply(cluster, ns, talker_pod(cluster))
        apply(cluster, ns, monitor("speed-limit", "always (speed < limit)"))
        got = until(
            "verdicts from the in-cluster operator",
            lambda: (
                (s := status(cluster, ns, "speed-limit")).get("verdicts", {}).get("violated") and s
            ),
            timeout=180,
        )
        assert got["phase"] == "Running" and got["tier"] == "edge", json.dumps(got) + cluster.run(
            "logs", "-n", ns, "-l", operator, "--tail=-1"
        )
        for got in privileges(cluster, ns, operator):  # (its API token it needs: Kopf's)
            assert got == HARDENED | {"token": True}, got
        for pod in json.loads(cluster.run("get", "pods", "-n", ns, "-l", operator, "-o", "json"))[
            "items"
        ]:  # its placement rounds plan with the exact solver, not only the greedy rule
            planned = cluster.run(
                "exec", "-n", ns, pod["metadata"]["name"], "--", "python3", "-c", PLANS
            )
            assert json.loads(planned) == {"up": ["c", "d"], "method": "milp"}, planned
        rights_when_namespaces_are_watched(cluster, ns)
        leader, worked, peers = acting()
        assert len(peers) == 2 and len(set(peers.values())) == 2, peers
        assert worked == [leader], (worked, peers)  # the other one waits: it did nothing
        # new operator pods resume the Monitor without redefining it (that would restart it)
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
        # a tier edit: one replica moves it, by one handoff (its epoch in both handlers' logs)
        name = f"{ns}.speed-limit"
        set_tier(cluster, ns, "speed-limit", "cloud")
        until(
            "the move to the cloud",
            lambda: status(cluster, ns, "speed-limit").get("tier") == "cloud",
        )
        (epoch,) = until("the handlers' records of the move", lambda: handoffs(cluster, ns, name))
        records = handoffs(cluster, ns, name)[epoch]
        assert sorted(records) == ["adopted", "committed", "held"], records
        restarted_mid_handoff(cluster, ns, name)
        rotated_token(cluster, ns)
        never_refused(cluster, ns)  # all it did, with only the verbs the chart grants
        uninstalled_with_monitors(cluster, ns)
    finally:
        cluster.run("delete", "monitor", "--all", "-n", ns, "--timeout=60s", check=False)
        unfinalize(cluster)
        subprocess.run(
            [helm(), "uninstall", "erv2", "--namespace", ns, "--kubeconfig", cluster.kubeconfig],
            capture_output=True,
            timeout=120,
        )
        cluster.run("delete", "namespace", ns, "--wait=false", check=False)


def rights_when_namespaces_are_watched(cluster: Cluster, ns: str) -> None:
    """operator.watchNamespaces set: the operator's ServiceAccount reads the handler pods in
    the release's namespace only (not in another, not cluster-wide), does what Kopf does with
    Monitors in the watched namespace only, and reads nothing else of the cluster but the
    nodes' labels. Each verb is one Kopf uses: no get, update, create or delete of Monitors."""
    elsewhere = "default"
    got = rights(
        cluster,
        f"{ns}/erv2-operator",
        [
            ("list", "pods", "-n", ns), ("watch", "pods", "-n", ns),
            ("get", "pods", "-n", ns),
            ("list", "pods", "-n", elsewhere), ("watch", "pods", "-n", elsewhere),
            ("list", "pods", "--all-namespaces"), ("watch", "pods", "--all-namespaces"),
            ("list", "monitors.edgerv.io", "-n", ns), ("watch", "monitors.edgerv.io", "-n", ns),
            ("patch", "monitors.edgerv.io", "-n", ns),
            ("patch", "monitors.edgerv.io", "-n", ns, "--subresource=status"),
            ("get", "monitors.edgerv.io", "-n", ns), ("update", "monitors.edgerv.io", "-n", ns),
            ("delete", "monitors.edgerv.io", "-n", ns),
            ("list", "monitors.edgerv.io", "-n", elsewhere),
            ("list", "monitors.edgerv.io", "--all-namespaces"),
            ("create", "events", "-n", ns), ("create", "events", "-n", elsewhere),
            ("patch", "kopfpeerings.kopf.dev/erv2-operator", "-n", ns),
            ("patch", "kopfpeerings.kopf.dev/another", "-n", ns),
            ("list", "clusterkopfpeerings.kopf.dev"),
            ("list", "nodes"), ("watch", "nodes"), ("patch", "nodes"),
            ("list", "namespaces"), ("list", "customresourcedefinitions.apiextensions.k8s.io"),
            ("get", "secrets", "-n", ns),
        ],
    )  # fmt: skip
    allowed = {q for q, yes in got.items() if yes}
    assert allowed == {
        f"list pods -n {ns}", f"watch pods -n {ns}",
        f"list monitors.edgerv.io -n {ns}", f"watch monitors.edgerv.io -n {ns}",
        f"patch monitors.edgerv.io -n {ns}",
        f"patch monitors.edgerv.io -n {ns} --subresource=status",
        f"create events -n {ns}",
        f"patch kopfpeerings.kopf.dev/erv2-operator -n {ns}",
        "list nodes", "watch nodes",
    }, got  # fmt: skip


def uninstalled_with_monitors(cluster: Cluster, ns: str) -> None:
    """`helm uninstall` with Monitors placed: its pre-delete hook stops the operator and
    takes the operator's finalizer off them, so they stay (the CRD is kept) and none is
    stuck on it: each can be deleted at once afterwards, and the namespace with it."""
    apply(cluster, ns, monitor("left-behind", "always (speed < limit)"))
    until(
        "the operator to place the Monitor left behind",
        lambda: status(cluster, ns, "left-behind").get("phase") == "Running",
        timeout=180,
    )
    done = subprocess.run(
        [helm(), "uninstall", "erv2", "--namespace", ns, "--kubeconfig", cluster.kubeconfig,
         "--wait", "--timeout", "300s"],
        capture_output=True, text=True, timeout=360,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    left = json.loads(cluster.run("get", "monitors", "-n", ns, "-o", "json"))["items"]
    names = sorted(m["metadata"]["name"] for m in left)
    assert "left-behind" in names and "speed-limit" in names, names
    held = [m["metadata"]["name"] for m in left if m["metadata"].get("finalizers")]
    assert held == [], held
    # (the talker and `helm test`'s pod are not the release's)
    selector = "app.kubernetes.io/instance=erv2,app.kubernetes.io/component in (handler,operator)"
    until(
        "the release's pods to go",
        lambda: (
            not json.loads(cluster.run("get", "pods", "-n", ns, "-l", selector, "-o", "json"))[
                "items"
            ]
        ),
    )
    cluster.run("delete", "monitors", "--all", "-n", ns, "--timeout=30s")  # not stuck


def handoffs(cluster: Cluster, ns: str, name: str) -> dict[str, list[str]]:
    """The handlers' records of the handoffs of monitor ``name``: epoch -> the steps
    recorded (held, adopted, committed, aborted), from the logs of both handlers."""
    logs = cluster.run("logs", "-n", ns, "-l", "app.kubernetes.io/component=handler", "--tail=-1")
    found: dict[str, list[str]] = {}
    for line in logs.splitlines():
        _, sep, record = line.partition("handoff ")
        epoch, _, rest = record.partition(" ")
        what, _, names = rest.partition(": ")
        if sep and epoch.isdigit() and name in names.split(", "):
            found.setdefault(epoch, []).append(what.split()[0])
    return found


class DriverKilled(BaseException):
    """The driver of a handoff dies (no handler error: nothing of ours catches it)."""


class DiesBeforeCommit(HandlerClient):
    def handoff(self, step: str, *args: Any, **kwargs: Any) -> tuple[int, bytes]:
        if step == "commit":
            raise DriverKilled(step)
        return super().handoff(step, *args, **kwargs)


def restarted_mid_handoff(cluster: Cluster, ns: str, name: str) -> None:
    """With the operator stopped, a move from the cloud to the edge is driven up to the
    adoption and never committed: the state an operator killed there leaves (the edge
    runs it, the cloud holds it released). The spec is edited to the edge meanwhile.
    The operator started again settles it: the cloud lets go, one copy runs, on the edge."""
    operator = "app.kubernetes.io/component=operator"
    cluster.run("scale", "deployment", "-n", ns, "-l", operator, "--replicas=0")
    until(
        "the operator to stop",
        lambda: (
            not json.loads(cluster.run("get", "pods", "-n", ns, "-l", operator, "-o", "json"))[
                "items"
            ]
        ),
    )
    address = {
        t: f"{handler_pod(cluster, ns, t)['status']['hostIP']}:8471" for t in ("edge", "cloud")
    }
    tls = handler_tls(cluster, ns, "erv2")
    edge = HandlerClient(address["edge"], TOKEN, tls)
    cloud = HandlerClient(address["cloud"], TOKEN, tls)
    with pytest.raises(DriverKilled):
        migrate(DiesBeforeCommit(address["cloud"], TOKEN, tls), edge, [name], timeout=30.0)
    held = cloud.monitor(name)
    assert held is not None and held["handoff"] == "released", held
    assert (runs := edge.monitor(name)) is not None and runs["active"], runs
    set_tier(cluster, ns, "speed-limit", "edge")
    cluster.run("scale", "deployment", "-n", ns, "-l", operator, "--replicas=1")

    def settled() -> bool:
        report = cloud.monitor(name)
        return report is not None and report["handoff"] is None and not report["active"]

    until("the restarted operator to settle the handoff", settled, timeout=180)
    assert (runs := edge.monitor(name)) is not None and runs["active"], runs
    got = until(
        "the status on the edge",
        lambda: (s := status(cluster, ns, "speed-limit")).get("tier") == "edge" and s,
    )
    assert got["phase"] == "Running", got
    logs = cluster.run("logs", "-n", ns, "-l", operator, "--tail=-1")
    handlers = cluster.run(
        "logs", "-n", ns, "-l", "app.kubernetes.io/component=handler", "--tail=-1"
    )
    assert "settled a handoff no one drove" in logs, logs + handlers
    records = handoffs(cluster, ns, name)
    assert len(records) == 2 and all("committed" in r for r in records.values()), records


def rotated_token(cluster: Cluster, ns: str) -> None:
    """`kubectl patch` of the token's Secret: the kubelet updates the mounted file on each
    node (within its sync period, a minute by default); the handlers then refuse the old
    token and take the new one, and the operator, following its own file, places a new
    Monitor with it. Nothing restarts: the pods' restart counts stay 0."""
    new = f"rotated-{uuid.uuid4().hex}"
    encoded = base64.b64encode(new.encode()).decode()
    cluster.run(
        "patch", "secret", "erv2-token", "-n", ns, "--type=merge",
        "-p", json.dumps({"data": {"token": encoded}}),
    )  # fmt: skip
    addresses = [
        f"{handler_pod(cluster, ns, t)['status']['hostIP']}:8471" for t in ("edge", "cloud")
    ]

    tls = handler_tls(cluster, ns, "erv2")

    def takes(address: str, token: str) -> bool:
        try:
            HandlerClient(address, token, tls).monitors(timeout=5.0)
        except ApiError:
            return False
        return True

    until(
        "the handlers to take the new token",
        lambda: all(takes(a, new) and not takes(a, TOKEN) for a in addresses),
        timeout=180,
    )
    apply(cluster, ns, monitor("after-rotation", "always (speed < limit)"))
    got = until(
        "the operator to place a Monitor with the new token",
        lambda: (s := status(cluster, ns, "after-rotation")).get("phase") == "Running" and s,
        timeout=180,
    )
    assert got["tier"] == "edge", got
    pods = json.loads(cluster.run("get", "pods", "-n", ns, "-o", "json"))["items"]
    restarts = {
        p["metadata"]["name"]: c["restartCount"]
        for p in pods
        for c in p["status"].get("containerStatuses", [])
    }
    assert not any(restarts.values()), restarts


# -- moves by the handoff: tier edits and pods going away (#16) -----------------------------


def events_of(cluster: Cluster, namespace: str, name: str) -> list[dict[str, Any]]:
    out = cluster.run(
        "get", "events", "-n", namespace, "--field-selector",
        f"involvedObject.name={name},involvedObject.kind=Monitor", "-o", "json",
    )  # fmt: skip
    return list(json.loads(out)["items"])


def evaluated(cluster: Cluster, namespace: str, name: str, last_step: int) -> Any:
    """The status once the monitor's verdicts reached ``last_step``."""
    return until(
        "every message evaluated",
        lambda: (
            (s := status(cluster, namespace, name)).get("lastVerdict", {}).get("step", 0)
            >= last_step
            and s
        ),
        timeout=150,
    )


def settled_on(cluster: Cluster, namespace: str, name: str, tier: str, moves: int) -> Any:
    return until(
        f"{name} running on {tier} after {moves} move(s)",
        lambda: (
            (s := status(cluster, namespace, name)).get("tier") == tier
            and s.get("phase") == "Running"
            and (s.get("migrations") or {}).get("count") == moves
            and s
        ),
        timeout=120,
    )


def test_a_tier_edit_moves_the_monitor_by_the_handoff_both_ways(
    cluster: Cluster, namespace: str, operator: KopfRunner, tmp_path: Path
) -> None:
    """`kubectl patch` of spec.placement.tier: edge -> cloud -> edge while a counter
    publishes. Each move keeps the state: the verdicts over the whole run equal edgerv
    check on the messages published; status, Events and printer columns say both moves."""
    name = "moving"
    apply(cluster, namespace, counting_monitor(name))
    until("it to run on the edge", lambda: status(cluster, namespace, name).get("tier") == "edge")
    apply(cluster, namespace, counter_pod(cluster, "counter"))
    until("the first violations", lambda: status(cluster, namespace, name).get("lastVerdict"))
    for tier, moves in (("cloud", 1), ("edge", 2)):
        set_tier(cluster, namespace, name, tier)
        got = settled_on(cluster, namespace, name, tier, moves)
        assert got["migrations"]["last"]["reason"] == f"spec.placement.tier is {tier}", got
    violations, last_step = expected_verdicts(tmp_path)
    got = evaluated(cluster, namespace, name, last_step)
    assert got["verdicts"]["violated"] == violations, got  # none lost, none twice
    assert got["lastVerdict"] == {"verdict": "violated", "step": last_step,
                                  "stamp": got["lastVerdict"]["stamp"]}, got  # fmt: skip
    assert got["observedGeneration"] == 3, got  # created, then two edits
    moved = [e for e in events_of(cluster, namespace, name) if e["reason"] == "Moved"]
    assert len(moved) == 2, moved
    assert "to cloud-" in moved[0]["message"] or "(cloud)" in moved[0]["message"], moved
    described = cluster.run("describe", "monitor", name, "-n", namespace)
    assert "Moved" in described and "Ready" in described, described
    table = cluster.run("get", "monitors", name, "-n", namespace, "-o", "wide")
    header = table.splitlines()[0].split()
    for column in ("PHASE", "TIER", "NODE", "LAST", "VIOLATIONS", "MOVES", "ASSERTION"):
        assert column in header, table
    assert "always (count < limit)" in table and "violated" in table, table
    cluster.run("delete", "pod", "counter", "-n", namespace, "--wait=false")
    cluster.run("delete", "monitor", name, "-n", namespace, "--timeout=60s")


def handler_pod_name(cluster: Cluster, namespace: str, tier: str) -> str:
    return str(handler_pod(cluster, namespace, tier)["metadata"]["name"])


def test_a_handler_pod_going_away_hands_its_monitors_over(
    cluster: Cluster, namespace: str, operator: KopfRunner, tmp_path: Path
) -> None:
    """`kubectl delete pod` of the edge handler: during its termination grace (the
    handler's --drain) the operator moves its monitor to the cloud by the handoff: the
    state goes with it (the verdicts equal edgerv check), status and an Event say so."""
    name = "drained"
    apply(cluster, namespace, counting_monitor(name))
    until("it to run on the edge", lambda: status(cluster, namespace, name).get("tier") == "edge")
    apply(cluster, namespace, counter_pod(cluster, "counter-2"))
    until("the first violations", lambda: status(cluster, namespace, name).get("lastVerdict"))
    edge = handler_pod_name(cluster, namespace, "edge")
    cluster.run("delete", "pod", edge, "-n", namespace, "--wait=false")
    got = settled_on(cluster, namespace, name, "cloud", 1)
    assert got["migrations"]["last"]["reason"] == f"pod {edge} is going away", got
    assert "stateLost" not in got, got
    violations, last_step = expected_verdicts(tmp_path)
    got = evaluated(cluster, namespace, name, last_step)
    assert got["verdicts"]["violated"] == violations and got["lastVerdict"]["step"] == last_step
    reasons = [e["reason"] for e in events_of(cluster, namespace, name)]
    assert "Moved" in reasons and "StateLost" not in reasons, reasons
    logs = cluster.run("logs", "-n", namespace, edge, "--tail=-1", check=False)
    cluster.run("delete", "pod", "counter-2", "-n", namespace, "--wait=false")
    cluster.run("delete", "monitor", name, "-n", namespace, "--timeout=60s")
    until("a new edge handler", lambda: pod_name_or_none(cluster, namespace, "edge") not in
          (None, edge))  # fmt: skip
    assert logs == "" or "drain" in logs, logs  # (a deleted pod's log may be gone already)


def pod_name_or_none(cluster: Cluster, namespace: str, tier: str) -> str | None:
    try:
        return handler_pod_name(cluster, namespace, tier)
    except ValueError:  # none, or two while one is going
        return None


def test_a_crashed_handler_loses_the_state_and_says_so(
    cluster: Cluster, namespace: str, operator: KopfRunner
) -> None:
    """kill -9 of the handler running a monitor: its container restarts empty; the
    operator starts the monitor again (afresh), and its status and an Event say the
    state was lost. (The project's cluster only: its nodes' processes are this host's.)"""
    if not cluster.link:
        pytest.skip("kills a handler's process from the host: the project's cluster only")
    name = "crashed"
    apply(cluster, namespace, talker_pod(cluster))
    apply(cluster, namespace, monitor(name, "always (speed < limit)", placement={"tier": "edge"}))
    until("verdicts", lambda: status(cluster, namespace, name).get("lastVerdict"), timeout=150)
    pattern = "edgerv handler --name=edge --listen=0.0.0.0:8470"
    pids = subprocess.run(["pgrep", "-f", pattern], capture_output=True, text=True).stdout.split()
    assert pids, f"no process matches {pattern!r}"
    subprocess.run(["kill", "-9", *pids], check=True)
    got = until(
        "the loss in the status",
        lambda: (s := status(cluster, namespace, name)).get("stateLost") and s,
        timeout=120,
    )
    assert "the monitor's state is lost" in got["stateLost"]["message"], got
    reasons = [e["reason"] for e in events_of(cluster, namespace, name)]
    assert reasons.count("StateLost") == 1, reasons
    again = until(
        "it to run again",
        lambda: (s := status(cluster, namespace, name)).get("phase") == "Running" and s,
        timeout=150,
    )
    assert again["verdicts"]["violated"] >= got["verdicts"]["violated"], (got, again)
    cluster.run("delete", "monitor", name, "-n", namespace, "--timeout=60s")


def crd_spec_properties(cluster: Cluster) -> dict[str, Any]:
    crd = json.loads(cluster.run("get", "crd", "monitors.edgerv.io", "-o", "json"))
    (version,) = crd["spec"]["versions"]
    return dict(version["schema"]["openAPIV3Schema"]["properties"]["spec"]["properties"])


def test_helm_upgrade_brings_a_changed_crd_and_uninstall_keeps_it(
    cluster: Cluster, namespace: str, tmp_path: Path
) -> None:
    """The CRDs are the chart's templates: the cluster's Monitor CRD is the repository's,
    an upgrade to a chart whose CRD changed changes the cluster's (a chart's crds/
    directory would never reach it), and `helm uninstall` keeps it (crds.keep: deleting a
    CRD deletes every Monitor). Runs last in this file: it uninstalls the release."""
    source = yaml.safe_load(CRD.read_text())
    wanted = source["spec"]["versions"][0]["schema"]["openAPIV3Schema"]["properties"]["spec"]
    assert crd_spec_properties(cluster).keys() == wanted["properties"].keys()
    changed = tmp_path / "edgerv"
    shutil.copytree(CHART, changed, symlinks=False)  # the CRD link: a copy of the file
    crd_file = changed / "files" / "crds" / "monitors.edgerv.io.yaml"
    edited = yaml.safe_load(crd_file.read_text())
    spec = edited["spec"]["versions"][0]["schema"]["openAPIV3Schema"]["properties"]["spec"]
    spec["properties"]["e2eNote"] = {"type": "string", "description": "added by an upgrade"}
    crd_file.write_text(yaml.safe_dump(edited))

    def upgrade(chart: Path) -> None:
        done = subprocess.run(
            [helm(), "upgrade", RELEASE, str(chart), "--namespace", namespace,
             "--kubeconfig", cluster.kubeconfig, "--reuse-values", "--wait", "--timeout", "240s"],
            capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr

    upgrade(changed)
    assert crd_spec_properties(cluster)["e2eNote"]["description"] == "added by an upgrade"
    upgrade(CHART)
    assert "e2eNote" not in crd_spec_properties(cluster)
    done = subprocess.run(
        [helm(), "uninstall", RELEASE, "--namespace", namespace, "--kubeconfig",
         cluster.kubeconfig, "--wait", "--timeout", "120s"],
        capture_output=True, text=True, timeout=180,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "kept due to the resource policy" in done.stdout + done.stderr, done.stdout
    assert crd_spec_properties(cluster).keys() == wanted["properties"].keys()  # still there
    selector = "app.kubernetes.io/component=handler"
    until(
        "the handlers to go",
        lambda: (
            not json.loads(
                cluster.run("get", "pods", "-n", namespace, "-l", selector, "-o", "json")
            )["items"]
        ),
    )
