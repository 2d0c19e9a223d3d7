"""Pure parts of the operator: a Monitor resource as the handlers' Monitor document, its
problems by field path, where it runs, and its status from the handlers' reports.

No Kubernetes and no network here: unit-tested as they are (tests/unit/test_operator.py).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from edgerv.core.diagnostics import Diagnostic, InputError
from edgerv.core.documents import parse_monitors_text
from edgerv.core.monitor import compile_monitor

_ASSERTION_LINE = 5  # where monitor_document puts the assertion
_ASSERTION_COLUMN = len('  assertion: "')  # its first character, less one


def handler_name(namespace: str, name: str) -> str:
    """The monitor's name on the handlers (they are shared by every namespace)."""
    return f"{namespace}.{name}"


def monitor_document(namespace: str, name: str, spec: Mapping[str, Any]) -> str:
    """The Monitor document a handler's ``PUT /v1/monitors/{name}`` takes (YAML)."""
    lines = [
        "apiVersion: edgerv.io/v1alpha1",
        "kind: Monitor",
        f"metadata: {{name: {json.dumps(handler_name(namespace, name))}}}",
        "spec:",
        f"  assertion: {json.dumps(spec.get('assertion'))}",
    ]
    lines += [f"  {key}: {json.dumps(value)}" for key, value in spec.items() if key != "assertion"]
    return "\n".join(lines) + "\n"


def describe(d: Diagnostic) -> str:
    """A problem as the resource's user reads it: the field path first."""
    message = d.message
    loc = d.location
    if loc.line == _ASSERTION_LINE and loc.col is not None and not message.startswith("spec."):
        message = f"spec.assertion, column {loc.col - _ASSERTION_COLUMN}: {message}"
    return f"{message} ({d.hint})" if d.hint else message


def problems(document: str) -> list[str]:
    """What is wrong with a Monitor document (its shape, its assertion), or nothing."""
    specs, diagnostics = parse_monitors_text("Monitor", document)
    if specs and not diagnostics:
        try:
            compile_monitor(specs[0])
        except InputError as exc:
            diagnostics = exc.diagnostics
    return [describe(d) for d in diagnostics if d.severity == "error"]


@dataclass(frozen=True)
class HandlerPod:
    """A handler of the cluster: its node, the node's tier and its API address."""

    node: str
    tier: str | None
    address: str  # HOST:PORT


def choose(
    handlers: Sequence[HandlerPod], tier: str | None, tiers: Sequence[str]
) -> HandlerPod | None:
    """Where a monitor starts: a handler of its ``placement.tier``, else of the lowest tier."""
    ranked = sorted(
        (h for h in handlers if h.tier in tiers), key=lambda h: (tiers.index(h.tier or ""), h.node)
    )
    for h in ranked:
        if h.tier == tier:
            return h
    return ranked[0] if ranked else None


def status_of(reports: Mapping[HandlerPod, Mapping[str, Any] | None]) -> dict[str, Any]:
    """A Monitor's status from each handler's ``GET /v1/monitors/{name}`` (None where the
    handler does not define it). Verdict and event counts add up over the handlers: a
    monitor that moved counted some here, some there."""
    running = [(h, r) for h, r in reports.items() if r and r.get("active")]
    moving = [h for h, r in reports.items() if r and r.get("handoff")]
    verdicts = {"violated": 0, "satisfied": 0}
    events = 0
    for r in reports.values():
        if r:
            for kind in verdicts:
                verdicts[kind] += int(r.get("verdicts", {}).get(kind, 0))
            events += int(r.get("events", 0))
    status: dict[str, Any] = {"verdicts": verdicts, "events": events}
    if len(running) == 1:
        h, r = running[0]
        status.update(phase="Running", handler=h.node, tier=h.tier, state=r.get("state"))
        status["message"] = "moving" if moving else ""
    elif moving:
        status.update(phase="Migrating", handler=None, tier=None, state=None, message="")
    elif running:
        nodes = ", ".join(sorted(h.node for h, _ in running))
        status.update(phase="Running", handler=None, tier=None, state=None)
        status["message"] = f"active on several handlers: {nodes}"
    else:
        status.update(phase="Pending", handler=None, tier=None, state=None)
        status["message"] = "no handler runs it"
    return status
