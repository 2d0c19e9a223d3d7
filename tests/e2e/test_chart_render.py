"""The chart rendered for the value sets users choose, checked twice, and `helm lint`.

Offline, with no cluster (helm and kubeconform as tests/cluster/build.sh builds them):
every manifest of every value set, hooks and `helm test`'s pod included, validated by
`kubeconform -strict` against JSON schemas of Kubernetes v1.33 made from its own OpenAPI
spec (`api/openapi-spec/swagger.json` of the k8s.io/kubernetes v1.33.13 module) and, for
custom resources, from their CRDs: the chart's (`files/crds/`) and the Prometheus
Operator's ServiceMonitor (generated from its Go types by controller-gen), by
tests/cluster/k8s_schemas.py. Unknown fields, wrong types, enums, bounds and quantities
are refused with the field's path; a resource without a schema fails, it is never
skipped. The Monitor documents of the examples and the docs are validated against the
Monitor CRD's schema the same way.

On the cluster, by the real API server of Kubernetes v1.33 (a server-side dry run: every
object validated against the server's own schemas, admission included, and what no
schema says).

Each value set also has what it promises checked in the rendered objects: TLS on or off
end to end (handler flags, probes' scheme, the operator's settings, the mounts), the
hardened securityContext of every container, and no value set that renders nothing.
"""

from __future__ import annotations

import json
import subprocess
import sys
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml

from kit.chart import CHART, ROOT, helm
from kit.kube import Cluster

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


