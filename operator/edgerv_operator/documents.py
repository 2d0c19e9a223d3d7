"""A Monitor resource as the handlers' Monitor document, its problems by field path, and
the handler pods it can run on.

Pure: no Kubernetes and no network (tests/unit/test_operator.py). The document is built
as data (:func:`monitor_document`) and sent as JSON (:func:`document_text`, which YAML
reads too); a problem the handlers' parser finds at a line and column of that text is
told back by the field it sits in (:func:`describe`), whatever the field.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NotRequired, TypedDict

import yaml

from edgerv.core.diagnostics import Diagnostic, InputError
from edgerv.core.documents import API_VERSION, KIND, MonitorSpec, parse_monitors_text
from edgerv.core.monitor import compile_monitor
from edgerv.core.robots import INSTANCE_LABEL, instance_name, instance_spec


class Metadata(TypedDict):
    name: str
    labels: NotRequired[dict[str, str]]


class MonitorDocument(TypedDict):
    """What a handler's ``PUT /v1/monitors/{name}`` takes (docs/monitors.md)."""

    apiVersion: str
    kind: str
    metadata: Metadata
    spec: dict[str, Any]


def handler_name(namespace: str, name: str) -> str:
    """The monitor's name on the handlers (they are shared by every namespace)."""
    return f"{namespace}.{name}"


def monitor_document(namespace: str, name: str, spec: Mapping[str, Any]) -> MonitorDocument:
    """The Monitor document for the handlers, from the resource's spec."""
    return {
        "apiVersion": API_VERSION,
        "kind": KIND,
        "metadata": {"name": handler_name(namespace, name)},
        "spec": dict(spec),
    }


def instance_document(
    namespace: str, name: str, spec: Mapping[str, Any], robot: str | None
) -> MonitorDocument:
    """The document of a Monitor's instance for ``robot`` (edgerv.core.robots): named
    ``<namespace>.<name>.<robot>``, labelled with its robot, reading the robot's graph;
    for no robot (a cluster without robots), the Monitor's own document."""
    if robot is None:
        return monitor_document(namespace, name, spec)
    return {
        "apiVersion": API_VERSION,
        "kind": KIND,
        "metadata": {
            "name": instance_name(handler_name(namespace, name), robot),
            "labels": {INSTANCE_LABEL: robot},
        },
        "spec": instance_spec(spec, robot),
    }


def document_text(document: MonitorDocument) -> str:
    """The document as the handlers read it: JSON, one field per line."""
    return json.dumps(document, indent=2, ensure_ascii=False) + "\n"


def _field_at(text: str, line: int, col: int) -> tuple[str, int | None] | None:
    """The field path of the value at 1-based ``line``:``col`` of ``text`` and, in a
    string value, the 1-based column within that string; None when no value is there."""
    try:
        root = yaml.compose(text)
    except yaml.YAMLError:
        return None
    offset = sum(len(x) for x in text.splitlines(keepends=True)[: line - 1]) + col - 1
    path: list[str] = []
    node = root
    while isinstance(node, yaml.MappingNode | yaml.SequenceNode):
        items: list[tuple[str, yaml.Node | None, yaml.Node]] = (
            [(str(k.value), k, v) for k, v in node.value]
            if isinstance(node, yaml.MappingNode)
            else [(str(i), None, v) for i, v in enumerate(node.value)]
        )
        for key, key_node, value in items:
            if (
                key_node is not None
                and key_node.start_mark.index <= offset < key_node.end_mark.index
            ):
                return ".".join([*path, key]), None  # the key itself
            start, end = value.start_mark.index, value.end_mark.index
            if start <= offset < end or offset == start:
                path.append(key)
                node = value
                break
        else:
            break
    if not path:
        return None
    within = None
    if isinstance(node, yaml.ScalarNode) and node.style == '"':
        prefix = text[node.start_mark.index : offset]
        try:
            within = len(json.loads(prefix + '"')) + 1
        except ValueError:
            within = None
    return ".".join(path), within


def describe(d: Diagnostic, text: str) -> str:
    """A problem as the resource's user reads it: the field path first."""
    message = d.message
    loc = d.location
    if loc.line is not None and loc.col is not None and not message.startswith("spec."):
        found = _field_at(text, loc.line, loc.col)
        if found is not None:
            path, within = found
            message = f"{path}, column {within}: {message}" if within else f"{path}: {message}"
    return f"{message} ({d.hint})" if d.hint else message


def problems(document: MonitorDocument) -> list[str]:
    """What is wrong with a Monitor document (its shape, its assertion), or nothing."""
    return read(document)[1]


def read(document: MonitorDocument) -> tuple[MonitorSpec | None, list[str]]:
    """A Monitor document as the handlers read it, and what is wrong with it (its shape,
    its assertion): the spec when nothing is. Kept for the last documents read (each
    Monitor's status refresh asks again every few seconds: its assertion is compiled
    once)."""
    spec, errors = _read_text(document_text(document))
    return spec, list(errors)


@functools.lru_cache(maxsize=1024)
def _read_text(text: str) -> tuple[MonitorSpec | None, tuple[str, ...]]:
    specs, diagnostics = parse_monitors_text("Monitor", text)
    if specs and not diagnostics:
        try:
            compile_monitor(specs[0])
        except InputError as exc:
            diagnostics = exc.diagnostics
    errors = tuple(describe(d, text) for d in diagnostics if d.severity == "error")
    return (specs[0] if specs and not errors else None), errors


@dataclass(frozen=True)
class HandlerPod:
    """A handler of the cluster: its pod, node, the node's tier and its API address.

    ``incarnation`` tells one run of its handler from the next: the pod's UID and its
    container's restart count (a handler restarts empty)."""

    node: str
    tier: str | None
    address: str  # HOST:PORT
    pod: str = ""
    incarnation: str = ""
    robot: str | None = None  # the robot whose node it is (None: a shared node)

    def __post_init__(self) -> None:
        if not self.incarnation:
            object.__setattr__(self, "incarnation", self.pod or self.address)
