"""The chart rendered for the value sets users choose, checked by the real API server of
Kubernetes v1.33 (a server-side dry run: every object validated against the server's own
schemas, admission included; the closest thing here to kubeconform), and `helm lint`.

Each value set also has what it promises checked in the rendered objects: TLS on or off
end to end (handler flags, probes' scheme, the operator's settings, the mounts), the
hardened securityContext of every container, and no value set that renders nothing.
"""

from __future__ import annotations

import json
import subprocess
import uuid
from collections.abc import Iterator
from typing import Any

import pytest
import yaml
from kube import Cluster
from test_chart_and_operator import CHART, helm

VALUE_SETS: dict[str, list[str]] = {
    "defaults": [],
    "plain HTTP": ["tls.enabled=false"],
    "your own certificate": ["tls.existingSecret=robot-tls", "tls.serverName=handlers.example"],
    "your own token": ["token.create=false", "token.existingSecret=robot-token"],
    "no operator, no CRDs": ["operator.enabled=false", "crds.install=false"],
    "watched namespaces, CRDs removed on uninstall": [
        "operator.watchNamespaces={NS}",  # NS: the scratch namespace (objects go there too)
        "crds.keep=false",
        "operator.replicas=2",
    ],
    "per tier, by digest, scraped": [
        "operator.tiers={edge,fog,cloud}",
        "handler.tiers.edge.tolerations[0].key=robot.example/dedicated",
        "handler.tiers.edge.tolerations[0].operator=Exists",
        "handler.tiers.edge.resources.limits.cpu=1",
        "handler.tiers.cloud.extraArgs={--max-monitors,20000}",
        "handler.image.digest=sha256:" + "ab" * 32,
        "metrics.serviceMonitor.enabled=true",
    ],
    "DDS: discovery, static peers, shared memory": [
        "handler.rosDomainId=42",
        "handler.ros.discoveryRange=LOCALHOST",
        "handler.ros.staticPeers={10.0.0.7,robot.local}",
        "handler.ros.transports=DEFAULT",
        "handler.ros.hostShm=true",
        "handler.tiers.cloud.extraEnv.ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET",
    ],
}


# The kinds the chart's CRDs define (files/crds/), and the Prometheus Operator's
# ServiceMonitor: the custom resources it may render.
CUSTOM_KINDS = {
    d["spec"]["names"]["kind"]
    for path in sorted((CHART / "files" / "crds").glob("*.yaml"))
    for d in yaml.safe_load_all(path.read_text())
    if d
} | {"ServiceMonitor"}


def render(release: str, ns: str, values: list[str]) -> list[dict[str, Any]]:
    args = [helm(), "template", release, str(CHART), "--namespace", ns]
    for value in values:
        args += ["--set", value]
    done = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return [d for d in yaml.safe_load_all(done.stdout) if d]


@pytest.fixture(scope="module")
def scratch(cluster: Cluster) -> Iterator[str]:
    ns = f"edgerv-render-{uuid.uuid4().hex[:6]}"
    cluster.run("create", "namespace", ns)
    try:
        yield ns
    finally:
        cluster.run("delete", "namespace", ns, "--wait=false", check=False)


