"""The e2e tier: a real Kubernetes cluster.

With ``KUBECONFIG`` set (your own cluster: kind, k3s), the tests use it; its
nodes must carry the ``edgerv.io/tier`` labels ``edge`` and ``cloud`` and have
the image ``edgerv/handler:dev`` (see the README). Otherwise the session brings
up the project's own cluster (``tests/cluster/cluster.py up``: built from
sources, cached) unless one is up already, and takes down at the end what it
brought up, also after failures.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from kit.kube import Cluster

ROOT = Path(__file__).resolve().parents[2]
CLUSTER = ROOT / "tests" / "cluster" / "cluster.py"
STATE = ROOT / ".cluster"


def _own_cluster_up() -> bool:
    kubectl = STATE / "bin" / "kubectl"
    if not kubectl.exists() or not (STATE / "kubeconfig").exists():
        return False
    done = subprocess.run(
        [str(kubectl), "--kubeconfig", str(STATE / "kubeconfig"), "get", "--raw", "/readyz"],
        capture_output=True,
        timeout=30,
    )
    return done.returncode == 0


@pytest.fixture(scope="session")
def cluster() -> Iterator[Cluster]:
    given = os.environ.get("KUBECONFIG")
    if given:
        yield Cluster(given, os.environ.get("KUBECTL", "kubectl"), {})
        return
    if os.geteuid() != 0:
        pytest.skip("the project's cluster needs root; or set KUBECONFIG to a cluster of yours")
    ours = not _own_cluster_up()
    if ours:
        up = subprocess.run([sys.executable, str(CLUSTER), "up"], timeout=3600)
        if up.returncode != 0:
            subprocess.run([sys.executable, str(CLUSTER), "down"], timeout=300)
            pytest.fail("the test cluster did not come up (see the output above)")
    sys.path.insert(0, str(CLUSTER.parent))
    import cluster as c

    try:
        yield Cluster(
            str(STATE / "kubeconfig"),
            str(STATE / "bin" / "kubectl"),
            {node: spec["link"] for node, spec in c.NODES.items()},
        )
    finally:
        if ours:
            subprocess.run([sys.executable, str(CLUSTER), "down"], timeout=300)
