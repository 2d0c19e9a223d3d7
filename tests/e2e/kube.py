"""Talking to the e2e cluster: kubectl with the session's kubeconfig."""

from __future__ import annotations

import subprocess
from dataclasses import dataclass


@dataclass
class Cluster:
    kubeconfig: str
    kubectl: str
    link: dict[str, str]  # node tier -> address on the link between the nodes (own cluster)

    def run(self, *args: str, check: bool = True, timeout: float = 120) -> str:
        done = subprocess.run(
            [self.kubectl, "--kubeconfig", self.kubeconfig, *args],
            capture_output=True,
            text=True,
            timeout=timeout,
        )
        if check and done.returncode != 0:
            raise AssertionError(f"kubectl {' '.join(args)}: {done.stderr}")
        return done.stdout
