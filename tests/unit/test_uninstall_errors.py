"""``python -m edgerv_operator.uninstall`` (the chart's pre-delete hook) never ends in a
traceback: no cluster to reach is a line and exit 2; a cluster that does not answer as
it must, a line and exit 70 (a Helm hook's log is all its reader has)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import yaml


def uninstall(tmp: Path, kubeconfig: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "HOME": str(tmp), "KUBECONFIG": str(kubeconfig), "EDGERV_NAMESPACE": "ns"}
    env.pop("KUBERNETES_SERVICE_HOST", None)
    return subprocess.run(
        [sys.executable, "-m", "edgerv_operator.uninstall"],
        env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip


def test_no_kubeconfig_is_one_line_and_exit_2(tmp_path: Path) -> None:
    done = uninstall(tmp_path, tmp_path / "nowhere.yaml")
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert done.stderr.startswith("edgerv uninstall: no cluster to reach")
    assert "kubeconfig" in done.stderr and len(done.stderr.strip().splitlines()) == 1


def test_a_cluster_that_does_not_answer_is_one_line_and_exit_70(tmp_path: Path) -> None:
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    kubeconfig = tmp_path / "config.yaml"
    kubeconfig.write_text(
        yaml.safe_dump(
            {
                "apiVersion": "v1",
                "kind": "Config",
                "clusters": [{"name": "c", "cluster": {"server": f"http://127.0.0.1:{port}"}}],
                "users": [{"name": "u", "user": {"token": "t"}}],
                "contexts": [{"name": "x", "context": {"cluster": "c", "user": "u"}}],
                "current-context": "x",
            }
        )
    )
    done = uninstall(tmp_path, kubeconfig)
    assert done.returncode == 70, done.stderr
    assert "Traceback" not in done.stderr
    lines = [line for line in done.stderr.splitlines() if line.startswith("edgerv uninstall:")]
    assert lines and "finalizer" in lines[-1], done.stderr
