"""The operator's Kopf handlers: thin glue over :mod:`edgerv_operator.monitors`.

A Monitor resource is defined on every handler of the cluster (the handler pods the
chart's DaemonSet runs, one per node, host networking) and runs on one: where it runs
already, else a handler of its ``placement.tier``, else of the lowest tier. Its status
is refreshed from the handlers every few seconds; a handler that restarted empty gets
its definitions again. Run it with ``kopf run -m edgerv_operator.handlers`` (the image
does) or ``python -m edgerv_operator``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import threading
from typing import Any

import kopf
import kubernetes

from edgerv.core.placement import PolicyConfig
from edgerv.handler.migrate import Handler, MigrationFailed, Rejected
from edgerv.handler.orchestrate import Orchestrator, Target
from edgerv_operator.config import ConfigError, OperatorConfig
from edgerv_operator.monitors import (
    HandlerPod,
    choose,
    handler_name,
    monitor_document,
    problems,
    status_of,
)

log = logging.getLogger("edgerv.operator")
MONITORS = ("edgerv.io", "v1alpha1", "monitors")
STATUS_SECONDS = 5.0
_config: OperatorConfig | None = None
_stop = threading.Event()  # ends the placement rounds


@kopf.on.startup()
def startup(settings: kopf.OperatorSettings, **_: Any) -> None:
    global _config
    try:
        _config = OperatorConfig.from_env()
    except ConfigError as exc:
        raise kopf.PermanentError(f"edgerv operator: {exc}") from None
    settings.persistence.finalizer = "edgerv.io/monitor"
    try:
        kubernetes.config.load_incluster_config()
    except kubernetes.config.ConfigException:  # outside a cluster: $KUBECONFIG, as read now
        kubernetes.config.load_kube_config(config_file=os.environ.get("KUBECONFIG"))
    if _config.placement_seconds > 0:
        _stop.clear()
        threading.Thread(
            target=placement_rounds, args=(_config,), name="edgerv-placement", daemon=True
        ).start()


@kopf.on.cleanup()
def cleanup(**_: Any) -> None:
    _stop.set()


def placement_rounds(cfg: OperatorConfig) -> None:
    """The placement policy over the cluster's handlers (docs/protocol.md): monitors move
    up a tier when a handler is under pressure and back down when it is calm, by the
    handoff. Starting monitors stays the resources' handlers' job."""
    policy = Orchestrator([], PolicyConfig(tiers=cfg.tiers), cfg.token, starts=False)
    while not _stop.wait(cfg.placement_seconds):
        try:
            pods = handler_pods(cfg)
            policy.set_targets([Target(p.tier, p.address) for p in pods if p.tier in cfg.tiers])
            for record in policy.round():
                log.info("placement: %s", json.dumps(record))
        except Exception:  # a failed round must not end the rounds
            log.exception("placement round failed")


SERVICE_ACCOUNT = "/var/run/secrets/kubernetes.io/serviceaccount/token"


@kopf.on.login()
def login(**kwargs: Any) -> kopf.ConnectionInfo | None:
    """In a pod: its service account, the API server by $KUBERNETES_SERVICE_HOST (no
    cluster DNS needed); elsewhere: $KUBECONFIG as it is now (the client library reads
    it once, at import)."""
    if os.path.exists(SERVICE_ACCOUNT):
        return kopf.login_via_client(**kwargs)
    return kopf.login_with_kubeconfig(**kwargs)


def config() -> OperatorConfig:
    if _config is None:
        raise kopf.TemporaryError("the operator is starting", delay=2)
    return _config


def handler_pods(cfg: OperatorConfig) -> list[HandlerPod]:
    """The ready handler pods, with their node's tier (label ``edgerv.io/tier``)."""
    core = kubernetes.client.CoreV1Api()
    pods = core.list_namespaced_pod(cfg.namespace, label_selector=cfg.selector).items
    tiers = {
        n.metadata.name: (n.metadata.labels or {}).get("edgerv.io/tier")
        for n in core.list_node().items
        if n.metadata is not None
    }
    ready = []
    for p in pods:
        st, node = p.status, p.spec.node_name if p.spec else None
        if st is None or node is None or not st.host_ip or st.phase != "Running":
            continue
        if {c.type: c.status for c in (st.conditions or [])}.get("Ready") == "True":
            ready.append(HandlerPod(node, tiers.get(node), f"{st.host_ip}:{cfg.port}"))
    return ready


def report(cfg: OperatorConfig, pod: HandlerPod, name: str) -> dict[str, Any] | None:
    """The handler's view of a monitor; None where it does not define it."""
    status, body = Handler(pod.address, cfg.token).call(
        f"/v1/monitors/{name}", method="GET", timeout=5.0
    )
    if status == 404:
        return None
    if status >= 400:
        raise MigrationFailed(f"{pod.address}: HTTP {status}: {body[:200]!r}")
    answer: dict[str, Any] = json.loads(body)
    return answer


