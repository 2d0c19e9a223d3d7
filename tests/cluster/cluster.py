"""A real Kubernetes cluster on this machine, built from sources: ``make cluster-up/down``.

What ``up`` does, in order (each step is skipped when already done):

1. binaries: ``build.sh`` compiles Kubernetes (kube-apiserver, controller-manager,
   scheduler, kubelet, kubectl), etcd, helm and pause from the Go module proxy
   into ``~/.cache/edgerv/k8s-vX`` (once per machine); kubectl and helm are
   linked into ``.cluster/bin``;
2. PKI: a CA, serving and client certificates, the service-account key
   (``openssl``), kubeconfigs; the admin one is ``.cluster/kubeconfig``;
3. the control plane, on this host: etcd, kube-apiserver (RBAC and Node
   authorization, NodeRestriction), kube-controller-manager, kube-scheduler;
4. three nodes, ``edge``, ``cloud`` and ``edge-b`` (a second robot's edge node, for
   the fleet tests), each a network namespace with its own containerd (Debian's,
   runc, cgroupfs) and kubelet (its own root dir and cgroup root). Each node
   reaches the API server over a veth pair; each edge node reaches the cloud over
   ``tests/netlab/linkdelay.py``, a user-space link that holds each packet
   ``EDGERV_LINK_DELAY_MS`` (20 ms) each way (no netem here); the two edges do not
   reach each other (two robots).
   Pod networking is the CNI bridge plugin (a subnet per node, no routes
   between the pod subnets; pods reach other nodes' addresses masqueraded as
   their node's): edgerv's handlers use the host network of their node. There is
   no kube-proxy: one NAT rule per node gives pods the ``kubernetes`` Service
   (10.96.0.1:443, the API server), which in-cluster clients (the operator) use;
5. images: a Debian base made with debootstrap and ``docker import``, the
   project's images built FROM it by Docker (``images/``) and imported into
   each node's containerd: ``edgerv/handler:dev``, ``edgerv/operator:dev``, and
   the pause image;
6. labels ``edgerv.io/tier=edge`` / ``cloud`` (``edge-b`` none: no handler runs there
   until a fleet test labels it); waits until every node is Ready.

``rejoin NODE`` restarts a node's kubelet, so that a Node a test deleted (`kubectl
delete node`) registers again. ``down`` stops everything ``up`` started (recorded in
``.cluster/pids``), unmounts what the kubelets and containerds mounted, removes the
namespaces and cgroups. Traffic stays on this machine: loopback, the veths and the link.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
STATE = Path(os.environ.get("EDGERV_CLUSTER_DIR", ROOT / ".cluster"))
CACHE = Path(os.environ.get("EDGERV_CACHE", Path.home() / ".cache" / "edgerv"))
LINKDELAY = ROOT / "tests" / "netlab" / "linkdelay.py"
DELAY_MS = float(os.environ.get("EDGERV_LINK_DELAY_MS", "20"))
PAUSE_IMAGE = "registry.k8s.io/pause:3.10"
HANDLER_IMAGE = "edgerv/handler:dev"
OPERATOR_IMAGE = "edgerv/operator:dev"
BASE_IMAGE = "edgerv/base:bookworm"
# both stages of images/*/Dockerfile carry it, and so every image built FROM them
IMAGE_VENDOR = "org.opencontainers.image.vendor=edgerv"
SERVICE_CIDR = "10.96.0.0/16"
API_PORT = 6443
READY = "jsonpath={.status.conditions[?(@.type=='Ready')].status}"

# name -> veth subnet index, address on its link (the robot's traffic), pod CIDR, the tier
# label its kubelet registers it with. edge-b is a second robot's edge node, with a link of
# its own to the cloud; it starts with no tier label, so no handler runs there and the tests
# of one robot see one edge; the fleet tests (tests/e2e/test_fleet.py) label it.
NODES: dict[str, dict[str, str | int | None]] = {
    "edge": {"index": 1, "link": "10.77.250.1", "pods": "10.244.1.0/24", "tier": "edge"},
    "cloud": {"index": 2, "link": "10.77.250.2", "pods": "10.244.2.0/24", "tier": "cloud"},
    "edge-b": {"index": 3, "link": "10.77.251.1", "pods": "10.244.3.0/24", "tier": None},
}
# the delayed links: (process, node A, its device, node B, its device, B's address there).
# The cloud is 10.77.250.2 from either edge: edge-b routes that address over its own link
# (a host accepts a packet for any of its addresses on any of its devices).
LINKS = [
    ("linkdelay", "edge", "ervkle", "cloud", "ervklc", "10.77.250.2"),
    ("linkdelay-b", "edge-b", "ervklb", "cloud", "ervklcb", "10.77.251.2"),
]


def log(msg: str) -> None:
    print(f"cluster: {msg}", file=sys.stderr, flush=True)


def sh(*args: str, check: bool = True, **kw: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run(list(args), check=check, text=True, capture_output=True, **kw)  # type: ignore[call-overload, no-any-return]


def versions() -> dict[str, str]:
    out = {}
    for line in (HERE / "versions.env").read_text().splitlines():
        if "=" in line and not line.startswith("#"):
            k, v = line.split("=", 1)
            out[k.strip()] = v.strip()
    return out


# -- processes -------------------------------------------------------------------------------


def netns(node: str) -> str:
    return f"ervk-{node}"


def start(
    name: str, argv: list[str], node: str | None = None, env: dict[str, str] | None = None
) -> int:
    """Start a long-running process (in ``node``'s network namespace), recorded for ``down``."""
    logs = STATE / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    if node is not None:  # only the network namespace: mounts must be shared with the host
        argv = ["nsenter", f"--net=/var/run/netns/{netns(node)}", *argv]
    with (logs / f"{name}.log").open("wb") as out:
        proc = subprocess.Popen(
            argv,
            stdout=out,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            env={**os.environ, **(env or {})},
        )
    pids = STATE / "pids"
    pids.mkdir(exist_ok=True)
    (pids / name).write_text(str(proc.pid))
    return proc.pid


def alive(name: str) -> bool:
    f = STATE / "pids" / name
    if not f.exists():
        return False
    try:
        os.kill(int(f.read_text()), 0)
    except (ProcessLookupError, ValueError):
        return False
    return True


def wait(what: str, check: object, timeout: float = 120.0, logname: str | None = None) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            if check():  # type: ignore[operator]
                return
        except Exception:  # not up yet
            pass
        if logname and not alive(logname):
            tail = (STATE / "logs" / f"{logname}.log").read_text()[-3000:]
            raise RuntimeError(f"{logname} exited while waiting for {what}:\n{tail}")
        time.sleep(0.5)
    tail = (STATE / "logs" / f"{logname}.log").read_text()[-3000:] if logname else ""
    raise TimeoutError(f"timed out waiting for {what}\n{tail}")


# -- PKI -------------------------------------------------------------------------------------


def _cert(
    pki: Path, name: str, subject: str, sans: list[str] | None = None, server: bool = False
) -> None:
    key, crt, ext = pki / f"{name}.key", pki / f"{name}.crt", pki / f"{name}.ext"
    usage = "serverAuth" if server else "clientAuth"
    lines = [
        "basicConstraints=CA:FALSE",
        "keyUsage=critical,digitalSignature,keyEncipherment",
        f"extendedKeyUsage={usage}" + (",clientAuth" if server else ""),
    ]
    if sans:
        lines.append("subjectAltName=" + ",".join(sans))
    wanted = "\n".join(lines) + "\n"
    if crt.exists() and ext.exists() and ext.read_text() == wanted:
        return  # made before with these names (a node added since: made again)
    sh("openssl", "genrsa", "-out", str(key), "2048")
    ext.write_text(wanted)
    csr = pki / f"{name}.csr"
    sh("openssl", "req", "-new", "-key", str(key), "-subj", subject, "-out", str(csr))
    sh(
        "openssl", "x509", "-req", "-in", str(csr), "-CA", str(pki / "ca.crt"),
        "-CAkey", str(pki / "ca.key"), "-CAcreateserial", "-days", "3650",
        "-extfile", str(ext), "-out", str(crt),
    )  # fmt: skip


def make_pki() -> Path:
    pki = STATE / "pki"
    pki.mkdir(parents=True, exist_ok=True)
    if not (pki / "ca.crt").exists():
        sh("openssl", "genrsa", "-out", str(pki / "ca.key"), "2048")
        sh(
            "openssl", "req", "-x509", "-new", "-key", str(pki / "ca.key"), "-days", "3650",
            "-subj", "/CN=edgerv-test-ca", "-out", str(pki / "ca.crt"),
        )  # fmt: skip
    sans = ["DNS:kubernetes", "DNS:kubernetes.default", "DNS:kubernetes.default.svc",
            "DNS:kubernetes.default.svc.cluster.local", "DNS:localhost",
            "IP:127.0.0.1", "IP:10.96.0.1"]  # fmt: skip
    sans += [f"IP:10.79.{n['index']}.1" for n in NODES.values()]
    _cert(pki, "apiserver", "/CN=kube-apiserver", sans, server=True)
    _cert(pki, "apiserver-kubelet-client", "/CN=kube-apiserver-kubelet-client/O=system:masters")
    _cert(pki, "etcd", "/CN=etcd", ["IP:127.0.0.1", "DNS:localhost"], server=True)
    _cert(pki, "admin", "/CN=edgerv-admin/O=system:masters")
    _cert(pki, "controller-manager", "/CN=system:kube-controller-manager")
    _cert(pki, "scheduler", "/CN=system:kube-scheduler")
    for node in NODES:
        _cert(pki, f"kubelet-{node}", f"/CN=system:node:{node}/O=system:nodes")
    if not (pki / "sa.key").exists():
        sh("openssl", "genrsa", "-out", str(pki / "sa.key"), "2048")
        sh("openssl", "rsa", "-in", str(pki / "sa.key"), "-pubout", "-out", str(pki / "sa.pub"))
    return pki


def kubeconfig(path: Path, server: str, cert: str) -> Path:
    pki = STATE / "pki"
    path.write_text(
        json.dumps(
            {
                "apiVersion": "v1",
                "kind": "Config",
                "clusters": [
                    {
                        "name": "edgerv",
                        "cluster": {"server": server, "certificate-authority": str(pki / "ca.crt")},
                    }
                ],
                "users": [
                    {
                        "name": cert,
                        "user": {
                            "client-certificate": str(pki / f"{cert}.crt"),
                            "client-key": str(pki / f"{cert}.key"),
                        },
                    }
                ],
                "contexts": [{"name": "edgerv", "context": {"cluster": "edgerv", "user": cert}}],
                "current-context": "edgerv",
            },
            indent=1,
        )
    )
    return path


# -- control plane ---------------------------------------------------------------------------


def control_plane(bins: Path) -> None:
    pki = STATE / "pki"
    if not alive("etcd"):
        start(
            "etcd",
            [
                str(bins / "etcd"), "--data-dir", str(STATE / "etcd"), "--name", "edgerv",
                "--listen-client-urls", "https://127.0.0.1:2379",
                "--advertise-client-urls", "https://127.0.0.1:2379",
                "--listen-peer-urls", "http://127.0.0.1:2380",
                "--cert-file", str(pki / "etcd.crt"), "--key-file", str(pki / "etcd.key"),
                "--client-cert-auth", "--trusted-ca-file", str(pki / "ca.crt"),
                "--log-level", "warn",
            ],
        )  # fmt: skip
    if not alive("kube-apiserver"):
        start(
            "kube-apiserver",
            [
                str(bins / "kube-apiserver"),
                "--etcd-servers", "https://127.0.0.1:2379",
                "--etcd-cafile", str(pki / "ca.crt"),
                "--etcd-certfile", str(pki / "apiserver-kubelet-client.crt"),
                "--etcd-keyfile", str(pki / "apiserver-kubelet-client.key"),
                "--bind-address", "0.0.0.0", "--secure-port", str(API_PORT),
                "--advertise-address", "10.79.1.1",
                "--tls-cert-file", str(pki / "apiserver.crt"),
                "--tls-private-key-file", str(pki / "apiserver.key"),
                "--client-ca-file", str(pki / "ca.crt"),
                "--kubelet-client-certificate", str(pki / "apiserver-kubelet-client.crt"),
                "--kubelet-client-key", str(pki / "apiserver-kubelet-client.key"),
                "--kubelet-preferred-address-types", "InternalIP",
                "--service-account-key-file", str(pki / "sa.pub"),
                "--service-account-signing-key-file", str(pki / "sa.key"),
                "--service-account-issuer", "https://kubernetes.default.svc.cluster.local",
                "--service-cluster-ip-range", SERVICE_CIDR,
                "--authorization-mode", "Node,RBAC",
                "--enable-admission-plugins", "NodeRestriction",
                "--allow-privileged=true",
                "--profiling=false",
            ],
        )  # fmt: skip
    admin = kubeconfig(STATE / "kubeconfig", f"https://127.0.0.1:{API_PORT}", "admin")
    wait(
        "the API server",
        lambda: (
            sh(
                str(bins / "kubectl"), "--kubeconfig", str(admin), "get", "--raw", "/readyz"
            ).returncode
            == 0
        ),
        logname="kube-apiserver",
    )
    cm = kubeconfig(
        STATE / "controller-manager.kubeconfig",
        f"https://127.0.0.1:{API_PORT}",
        "controller-manager",
    )
    if not alive("kube-controller-manager"):
        start(
            "kube-controller-manager",
            [
                str(bins / "kube-controller-manager"), "--kubeconfig", str(cm),
                "--authentication-kubeconfig", str(cm), "--authorization-kubeconfig", str(cm),
                "--service-account-private-key-file", str(pki / "sa.key"),
                "--root-ca-file", str(pki / "ca.crt"),
                "--cluster-signing-cert-file", str(pki / "ca.crt"),
                "--cluster-signing-key-file", str(pki / "ca.key"),
                "--use-service-account-credentials",
                "--service-cluster-ip-range", SERVICE_CIDR,
                "--bind-address", "127.0.0.1", "--leader-elect=false",
            ],
        )  # fmt: skip
    # This API server's own controller manager works: it made the default namespace's
    # ServiceAccount (pods need one). One that could not bind its port (a stray of an
    # earlier cluster holds it) exits, and this says so with its log, instead of a
    # cluster whose Deployments and DaemonSets never get pods.
    wait(
        "the controller manager (the default ServiceAccount)",
        lambda: (
            sh(
                str(bins / "kubectl"), "--kubeconfig", str(admin), "get", "serviceaccount",
                "default", "--namespace", "default",
            ).returncode
            == 0
        ),
        logname="kube-controller-manager",
    )  # fmt: skip
    sched = kubeconfig(STATE / "scheduler.kubeconfig", f"https://127.0.0.1:{API_PORT}", "scheduler")
    if not alive("kube-scheduler"):
        start(
            "kube-scheduler",
            [
                str(bins / "kube-scheduler"), "--kubeconfig", str(sched),
                "--authentication-kubeconfig", str(sched), "--authorization-kubeconfig", str(sched),
                "--bind-address", "127.0.0.1", "--leader-elect=false",
            ],
        )  # fmt: skip


# -- nodes -----------------------------------------------------------------------------------


def node_network() -> None:
    """The nodes' namespaces, their veths to this host, and the delayed link between them."""
    existing = sh("ip", "netns", "list").stdout
    for node, n in NODES.items():
        ns, i = netns(node), n["index"]
        if ns not in existing:
            sh("ip", "netns", "add", ns)
            sh("ip", "-n", ns, "link", "set", "lo", "up")
            host_if, node_if = f"ervk{i}h", f"ervk{i}n"
            sh("ip", "link", "add", host_if, "type", "veth", "peer", "name", node_if)
            sh("ip", "link", "set", node_if, "netns", ns)
            sh("ip", "addr", "add", f"10.79.{i}.1/30", "dev", host_if)
            sh("ip", "link", "set", host_if, "up")
            sh("ip", "-n", ns, "addr", "add", f"10.79.{i}.2/30", "dev", node_if)
            sh("ip", "-n", ns, "link", "set", node_if, "up")
            api_service(ns, f"10.79.{i}.1")
    for name, a, a_dev, b, b_dev, b_address in LINKS:
        if alive(name):
            continue
        start(name, [sys.executable, str(LINKDELAY), a_dev, b_dev, str(DELAY_MS)])
        wait(
            f"the link {a}-{b}",
            lambda name=name: "ready" in (STATE / "logs" / f"{name}.log").read_text(),
            20,
            name,
        )  # fmt: skip
        for node, dev, address in ((a, a_dev, NODES[a]["link"]), (b, b_dev, b_address)):
            ns = netns(node)
            sh("ip", "link", "set", dev, "netns", ns)
            sh("ip", "-n", ns, "addr", "add", f"{address}/24", "dev", dev)
            sh("ip", "-n", ns, "link", "set", dev, "up", "multicast", "on")
        cloud = str(NODES[b]["link"])
        if cloud != b_address:  # the cloud's address on the first link, over this one
            sh("ip", "-n", netns(a), "route", "add", f"{cloud}/32", "dev", a_dev)


def api_service(ns: str, host: str) -> None:
    """The one Service pods need without kube-proxy: ``kubernetes`` (10.96.0.1:443) to
    the API server, for host-network pods (OUTPUT) and pod-network pods (PREROUTING);
    and routes to the other nodes."""
    sh("ip", "-n", ns, "route", "add", "10.96.0.1/32", "via", host)  # routed, then rewritten
    # and the other nodes' addresses through this host (the management network; the
    # robot's traffic between the nodes takes the delayed link)
    sh("ip", "-n", ns, "route", "add", "10.79.0.0/16", "via", host)
    for chain in ("OUTPUT", "PREROUTING"):
        sh("ip", "netns", "exec", ns, "iptables", "-t", "nat", "-A", chain,
           "-d", "10.96.0.1/32", "-p", "tcp", "--dport", "443",
           "-j", "DNAT", "--to-destination", f"{host}:{API_PORT}")  # fmt: skip


# Both nodes run on this one host, so every piece of host state a kubelet or a containerd
# would take by default is either given to each node (below) or shared for a stated reason.
# A kubelet removes what it believes is its own and does not know: the default pod log
# directory /var/log/pods, shared, let one node's kubelet delete the other's pod logs
# (its garbage collection removes every pod log directory of a pod it does not run).
#
# Each node's own (under .cluster/nodes/NODE): the kubelet's root dir, certificates, pod
# log dir (podLogsDir) and volume plugin dir; containerd's root, state, sockets, opt dir
# and runc root; the CNI configuration and IPAM data; the network namespace (so the
# kubelet's ports, iptables rules and the pods' bridge cni0); the cgroup root.
#
# Shared, and why that is safe:
# - /var/log/containers: the kubelet makes its container log symlinks there (a fixed path);
#   each name holds the pod, namespace, container and its 64-hex container ID, so they
#   never collide, and a kubelet removes only symlinks whose target is gone, that is
#   once the owning node removed its own pod's logs;
# - /var/lib/cni (the CNI plugins' result cache) and /run/netns (the pods' network
#   namespaces): entries are named by network (edgerv-NODE) and container ID, or by
#   random names;
# - /run/containerd/s: the shims' sockets, named by a hash of their containerd's
#   address and the container ID;
# - /run/xtables.lock: iptables' lock serializes rule changes across namespaces, which is
#   what it is for;
# - /dev/kmsg and the host's memory, disk and cgroup statistics: read only (each kubelet
#   watches OOM kills and its eviction thresholds; both see the same host).
NODE_DIRS = ("containerd", "containerd-state", "containerd-opt", "runc", "kubelet", "cni",
             "pod-logs", "volume-plugins")  # fmt: skip


def node_dirs(node: str) -> Path:
    d = STATE / "nodes" / node
    for sub in NODE_DIRS:
        (d / sub).mkdir(parents=True, exist_ok=True)
    return d


def containerd(node: str) -> Path:
    d = node_dirs(node)
    sock = d / "containerd.sock"
    config = d / "containerd.toml"
    config.write_text(
        textwrap.dedent(
            f"""\
            version = 2
            root = "{d / "containerd"}"
            state = "{d / "containerd-state"}"
            [grpc]
              address = "{sock}"
            [ttrpc]
              address = "{d / "containerd-ttrpc.sock"}"
            [debug]
              address = "{d / "containerd-debug.sock"}"
            [plugins."io.containerd.internal.v1.opt"]
              path = "{d / "containerd-opt"}"
            [plugins."io.containerd.grpc.v1.cri"]
              sandbox_image = "{PAUSE_IMAGE}"
              # this machine denies CAP_SYS_RESOURCE: oom_score_adj may only go up
              restrict_oom_score_adj = true
              [plugins."io.containerd.grpc.v1.cri".containerd]
                snapshotter = "overlayfs"
                default_runtime_name = "runc"
                [plugins."io.containerd.grpc.v1.cri".containerd.runtimes.runc]
                  runtime_type = "io.containerd.runc.v2"
                  [plugins."io.containerd.grpc.v1.cri".containerd.runtimes.runc.options]
                    SystemdCgroup = false
                    Root = "{d / "runc"}"
              [plugins."io.containerd.grpc.v1.cri".cni]
                bin_dir = "/usr/lib/cni"
                conf_dir = "{d / "cni"}"
            """
        )
    )
    (d / "cni" / "10-bridge.conflist").write_text(
        json.dumps(
            {
                "cniVersion": "0.4.0",
                "name": f"edgerv-{node}",
                "plugins": [
                    {
                        "type": "bridge",
                        "bridge": "cni0",
                        "isGateway": True,
                        "isDefaultGateway": True,
                        "ipMasq": True,  # pods reach the other nodes as their node
                        "ipam": {
                            "type": "host-local",
                            "ranges": [[{"subnet": NODES[node]["pods"]}]],
                            "dataDir": str(d / "cni-ipam"),
                        },
                    },
                    {"type": "loopback"},
                ],
            }
        )
    )
    name = f"containerd-{node}"
    if not alive(name):
        start(name, ["containerd", "--config", str(config)], node=node)
        wait(f"containerd on {node}", lambda: sock.exists(), 30, name)
    return sock


def kubelet(node: str, bins: Path) -> None:
    d = node_dirs(node)
    pki = STATE / "pki"
    kc = kubeconfig(
        d / "kubelet.kubeconfig",
        f"https://10.79.{NODES[node]['index']}.1:{API_PORT}",
        f"kubelet-{node}",
    )
    config = d / "kubelet.yaml"
    config.write_text(
        json.dumps(
            {
                "apiVersion": "kubelet.config.k8s.io/v1beta1",
                "kind": "KubeletConfiguration",
                "authentication": {
                    "anonymous": {"enabled": False},
                    "webhook": {"enabled": False},
                    "x509": {"clientCAFile": str(pki / "ca.crt")},
                },
                "authorization": {"mode": "AlwaysAllow"},
                "cgroupDriver": "cgroupfs",
                "cgroupRoot": f"/edgerv-{node}",
                "cgroupsPerQOS": True,
                "enforceNodeAllocatable": [],
                "failSwapOn": False,
                "failCgroupV1": False,
                "containerRuntimeEndpoint": f"unix://{d / 'containerd.sock'}",
                "podLogsDir": str(d / "pod-logs"),  # the default is shared: see NODE_DIRS
                "volumePluginDir": str(d / "volume-plugins"),
                "podCIDR": NODES[node]["pods"],
                "resolvConf": "",
                "clusterDomain": "cluster.local",
                "evictionHard": {"memory.available": "100Mi", "nodefs.available": "1%",
                                 "imagefs.available": "1%"},
                "imageGCHighThresholdPercent": 100,
                "serializeImagePulls": False,
                "makeIPTablesUtilChains": False,
                "localStorageCapacityIsolation": False,
            },
            indent=1,
        )
    )  # fmt: skip
    for sub in Path("/sys/fs/cgroup").iterdir():  # the kubelet wants its cgroup root made
        if sub.name != "unified" and (sub / "cgroup.procs").exists():
            (sub / f"edgerv-{node}").mkdir(exist_ok=True)
    name, tier = f"kubelet-{node}", NODES[node]["tier"]
    if not alive(name):
        start(
            name,
            [
                str(bins / "kubelet"), "--config", str(config), "--kubeconfig", str(kc),
                "--root-dir", str(d / "kubelet"), "--hostname-override", node,
                "--node-ip", f"10.79.{NODES[node]['index']}.2",
                *(["--node-labels", f"edgerv.io/tier={tier}"] if tier else []),
                "--cert-dir", str(d / "kubelet-pki"),
            ],
            node=node,
        )  # fmt: skip


# -- images ----------------------------------------------------------------------------------


def docker_ready() -> None:
    if sh("docker", "info", check=False).returncode == 0:
        return
    if shutil.which("dockerd") is None:
        raise RuntimeError("Docker is not installed: apt-get install -y docker.io")
    log("starting dockerd (host networking only: no bridge, no iptables)")
    start("dockerd", ["dockerd", "--bridge=none", "--iptables=false", "--ip-masq=false"])
    wait("dockerd", lambda: sh("docker", "info", check=False).returncode == 0, 60, "dockerd")


def base_image() -> None:
    if sh("docker", "image", "inspect", BASE_IMAGE, check=False).returncode == 0:
        return
    rootfs = CACHE / "rootfs-bookworm"
    if not rootfs.exists():
        log("debootstrap: a minimal Debian bookworm with python3 (about a minute)")
        tmp = CACHE / "rootfs-bookworm.tmp"
        shutil.rmtree(tmp, ignore_errors=True)
        subprocess.run(
            ["debootstrap", "--variant=minbase", "--include=python3,python3-venv",
             "bookworm", str(tmp), "http://deb.debian.org/debian"],
            check=True, stdout=subprocess.DEVNULL,
        )  # fmt: skip
        tmp.rename(rootfs)
    log(f"docker import {BASE_IMAGE}")
    tar = subprocess.Popen(["tar", "-C", str(rootfs), "-c", "."], stdout=subprocess.PIPE)
    subprocess.run(["docker", "import", "-", BASE_IMAGE], stdin=tar.stdout, check=True,
                   stdout=subprocess.DEVNULL)  # fmt: skip
    tar.wait()


def prune_stale_images() -> None:
    """Each rebuild of a tag leaves the image it named before untagged, and each build of
    a changed edgerv wheel a new first stage: about 0.7 GB a build, 47 GB in a day of test
    runs here (then `docker save` failed: no space left on device). Remove those of ours
    (the label) that nothing names and that are over an hour old: a build in progress
    keeps its cache, and nobody else's images are touched."""
    sh("docker", "image", "prune", "--force", "--filter", f"label={IMAGE_VENDOR}",
       "--filter", "until=1h", check=False)  # fmt: skip


def images() -> list[Path]:
    """Build edgerv/handler:dev and edgerv/operator:dev from the working tree, as
    images/README.md says (the dependencies as locked, checked against their hashes);
    return the saved images (tars)."""
    context = CACHE / "image-context"
    wheels = context / "build" / "wheels"
    wheels.mkdir(parents=True, exist_ok=True)
    for old in wheels.glob("edgerv-*.whl"):
        old.unlink()
    log("wheels: the locked dependencies and edgerv (pip's cache makes this quick)")
    for kind in ("handler", "operator"):
        lock = ROOT / "images" / kind / "requirements.lock"
        (context / kind).mkdir(exist_ok=True)
        shutil.copyfile(lock, context / kind / "requirements.lock")
        subprocess.run(
            [sys.executable, "-m", "pip", "download", "--quiet", "--require-hashes",
             "--no-deps", "--dest", str(wheels), "-r", str(lock)],
            check=True,
        )  # fmt: skip
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--wheel-dir",
         str(wheels), str(ROOT)],
        check=True,
    )  # fmt: skip
    for old in wheels.glob("edgerv_msgs-*.whl"):
        old.unlink()
    built = sorted((ROOT / "images" / "build" / "wheels").glob("edgerv_msgs-*.whl"))
    if len(built) != 1:
        raise RuntimeError(
            f"{len(built)} edgerv_msgs wheels in images/build/wheels: `make install` "
            "(interfaces/build.sh) leaves the one the handler's image needs there"
        )
    shutil.copy(built[0], wheels)
    prune_stale_images()
    tars = []
    for image, kind in ((HANDLER_IMAGE, "handler"), (OPERATOR_IMAGE, "operator")):
        log(f"docker build {image}")
        subprocess.run(
            ["docker", "build", "--quiet", "--network", "host", "--build-arg",
             f"BASE={BASE_IMAGE}", "-t", image, "-f", str(ROOT / "images" / kind / "Dockerfile"),
             str(context)],
            check=True, stdout=subprocess.DEVNULL,
        )  # fmt: skip
        out = STATE / "images" / f"{kind}.tar"
        out.parent.mkdir(parents=True, exist_ok=True)
        subprocess.run(["docker", "save", "-o", str(out), image], check=True)
        tars.append(out)
    return tars


