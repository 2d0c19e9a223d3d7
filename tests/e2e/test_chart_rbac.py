"""The operator's rights (#18, least privilege), on the real cluster and as rendered.

With Monitors in every namespace (operator.watchNamespaces empty) the operator runs in the
cluster with the chart's rights and places a Monitor of another namespace, while its
ServiceAccount may read pods in the release's namespace only: Kopf would watch every
resource of one operator in one scope, so the handler pods have an operator of their own,
watching that namespace (edgerv_operator/pods.py). The handlers' ServiceAccount has no
right, and Monitor rights come with the built-in view and edit roles. (With watchNamespaces
set: test_chart_and_operator.py::test_helm_install_runs_the_operator_in_the_cluster.)

A module of its own: a cluster-wide operator sees every Monitor of the cluster, so it runs
where no other release's Monitors are (test_chart_and_operator.py's have gone with their
CRD at the end of that module).
"""

from __future__ import annotations

import json
import subprocess
import uuid
from typing import Any

import yaml

from kit.chart import (
    CHART,
    TOKEN,
    apply,
    helm,
    install,
    monitor,
    never_refused,
    rights,
    status,
    talker_pod,
    unfinalize,
    until,
)
from kit.kube import Cluster

CRDS = ("monitors.edgerv.io", "kopfpeerings.kopf.dev", "clusterkopfpeerings.kopf.dev")


def test_a_cluster_wide_operator_reads_pods_in_its_namespace_only(cluster: Cluster) -> None:
    ns, other = (f"edgerv-rbac-{uuid.uuid4().hex[:6]}" for _ in range(2))
    until(  # a CRD an earlier module deleted (--wait=false) must be gone to be made again
        "the CRDs of an earlier release to go",
        lambda: not any(cluster.attempt("get", "crd", crd)[0] == 0 for crd in CRDS),
    )
    try:
        # a first install on a cluster without the CRDs, the operator on (its release's
        # ClusterKopfPeering is made: Kopf's CRDs come from the chart's crds/, installed
        # before the templates), as `helm install` is a user's first step
        install(cluster, "ervc", ns, "handler.port=8472", f"token.value={TOKEN}")
        cluster.run("create", "namespace", other)
        apply(cluster, other, talker_pod(cluster))
        apply(cluster, other, monitor("speed-limit", "always (speed < limit)"))
        got = until(
            "verdicts from the cluster-wide operator",
            lambda: (
                (s := status(cluster, other, "speed-limit")).get("verdicts", {}).get("violated")
                and s
            ),
            timeout=180,
        )
        assert got["phase"] == "Running" and got["tier"] == "edge", got
        got = rights(
            cluster,
            f"{ns}/ervc-operator",
            [
                ("list", "pods", "-n", ns), ("watch", "pods", "-n", ns),
                ("get", "pods", "-n", ns),
                ("list", "pods", "-n", other), ("watch", "pods", "-n", other),
                ("list", "pods", "--all-namespaces"), ("watch", "pods", "--all-namespaces"),
                ("list", "monitors.edgerv.io", "--all-namespaces"),
                ("watch", "monitors.edgerv.io", "--all-namespaces"),
                ("patch", "monitors.edgerv.io", "-n", other),
                ("patch", "monitors.edgerv.io", "-n", other, "--subresource=status"),
                ("get", "monitors.edgerv.io", "-n", other),
                ("update", "monitors.edgerv.io", "-n", other),
                ("create", "monitors.edgerv.io", "-n", other),
                ("create", "events", "-n", other),
                ("patch", "clusterkopfpeerings.kopf.dev/ervc-operator"),
                ("patch", "clusterkopfpeerings.kopf.dev/another"),
                ("list", "clusterkopfpeerings.kopf.dev"),
                ("list", "kopfpeerings.kopf.dev", "-n", other),
                ("list", "nodes"), ("watch", "nodes"), ("get", "nodes"),
                ("list", "namespaces"),
                ("list", "customresourcedefinitions.apiextensions.k8s.io"),
                ("get", "secrets", "-n", ns),
            ],
        )  # fmt: skip
        assert {q for q, yes in got.items() if yes} == {
            f"list pods -n {ns}", f"watch pods -n {ns}",
            "list monitors.edgerv.io --all-namespaces",
            "watch monitors.edgerv.io --all-namespaces",
            f"patch monitors.edgerv.io -n {other}",
            f"patch monitors.edgerv.io -n {other} --subresource=status",
            f"create events -n {other}",
            "patch clusterkopfpeerings.kopf.dev/ervc-operator",
            "list clusterkopfpeerings.kopf.dev",
            "list nodes", "watch nodes",
        }, got  # fmt: skip
        # the handlers: no right at all (and no token mounted: test_chart_and_operator.py)
        handler = rights(
            cluster,
            f"{ns}/ervc-handler",
            [("list", "pods", "-n", ns), ("get", "secrets", "-n", ns), ("list", "nodes"),
             ("list", "monitors.edgerv.io", "-n", ns)],
        )  # fmt: skip
        assert not any(handler.values()), handler
        sa = json.loads(cluster.run("get", "sa", "ervc-handler", "-n", ns, "-o", "json"))
        assert sa["automountServiceAccountToken"] is False, sa
        monitor_rights_are_aggregated(cluster, other)
        never_refused(cluster, ns)
        cluster.run("delete", "monitor", "speed-limit", "-n", other, "--timeout=60s")
    finally:
        cluster.run("delete", "monitors", "--all", "-n", other, "--timeout=60s", check=False)
        unfinalize(cluster)
        subprocess.run(
            [helm(), "uninstall", "ervc", "--namespace", ns, "--kubeconfig", cluster.kubeconfig],
            capture_output=True,
            timeout=180,
        )
        for name in (ns, other):
            cluster.run("delete", "namespace", name, "--wait=false", check=False)
        for crd in CRDS:  # made by this test
            cluster.run("delete", "crd", crd, "--wait=false", check=False)