def define(cfg: OperatorConfig, pod: HandlerPod, name: str, document: str, active: bool) -> None:
    Handler(pod.address, cfg.token).call(
        f"/v1/monitors/{name}?active={'true' if active else 'false'}",
        raw=document.encode(),
        method="PUT",
        check=True,
        timeout=30.0,
    )


def place(
    cfg: OperatorConfig, namespace: str, name: str, spec: dict[str, Any], redefine: bool = True
) -> dict[str, Any]:
    """Define the monitor on every handler, running on one; return its status.

    ``redefine``: give the definition to every handler (a new or changed spec: that
    restarts the monitor). Without it (the operator restarted, a handler restarted
    empty), only handlers lacking it get it, and a running monitor keeps its state."""
    document = monitor_document(namespace, name, spec)
    errors = problems(document)
    if errors:
        raise kopf.PermanentError("; ".join(errors))
    pods = handler_pods(cfg)
    if not pods:
        raise kopf.TemporaryError(f"no edgerv handler is ready in {cfg.namespace}", delay=10)
    hname = handler_name(namespace, name)
    try:
        reports = {p: report(cfg, p, hname) for p in pods}
        running = [p for p, r in reports.items() if r and r.get("active")]
        target = (
            running[0]
            if running
            else choose(pods, (spec.get("placement") or {}).get("tier"), cfg.tiers)
        )
        if target is None:
            raise kopf.TemporaryError(
                f"no handler runs on a node of the tiers {','.join(cfg.tiers)}", delay=30
            )
        for p in sorted(pods, key=lambda p: p == target):  # idle everywhere first, then run
            if redefine or reports[p] is None:
                define(cfg, p, hname, document, active=p == target)
            elif p == target and not (reports[p] or {}).get("active"):
                Handler(p.address, cfg.token).call(
                    f"/v1/monitors/{hname}/activate", check=True, timeout=30.0
                )
        return status_of({p: report(cfg, p, hname) for p in pods})
    except Rejected as exc:
        if exc.status < 500:  # the handler refuses the definition: fix the resource
            raise kopf.PermanentError(str(exc)) from None
        raise kopf.TemporaryError(str(exc), delay=10) from None
    except MigrationFailed as exc:  # unreachable for now
        raise kopf.TemporaryError(str(exc), delay=10) from None


@kopf.on.create(*MONITORS)
@kopf.on.update(*MONITORS, field="spec")
def apply_fn(
    name: str, namespace: str | None, spec: kopf.Spec, patch: kopf.Patch, **_: Any
) -> None:
    _apply(name, namespace, spec, patch, redefine=True)


@kopf.on.resume(*MONITORS)
def resume_fn(
    name: str, namespace: str | None, spec: kopf.Spec, patch: kopf.Patch, **_: Any
) -> None:
    """The operator restarted: what runs goes on running (its state intact)."""
    _apply(name, namespace, spec, patch, redefine=False)


def _apply(
    name: str, namespace: str | None, spec: kopf.Spec, patch: kopf.Patch, redefine: bool
) -> None:
    try:
        patch.status.update(place(config(), namespace or "", name, dict(spec), redefine))
    except kopf.PermanentError as exc:
        patch.status.update(phase="Error", message=str(exc))
        raise


@kopf.on.delete(*MONITORS)
def delete_fn(name: str, namespace: str | None, **_: Any) -> None:
    cfg = config()
    for pod in handler_pods(cfg):
        with contextlib.suppress(MigrationFailed):  # a handler that is gone has none
            Handler(pod.address, cfg.token).call(
                f"/v1/monitors/{handler_name(namespace or '', name)}",
                method="DELETE",
                timeout=10.0,
            )


@kopf.timer(*MONITORS, interval=STATUS_SECONDS, initial_delay=STATUS_SECONDS)
def status_fn(
    name: str,
    namespace: str | None,
    spec: kopf.Spec,
    status: kopf.Status,
    patch: kopf.Patch,
    **_: Any,
) -> None:
    """Refresh the status; give the definition again to handlers that lost it (never
    during a handoff: a new definition would restart the monitor and undo it)."""
    if status.get("phase") == "Error":
        return  # until the spec changes
    namespace = namespace or ""
    cfg = config()
    pods = handler_pods(cfg)
    hname = handler_name(namespace, name)
    try:
        reports = {p: report(cfg, p, hname) for p in pods}
    except MigrationFailed as exc:
        log.warning("monitor %s/%s: %s", namespace, name, exc)
        return
    moving = any(r and r.get("handoff") for r in reports.values())
    if not moving and (
        any(r is None for r in reports.values())
        or not any(r and r.get("active") for r in reports.values())
    ):
        patch.status.update(place(cfg, namespace, name, dict(spec), redefine=False))
        return
    patch.status.update(status_of(reports))
