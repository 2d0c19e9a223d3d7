"""The operator's view of a fleet, without Kubernetes: a Monitor's instances from the
nodes' labels (one per selected robot, or the Monitor itself in a cluster without
robots), the handlers that may run each, the instances the survey finds of one Monitor,
and where a new instance starts. docs/protocol.md, "Fleet"."""

from __future__ import annotations

from typing import Any

import kopf
import pytest

from edgerv.control.orchestrate import Target
from edgerv.control.orchestrate_command import parse_handlers
from edgerv.control.wire import MonitorReport
from edgerv.core.diagnostics import InputError
from edgerv.core.documents import parse_monitors_text
from edgerv.core.robots import fleet_of
from edgerv_operator.config import OperatorConfig
from edgerv_operator.documents import HandlerPod
from edgerv_operator.handlers import (
    Handlers,
    Operator,
    _fleet_status,
    changed,
    cluster_handlers,
    instances,
    ours,
)
from edgerv_operator.placement import choose, drained, placement_of
from edgerv_operator.pods import PodFacts

SPEC: dict[str, Any] = {
    "assertion": "always (speed < limit)",
    "signals": {"speed": {"topic": "/speed", "type": "std_msgs/msg/Float64"}},
    "parameters": {"limit": 2},
    "onViolation": {"publish": {"topic": "cmd_vel", "type": "geometry_msgs/msg/Twist"}},
}
NODES = {
    "jetson-7": {"edgerv.io/robot": "amr-7", "site": "hall-a", "edgerv.io/tier": "edge"},
    "pc-7": {"edgerv.io/robot": "amr-7", "edgerv.io/tier": "edge"},
    "jetson-8": {"edgerv.io/robot": "amr-8", "site": "hall-b", "edgerv.io/tier": "edge"},
    "cloud-1": {"edgerv.io/tier": "cloud"},
    "odd": {"edgerv.io/robot": "Not_A_Name"},
}
FLEET = fleet_of(NODES)
ENV = {"EDGERV_TOKEN": "t", "EDGERV_NAMESPACE": "edgerv", "EDGERV_PLAIN_HTTP": "true"}


def pod(node: str) -> HandlerPod:
    labels = NODES[node]
    return HandlerPod(
        node, labels.get("edgerv.io/tier"), f"{node}:8470", f"h-{node}", "", FLEET.robot_of(node)
    )


def test_a_monitor_runs_an_instance_per_selected_robot_each_reading_its_robots_graph() -> None:
    found = instances("speed", "lab", SPEC, FLEET)
    assert [(i.hname, i.robot) for i in found] == [
        ("lab.speed.amr-7", "amr-7"),
        ("lab.speed.amr-8", "amr-8"),
    ]
    specs, diagnostics = parse_monitors_text("instance", found[1].document)
    assert not diagnostics
    (spec,) = specs
    assert spec.name == "lab.speed.amr-8" and spec.placement.robot == "amr-8"
    assert spec.topics == ["/amr_8/speed"]
    assert spec.on_violation is not None and spec.on_violation.publish is not None
    assert spec.on_violation.publish.topic == "/amr_8/cmd_vel"  # on the violating robot only
    assert FLEET.refused == {"odd": "Not_A_Name"}  # serves no robot, and is said


def test_spec_robots_selects_by_any_node_of_a_robot_and_may_select_none() -> None:
    hall_a = {**SPEC, "robots": {"matchLabels": {"site": "hall-a"}}}
    assert [i.robot for i in instances("speed", "lab", hall_a, FLEET)] == ["amr-7"]
    # amr-7's pc-7 has no site label, its jetson has: the robot is selected all the same
    not_b = {**SPEC, "robots": {"matchExpressions": [{"key": "site", "operator": "NotIn",
                                                       "values": ["hall-b"]}]}}  # fmt: skip
    assert [i.robot for i in instances("speed", "lab", not_b, FLEET)] == ["amr-7"]
    nobody = {**SPEC, "robots": {"matchLabels": {"site": "moon"}}}
    assert instances("speed", "lab", nobody, FLEET) == []


def test_a_cluster_without_robots_runs_the_monitor_once_as_written() -> None:
    (one,) = instances("speed", "lab", SPEC, fleet_of({"edge": {}, "cloud": {}}))
    assert (one.hname, one.robot) == ("lab.speed", None)
    (spec,), _ = parse_monitors_text("m", one.document)
    assert spec.topics == ["/speed"] and spec.placement.robot is None


