"""The operator's pure parts: its settings, the resource as a handler's document, its
problems by field path, where it starts and moves (tier edits, drains). Its status and
Events: tests/unit/test_operator_status.py."""

from __future__ import annotations

from typing import Any

import pytest
import yaml

from edgerv.control.placement import (
    HandlerReport,
    MonitorLoad,
    PolicyConfig,
    PolicyMemory,
    plan,
)
from edgerv.core.documents import Placement, parse_monitors_text
from edgerv_operator.config import VARIABLES, ConfigError, OperatorConfig, UninstallConfig
from edgerv_operator.documents import (
    HandlerPod,
    document_text,
    handler_name,
    monitor_document,
    problems,
)
from edgerv_operator.placement import change, choose, destination, placement_of

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
        ({**ENV, "EDGERV_TIER_LATENCY": "cloud=far"}, "EDGERV_TIER_LATENCY: 'cloud=far' is not"),
        ({**ENV, "EDGERV_TIER_LATENCY": "fog=5"}, "EDGERV_TIER_LATENCY: tier fog is not one of"),
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
    policy = PolicyConfig(tiers=("edge", "cloud"))
    assert choose([stray, cloud, edge], Placement("cloud"), policy) == cloud
    assert choose([stray, cloud, edge], Placement(), policy) == edge
    assert choose([stray, cloud, edge], Placement("fog"), policy) == edge  # not a tier: lowest
    assert choose([stray, cloud], Placement(), policy) == cloud  # the edge's is starting
    assert choose([stray, edge], Placement("cloud"), policy) is None  # never below its home
    assert choose([stray], Placement(), policy) is None


def test_a_monitor_starts_within_its_latency_budget_on_the_least_loaded() -> None:
    """The policy's rule, not the first pod by name: maxLatencyMs holds it below a tier
    too far from the robot, and of a tier's handlers the least loaded one takes it, as
    the placement rounds last read them (one not read yet counts as idle)."""
    e1, e2 = HandlerPod("e1", "edge", "a:1"), HandlerPod("e2", "edge", "b:1")
    cloud = HandlerPod("c", "cloud", "c:1")
    policy = PolicyConfig(tiers=("edge", "cloud"), tier_latency_ms={"cloud": 40.0})
    near = Placement(max_latency_ms=20.0)
    assert choose([cloud], near, policy) is None  # the cloud is 40 ms away: it waits
    assert choose([cloud], Placement(max_latency_ms=50.0), policy) == cloud
    assert choose([e1, e2], near, policy) == e1  # neither read yet: by node
    seen = {e1: HandlerReport("e1", "edge", 0.6), e2: HandlerReport("e2", "edge", 0.2)}
    assert choose([e1, e2], near, policy, seen) == e2  # the least loaded
    hot = {e2: HandlerReport("e2", "edge", 0.9)}  # under pressure (CPU above 85%)
    assert choose([e1, e2], near, policy, hot) == e1
    spec = {**SPEC, "placement": {"tier": "edge", "migrate": "pinned", "maxLatencyMs": 20}}
    assert placement_of(spec) == Placement("edge", "pinned", 20.0)
    assert placement_of({"assertion": "x"}) == Placement()


@pytest.mark.parametrize(
    ("cpus", "placement"),
    [
        ({"e1": 0.3, "e2": 0.1, "c": 0.0}, Placement()),
        ({"e1": 0.1, "e2": 0.1, "c": 0.0}, Placement()),  # a tie: by name
        ({"e1": 0.95, "e2": 0.9, "c": 0.0}, Placement()),  # both pressed: still the edge
        ({"e1": 0.3, "e2": 0.1, "c": 0.5}, Placement("cloud")),
        ({"e1": 0.3, "c": 0.5}, Placement("fog")),  # not a tier: the lowest
        ({"c": 0.5}, Placement()),  # no edge handler: the nearest tier above
        ({"c": 0.5}, Placement(max_latency_ms=10.0)),  # ... which is too far: nowhere
        ({"e1": 0.3, "e2": 0.1}, Placement("cloud")),  # never below its home tier
    ],
)
def test_the_operator_and_the_orchestrator_start_a_monitor_in_the_same_place(
    cpus: dict[str, float], placement: Placement
) -> None:
    """One rule for where a monitor starts: asked of the same handlers, the operator's
    choice for a new Monitor and the orchestrator's start move name the same handler."""
    tiers = {"e1": "edge", "e2": "edge", "c": "cloud"}
    policy = PolicyConfig(tiers=("edge", "cloud"), tier_latency_ms={"cloud": 40.0})
    off = {"m": MonitorLoad(active=False)}
    reports = [HandlerReport(n, tiers[n], cpu, monitors=off) for n, cpu in cpus.items()]
    pods = {r.name: HandlerPod(r.name, r.tier, f"{r.name}:8470") for r in reports}
    moves = plan(reports, {"m": placement}, policy, PolicyMemory(), now=0.0)
    orchestrated = moves[0].destination if moves else None
    seen = {pods[r.name]: r for r in reports}
    chosen = choose(list(pods.values()), placement, policy, seen)
    assert (chosen.node if chosen else None) == orchestrated


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
    config = OperatorConfig.from_env(env)
    assert config.selector == "app=edgerv, component=handler"
    assert config.selector_labels == {"app": "edgerv", "component": "handler"}
    assert OperatorConfig.from_env(ENV).selector_labels == {
        "app.kubernetes.io/name": "edgerv",
        "app.kubernetes.io/component": "handler",
    }
    bad = {**ENV, "EDGERV_HANDLER_SELECTOR": "app!=edgerv"}
    with pytest.raises(ConfigError, match="EDGERV_HANDLER_SELECTOR: 'app!=edgerv'"):
        OperatorConfig.from_env(bad)  # before any pod is watched