def monitor_rights_are_aggregated(cluster: Cluster, ns: str) -> None:
    """A user bound to the built-in `edit` ClusterRole in a namespace may create Monitors
    there, one bound to `view` may read them only: the chart's roles aggregate into them."""
    for user, role in (("e2e-editor", "edit"), ("e2e-viewer", "view")):
        cluster.run("create", "rolebinding", user, f"--clusterrole={role}", f"--user={user}",
                    "-n", ns)  # fmt: skip

    def may(user: str, verb: str) -> bool:
        _, out, _ = cluster.attempt("auth", "can-i", verb, "monitors.edgerv.io", "-n", ns,
                                    f"--as={user}")  # fmt: skip
        return out.strip() == "yes"

    assert [may("e2e-editor", v) for v in ("create", "patch", "delete", "list")] == [True] * 4
    assert [may("e2e-viewer", v) for v in ("list", "watch", "get")] == [True] * 3
    assert [may("e2e-viewer", v) for v in ("create", "patch", "delete")] == [False] * 3


# -- as rendered: who may read pods, where ---------------------------------------------------


def rbac(values: list[str]) -> list[dict[str, Any]]:
    args = [helm(), "template", "r", str(CHART), "--namespace", "rel"]
    for value in values:
        args += ["--set", value]
    done = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    docs = [d for d in yaml.safe_load_all(done.stdout) if d]
    return [d for d in docs if d["kind"] in ("Role", "ClusterRole")]


def granted(roles: list[dict[str, Any]], name: str) -> dict[tuple[str, str], set[str]]:
    """(kind, namespace) -> the resources the role ``name`` grants there."""
    return {
        (r["kind"], r["metadata"].get("namespace", "")): {
            res for rule in r["rules"] for res in rule["resources"]
        }
        for r in roles
        if r["metadata"]["name"] in (name, f"{name}-pods")
    }


def test_the_rendered_operator_roles_read_pods_in_the_release_namespace_only() -> None:
    every = granted(rbac([]), "r-operator")
    assert every == {
        ("ClusterRole", ""): {
            "nodes", "monitors", "monitors/status", "events", "clusterkopfpeerings"
        },
        ("Role", "rel"): {"pods"},
    }, every  # fmt: skip
    watched = granted(rbac(["operator.watchNamespaces={a,b}"]), "r-operator")
    in_watched = {"monitors", "monitors/status", "events", "kopfpeerings"}
    assert watched == {
        ("ClusterRole", ""): {"nodes"},
        ("Role", "rel"): {"pods"},
        ("Role", "a"): in_watched,
        ("Role", "b"): in_watched,
    }, watched
    for roles in (rbac([]), rbac(["operator.watchNamespaces={a}"])):
        for r in roles:
            if r["metadata"]["name"].startswith("r-operator"):
                verbs = {v for rule in r["rules"] for v in rule["verbs"]}
                assert verbs <= {"list", "watch", "patch", "create"}, r
                creates = [x for x in r["rules"] if "create" in x["verbs"]]
                assert all(x["resources"] == ["events"] for x in creates), r
