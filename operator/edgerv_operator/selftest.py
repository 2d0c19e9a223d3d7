"""``python -m edgerv_operator.selftest``: what ``helm test`` runs in the operator's image.

With the operator's settings (the chart gives the test pod the same: EDGERV_NAMESPACE,
EDGERV_HANDLER_SELECTOR, the token and the TLS CA), it lists the release's handler pods
and calls each one's API as the operator does (HTTPS verified, the bearer token), and
prints what each runs. It fails (exit 1) when no handler pod runs, or when one does not
answer, refuses the token or shows a certificate the CA did not sign: what would keep
the operator from placing Monitors. Exit 2: its settings are wrong.
"""

from __future__ import annotations

import os
import sys

from kubernetes import client, config

from edgerv.control.client import ApiError, HandlerClient
from edgerv_operator.config import ConfigError, OperatorConfig
from edgerv_operator.constants import SERVICE_ACCOUNT_TOKEN


def main() -> int:
    try:
        cfg = OperatorConfig.from_env()
    except ConfigError as exc:
        print(f"edgerv selftest: {exc}", file=sys.stderr)
        return 2
    if os.path.exists(SERVICE_ACCOUNT_TOKEN):
        config.load_incluster_config()
    else:
        config.load_kube_config()
    listed = client.CoreV1Api().list_namespaced_pod(cfg.namespace, label_selector=cfg.selector)
    running = [  # (pod, node, node's address)
        (p.metadata.name, p.spec.node_name, p.status.host_ip)
        for p in listed.items
        if p.metadata and p.spec and p.status and p.status.phase == "Running" and p.status.host_ip
    ]
    if not running:
        print(
            f"edgerv selftest: no handler pod runs in {cfg.namespace} ({cfg.selector}): "
            f"label nodes with their tier (kubectl label node NODE {cfg.tier_label}=edge)",
            file=sys.stderr,
        )
        return 1
    failed = 0
    for pod, node, host_ip in running:
        handler = HandlerClient(cfg.url(f"{host_ip}:{cfg.port}"), cfg.token, cfg.tls)
        try:
            monitors = handler.monitors(timeout=10.0)
        except ApiError as exc:
            print(f"{pod} on {node}: FAILED: {exc}")
            failed += 1
            continue
        active = sum(1 for m in monitors if m.get("active"))
        print(f"{pod} on {node} ({handler.base}): ok, {len(monitors)} monitors, {active} running")
    print(f"{len(running) - failed} of {len(running)} handlers answered")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
