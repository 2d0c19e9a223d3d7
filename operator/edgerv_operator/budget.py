"""The edge handler's CPU budget on Kubernetes: its pod resized in place (issue 37).

The planner's second lever (:func:`edgerv.core.planner.handler_budget`) sets a handler's
CPU budget each placement round. On Kubernetes the budget is the handler container's CPU
limit, the CFS quota the kubelet gives its cgroup, and it is changed through the pod's
``resize`` subresource (in-place pod resize: Kubernetes 1.33, on by default): the kubelet
changes the quota of the running container, which is not restarted, so its monitors keep
their state. The operator's rights grow by exactly that: ``get`` and ``patch`` on
``pods/resize`` in the release's namespace (helm/README.md, "RBAC").

:class:`PodCpuBudget` is :class:`edgerv.control.cpu_budget.CpuBudget` for one handler
pod; :class:`Levers` keeps one lever a budgeted handler pod (``operator.budget.tier``'s),
made and dropped as pods come and go, each keeping its history (when it last changed)
while its pod runs.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
from collections.abc import Callable, Sequence
from typing import Any

from edgerv.control.cpu_budget import CpuBudgetError, bounded
from edgerv.control.orchestrate import BudgetLever, Target
from edgerv.core.planner import BudgetConfig
from edgerv_operator.constants import HANDLER_CONTAINER, SERVICE_ACCOUNT_TOKEN
from edgerv_operator.documents import HandlerPod

MILLI = 1000  # a CPU quantity's unit here: the millicore, the least Kubernetes keeps
API_TIMEOUT = (5.0, 10.0)  # seconds to connect to the API server, and for its answer
_CPU = re.compile(r"\A(?:(\d+(?:\.\d*)?|\.\d+)(m?))\Z")


def cpu_cores(quantity: str) -> float:
    """A Kubernetes CPU quantity (``500m``, ``1``, ``1.5``) in cores; ValueError otherwise."""
    found = _CPU.match(str(quantity).strip())
    if found is None:
        raise ValueError(f"'{quantity}' is not a CPU quantity (e.g. 500m, 1, 1.5)")
    number, milli = found.groups()
    return float(number) / (MILLI if milli else 1)


def cpu_quantity(cores: float) -> str:
    """``cores`` as a CPU quantity in millicores (at least 1m)."""
    return f"{max(1, round(cores * MILLI))}m"


class PodCpuBudget:
    """The CPU budget of the handler container of pod ``pod`` in ``namespace``: its CPU
    limit, read and changed through the pod's ``resize`` subresource with ``api`` (a
    ``kubernetes.client.CoreV1Api``), within [floor, ceiling] cores. A container with no
    CPU limit reads as the ceiling; setting a budget gives it one (the pod's QoS class
    stays: the chart's handlers request CPU). A limit outside the bounds (the pod's
    spec, or an edit by hand) reads as it is, so that the planner brings it within."""

    def __init__(self, api: Any, namespace: str, pod: str, floor: float, ceiling: float) -> None:
        self.api, self.namespace, self.pod = api, namespace, pod
        self._floor, self._ceiling = floor, ceiling

    @property
    def floor(self) -> float:
        return self._floor

    @property
    def ceiling(self) -> float:
        return self._ceiling

    def cores(self) -> float:
        pod = self._call("read", self.api.read_namespaced_pod_resize)
        if infeasible(pod) is not None:  # the spec's limit was never put in force
            return self._in_force(pod)
        return self._limit(pod)

    def set_cores(self, cores: float) -> float:
        wanted = bounded(cores, self._floor, self._ceiling)
        body = {
            "spec": {
                "containers": [
                    {
                        "name": HANDLER_CONTAINER,
                        "resources": {"limits": {"cpu": cpu_quantity(wanted)}},
                    }
                ]
            }
        }
        pod = self._call("resize", self.api.patch_namespaced_pod_resize, body)
        refused = infeasible(pod)
        if refused is not None:
            raise CpuBudgetError(
                f"the kubelet cannot resize pod {self.namespace}/{self.pod} to "
                f"{cpu_quantity(wanted)} CPU: Infeasible ({refused}); its budget stays "
                f"{self._in_force(pod):g} cores, and monitors move instead"
            )
        return self._limit(pod)

    def _call(self, verb: str, method: Callable[..., Any], *body: Any) -> Any:
        """``method`` on this pod, within API_TIMEOUT (a placement round waits for it);
        the API's refusal, or no answer, as a CpuBudgetError saying what to do."""
        from kubernetes.client.exceptions import ApiException  # (the operator's extra)
        from urllib3.exceptions import HTTPError

        try:
            return method(self.pod, self.namespace, *body, _request_timeout=API_TIMEOUT)
        except ApiException as exc:
            where = f"pod {self.namespace}/{self.pod}"
            if exc.status == 403:
                why = (
                    f"the operator may not {verb} {where} (pods/resize: the chart's Role "
                    "gives get and patch on it when operator.budget.tier is set)"
                )
            elif exc.status == 404:
                why = f"{where} is gone (a new one gets a lever of its own)"
            else:
                reason = exc.reason or ""
                with contextlib.suppress(ValueError, AttributeError):  # (not JSON)
                    reason = json.loads(exc.body or "{}").get("message") or reason
                why = (
                    f"the API server refused to {verb} {where} ({exc.status}: {reason}); "
                    "in-place resize needs Kubernetes 1.33 or later"
                )
            raise CpuBudgetError(why) from None
        except (OSError, HTTPError) as exc:
            raise CpuBudgetError(f"the API server did not answer ({exc})") from None

    def _in_force(self, pod: Any) -> float:
        """The handler container's CPU limit the kubelet has put in force (its status),
        in cores; the spec's where the status does not say."""
        for status in (pod.status and pod.status.container_statuses) or ():
            if status.name == HANDLER_CONTAINER and status.resources is not None:
                cpu = (status.resources.limits or {}).get("cpu")
                if cpu is None:
                    return self._ceiling
                with contextlib.suppress(ValueError):
                    return cpu_cores(cpu)
        return self._limit(pod)

    def _limit(self, pod: Any) -> float:
        """The handler container's CPU limit in ``pod`` (as the API sent it), in cores."""
        for container in pod.spec.containers or ():
            if container.name == HANDLER_CONTAINER:
                limits = (container.resources and container.resources.limits) or {}
                cpu = limits.get("cpu")
                if cpu is None:
                    return self._ceiling
                try:  # (above the ceiling as it is: the planner brings it within)
                    return cpu_cores(cpu)
                except ValueError as exc:
                    raise CpuBudgetError(f"pod {self.namespace}/{self.pod}: {exc}") from None
        raise CpuBudgetError(
            f"pod {self.namespace}/{self.pod} has no container '{HANDLER_CONTAINER}'"
        )