# The chart's CRDs: the Monitor's, templated (files/crds/), and Kopf's peerings, in crds/
# (installed before the templates, so that the release's peering objects can be made).
CRD_FILES = sorted([*(CHART / "files" / "crds").glob("*.yaml"), *(CHART / "crds").glob("*.yaml")])
# The kinds they define, and the Prometheus Operator's ServiceMonitor: the custom
# resources the chart may render.
CUSTOM_KINDS = {
    d["spec"]["names"]["kind"]
    for path in CRD_FILES
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


# --- Offline: kubeconform against Kubernetes v1.33's schemas (no cluster) ------------------

BUILD = ROOT / "tests" / "cluster" / "build.sh"
OFFLINE_NS = "edgerv-render"  # the namespace of the offline renders (NS in VALUE_SETS)
# Where Monitor documents live besides the CRD: the examples, and the docs' YAML blocks.
MONITOR_DOCS = ["examples/**/*.yaml", "README.md", "docs/*.md"]


@dataclass(frozen=True)
class Kubeconform:
    """helm, kubeconform and the JSON schemas, as tests/cluster/build.sh makes them:
    Kubernetes' from its OpenAPI spec, the custom resources' from their CRDs (the chart's,
    and the Prometheus Operator's ServiceMonitor) by tests/cluster/k8s_schemas.py."""

    helm: str
    kubeconform: str
    version: str
    locations: tuple[str, ...]
    custom: tuple[str, ...]  # the CRDs' schema files

    def template(self, values: list[str]) -> str:
        args = [self.helm, "template", "r", str(CHART), "--namespace", OFFLINE_NS]
        for value in values:
            args += ["--set", value]
        done = subprocess.run(args, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        return done.stdout

    def validate(self, text: str) -> tuple[list[dict[str, Any]], dict[str, int]]:
        """kubeconform -strict -summary over ``text``: each resource's result, the summary."""
        args = [self.kubeconform, "-strict", "-summary", "-output", "json", "-verbose"]
        args += ["-kubernetes-version", self.version]
        for location in self.locations:
            args += ["-schema-location", location]
        done = subprocess.run([*args, "-"], input=text, capture_output=True, text=True, timeout=120)
        out = json.loads(done.stdout)
        bad = out["summary"]["invalid"] + out["summary"]["errors"]
        assert done.returncode == (1 if bad else 0), done.stderr  # no other failure
        return out["resources"], out["summary"]


def _versions() -> dict[str, str]:
    text = (BUILD.parent / "versions.env").read_text()
    return dict(line.split("=", 1) for line in text.splitlines() if "=" in line and line[:1] != "#")


@pytest.fixture(scope="module")
def kubeconform(tmp_path_factory: pytest.TempPathFactory) -> Kubeconform:
    """Builds what is missing (build.sh, cached under ~/.cache/edgerv: the first time on a
    machine a few minutes, Go compiling): a failed build fails the tests, never skips them."""
    built = subprocess.run(
        ["bash", str(BUILD), "helm", "kubeconform", "schemas"],
        capture_output=True, text=True, timeout=3600,
    )  # fmt: skip
    if built.returncode != 0:
        pytest.fail(f"build.sh helm kubeconform schemas failed:\n{built.stderr[-4000:]}")
    bins = Path(built.stdout.strip().splitlines()[-1])
    sys.path.insert(0, str(BUILD.parent))
    import k8s_schemas

    versions = _versions()
    version = versions["K8S_VERSION"]
    kubernetes = k8s_schemas.kubernetes_root(version)
    prometheus = (
        kubernetes.parent
        / "crds"
        / f"prometheus-operator-v{versions['PROMETHEUS_OPERATOR_VERSION']}"
    )
    crds = [*CRD_FILES, prometheus / "monitoring.coreos.com_servicemonitors.yaml"]
    docs = [d for path in crds for d in yaml.safe_load_all(path.read_text())]
    out = tmp_path_factory.mktemp("crd-schemas")
    custom = k8s_schemas.make_crds(docs, version, out, kubernetes)
    return Kubeconform(
        str(bins / "helm"), str(bins / "kubeconform"), version,
        (str(kubernetes), str(out)), tuple(custom),
    )  # fmt: skip


def test_the_schemas_cover_every_kind_the_chart_renders(kubeconform: Kubeconform) -> None:
    assert kubeconform.custom == (
        "clusterkopfpeering-kopf-v1.json",
        "kopfpeering-kopf-v1.json",
        "monitor-edgerv-v1alpha1.json",
        "servicemonitor-monitoring-v1.json",
    )
    strict = Path(kubeconform.locations[0]) / f"v{kubeconform.version}-standalone-strict"
    assert len(list(strict.glob("*-*.json"))) > 250  # every kind of the spec, alpha included
    schema = json.loads((strict / "deployment-apps-v1.json").read_text())
    assert schema["properties"]["apiVersion"]["enum"] == ["apps/v1"]
    assert schema["definitions"]["io.k8s.api.core.v1.Container"]["additionalProperties"] is False


@pytest.mark.parametrize("name", list(VALUE_SETS))
def test_each_value_set_renders_manifests_kubeconform_finds_valid(
    kubeconform: Kubeconform, name: str
) -> None:
    """Every manifest the value set renders (hooks and `helm test`'s pod included),
    validated by kubeconform -strict against Kubernetes v1.33's schemas and the CRDs':
    each one valid, none skipped for want of a schema."""
    text = kubeconform.template([v.replace("NS", OFFLINE_NS) for v in VALUE_SETS[name]])
    docs = [d for d in yaml.safe_load_all(text) if d]
    results, summary = kubeconform.validate(text)
    not_valid = [r for r in results if r["status"] != "statusValid"]
    assert summary == {"valid": len(docs), "invalid": 0, "errors": 0, "skipped": 0}, not_valid
    assert sorted((r["kind"], r["name"]) for r in results) == sorted(
        (d["kind"], d["metadata"]["name"]) for d in docs
    )
    kinds = {d["kind"] for d in docs}
    assert "DaemonSet" in kinds, kinds
    assert ("CustomResourceDefinition" in kinds) is ("crds.install=false" not in VALUE_SETS[name])


def _monitor_documents() -> dict[str, list[dict[str, Any]]]:
    """Each file's Monitor documents: YAML files, and the ```yaml blocks of Markdown."""
    found: dict[str, list[dict[str, Any]]] = {}
    for pattern in MONITOR_DOCS:
        for path in sorted(ROOT.glob(pattern)):
            text = path.read_text()
            blocks = (
                [b.split("```", 1)[0] for b in text.split("```yaml\n")[1:]]
                if path.suffix == ".md"
                else [text]
            )
            docs = [d for b in blocks for d in yaml.safe_load_all(b) if d]
            monitors = [d for d in docs if isinstance(d, dict) and d.get("kind") == "Monitor"]
            if monitors:
                found[str(path.relative_to(ROOT))] = monitors
    return found


def test_the_monitor_examples_are_valid_for_the_crds_schema(kubeconform: Kubeconform) -> None:
    found = _monitor_documents()
    assert {"examples/speed-limit.yaml", "examples/robot/case-study.yaml"} <= set(found), found
    for path, monitors in found.items():
        text = "\n---\n".join(json.dumps(d) for d in monitors)
        results, summary = kubeconform.validate(text)
        not_valid = [r for r in results if r["status"] != "statusValid"]
        assert summary == {"valid": len(monitors), "invalid": 0, "errors": 0, "skipped": 0}, (
            path, not_valid,
        )  # fmt: skip


def test_kubeconform_refuses_a_wrong_manifest_naming_the_field(kubeconform: Kubeconform) -> None:
    """The same checks refuse what the API server would refuse: each manifest here is a
    valid one of the chart (or an example) with one mistake, refused with its field's path
    and what is wrong there; and a kind without a schema is an error, not a pass."""
    text = kubeconform.template(["metrics.serviceMonitor.enabled=true"])
    docs = [d for d in yaml.safe_load_all(text) if d]
    of = {d["kind"]: d for d in docs}
    monitor = _monitor_documents()["examples/speed-limit.yaml"][0]
    pod = "/spec/template/spec"

    def changed(doc: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
        doc = json.loads(json.dumps(doc))
        *parents, last = path.strip("/").split("/")
        at: Any = doc
        for key in parents:
            at = at[int(key)] if isinstance(at, list) else at[key]
        at[last] = value
        return doc

    cases = [  # (manifest, the field's path, what kubeconform says there)
        (changed(of["Deployment"], f"{pod}/containers/0/imagePullPolcy", "Always"),
         f"{pod}/containers/0", "additional properties 'imagePullPolcy' not allowed"),
        (changed(of["DaemonSet"], "/spec/minReadySeconds", "ten"),
         "/spec/minReadySeconds", "got string, want null or integer"),
        (changed(of["DaemonSet"], f"{pod}/containers/0/resources/limits/memory", "1GB"),
         f"{pod}/containers/0/resources/limits/memory", "'1GB' does not match pattern"),
        (changed(of["Service"], "/spec/ports/0/port", 2**31),
         "/spec/ports/0/port", "maximum: got 2.147483648"),  # int32's; printed as 2.1×10⁰⁹
        (changed(of["Secret"], "/metadata/labels/tier", 1),
         "/metadata/labels/tier", "got number, want null or string"),
        (changed(of["CustomResourceDefinition"], "/spec/versions/0/schema/openAPIV3Schema/"
                 "properties/status/minLenght", 1),
         "/spec/versions/0/schema/openAPIV3Schema/properties/status",
         "additional properties 'minLenght' not allowed"),
        (changed(monitor, "/spec/sortTreshold", 3), "/spec",
         "additional properties 'sortTreshold' not allowed"),
        (changed(monitor, "/spec/onVerdict", "restart"), "/spec/onVerdict",
         "value must be one of 'reset', 'halt'"),
        (changed(monitor, "/spec/signals/speed/qos", {"depth": 0}),
         "/spec/signals/speed/qos/depth", "minimum: got 0, want 1"),
        (changed(of["ServiceMonitor"], "/spec/endpoints/0/scheme", "tls"),
         "/spec/endpoints/0/scheme", "value must be one of"),
    ]  # fmt: skip
    for doc, path, says in cases:
        (result,), summary = kubeconform.validate(json.dumps(doc))
        assert summary["invalid"] == 1 and result["status"] == "statusInvalid", (says, result)
        # the whole tree of errors ("validationErrors" has its first level only)
        assert f"at '{path}': {says}" in result["msg"], (path, says, result["msg"])
    # A kind no schema describes fails: nothing checked is never a pass.
    (result,), summary = kubeconform.validate(
        "apiVersion: example.com/v1\nkind: Widget\nmetadata: {name: w}\n"
    )
    assert summary == {"valid": 0, "invalid": 0, "errors": 1, "skipped": 0}, summary
    assert result["msg"] == "could not find schema for Widget", result
