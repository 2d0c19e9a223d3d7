"""The operator's pure parts: its settings, the resource as a handler's document, its
problems by field path, where it starts, and its status from the handlers' reports."""

from __future__ import annotations

from typing import Any

import pytest
import yaml

from edgerv.core.documents import parse_monitors_text
from edgerv_operator.config import ConfigError, OperatorConfig
from edgerv_operator.monitors import (
    HandlerPod,
    choose,
    handler_name,
    monitor_document,
    problems,
    status_of,
)

ENV = {"EDGERV_TOKEN": "t", "EDGERV_NAMESPACE": "edgerv"}
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
    assert OperatorConfig.from_env({"EDGERV_TOKEN": "t", "POD_NAMESPACE": "x"}).namespace == "x"
    for env, error in [
        ({"EDGERV_NAMESPACE": "x"}, "EDGERV_TOKEN: not set"),
        ({"EDGERV_TOKEN": "t"}, "EDGERV_NAMESPACE: not set"),
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
    assert yaml.safe_load(doc)["spec"] == SPEC
    (spec,), diagnostics = parse_monitors_text("Monitor", doc)
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


def test_a_monitor_starts_on_its_tier_else_on_the_lowest() -> None:
    edge = HandlerPod("n1", "edge", "10.0.0.1:8470")
    cloud = HandlerPod("n2", "cloud", "10.0.0.2:8470")
    stray = HandlerPod("n3", None, "10.0.0.3:8470")
    tiers = ("edge", "cloud")
    assert choose([stray, cloud, edge], "cloud", tiers) == cloud
    assert choose([stray, cloud, edge], None, tiers) == edge
    assert choose([stray, cloud, edge], "fog", tiers) == edge
    assert choose([stray, cloud], None, tiers) == cloud
    assert choose([stray], None, tiers) is None


def test_status_adds_up_the_handlers_reports() -> None:
    edge = HandlerPod("n1", "edge", "a:1")
    cloud = HandlerPod("n2", "cloud", "b:1")

    def seen(active: bool, violated: int, handoff: str | None = None) -> dict[str, Any]:
        return {
            "active": active,
            "handoff": handoff,
            "state": "violated" if active else "inactive",
            "events": 10,
            "verdicts": {"violated": violated, "satisfied": 0},
        }

    s = status_of({edge: seen(True, 3), cloud: seen(False, 4)})
    assert s["phase"] == "Running" and (s["handler"], s["tier"]) == ("n1", "edge")
    assert s["verdicts"] == {"violated": 7, "satisfied": 0} and s["events"] == 20
    assert (
        status_of({edge: seen(False, 0, "released"), cloud: seen(False, 0, "receiving")})["phase"]
        == "Migrating"
    )
    assert status_of({edge: None, cloud: seen(False, 0)})["message"] == "no handler runs it"
    assert (
        "several handlers: n1, n2"
        in status_of({edge: seen(True, 0), cloud: seen(True, 0)})["message"]
    )