def test_helm_lint_passes() -> None:
    done = subprocess.run(
        [helm(), "lint", str(CHART), "--strict"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stdout + done.stderr


def test_bad_values_are_refused_by_the_values_schema() -> None:
    for value, says in [
        ("tls.enabled=maybe", "at '/tls/enabled': got string, want boolean"),
        ("tls.serverName=Not_A_Name", "at '/tls/serverName'"),
        ("tls.validityDays=0", "at '/tls/validityDays'"),
        ("tls.cert=x", "at '/tls': additional properties 'cert' not allowed"),
        ("handler.ros.discoveryRange=LAN", "at '/handler/ros/discoveryRange'"),
        ("handler.ros.staticPeers={a;b}", "at '/handler/ros/staticPeers/0'"),
    ]:
        done = subprocess.run(
            [helm(), "template", "r", str(CHART), "--set", value],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert done.returncode != 0 and says in done.stderr, (value, done.stderr)


def containers(docs: list[dict[str, Any]], component: str) -> list[dict[str, Any]]:
    """The containers of the component's workloads (the handlers': one DaemonSet a tier)."""
    return [
        c
        for d in docs
        if d["kind"] in ("DaemonSet", "Deployment")
        and d["metadata"]["labels"].get("app.kubernetes.io/component") == component
        for c in d["spec"]["template"]["spec"]["containers"]
    ]


def env_of(container: dict[str, Any]) -> dict[str, str]:
    return {e["name"]: e.get("value", "") for e in container.get("env", [])}


@pytest.mark.parametrize("name", list(VALUE_SETS))
def test_each_value_set_renders_objects_the_api_server_accepts(
    cluster: Cluster, scratch: str, name: str
) -> None:
    values = [v.replace("NS", scratch) for v in VALUE_SETS[name]]
    docs = render("r", scratch, values)
    kinds = sorted({d["kind"] for d in docs})
    assert "DaemonSet" in kinds, kinds
    known = json.loads(cluster.run("get", "crd", "-o", "json"))["items"]
    served = {c["spec"]["names"]["kind"] for c in known}
    # A custom resource (Kopf's peering objects) cannot be dry-run where its CRD is not in
    # the cluster yet (the CRD is only dry-run created in the same call): left out.
    checkable = [d for d in docs if d["kind"] not in CUSTOM_KINDS - served]
    # A pod's ServiceAccount must exist for its admission (`helm test`'s pod): those of the
    # render are made for real first, in the scratch namespace, which goes after the tests.
    accounts = [d for d in checkable if d["kind"] == "ServiceAccount"]
    cluster.run("apply", "-n", scratch, "-f", "-", input="\n---\n".join(map(json.dumps, accounts)))
    code, out, err = cluster.attempt(
        "apply", "--dry-run=server", "-n", scratch, "-f", "-",
        input="\n---\n".join(json.dumps(d) for d in checkable),
    )  # fmt: skip
    assert code == 0, f"{name}: {err}"
    assert out.count("(server dry run)") == len(checkable), out
    for c in (containers(docs, "handler") + (
        containers(docs, "operator") if "operator.enabled=false" not in values else []
    )):  # fmt: skip
        sc = c["securityContext"]
        assert sc["runAsNonRoot"] and sc["readOnlyRootFilesystem"], (name, c["name"], sc)
        assert sc["capabilities"] == {"drop": ["ALL"]} and not sc["allowPrivilegeEscalation"]
        assert sc["seccompProfile"] == {"type": "RuntimeDefault"}
    tiers = ["edge", "fog", "cloud"] if "operator.tiers={edge,fog,cloud}" in values else [
        "edge", "cloud"
    ]  # fmt: skip
    handlers = {  # tier -> its DaemonSet and the handler container
        d["metadata"]["labels"]["edgerv.io/handler-tier"]: (
            d,
            d["spec"]["template"]["spec"]["containers"][0],
        )
        for d in docs
        if d["kind"] == "DaemonSet"
    }
    assert sorted(handlers) == sorted(tiers), handlers.keys()  # a DaemonSet a tier
    for tier, (ds, c) in handlers.items():
        (term,) = ds["spec"]["template"]["spec"]["affinity"]["nodeAffinity"][
            "requiredDuringSchedulingIgnoredDuringExecution"
        ]["nodeSelectorTerms"]
        assert term["matchExpressions"] == [
            {"key": "edgerv.io/tier", "operator": "In", "values": [tier]}
        ], term
        assert ds["spec"]["selector"]["matchLabels"]["edgerv.io/handler-tier"] == tier
        assert c["resources"]["requests"], c["resources"]  # never the first evicted
    if name == "per tier, by digest, scraped":
        edge, cloud = handlers["edge"], handlers["cloud"]
        assert edge[0]["spec"]["template"]["spec"]["tolerations"] == [
            {"key": "robot.example/dedicated", "operator": "Exists"}
        ]
        assert "tolerations" not in cloud[0]["spec"]["template"]["spec"]
        assert edge[1]["resources"] == {  # the tier's over the common ones
            "requests": {"cpu": "100m", "memory": "256Mi"},
            "limits": {"cpu": 1, "memory": "1Gi"},
        }, edge[1]["resources"]
        assert cloud[1]["args"][-2:] == ["--max-monitors", "20000"]
        assert "--max-monitors" not in edge[1]["args"]
        assert cloud[1]["image"] == "edgerv/handler@sha256:" + "ab" * 32
        (monitor,) = [d for d in docs if d["kind"] == "ServiceMonitor"]
        (endpoint,) = monitor["spec"]["endpoints"]
        assert endpoint["scheme"] == "https" and endpoint["tlsConfig"]["serverName"] == (
            f"r-handler.{scratch}.svc"
        ), endpoint
    dds = name == "DDS: discovery, static peers, shared memory"
    for tier, (ds, c) in handlers.items():  # ROS 2 discovery and transport, as the values say
        env = env_of(c)
        assert env["ROS_DOMAIN_ID"] == ("42" if dds else "0"), env
        assert env["FASTDDS_BUILTIN_TRANSPORTS"] == ("DEFAULT" if dds else "UDPv4"), env
        assert env.get("ROS_STATIC_PEERS") == ("10.0.0.7;robot.local" if dds else None), env
        assert env.get("ROS_AUTOMATIC_DISCOVERY_RANGE") == (
            None if not dds else "SUBNET" if tier == "cloud" else "LOCALHOST"  # extraEnv wins
        ), env
        assert len(env) == len(c["env"]), c["env"]  # each variable once
        pod = ds["spec"]["template"]["spec"]
        shm = [v for v in pod["volumes"] if v.get("hostPath", {}).get("path") == "/dev/shm"]
        mounted = [m for m in c["volumeMounts"] if m["mountPath"] == "/dev/shm"]
        assert (len(shm), len(mounted)) == ((1, 1) if dds else (0, 0)), (shm, mounted)
    handler = handlers["edge"][1]
    tls = "tls.enabled=false" not in values
    assert ("--plain-http" in handler["args"]) is not tls, handler["args"]
    assert ("--tls-cert=/var/run/edgerv-tls/tls.crt" in handler["args"]) is tls
    assert handler["readinessProbe"]["httpGet"]["scheme"] == ("HTTPS" if tls else "HTTP")
    if "operator.enabled=false" not in values:
        (operator,) = containers(docs, "operator")
        env = env_of(operator)
        if tls:
            assert env["EDGERV_TLS_CA_FILE"] == "/var/run/edgerv-tls/ca.crt", env
            server_name = "handlers.example" if "tls.serverName=handlers.example" in values else (
                f"r-handler.{scratch}.svc"
            )  # fmt: skip
            assert env["EDGERV_TLS_SERVER_NAME"] == server_name, env
        else:
            assert env["EDGERV_PLAIN_HTTP"] == "true" and "EDGERV_TLS_CA_FILE" not in env, env
    secrets = {d["metadata"]["name"] for d in docs if d["kind"] == "Secret"}
    made_tls = tls and not any(v.startswith("tls.existingSecret=") for v in values)
    assert ("r-tls" in secrets) is made_tls, secrets


def test_the_charts_certificate_names_the_server_and_is_signed_by_its_ca(
    scratch: str, tmp_path: Any
) -> None:
    """What `helm install` puts in the TLS Secret (Helm's genCA and genSignedCert),
    checked by openssl: the certificate verifies against the CA, carries the server
    name the operator verifies, and is for a server. The pods' checksum annotation is of
    this very pair (a new one rolls them)."""
    import base64
    import hashlib

    docs = render("r", scratch, [])
    (secret,) = [d for d in docs if d["kind"] == "Secret" and d["metadata"]["name"] == "r-tls"]
    for key in ("ca.crt", "tls.crt", "tls.key"):
        (tmp_path / key).write_bytes(base64.b64decode(secret["data"][key]))
    verify = subprocess.run(
        ["openssl", "verify", "-CAfile", str(tmp_path / "ca.crt"), str(tmp_path / "tls.crt")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert verify.returncode == 0, verify.stdout + verify.stderr
    ext = subprocess.run(
        ["openssl", "x509", "-in", str(tmp_path / "tls.crt"), "-noout", "-ext",
         "subjectAltName,extendedKeyUsage"],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    assert f"DNS:r-handler.{scratch}.svc" in ext and "TLS Web Server Authentication" in ext
    data = json.dumps(secret["data"], separators=(",", ":"), sort_keys=True)
    digest = hashlib.sha256(data.encode()).hexdigest()
    for d in docs:
        if d["kind"] in ("DaemonSet", "Deployment"):
            assert d["spec"]["template"]["metadata"]["annotations"]["checksum/tls"] == digest
