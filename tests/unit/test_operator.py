"""The operator's pure parts: its settings, the resource as a handler's document, its
problems by field path, where it starts and moves (tier edits, drains). Its status and
Events: tests/unit/test_operator_status.py."""

from __future__ import annotations

from typing import Any

import pytest
import yaml

from edgerv.core.documents import parse_monitors_text
from edgerv_operator.config import ConfigError, OperatorConfig, selector_labels
from edgerv_operator.documents import (
    HandlerPod,
    document_text,
    handler_name,
    monitor_document,
    problems,
)
from edgerv_operator.placement import change, choose, destination

ENV = {"EDGERV_TOKEN": "t", "EDGERV_NAMESPACE": "edgerv", "EDGERV_PLAIN_HTTP": "true"}
SPEC: dict[str, Any] = {
    "assertion": "always (running -> speed < limit)",
    "signals": {
        "running": {"topic": "/running", "type": "std_msgs/msg/Bool"},
        "speed": {"topic": "/speed", "type": "std_msgs/msg/Float64", "qos": {"depth": 50}},
    },
    "parameters": {"limit": 100},
    "placement": {"tier": "cloud"},
}


def test_settings_and_their_errors_name_the_variable() -> None:
    cfg = OperatorConfig.from_env({**ENV, "EDGERV_TIERS": "edge, fog,cloud"})
    assert (cfg.port, cfg.tiers, cfg.namespace) == (8470, ("edge", "fog", "cloud"), "edgerv")
    assert cfg.placement_seconds == 5.0
    assert cfg.tls is None and cfg.url("10.0.0.2:8470") == "http://10.0.0.2:8470"
    assert (
        OperatorConfig.from_env({**ENV, "POD_NAMESPACE": "x", "EDGERV_NAMESPACE": ""}).namespace
        == "x"
    )
    for env, error in [
        ({**ENV, "EDGERV_PLAIN_HTTP": ""}, "EDGERV_TLS_CA_FILE: not set"),
        ({**ENV, "EDGERV_PLAIN_HTTP": "yes"}, "EDGERV_PLAIN_HTTP: 'yes' is not true or false"),
        ({**ENV, "EDGERV_TLS_CA_FILE": "/ca.crt"}, "EDGERV_PLAIN_HTTP: true, and EDGERV_TLS_CA"),
        (
            {**ENV, "EDGERV_PLAIN_HTTP": "false", "EDGERV_TLS_CA_FILE": "/missing/ca.crt"},
            "EDGERV_TLS_CA_FILE: cannot use the CA certificate: No such file",
        ),
        ({"EDGERV_NAMESPACE": "x"}, "EDGERV_TOKEN: not set"),
        ({**ENV, "EDGERV_NAMESPACE": ""}, "EDGERV_NAMESPACE: not set"),
        ({**ENV, "EDGERV_HANDLER_PORT": "80a"}, "EDGERV_HANDLER_PORT: '80a' is not a port"),
        ({**ENV, "EDGERV_HANDLER_PORT": "70000"}, "EDGERV_HANDLER_PORT: '70000'"),
        ({**ENV, "EDGERV_TIERS": "edge,,cloud"}, "EDGERV_TIERS: 'edge,,cloud' is not a list"),
        ({**ENV, "EDGERV_TIERS": "edge,edge"}, "EDGERV_TIERS"),
        ({**ENV, "EDGERV_PLACEMENT_SECONDS": "soon"}, "EDGERV_PLACEMENT_SECONDS: 'soon'"),
        ({**ENV, "EDGERV_PLACEMENT_SECONDS": "-1"}, "EDGERV_PLACEMENT_SECONDS: '-1'"),
    ]:
        with pytest.raises(ConfigError, match=error):
            OperatorConfig.from_env(env)