def test_the_environment_is_read_once_into_the_settings() -> None:
    """What the process launcher and the placement read is in the one settings object."""
    config = OperatorConfig.from_env(
        {
            **ENV,
            "EDGERV_WATCH_NAMESPACES": "robots, lab,robots,",
            "EDGERV_PEERING": "edgerv",
            "EDGERV_LIVENESS": "",
            "EDGERV_TIERS": "edge,fog,cloud",
            "EDGERV_TIER_LATENCY": "fog=5, cloud=40",
        }
    )
    assert (config.watch_namespaces, config.peering, config.liveness) == (
        ("robots", "lab"),
        "edgerv",
        "",
    )
    assert config.policy == PolicyConfig(
        tiers=("edge", "fog", "cloud"), tier_latency_ms={"fog": 5.0, "cloud": 40.0}
    )
    default = OperatorConfig.from_env(ENV)
    assert (default.watch_namespaces, default.peering) == ((), "")
    assert default.liveness == "http://0.0.0.0:8080/healthz"
    assert default.policy == PolicyConfig(tiers=("edge", "cloud"))
    hook = UninstallConfig.from_env({"EDGERV_NAMESPACE": "edgerv"})
    assert (hook.namespace, hook.deployment, hook.watch_namespaces) == ("edgerv", "", ())
    with pytest.raises(ConfigError, match="EDGERV_NAMESPACE: not set"):
        UninstallConfig.from_env({"EDGERV_OPERATOR_DEPLOYMENT": "op"})


def test_a_new_monitor_is_placed_by_the_loads_the_placement_rounds_read() -> None:
    """The Kopf glue hands ``choose`` each ready pod's load as its placement rounds last
    polled it (the pod's API address is the round's target); a pod not polled yet has none."""
    from edgerv.control.orchestrate import Orchestrator, Target
    from edgerv_operator.handlers import Operator

    config = OperatorConfig.from_env(ENV)
    op = Operator(config, Orchestrator([], config.policy, config.token, starts=False))
    e1, e2 = HandlerPod("e1", "edge", "10.0.0.1:8470"), HandlerPod("e2", "edge", "10.0.0.2:8470")
    report = HandlerReport("e2", "edge", 0.1)
    op.orchestrator.seen = {Target("edge", "http://10.0.0.2:8470"): report}
    assert op.target(e2) == Target("edge", "http://10.0.0.2:8470")
    assert op.seen([e1, e2]) == {e2: report}
    busy = {e1: HandlerReport("e1", "edge", 0.5), **op.seen([e1, e2])}
    assert choose([e1, e2], Placement(), op.orchestrator.config, busy) == e2


def test_the_operator_refuses_a_bad_setting_before_it_starts(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``edgerv-operator`` reads its settings once, first: one it cannot use ends it at
    once (exit 2, the variable named, no traceback), before Kopf runs."""
    from edgerv_operator.__main__ import main

    for name in VARIABLES:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("EDGERV_NAMESPACE", "edgerv")
    monkeypatch.setenv("EDGERV_TOKEN", "t")
    monkeypatch.setenv("EDGERV_PLAIN_HTTP", "maybe")
    with pytest.raises(SystemExit) as exited:
        main()
    assert exited.value.code == 2
    err = capsys.readouterr().err
    assert err == "edgerv-operator: EDGERV_PLAIN_HTTP: 'maybe' is not true or false\n", err
