"""Talking to the e2e cluster: kubectl with the session's kubeconfig."""

from __future__ import annotations

import subprocess
from dataclasses import dataclass


@dataclass
class Cluster:
    kubeconfig: str
    kubectl: str
    link: dict[str, str]  # node tier -> address on the link between the nodes (own cluster)

    def run(
        self, *args: str, check: bool = True, timeout: float = 120, input: str | None = None
    ) -> str:
        code, out, err = self.attempt(*args, timeout=timeout, input=input)
        if check and code != 0:
            raise AssertionError(f"kubectl {' '.join(args)}: {err}")
        return out

    def attempt(
        self, *args: str, timeout: float = 120, input: str | None = None
    ) -> tuple[int, str, str]:
        """kubectl's exit code, output and errors."""
        done = subprocess.run(
            [self.kubectl, "--kubeconfig", self.kubeconfig, *args],
            capture_output=True,
            text=True,
            timeout=timeout,
            input=input,
        )
        return done.returncode, done.stdout, done.stderr
