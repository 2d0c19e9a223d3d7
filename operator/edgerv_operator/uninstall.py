"""``python -m edgerv_operator.uninstall``: what ``helm uninstall`` runs first (a pre-delete
hook), so that no Monitor is left stuck on the operator's finalizer once it is gone.

The operator puts its finalizer (:data:`~edgerv_operator.constants.FINALIZER`) on every
Monitor it places, and takes it off when it has removed the monitor from the handlers.
Uninstalled, it would never take it off again: a Monitor deleted afterwards, and with it
its namespace, would hang for ever. So, in this order:

1. the operator's Deployment is scaled to 0 and its pods are waited for (a running
   operator would put its finalizer back on the Monitors it sees change);
2. the finalizer is taken off every Monitor it watches (each patch names the resource
   version it read: one changed meanwhile is read again).

The Monitors themselves stay (the CRD is kept by default: ``crds.keep``): a later
install's operator takes them up again. Settings: EDGERV_NAMESPACE (the release's),
EDGERV_OPERATOR_DEPLOYMENT (its name; empty: no operator in the cluster) and
EDGERV_WATCH_NAMESPACES (as the operator's; empty: every namespace), read by
:class:`~edgerv_operator.config.UninstallConfig`.
"""

from __future__ import annotations

import os
import sys
import time
from typing import Any, cast

import urllib3
from kubernetes import client, config
from kubernetes.client.exceptions import ApiException

from edgerv_operator.config import ConfigError, UninstallConfig
from edgerv_operator.constants import FINALIZER, GROUP, PLURAL, SERVICE_ACCOUNT_TOKEN, VERSION

STOP_SECONDS = 120.0  # the operator's grace is 75 s: a move in progress ends first


def stop_operator(apps: client.AppsV1Api, core: client.CoreV1Api, ns: str, name: str) -> None:
    """Scale the operator to 0 and wait until none of its pods is left."""
    try:
        deployment = apps.read_namespaced_deployment(name, ns)
    except ApiException as exc:
        if exc.status == 404:
            print(f"no operator Deployment {ns}/{name}: nothing to stop")
            return
        raise
    apps.patch_namespaced_deployment_scale(name, ns, {"spec": {"replicas": 0}})
    spec = deployment.spec
    labels = (spec.selector.match_labels if spec else None) or {}
    selector = ",".join(f"{k}={v}" for k, v in labels.items())
    deadline = time.monotonic() + STOP_SECONDS
    while core.list_namespaced_pod(ns, label_selector=selector).items:
        if time.monotonic() > deadline:
            raise TimeoutError(f"the operator's pods ({selector}) did not stop in time")
        time.sleep(1.0)
    print(f"stopped the operator {ns}/{name}")


def release_monitors(custom: client.CustomObjectsApi, namespaces: list[str]) -> int:
    """Take the operator's finalizer off every Monitor of ``namespaces`` (empty: all)."""
    listed: list[dict[str, Any]] = []
    for ns in namespaces or [""]:
        if ns:
            got = custom.list_namespaced_custom_object(GROUP, VERSION, ns, PLURAL)
        else:
            got = custom.list_cluster_custom_object(GROUP, VERSION, PLURAL)
        listed += cast(dict[str, Any], got)["items"]
    released = 0
    for monitor in listed:
        meta = monitor["metadata"]
        for _ in range(5):  # read again when it changed meanwhile (409)
            finalizers = meta.get("finalizers") or []
            if FINALIZER not in finalizers:
                break
            patch = {
                "metadata": {
                    "finalizers": [f for f in finalizers if f != FINALIZER],
                    "resourceVersion": meta["resourceVersion"],
                }
            }
            try:
                custom.patch_namespaced_custom_object(
                    GROUP, VERSION, meta["namespace"], PLURAL, meta["name"], patch
                )
                released += 1
                break
            except ApiException as exc:
                if exc.status == 404:
                    break  # gone meanwhile
                if exc.status != 409:
                    raise
                again = custom.get_namespaced_custom_object(
                    GROUP, VERSION, meta["namespace"], PLURAL, meta["name"]
                )
                meta = cast(dict[str, Any], again)["metadata"]
    print(f"took the operator's finalizer off {released} of {len(listed)} Monitors")
    return released


LEFT = "the Monitors keep the operator's finalizer until this runs again (helm uninstall)"


def main() -> int:
    """0 done; 2 no settings or no cluster to reach; 70 the cluster answered otherwise
    than it must (one line each, never a traceback: a Helm hook's log is all one reads)."""
    try:
        settings = UninstallConfig.from_env()
    except ConfigError as exc:
        print(f"edgerv uninstall: {exc}", file=sys.stderr)
        return 2
    try:
        if os.path.exists(SERVICE_ACCOUNT_TOKEN):
            config.load_incluster_config()
        else:
            config.load_kube_config()
    except (config.ConfigException, OSError) as exc:
        print(
            f"edgerv uninstall: no cluster to reach ({exc}): in a pod it reads its service "
            "account, elsewhere a kubeconfig (KUBECONFIG, or ~/.kube/config)",
            file=sys.stderr,
        )
        return 2
    try:
        if settings.deployment:
            stop_operator(
                client.AppsV1Api(), client.CoreV1Api(), settings.namespace, settings.deployment
            )
        release_monitors(client.CustomObjectsApi(), list(settings.watch_namespaces))
    except ApiException as exc:
        print(
            f"edgerv uninstall: the API server answered {exc.status} {exc.reason}: {LEFT}",
            file=sys.stderr,
        )
        return 70
    except (TimeoutError, OSError, urllib3.exceptions.HTTPError) as exc:
        print(f"edgerv uninstall: {exc}: {LEFT}", file=sys.stderr)
        return 70
    return 0


if __name__ == "__main__":
    sys.exit(main())