def test_a_spec_that_cannot_run_is_refused_by_field() -> None:
    bad = {**SPEC, "robots": {"matchLabels": {"site": "no spaces"}}}
    with pytest.raises(kopf.PermanentError, match=r"spec\.robots\.matchLabels\.site"):
        instances("speed", "lab", bad, FLEET)


def test_an_instance_starts_on_its_robots_handler_or_a_shared_one_never_another_robots() -> None:
    handlers = Handlers([pod(n) for n in ("jetson-7", "jetson-8", "cloud-1")], [], [])
    config = OperatorConfig.from_env(ENV).policy
    for robot, edge in (("amr-7", "jetson-7"), ("amr-8", "jetson-8")):
        mine = handlers.hosting(robot)
        assert {p.node for p in mine.ready} == {edge, "cloud-1"}
        start = choose(mine.ready, placement_of(SPEC), config)
        assert start is not None and start.node == edge
        up = choose(mine.ready, placement_of({"placement": {"tier": "cloud"}}), config)
        assert up is not None and up.node == "cloud-1"
    # its robot's edge handler not ready: the nearest tier above it may use, never amr-8's edge
    assert choose(
        Handlers([pod("jetson-8"), pod("cloud-1")], [], []).hosting("amr-7").ready,
        placement_of(SPEC),
        config,
    ) == pod("cloud-1")


def report(name: str, robot: str | None) -> MonitorReport:
    placement: dict[str, Any] = {"tier": None, "migrate": "auto", "maxLatencyMs": None}
    if robot is not None:
        placement["robot"] = robot
    return {"name": name, "placement": placement, "handoff": None}  # type: ignore[typeddict-item]


def test_the_survey_finds_a_monitors_instances_and_no_other_monitors() -> None:
    op = Operator(OperatorConfig.from_env(ENV), orchestrator=None)  # type: ignore[arg-type]
    op.reports = {
        pod("cloud-1"): {
            "lab.a.amr-7": report("lab.a.amr-7", "amr-7"),
            "lab.a": report("lab.a", None),  # from before the cluster had robots
            "lab.a.b": report("lab.a.b", None),  # Monitor a.b of a cluster without robots
            "lab.a.b.amr-8": report("lab.a.b.amr-8", "amr-8"),  # Monitor a.b's instance
        },
        pod("jetson-8"): {"lab.a.amr-8": report("lab.a.amr-8", "amr-8")},
    }
    assert ours(op, "lab.a") == {"lab.a.amr-7": "amr-7", "lab.a": None, "lab.a.amr-8": "amr-8"}
    assert ours(op, "lab.a.b") == {"lab.a.b": None, "lab.a.b.amr-8": "amr-8"}


def test_edgerv_orchestrate_is_told_each_handlers_robot() -> None:
    assert parse_handlers(
        "edge@amr-7=10.0.0.2:8470,edge@amr-8=10.0.0.3:8470,cloud=10.0.0.9:8470"
    ) == [
        Target("edge", "10.0.0.2:8470", "amr-7"),
        Target("edge", "10.0.0.3:8470", "amr-8"),
        Target("cloud", "10.0.0.9:8470", None),
    ]
    with pytest.raises(InputError, match="'Amr_7' is not a robot's name"):
        parse_handlers("edge@Amr_7=10.0.0.2:8470")


def test_the_cluster_handlers_know_their_robot_and_a_refused_or_deleted_node_runs_nothing() -> None:
    cfg = OperatorConfig.from_env(ENV)
    pods = {
        node: [PodFacts("edgerv", f"h-{node}", node, f"10.0.0.{i}", True, False, f"u{i}")]
        for i, node in enumerate(NODES)
    }
    found = cluster_handlers(cfg, pods, {n: [labels] for n, labels in NODES.items()})  # type: ignore[arg-type]
    assert {(h.node, h.robot) for h in found.ready} == {
        ("jetson-7", "amr-7"), ("pc-7", "amr-7"), ("jetson-8", "amr-8"), ("cloud-1", None),
    }  # fmt: skip
    # "odd" names no robot: it is neither a robot's nor shared; asked, given nothing
    assert [h.node for h in found.unready] == ["odd"]
    assert "odd" not in {h.node for h in found.hosting("amr-7").ready}
    # jetson-8's Node deleted (its pod runs on until the pod garbage collector comes): not a
    # shared handler, and robot amr-8 is gone; asked, given nothing
    gone = {n: [labels] for n, labels in NODES.items() if n != "jetson-8"}
    found = cluster_handlers(cfg, pods, gone)  # type: ignore[arg-type]
    assert sorted(h.node for h in found.unready) == ["jetson-8", "odd"]
    assert "jetson-8" not in {h.node for h in found.hosting("amr-7").ready}