def pause_image(bins: Path) -> Path:
    out = STATE / "images" / "pause.tar"
    if out.exists():
        return out
    ctx = STATE / "images" / "pause-context"
    ctx.mkdir(parents=True, exist_ok=True)
    shutil.copy(bins / "pause", ctx / "pause")
    (ctx / "Dockerfile").write_text(
        'FROM scratch\nCOPY pause /pause\nUSER 65535:65535\nENTRYPOINT ["/pause"]\n'
    )
    subprocess.run(["docker", "build", "--quiet", "--network", "host", "-t", PAUSE_IMAGE, str(ctx)],
                   check=True, stdout=subprocess.DEVNULL)  # fmt: skip
    subprocess.run(["docker", "save", "-o", str(out), PAUSE_IMAGE], check=True)
    return out


def load_images(tars: list[Path]) -> None:
    for node in NODES:
        sock = STATE / "nodes" / node / "containerd.sock"
        for tar in tars:
            subprocess.run(
                ["ctr", "--address", str(sock), "-n", "k8s.io", "images", "import", str(tar)],
                check=True, stdout=subprocess.DEVNULL,
            )  # fmt: skip


# -- up / down -------------------------------------------------------------------------------


def kubectl(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    return sh(
        str(STATE / "bin" / "kubectl"),
        "--kubeconfig",
        str(STATE / "kubeconfig"),
        *args,
        check=check,
    )


PACKAGES = {  # what the cluster needs from Debian: a command (or file) it provides -> package
    "containerd": "containerd",
    "ctr": "containerd",
    "runc": "runc",
    "dockerd": "docker.io",
    "debootstrap": "debootstrap",
    "/usr/lib/cni/bridge": "containernetworking-plugins",
    "nsenter": "util-linux",
    "iptables": "iptables",
    "openssl": "openssl",
    "go": "golang",
}


def ensure_packages() -> None:
    missing = sorted(
        {
            pkg
            for need, pkg in PACKAGES.items()
            if not (Path(need).exists() if need.startswith("/") else shutil.which(need))
        }
    )
    if not missing:
        return
    if "golang" in missing:
        raise RuntimeError("Go is needed to build Kubernetes: install Go >= 1.24")
    log(f"installing from Debian: {' '.join(missing)}")
    subprocess.run(["apt-get", "update", "-q"], check=True, stdout=subprocess.DEVNULL)
    subprocess.run(
        ["apt-get", "install", "-y", "-q", *missing],
        check=True,
        stdout=subprocess.DEVNULL,
        env={**os.environ, "DEBIAN_FRONTEND": "noninteractive"},
    )


def up() -> None:
    started = time.monotonic()
    STATE.mkdir(parents=True, exist_ok=True)
    ensure_packages()
    if not alive("kube-apiserver"):  # leftovers of a run that was killed: clear them first
        down(quiet=True)
    log("binaries (compiled once per machine into the cache)")
    built = subprocess.run(
        ["bash", str(HERE / "build.sh")], check=True, stdout=subprocess.PIPE, text=True
    )
    bins = Path(built.stdout.strip().splitlines()[-1])
    (STATE / "bin").mkdir(exist_ok=True)
    for b in ("kubectl", "helm"):
        link = STATE / "bin" / b
        if not link.exists():
            link.symlink_to(bins / b)
    log("certificates")
    make_pki()
    log("control plane: etcd, kube-apiserver, kube-controller-manager, kube-scheduler")
    control_plane(bins)
    log(
        f"nodes: {', '.join(NODES)} (network namespaces; a {DELAY_MS:g} ms link from each "
        "edge node to the cloud)"
    )
    node_network()
    for node in NODES:
        containerd(node)
    log("images")
    docker_ready()
    base_image()
    tars = [pause_image(bins), *images()]
    load_images(tars)
    for node in NODES:
        kubelet(node, bins)
    for node in NODES:
        wait_ready(node)
    log(f"up in {time.monotonic() - started:.0f} s: KUBECONFIG={STATE / 'kubeconfig'}")
    print(kubectl("get", "nodes", "-L", "edgerv.io/tier", "-o", "wide").stdout)


def _unmount_under(path: Path) -> None:
    mounts = []
    for line in Path("/proc/self/mountinfo").read_text().splitlines():
        point = line.split()[4]
        if point.startswith(str(path)):
            mounts.append(point)
    for point in sorted(mounts, key=len, reverse=True):
        subprocess.run(["umount", "-l", point], capture_output=True)


def stop(name: str) -> None:
    """Stop a process ``start`` started (its session: TERM, then KILL after 10 s)."""
    f = STATE / "pids" / name
    if not f.exists():
        return
    pid = int(f.read_text())
    try:
        os.killpg(pid, signal.SIGTERM)
    except ProcessLookupError:
        f.unlink()
        return
    for _ in range(100):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(pid, signal.SIGKILL)
    f.unlink()


def rejoin(node: str) -> None:
    """A node whose Node object was deleted (`kubectl delete node`) registers again, as
    an administrator brings one back: its kubelet restarted (a kubelet registers at its
    start only), with the labels it registers with."""
    if node not in NODES:
        raise RuntimeError(f"no node {node}: the nodes are {', '.join(NODES)}")
    stop(f"kubelet-{node}")
    kubelet(node, (STATE / "bin" / "kubectl").resolve().parent)
    wait_ready(node)
    log(f"{node} registered again")


def wait_ready(node: str) -> None:
    """Until the node's kubelet has registered it and it is Ready (3 min at most; its
    kubelet's log on failure)."""
    wait(
        f"node {node} Ready",
        lambda: kubectl("get", "node", node, "-o", READY).stdout == "True",
        180,
        f"kubelet-{node}",
    )


def down(quiet: bool = False) -> None:
    pids = STATE / "pids"
    order = ["kubelet-edge", "kubelet-edge-b", "kubelet-cloud", "kube-scheduler",
             "kube-controller-manager", "kube-apiserver", "etcd", "containerd-edge",
             "containerd-edge-b", "containerd-cloud", "linkdelay", "linkdelay-b",
             "dockerd"]  # fmt: skip
    names = (
        order + sorted(p.name for p in pids.glob("*") if p.name not in order)
        if pids.exists()
        else []
    )
    for name in names:
        stop(name)
    # processes of this cluster no pid file names (two `up`s at once: the second's pid
    # files replace the first's): every process started with a path in the state directory
    subprocess.run(["pkill", "-9", "-f", f"{STATE}/"], capture_output=True)
    # containers left by the shims (their own sessions): kill what runs from the nodes' dirs
    for node in NODES:
        subprocess.run(
            ["pkill", "-9", "-f", f"containerd-shim.*{STATE / 'nodes' / node}"], capture_output=True
        )
    for node in NODES:  # the runc state of the nodes' containers (each node its own root)
        runc_root = STATE / "nodes" / node / "runc" / "k8s.io"
        for state in runc_root.glob("*/state.json") if runc_root.exists() else []:
            subprocess.run(["runc", "--root", str(runc_root), "delete", "--force",
                            state.parent.name], capture_output=True)  # fmt: skip
    _unmount_under(STATE / "nodes")
    for node in NODES:
        subprocess.run(["ip", "netns", "del", netns(node)], capture_output=True)
        for i in (NODES[node]["index"],):
            subprocess.run(["ip", "link", "del", f"ervk{i}h"], capture_output=True)
        for sub in Path("/sys/fs/cgroup").iterdir():
            root = sub / f"edgerv-{node}"
            if root.exists():
                for d in sorted(root.rglob("*"), key=lambda p: len(str(p)), reverse=True):
                    if d.is_dir():
                        with contextlib.suppress(OSError):
                            d.rmdir()
                with contextlib.suppress(OSError):
                    root.rmdir()
    # a fresh cluster each time: etcd's data and the nodes' state go; certificates, images stay
    for d in (STATE / "etcd", STATE / "nodes"):
        shutil.rmtree(d, ignore_errors=True)
    if not quiet:
        log("down")


def main() -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("action", choices=["up", "down", "rejoin"])
    p.add_argument("node", nargs="?", help="rejoin: the node to register again")
    args = p.parse_args()
    if os.geteuid() != 0:
        print("cluster: needs root (network namespaces, containerd, kubelet)", file=sys.stderr)
        return 2
    if args.action == "up":
        try:
            up()
        except (subprocess.CalledProcessError, RuntimeError, TimeoutError) as exc:
            detail = getattr(exc, "stderr", None) or ""
            print(f"cluster: up failed: {exc}\n{detail}", file=sys.stderr)
            return 1
    elif args.action == "rejoin":
        try:
            rejoin(args.node or "")
        except (subprocess.CalledProcessError, RuntimeError, TimeoutError) as exc:
            print(f"cluster: rejoin failed: {exc}", file=sys.stderr)
            return 1
    else:
        down()
    return 0


if __name__ == "__main__":
    sys.exit(main())
