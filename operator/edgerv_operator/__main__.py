"""``edgerv-operator``: run the operator (``kopf run`` on its handlers).

Its Monitors are those of the namespaces of ``EDGERV_WATCH_NAMESPACES`` (comma-separated),
or of all; the handler pods it reads in their namespace only (``EDGERV_NAMESPACE``), by a
second Kopf operator its startup starts (:mod:`edgerv_operator.pods`). It answers its
liveness probe on ``EDGERV_LIVENESS`` (default ``http://0.0.0.0:8080/healthz``; empty: none). With
``EDGERV_PEERING`` (the chart sets it) replicas meet in that Kopf peering object and
only the one of highest priority acts (each draws its priority at random when it
starts); without it the operator runs alone (``--standalone``).
"""

from __future__ import annotations

import os
import secrets

from kopf.cli import main as kopf_cli


def main() -> None:
    watched = [n.strip() for n in os.environ.get("EDGERV_WATCH_NAMESPACES", "").split(",")]
    namespaces = [n for n in dict.fromkeys(watched) if n]
    scope = [a for n in namespaces for a in ("--namespace", n)] or ["--all-namespaces"]
    liveness = os.environ.get("EDGERV_LIVENESS", "http://0.0.0.0:8080/healthz")
    probe = [f"--liveness={liveness}"] if liveness else []
    peering = os.environ.get("EDGERV_PEERING", "")
    # a random priority: two replicas of equal priority would both pause
    peers = (
        [f"--peering={peering}", f"--priority={1 + secrets.randbelow(1_000_000)}"]
        if peering
        else ["--standalone"]
    )
    kopf_cli(
        args=["run", *peers, *probe, *scope, "-m", "edgerv_operator.handlers"],
        prog_name="edgerv-operator",
    )


if __name__ == "__main__":
    main()