def infeasible(pod: Any) -> str | None:
    """Why the kubelet refuses ``pod``'s resize for good (its ``PodResizePending``
    condition, reason ``Infeasible``: the node has not the CPU), else None. A resize
    ``Deferred`` (the node may have the CPU later) is left to the kubelet."""
    for condition in (pod.status and pod.status.conditions) or ():
        if condition.type == "PodResizePending" and condition.reason == "Infeasible":
            return condition.message or "the node cannot give it"
    return None


def core_api() -> Any:
    """A ``kubernetes.client.CoreV1Api`` logged in as the operator: in a pod its service
    account, elsewhere $KUBECONFIG (as the operator's Kopf login)."""
    from kubernetes import client, config

    if os.path.exists(SERVICE_ACCOUNT_TOKEN):
        config.load_incluster_config()
    else:
        config.load_kube_config()
    return client.CoreV1Api()


class Levers:
    """One budget lever a handler pod of the budgeted tier, for the placement rounds;
    ``api`` made on first use (``make_api``: a ``CoreV1Api`` logged in as the operator)."""

    def __init__(
        self,
        tier: str,
        bounds: BudgetConfig,
        namespace: str,
        make_api: Callable[[], Any],
        target: Callable[[HandlerPod], Target],
    ) -> None:
        self.tier, self.bounds, self.namespace = tier, bounds, namespace
        self._make_api, self._target = make_api, target
        self._api: Any = None
        self._kept: dict[str, BudgetLever] = {}  # pod incarnation -> its lever

    def of(self, pods: Sequence[HandlerPod]) -> list[BudgetLever]:
        """The levers of ``pods`` of the budgeted tier (a pod's lever kept while it runs)."""
        chosen = [p for p in pods if p.tier == self.tier]
        if chosen and self._api is None:
            self._api = self._make_api()
        kept = {}
        for pod in chosen:
            lever = self._kept.get(pod.incarnation)
            if lever is None:
                budget = PodCpuBudget(
                    self._api, self.namespace, pod.pod, self.bounds.floor, self.bounds.ceiling
                )
                lever = BudgetLever(budget, self._target(pod), self.bounds, f"pod {pod.pod}")
            kept[pod.incarnation] = lever
        self._kept = kept
        return list(kept.values())
