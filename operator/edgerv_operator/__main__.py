"""``edgerv-operator``: run the operator (Kopf, on its handlers: :mod:`edgerv_operator.handlers`).

Its settings are read once, here (:class:`~edgerv_operator.config.OperatorConfig`: a
setting it cannot use ends it at once, exit 2, naming the variable), and handed to its
handlers in Kopf's ``memo``. Its Monitors are those of the namespaces of
``EDGERV_WATCH_NAMESPACES`` (comma-separated), or of all; the handler pods it reads in
their namespace only (``EDGERV_NAMESPACE``), by a second Kopf operator its startup starts
(:mod:`edgerv_operator.pods`). It answers its liveness probe on ``EDGERV_LIVENESS``
(default ``http://0.0.0.0:8080/healthz``; empty: none). With ``EDGERV_PEERING`` (the
chart sets it) replicas meet in that Kopf peering object and only the one of highest
priority acts (each draws its priority at random when it starts); without it the
operator runs alone (standalone).
"""

from __future__ import annotations

import secrets
import sys

import kopf

from edgerv_operator import handlers
from edgerv_operator.config import ConfigError, OperatorConfig


def main() -> None:
    try:
        config = OperatorConfig.from_env()
    except ConfigError as exc:
        print(f"edgerv-operator: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    kopf.configure(log_prefix=None)  # as `kopf run` logs
    kopf.run(
        standalone=not config.peering,
        peering_name=config.peering or None,
        # a random priority: two replicas of equal priority would both pause
        priority=1 + secrets.randbelow(1_000_000) if config.peering else None,
        liveness_endpoint=config.liveness or None,
        clusterwide=not config.watch_namespaces,
        namespaces=config.watch_namespaces,
        memo=kopf.Memo({handlers.CONFIG: config}),
    )


if __name__ == "__main__":
    main()