def test_a_refresh_patches_only_what_changed() -> None:
    entry = {"phase": "Running", "events": 10, "verdicts": {"violated": 0, "satisfied": 0}}
    robots = {"amr-6": entry, "amr-7": entry, "amr-8": entry}
    status = {"phase": "Running", "desired": 3, "robots": robots}
    new = {
        "phase": "Running",
        "desired": 2,
        # amr-6 gone (a merge patch removes it), amr-9 never there: nothing to remove
        "robots": {"amr-6": None, "amr-7": entry, "amr-8": {**entry, "events": 11}, "amr-9": None},
        "lastVerdict": None,
    }
    assert changed(status, new) == {
        "desired": 2,
        "robots": {"amr-6": None, "amr-8": {**entry, "events": 11}},
        "lastVerdict": None,
    }
    assert changed(status, {k: v for k, v in status.items()}) == {}  # an idle fleet: nothing
    assert changed({}, status) == status


def test_a_drained_handler_hands_each_robots_instances_to_a_handler_that_may_run_them() -> None:
    tiers = ("edge", "cloud")
    cloud, jetson7, jetson8, pc7 = pod("cloud-1"), pod("jetson-7"), pod("jetson-8"), pod("pc-7")
    # the cloud going away: amr-7's instances to amr-7's edge, amr-8's to amr-8's (below it,
    # nothing else of its tier), a robotless monitor to the first edge
    active = {"m.amr-7": "amr-7", "m.amr-8": "amr-8", "n.amr-8": "amr-8", "plain": None}
    assert drained(cloud, active, [jetson7, jetson8], tiers) == [
        (jetson7, ["m.amr-7", "plain"]),
        (jetson8, ["m.amr-8", "n.amr-8"]),
    ]
    # amr-7's jetson going away: to amr-7's other node of its tier, never amr-8's
    assert drained(jetson7, {"m.amr-7": "amr-7"}, [jetson8, pc7, cloud], tiers) == [
        (pc7, ["m.amr-7"])
    ]
    # amr-8's only edge going away: up to the shared cloud; nowhere to go: it stays
    assert drained(jetson8, {"m.amr-8": "amr-8"}, [jetson7, cloud], tiers) == [(cloud, ["m.amr-8"])]
    assert drained(jetson8, {"m.amr-8": "amr-8"}, [jetson7], tiers) == []


def test_an_idle_instance_keeps_its_entry_but_a_violated_event_owed_is_still_told(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A fleet's refresh skips the instances whose reports did not change, but not one
    whose Violated Event waits out its minute: it is told once the minute has passed."""
    clock = [1000.0]
    monkeypatch.setattr("edgerv_operator.handlers.time.time", lambda: clock[0])
    op = Operator(OperatorConfig.from_env(ENV), orchestrator=None)  # type: ignore[arg-type]
    fleet = fleet_of({"jetson-7": NODES["jetson-7"]})
    (inst,) = instances("speed", "lab", SPEC, fleet)
    edge = pod("jetson-7")

    def survey(violated: int) -> None:
        r = {**report(inst.hname, "amr-7"), "active": True, "events": 100 + violated,
             "verdicts": {"violated": violated, "satisfied": 0}, "lastVerdict": None}  # fmt: skip
        op.reports, op.index = {edge: {inst.hname: r}}, {inst.hname: {edge: r}}  # type: ignore[dict-item]
        op.pods_seen = (frozenset([edge]), frozenset())

    def refresh(status: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
        new, events = _fleet_status(op, status, [inst], 1, fleet)
        return {**status, **new}, [e.message for e in events if e.reason == "Violated"]

    survey(3)
    status, told = refresh({})
    assert told == ["robot amr-7: violated 3 more times (3 in all)"]
    survey(5)  # two more within the minute: owed
    clock[0] += 10
    status, told = refresh(status)
    assert told == [] and status["robots"]["amr-7"]["verdicts"]["violated"] == 5
    clock[0] += 60  # the robot went quiet: the same reports, the minute over
    status, told = refresh(status)
    assert told == ["robot amr-7: violated 2 more times (5 in all)"]
    entry, kept = status["robots"]["amr-7"], op.entries[inst.hname]
    status, told = refresh(status)  # nothing owed, nothing changed: the entry as it was
    assert told == [] and status["robots"]["amr-7"] == entry
    assert op.entries[inst.hname] is kept  # (not made again)
