"""The handler pods, watched in their own namespace only: a second Kopf operator.

Kopf watches every resource of one operator in that operator's scope (its dimensions are
resources x namespaces: ``orchestration.spawn_missing_watchers``), so an operator whose
Monitors are cluster-wide would watch pods cluster-wide too, and need the right to read
every pod of the cluster. The handler pods live in one namespace (the release's): this
operator, with a registry of its own, watches them there and nothing else, and keeps the
index the main operator reads (:attr:`PodWatch.index`).

It runs as Kopf's documentation embeds an operator: ``kopf.run`` in a thread of its own,
with its own event loop and a stop flag. Not in the main operator's loop: ``spawn_tasks``
there would replace the main operator's SIGTERM handler by its own (``add_signal_handler``
keeps one per signal), its ``run_tasks`` would at its end cancel every task of the loop
started after it (the main operator's too), and it sets the API credentials and settings
of the calling context (``auth.vault_var``, ``posting.settings_var``). In a thread of its
own none of that is shared: Kopf leaves signals to the main thread, and the loop, the
tasks and the context are its own. It is standalone (no peering: it only reads, every
replica keeps its own index), posts no Events, and observes neither namespaces nor CRDs
(``settings.scanning.disabled``): it needs ``list`` and ``watch`` on pods in that one
namespace, nothing else.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import kopf

from edgerv_operator.constants import SERVICE_ACCOUNT_TOKEN

log = logging.getLogger("edgerv.operator")
INDEX = "handler_pods"
LISTED_SECONDS = 20.0  # how long the main operator's startup waits for the first listing


def login(**kwargs: Any) -> kopf.ConnectionInfo | None:
    """In a pod: its service account; elsewhere: $KUBECONFIG as it is now."""
    if os.path.exists(SERVICE_ACCOUNT_TOKEN):
        return kopf.login_via_client(**kwargs)
    return kopf.login_with_kubeconfig(**kwargs)


@dataclass(frozen=True)
class PodFacts:
    namespace: str
    name: str
    node: str
    host_ip: str
    ready: bool
    leaving: bool  # deletionTimestamp set: it is going away
    incarnation: str  # UID and restart count


def handler_pods(
    name: str,
    namespace: str | None,
    uid: str | None,
    spec: kopf.Spec,
    status: kopf.Status,
    meta: kopf.Meta,
    **_: Any,
) -> dict[str, PodFacts] | None:
    """The index: each running handler pod's facts, by its name."""
    node, host_ip = spec.get("nodeName"), status.get("hostIP")
    if not node or not host_ip or status.get("phase") != "Running":
        return None
    conditions = {c.get("type"): c.get("status") for c in status.get("conditions") or []}
    restarts = sum(int(c.get("restartCount", 0)) for c in status.get("containerStatuses") or [])
    facts = PodFacts(
        namespace or "",
        name,
        str(node),
        str(host_ip),
        conditions.get("Ready") == "True",
        meta.get("deletionTimestamp") is not None,
        f"{uid}/{restarts}",
    )
    return {name: facts}


THREAD = "edgerv-pods"


class _SignalsLeftToTheMainThread(logging.Filter):
    """Drop Kopf's warning that a thread other than the main one leaves OS signals alone,
    for this one's operator: that is the point (the main operator takes SIGTERM and stops
    this one)."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not (record.threadName == THREAD and "OS signals are ignored" in str(record.msg))


class PodWatch:
    """The pods operator's thread, its index, and whether its first listing is done:
    the pods of ``namespace`` that carry ``labels`` (the handler pods')."""

    def __init__(self, namespace: str, labels: Mapping[str, str] | None = None) -> None:
        self.namespace = namespace
        self.labels = dict(labels or {})
        self.index: Mapping[str, Any] = {}  # Kopf's index (the same object, kept up to date)
        self.listed = threading.Event()  # every pod of the namespace indexed once
        self.stopping = threading.Event()  # Kopf's stop flag
        self._thread = threading.Thread(target=self._run, name=THREAD, daemon=True)

    def start(self) -> None:
        logging.getLogger("kopf._core.reactor.running").addFilter(_SignalsLeftToTheMainThread())
        self._thread.start()

    @property
    def alive(self) -> bool:
        """Running, or stopped because it was asked to."""
        return self._thread.is_alive() or self.stopping.is_set()

    def wait_listed(self, timeout: float = LISTED_SECONDS) -> bool:
        """Until the namespace's pods are indexed (Kopf calls the event handler only once
        every pod of its first listing is indexed); False after ``timeout``: no pod there
        at all (the index is empty, rightly), or the watch is failing (its log says why)."""
        return self.listed.wait(timeout)

    def stop(self, timeout: float = 10.0) -> None:
        self.stopping.set()
        if self._thread.is_alive():
            self._thread.join(timeout)

    def _registry(self) -> kopf.OperatorRegistry:
        """Its own registry: the pods index, the login, and this watch's two handlers."""
        registry = kopf.OperatorRegistry()
        kopf.on.login(registry=registry)(login)
        kopf.index("", "v1", "pods", id=INDEX, labels=self.labels, registry=registry)(handler_pods)

        @kopf.on.startup(id="pods watch", registry=registry)
        def started(settings: kopf.OperatorSettings, **kwargs: Any) -> None:
            settings.scanning.disabled = True  # no namespaces or CRDs observed: one namespace
            settings.posting.enabled = False  # it posts no Events (it has no right to)
            self.index = kwargs[INDEX]

        def unlisted(**_: Any) -> bool:
            return not self.listed.is_set()

        # any pod of the namespace (the operator's own, in the cluster); once only
        @kopf.on.event("", "v1", "pods", id="pods listed", when=unlisted, registry=registry)
        async def seen(**_: Any) -> None:
            self.listed.set()

        return registry

    def _run(self) -> None:
        try:
            kopf.run(
                registry=self._registry(),
                namespaces=[self.namespace],
                standalone=True,
                stop_flag=self.stopping,
            )
        except Exception as exc:  # the main operator's probe reports it (alive is False)
            log.error("the handler pods' watch in %s failed: %r", self.namespace, exc)
        else:
            if not self.stopping.is_set():
                log.error("the handler pods' watch in %s stopped", self.namespace)
