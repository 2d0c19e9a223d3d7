"""One schema, not two: the Monitor CRD's OpenAPI schema and the handler's own reading of
a Monitor document (edgerv.core.documents) agree on every field of the spec.

The API server checks a Monitor against the CRD when it is applied; `edgerv check`, the
handlers and the operator read it with documents.py. Where the two disagree, a Monitor
the cluster accepted fails later in its status (or one refused there would run
locally). So, walking the CRD's schema field by field, documents.py is probed at each
bound the schema states: every key the schema lists is read and every other refused,
what it requires is required, each enum value accepted and any other refused, a number
accepted at its minimum and maximum and refused just past them, an empty string refused
where the schema says minLength 1.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from edgerv.core.documents import parse_monitors_text

CRD = yaml.safe_load((Path(__file__).parents[2] / "crds" / "monitors.edgerv.io.yaml").read_text())
SPEC = CRD["spec"]["versions"][0]["schema"]["openAPIV3Schema"]["properties"]["spec"]

# A Monitor with every field of the spec set, valid: each probe changes one field of it.
BASE: dict[str, Any] = {
    "apiVersion": "edgerv.io/v1alpha1",
    "kind": "Monitor",
    "metadata": {"name": "probe"},
    "spec": {
        "assertion": "always (x < limit)",
        "signals": {
            "x": {
                "topic": "/x",
                "type": "std_msgs/msg/Float64",
                "field": "data",
                "initial": 0.0,
                "qos": {"reliability": "auto", "durability": "auto", "depth": 10},
            }
        },
        "parameters": {"limit": 5},
        "sortThreshold": 1,
        "bufferCapacity": 10**8,  # at least any sortThreshold probed
        "onVerdict": "reset",
        "onViolation": {
            "publish": {"topic": "/stop", "type": "std_msgs/msg/Bool", "message": {"data": True}},
            "call": {
                "service": "/estop",
                "type": "std_srvs/srv/SetBool",
                "request": {"data": True},
                "timeoutMs": 1000,
            },
        },
        "placement": {"tier": "edge", "migrate": "auto", "maxLatencyMs": 20},
        "robots": {
            "matchLabels": {"site": "hall-a"},
            "matchExpressions": [{"key": "model", "operator": "In", "values": ["mir250"]}],
        },
    },
}
SIGNAL = "x"  # the key standing for any of spec.signals' (additionalProperties)


def accepts(doc: dict[str, Any]) -> bool:
    specs, diagnostics = parse_monitors_text("probe.yaml", yaml.safe_dump(doc))
    return bool(specs) and not [d for d in diagnostics if d.severity == "error"]


def with_value(path: tuple[str, ...], value: Any) -> dict[str, Any]:
    """BASE with the field at ``path`` (under spec) set to ``value`` (removed: ...)."""
    doc = copy.deepcopy(BASE)
    node = doc["spec"]
    for key in path[:-1]:
        node = node[key]
    if value is ...:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return doc


def objects(
    schema: dict[str, Any], path: tuple[str, ...] = ()
) -> Iterator[tuple[tuple[str, ...], dict[str, Any]]]:
    """Every object schema under ``schema`` with listed properties, with its path."""
    if "properties" in schema:
        yield path, schema
        for key, sub in schema["properties"].items():
            yield from objects(sub, (*path, key))
    if isinstance(schema.get("additionalProperties"), dict):
        yield from objects(schema["additionalProperties"], (*path, SIGNAL))


def leaves(schema: dict[str, Any]) -> Iterator[tuple[tuple[str, ...], dict[str, Any]]]:
    for path, obj in objects(schema):
        for key, sub in obj["properties"].items():
            if "properties" not in sub and "additionalProperties" not in sub:
                yield (*path, key), sub


def test_the_base_monitor_is_read_and_sets_every_field_the_schema_lists() -> None:
    assert accepts(BASE)
    for path, _ in leaves(SPEC):
        node = BASE["spec"]
        for key in path:
            assert key in node, f"BASE lacks spec.{'.'.join(path)}: add it"
            node = node[key]


@pytest.mark.parametrize(
    "path", [p for p, _ in objects(SPEC)], ids=lambda p: ".".join(("spec", *p))
)
def test_an_object_has_the_keys_the_schema_lists_and_requires_what_it_requires(
    path: tuple[str, ...],
) -> None:
    schema = dict(objects(SPEC))[path]
    # a key the schema does not list is refused (the API server would prune it silently)
    assert not accepts(with_value((*path, "unlisted"), 1))
    for key in schema["properties"]:
        removed = accepts(with_value((*path, key), ...))
        required = key in schema.get("required", [])
        crd = "requires" if required else "does not require"
        ours = "reads the monitor" if removed else "refuses it"
        assert removed != required, (
            f"spec.{'.'.join((*path, key))}: the CRD {crd} it, documents.py {ours} without it"
        )


def _bounds(schema: dict[str, Any]) -> Iterator[tuple[Any, bool]]:
    """(value, whether the schema accepts it) at each bound it states."""
    kind = schema.get("type")
    if "enum" in schema:
        for value in schema["enum"]:
            yield value, True
        yield "not-a-choice", False
    if kind in ("integer", "number"):
        step = 1 if kind == "integer" else 0.5
        if "minimum" in schema:
            low = schema["minimum"]
            exclusive = schema.get("exclusiveMinimum", False)
            yield low, not exclusive
            yield low - step, False
            if exclusive:
                yield low + step, True
        if "maximum" in schema:
            yield schema["maximum"], True
            yield schema["maximum"] + step, False
        if "maximum" not in schema:
            yield 10**12, True  # no maximum: a large value is read
    if kind == "string" and schema.get("minLength", 0) >= 1:
        yield "", False


@pytest.mark.parametrize(
    ("path", "value", "accepted"),
    [(p, v, a) for p, s in leaves(SPEC) for v, a in _bounds(s)],
    ids=lambda x: ".".join(("spec", *x)) if isinstance(x, tuple) else repr(x),
)
def test_each_bound_of_the_schema_is_the_documents_own(
    path: tuple[str, ...], value: Any, accepted: bool
) -> None:
    assert accepts(with_value(path, value)) == accepted, (
        f"spec.{'.'.join(path)} = {value!r}: the CRD {'accepts' if accepted else 'refuses'} it, "
        f"documents.py does not"
    )