def test_the_resource_becomes_the_handlers_document() -> None:
    doc = monitor_document("robots", "speed-limit", SPEC)
    assert doc["spec"] == SPEC and doc["spec"] is not SPEC  # data, not text
    text = document_text(doc)
    assert yaml.safe_load(text) == doc  # the handlers read it as YAML (JSON is YAML)
    (spec,), diagnostics = parse_monitors_text("Monitor", text)
    assert not diagnostics
    assert spec.name == handler_name("robots", "speed-limit") == "robots.speed-limit"
    assert spec.signals["speed"].qos.depth == 50 and spec.placement.tier == "cloud"
    assert problems(doc) == []


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            {"assertion": "always (running -> speed < limt)"},
            "spec.assertion, column 28: unknown signal or parameter 'limt' (did you mean 'limit'?)",
        ),
        (
            {"signals": {"speed": {"topic": "/speed", "type": "std_msgs/msg/Float65"}}},
            "spec.signals.speed.type: unknown message type 'std_msgs/msg/Float65'",
        ),
        ({"onVerdict": "stop"}, "spec.onVerdict"),
        ({"sortThreshold": 10, "bufferCapacity": 5}, "spec.sortThreshold: 10 is more than"),
    ],
)
def test_problems_name_the_field(change: dict[str, Any], message: str) -> None:
    found = problems(monitor_document("ns", "m", {**SPEC, **change}))
    assert any(p.startswith(message) for p in found), found


def test_a_monitor_starts_on_its_tier_else_on_the_nearest_above() -> None:
    edge = HandlerPod("n1", "edge", "10.0.0.1:8470")
    cloud = HandlerPod("n2", "cloud", "10.0.0.2:8470")
    stray = HandlerPod("n3", None, "10.0.0.3:8470")
    tiers = ("edge", "cloud")
    assert choose([stray, cloud, edge], "cloud", tiers) == cloud
    assert choose([stray, cloud, edge], None, tiers) == edge
    assert choose([stray, cloud, edge], "fog", tiers) == edge  # not a tier: the lowest
    assert choose([stray, cloud], None, tiers) == cloud  # the edge's handler is starting
    assert choose([stray, edge], "cloud", tiers) is None  # never below its home: it waits
    assert choose([stray], None, tiers) is None


def test_a_tier_edit_moves_other_placement_edits_update_anything_else_restarts() -> None:
    moved = {**SPEC, "placement": {"tier": "edge"}}
    assert change(SPEC, dict(SPEC)) == "none"
    assert change(SPEC, moved) == "move"
    assert change({k: v for k, v in SPEC.items() if k != "placement"}, SPEC) == "move"
    pinned = {**SPEC, "placement": {"tier": "cloud", "migrate": "pinned"}}
    assert change(SPEC, pinned) == "placement"
    assert change(SPEC, {**moved, "parameters": {"limit": 90}}) == "redefine"
    assert change(None, SPEC) == "redefine"


def test_where_a_moved_or_drained_monitor_goes() -> None:
    edge1, edge2 = HandlerPod("e1", "edge", "a:1", "h-e1"), HandlerPod("e2", "edge", "b:1", "h-e2")
    fog, cloud = HandlerPod("f", "fog", "c:1", "h-f"), HandlerPod("c", "cloud", "d:1", "h-c")
    tiers = ("edge", "fog", "cloud")
    every = [cloud, fog, edge2, edge1]
    assert destination(every, "cloud", tiers) == cloud
    assert destination([edge1, fog], "cloud", tiers) is None  # the move waits for one
    # a pod going away: its own tier first, then up, then down
    assert destination(every, None, tiers, leaving=edge1) == edge2
    assert destination([edge1, fog, cloud], None, tiers, leaving=edge1) == fog
    assert destination([edge1, edge2, cloud], None, tiers, leaving=cloud) == edge1
    assert destination([edge1], None, tiers, leaving=edge1) is None


def test_the_pod_index_reads_the_selector_and_refuses_what_it_cannot_read() -> None:
    env = {**ENV, "EDGERV_HANDLER_SELECTOR": "app=edgerv, component=handler"}
    assert selector_labels(env) == {"app": "edgerv", "component": "handler"}
    assert OperatorConfig.from_env(env).selector == "app=edgerv, component=handler"
    bad = {**ENV, "EDGERV_HANDLER_SELECTOR": "app!=edgerv"}
    assert selector_labels(bad) == selector_labels({})  # the default, until startup refuses it
    with pytest.raises(ConfigError, match="EDGERV_HANDLER_SELECTOR: 'app!=edgerv'"):
        OperatorConfig.from_env(bad)
