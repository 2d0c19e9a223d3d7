"""A fleet (issue 36): robots from the nodes' labels, a Monitor's choice of them
(``spec.robots``, a Kubernetes label selector), one instance per robot in its namespace
(edgerv.core.robots); ``spec.robots`` and the instance label as the parser reads them,
with located errors; the instance's robot on the wire; the operator's instance document
and its EDGERV_ROBOT_LABEL. The placement policy with robots:
tests/unit/test_fleet_placement.py; a fleet's status: tests/unit/test_fleet_status.py."""

from __future__ import annotations

import copy
import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from edgerv.control.wire import parse_load, placement_from_json, placement_json
from edgerv.core.diagnostics import Diagnostic
from edgerv.core.documents import MonitorSpec, Placement, parse_monitors_text, read_monitors
from edgerv.core.robots import (
    INSTANCE_LABEL,
    ROBOT_LABEL,
    Fleet,
    Requirement,
    Robot,
    Selector,
    fleet_of,
    in_namespace,
    instance_name,
    instance_spec,
    may_host,
    ros_namespace,
)
from edgerv_operator.config import VARIABLES, ConfigError, OperatorConfig
from edgerv_operator.documents import (
    document_text,
    instance_document,
    monitor_document,
    read,
)
from kit.counts import props
from kit.documents import monitor_doc, write

# -- an independent reading of a label selector, from the Kubernetes documentation ------
# ("Labels and Selectors"): matchLabels {k: v} is the requirement "k In (v)"; every
# requirement must hold; In: the label is there with one of the values; NotIn: it is not
# there, or its value is none of them; Exists / DoesNotExist: the key is there / is not.


def reference_matches(selector: dict[str, Any], labels: dict[str, str]) -> bool:
    requirements = [(k, "In", [v]) for k, v in selector.get("matchLabels", {}).items()]
    requirements += [
        (r["key"], r["operator"], r.get("values", [])) for r in selector.get("matchExpressions", [])
    ]
    for key, operator, values in requirements:
        here = key in labels
        value = labels.get(key)
        holds = {
            "In": here and value in set(values),
            "NotIn": (not here) or value not in set(values),
            "Exists": here,
            "DoesNotExist": not here,
        }[operator]
        if not holds:
            return False
    return True


def as_selector(selector: dict[str, Any]) -> Selector:
    return Selector(
        dict(selector.get("matchLabels", {})),
        tuple(
            Requirement(r["key"], r["operator"], tuple(r.get("values", [])))
            for r in selector.get("matchExpressions", [])
        ),
    )


KEYS = st.sampled_from(["site", "model", "edgerv.io/zone", "a"])
VALUES = st.sampled_from(["hall-a", "hall-b", "mir250", ""])
LABELS = st.dictionaries(KEYS, VALUES, max_size=4)


@st.composite
def selectors(draw: st.DrawFn) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if draw(st.booleans()):
        out["matchLabels"] = draw(st.dictionaries(KEYS, VALUES, max_size=3))
    if draw(st.booleans()):
        expressions = []
        for _ in range(draw(st.integers(0, 3))):
            operator = draw(st.sampled_from(["In", "NotIn", "Exists", "DoesNotExist"]))
            r: dict[str, Any] = {"key": draw(KEYS), "operator": operator}
            if operator in ("In", "NotIn"):
                r["values"] = draw(st.lists(VALUES, min_size=1, max_size=3))
            expressions.append(r)
        out["matchExpressions"] = expressions
    return out


@props(150)
@given(selectors(), LABELS)
def test_a_selector_matches_as_kubernetes_reads_a_label_selector(
    selector: dict[str, Any], labels: dict[str, str]
) -> None:
    assert as_selector(selector).matches(labels) == reference_matches(selector, labels)


def test_each_operator_on_the_labels_it_is_about() -> None:
    hall = {"site": "hall-a", "model": "mir250"}
    assert Requirement("site", "In", ("hall-a", "hall-b")).matches(hall)
    assert not Requirement("site", "In", ("hall-b",)).matches(hall)
    assert not Requirement("zone", "In", ("",)).matches(hall)  # absent: not In, even ""
    assert Requirement("zone", "In", ("",)).matches({"zone": ""})
    assert Requirement("site", "NotIn", ("hall-b",)).matches(hall)
    assert not Requirement("site", "NotIn", ("hall-a",)).matches(hall)
    assert Requirement("zone", "NotIn", ("x",)).matches(hall)  # absent: NotIn
    assert Requirement("model", "Exists").matches(hall)
    assert not Requirement("zone", "Exists").matches(hall)
    assert Requirement("zone", "DoesNotExist").matches(hall)
    assert not Requirement("model", "DoesNotExist").matches(hall)
    # matchLabels: every one equal; and with the expressions: all of them
    assert Selector({"site": "hall-a"}).matches(hall)
    assert not Selector({"site": "hall-a", "model": "mir100"}).matches(hall)
    assert not Selector({"site": "hall-a"}, (Requirement("model", "DoesNotExist"),)).matches(hall)
    # the empty selector: everything, no labels at all included
    assert Selector().matches({}) and Selector().matches(hall)


# -- robots: from the nodes' labels --------------------------------------------------------


def test_robots_come_from_the_nodes_robot_label() -> None:
    nodes = {
        "amr-7-a": {ROBOT_LABEL: "amr-7", "site": "hall-a"},
        "amr-7-b": {ROBOT_LABEL: "amr-7", "site": "hall-b", "gpu": "yes"},
        "amr-8": {ROBOT_LABEL: "amr-8", "site": "hall-b"},
        "cloud-1": {"edgerv.io/tier": "cloud"},
        "odd": {ROBOT_LABEL: "AMR_9"},
    }
    fleet = fleet_of(nodes)
    assert sorted(fleet.robots) == ["amr-7", "amr-8"]
    assert fleet.robots["amr-7"] == Robot(
        "amr-7", {"amr-7-a": nodes["amr-7-a"], "amr-7-b": nodes["amr-7-b"]}
    )
    assert fleet.shared == frozenset({"cloud-1"})
    assert fleet.refused == {"odd": "AMR_9"}
    assert [fleet.robot_of(n) for n in ("amr-7-b", "amr-8", "cloud-1", "odd", "nowhere")] == [
        "amr-7",
        "amr-8",
        None,
        None,
        None,
    ]
    # a robot is selected when one of its nodes matches: amr-7 has a node in hall-b
    assert fleet.selected(Selector({"site": "hall-b"})) == ["amr-7", "amr-8"]
    assert fleet.selected(Selector({"gpu": "yes"})) == ["amr-7"]
    assert fleet.selected(Selector({"site": "hall-c"})) == []
    # ... and DoesNotExist by one node that lacks the label (amr-7-a has no gpu label)
    assert fleet.selected(Selector(expressions=(Requirement("gpu", "DoesNotExist"),))) == [
        "amr-7",
        "amr-8",
    ]
    assert fleet.selected(None) == fleet.selected(Selector()) == ["amr-7", "amr-8"]
    # the fleet keeps its own copy of the labels
    nodes["amr-8"]["site"] = "hall-a"
    assert fleet.selected(Selector({"site": "hall-a"})) == ["amr-7"]


def test_another_robot_label_is_read_when_configured() -> None:
    nodes = {"n1": {"example.com/robot": "amr-1", ROBOT_LABEL: "amr-2"}, "n2": {}}
    fleet = fleet_of(nodes, "example.com/robot")
    assert list(fleet.robots) == ["amr-1"] and fleet.shared == frozenset({"n2"})
    assert fleet_of({}) == Fleet({}, {}, frozenset())


@pytest.mark.parametrize(
    ("name", "valid"),
    [
        ("a", True),
        ("amr-7", True),
        ("a" * 63, True),
        ("a1-b2-c3", True),
        ("a--b", True),  # a DNS label may repeat '-'
        ("a" * 64, False),
        ("7amr", False),  # a ROS namespace token starts with a letter
        ("-amr", False),
        ("amr-", False),
        ("Amr", False),
        ("amr_7", False),
        ("amr.7", False),  # '.' would make an instance's name ambiguous
        ("", False),
        ("amr 7", False),
    ],
)
def test_a_robot_is_named_as_a_dns_label_starting_with_a_letter(name: str, valid: bool) -> None:
    fleet = fleet_of({"n": {ROBOT_LABEL: name}})
    assert (list(fleet.robots) == [name]) is valid
    assert (fleet.refused == {"n": name}) is not valid
    assert fleet.shared == frozenset()  # labelled: never shared, even when refused


ROBOT_NAMES = st.from_regex(r"[a-z]([-a-z0-9]{0,61}[a-z0-9])?", fullmatch=True)
NODE_LABELS = st.dictionaries(
    st.sampled_from(["n1", "n2", "n3", "n4", "n5"]),
    st.dictionaries(
        st.sampled_from([ROBOT_LABEL, "site"]),
        st.one_of(st.sampled_from(["amr-1", "amr-2", "hall-a", "Bad", "9x"]), ROBOT_NAMES),
        max_size=2,
    ),
    max_size=5,
)


@props(80)
@given(NODE_LABELS, selectors())
def test_every_node_is_a_robots_shared_or_refused_and_selection_is_by_any_node(
    nodes: dict[str, dict[str, str]], selector: dict[str, Any]
) -> None:
    fleet = fleet_of(nodes)
    for node, labels in nodes.items():
        owners = [r.name for r in fleet.robots.values() if node in r.nodes]
        kinds = [bool(owners), node in fleet.shared, node in fleet.refused]
        assert kinds.count(True) == 1, (node, fleet)
        assert fleet.robot_of(node) == (owners[0] if owners else None)
        if owners:
            assert owners == [labels[ROBOT_LABEL]]
    wanted = sorted(
        {
            labels[ROBOT_LABEL]
            for node, labels in nodes.items()
            if fleet.robot_of(node) is not None and reference_matches(selector, labels)
        }
    )
    assert fleet.selected(as_selector(selector)) == wanted


# -- names: a robot's namespace, an instance's name and spec --------------------------------


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("/odom", "/amr_7/odom"),
        ("odom", "/amr_7/odom"),  # relative: into the robot's namespace too
        ("/sensors/scan", "/amr_7/sensors/scan"),
        ("~/state", "~/state"),  # private: the handler's own
        ("~", "~"),
        ("{node}/x", "{node}/x"),  # a substitution: the handler's
        ("/robots/{ns}/x", "/robots/{ns}/x"),
    ],
)
def test_a_name_goes_into_the_robots_namespace(name: str, expected: str) -> None:
    assert ros_namespace("amr-7") == "/amr_7"
    assert in_namespace(name, "amr-7") == expected


@props(100)
@given(ROBOT_NAMES, ROBOT_NAMES)
def test_two_robots_never_share_a_namespace_and_names_are_unambiguous(a: str, b: str) -> None:
    assert (ros_namespace(a) == ros_namespace(b)) == (a == b)
    assert re.fullmatch(r"/[a-z][a-z0-9_]*", ros_namespace(a))
    assert instance_name("ns.m", a) == f"ns.m.{a}"
    assert instance_name("ns.m", a).rsplit(".", 1)[1] == a  # a robot's name has no '.'


SPEC: dict[str, Any] = {
    "assertion": "always (running -> speed < limit)",
    "signals": {
        "running": {"topic": "/running", "type": "std_msgs/msg/Bool"},
        "speed": {"topic": "speed", "type": "std_msgs/msg/Float64", "qos": {"depth": 5}},
    },
    "parameters": {"limit": 100},
    "placement": {"tier": "edge", "maxLatencyMs": 20},
    "onViolation": {
        "publish": {"topic": "/stop", "type": "std_msgs/msg/Bool", "message": {"data": True}},
        "call": {"service": "halt", "type": "std_srvs/srv/Trigger"},
    },
    "robots": {"matchLabels": {"site": "hall-a"}},
}


def test_an_instance_reads_and_acts_in_its_robots_namespace() -> None:
    before = copy.deepcopy(SPEC)
    out = instance_spec(SPEC, "amr-7")
    assert before == SPEC  # its input untouched
    assert "robots" not in out  # it has chosen
    assert out["signals"]["running"]["topic"] == "/amr_7/running"
    assert out["signals"]["speed"] == {
        "topic": "/amr_7/speed",
        "type": "std_msgs/msg/Float64",
        "qos": {"depth": 5},
    }
    assert out["onViolation"]["publish"]["topic"] == "/amr_7/stop"
    assert out["onViolation"]["publish"]["message"] == {"data": True}
    assert out["onViolation"]["call"] == {"service": "/amr_7/halt", "type": "std_srvs/srv/Trigger"}
    for same in ("assertion", "parameters", "placement"):
        assert out[same] == SPEC[same]
    out["signals"]["speed"]["qos"]["depth"] = 9  # a copy all the way down
    out["placement"]["tier"] = "cloud"
    assert before == SPEC
    # parts of another shape than a topic's are left as they are
    odd = {"signals": {"a": "not a mapping", "b": {"topic": 7}}, "onViolation": {"call": None}}
    assert instance_spec(odd, "r") == odd


TOPICS = st.one_of(
    st.sampled_from(["/odom", "odom", "/a/b", "~/x", "{node}/x", ""]),
    st.text(alphabet="/~{}ab_1", max_size=8),
    st.integers(),
    st.none(),
)
LEAVES = st.one_of(st.none(), st.booleans(), st.integers(), st.text(max_size=5))
JUNK = st.recursive(
    LEAVES,
    lambda kids: (
        st.lists(kids, max_size=3) | st.dictionaries(st.text(max_size=5), kids, max_size=3)
    ),
    max_leaves=8,
)


@st.composite
def specs(draw: st.DrawFn) -> dict[str, Any]:
    spec: dict[str, Any] = draw(st.dictionaries(st.sampled_from(["assertion", "x"]), JUNK))
    if draw(st.booleans()):
        spec["signals"] = draw(
            st.dictionaries(
                st.text(min_size=1, max_size=4),
                st.one_of(
                    st.fixed_dictionaries(
                        {"topic": TOPICS}, optional={"type": JUNK, "field": JUNK}
                    ),
                    JUNK,
                ),
                max_size=4,
            )
        )
    if draw(st.booleans()):
        spec["onViolation"] = draw(
            st.one_of(
                st.fixed_dictionaries(
                    {},
                    optional={
                        "publish": st.one_of(
                            st.fixed_dictionaries({"topic": TOPICS}, optional={"message": JUNK}),
                            JUNK,
                        ),
                        "call": st.one_of(
                            st.fixed_dictionaries({"service": TOPICS}, optional={"request": JUNK}),
                            JUNK,
                        ),
                    },
                ),
                JUNK,
            )
        )
    if draw(st.booleans()):
        spec["robots"] = draw(JUNK)
    return spec


def names_in(spec: dict[str, Any]) -> dict[tuple[str, ...], str]:
    """Where the topics and services an instance_spec rewrites are, and what they are."""
    found: dict[tuple[str, ...], str] = {}
    signals = spec.get("signals")
    if isinstance(signals, dict):
        for name, signal in signals.items():
            if isinstance(signal, dict) and isinstance(signal.get("topic"), str):
                found[("signals", name, "topic")] = signal["topic"]
    reaction = spec.get("onViolation")
    if isinstance(reaction, dict):
        for part, key in (("publish", "topic"), ("call", "service")):
            p = reaction.get(part)
            if isinstance(p, dict) and isinstance(p.get(key), str):
                found[("onViolation", part, key)] = p[key]
    return found


def without(spec: dict[str, Any], paths: dict[tuple[str, ...], str]) -> dict[str, Any]:
    out = copy.deepcopy(spec)
    out.pop("robots", None)
    for path in paths:
        node = out
        for step in path[:-1]:
            node = node[step]
        node[path[-1]] = "<name>"
    return out


@props(80)
@given(specs(), ROBOT_NAMES)
def test_instance_spec_rewrites_each_name_once_and_nothing_else(
    spec: dict[str, Any], robot: str
) -> None:
    before = copy.deepcopy(spec)
    out = instance_spec(spec, robot)
    assert spec == before  # never mutates its input
    assert "robots" not in out
    names = names_in(before)
    assert names_in(out) == {p: in_namespace(n, robot) for p, n in names.items()}
    for path, name in names.items():  # once: not twice, not left alone
        if not name.startswith("~") and "{" not in name:
            assert names_in(out)[path] == ros_namespace(robot) + "/" + name.lstrip("/")
    assert without(out, names) == without(before, names)  # the rest as it was


def test_who_may_host_whom() -> None:
    assert may_host(None, None) and may_host("a", None)  # a shared handler: anyone
    assert may_host(None, "a")  # a monitor of no robot: anywhere
    assert may_host("a", "a")
    assert not may_host("a", "b") and not may_host("b", "a")


# -- spec.robots and the instance label, as the parser reads them ---------------------------

HEAD = """apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata:
  name: m
spec:
  assertion: always (speed < 100)
  signals:
    speed: {topic: /speed, type: std_msgs/msg/Float64}
  robots:
"""  # spec.robots' first line is line 10


def parsed(text: str) -> tuple[list[MonitorSpec], list[Diagnostic]]:
    return parse_monitors_text("f.yaml", text)


def test_spec_robots_is_read_into_a_selector() -> None:
    body = """\
    matchLabels: {site: hall-a, edgerv.io/zone: "7"}
    matchExpressions:
      - {key: model, operator: In, values: [mir250, mir100]}
      - {key: retired, operator: DoesNotExist}
      - {key: lidar, operator: Exists, values: []}
      - key: site
        operator: NotIn
        values: [hall-c]
"""
    (spec,), diagnostics = parsed(HEAD + body)
    assert diagnostics == []
    assert spec.robots == Selector(
        {"site": "hall-a", "edgerv.io/zone": "7"},
        (
            Requirement("model", "In", ("mir250", "mir100")),
            Requirement("retired", "DoesNotExist"),
            Requirement("lidar", "Exists"),
            Requirement("site", "NotIn", ("hall-c",)),
        ),
    )
    assert spec.placement.robot is None  # the Monitor itself is no instance
    (spec,), _ = parsed(HEAD + "    {}\n")
    assert spec.robots == Selector() and spec.robots.matches({})
    (spec,), _ = parsed(HEAD.replace("  robots:\n", ""))
    assert spec.robots is None


@pytest.mark.parametrize(
    ("body", "line", "col", "message"),
    [
        ("    matchLabels: {site: hall a}\n", 10, 25, "spec.robots.matchLabels.site: 'hall a'"),
        ("    matchLabels: {Site!: x}\n", 10, 19, "spec.robots.matchLabels.Site!: 'Site!' is not"),
        (
            "    matchLabels: {site: 7}\n",
            10,
            25,
            "spec.robots.matchLabels.site: must be one of: str",
        ),
        ("    matchLabels: [site]\n", 10, 18, "spec.robots.matchLabels: must map label keys"),
        ("    matchLabel: {}\n", 10, 5, "spec.robots.matchLabel: unknown field"),
        ("    - site\n", 10, 5, "spec.robots: must be a mapping"),
        (
            "    matchExpressions: {key: a}\n",
            10,
            23,
            "spec.robots.matchExpressions: must be a list",
        ),
        (
            "    matchExpressions:\n      - {key: a, operator: In}\n",
            11,
            9,
            "spec.robots.matchExpressions[0].values: In needs a non-empty list of values",
        ),
        (
            "    matchExpressions:\n      - {key: a, operator: NotIn, values: []}\n",
            11,
            43,
            "spec.robots.matchExpressions[0].values: NotIn needs a non-empty list of values",
        ),
        (
            "    matchExpressions:\n      - {key: a, operator: Exists, values: [x]}\n",
            11,
            44,
            "spec.robots.matchExpressions[0].values: Exists takes no values",
        ),
        (
            "    matchExpressions:\n      - {key: a, operator: Equals, values: [x]}\n",
            11,
            28,
            "spec.robots.matchExpressions[0].operator: must be In, NotIn, Exists or "
            "DoesNotExist, not 'Equals'",
        ),
        (
            "    matchExpressions:\n      - {key: a, operator: In, values: x}\n",
            11,
            40,
            "spec.robots.matchExpressions[0].values: must be a list of label values",
        ),
        (
            "    matchExpressions:\n      - {key: a, operator: In, values: [ok, 'not ok']}\n",
            11,
            45,
            "spec.robots.matchExpressions[0].values[1]: 'not ok' is not a label value",
        ),
        (
            "    matchExpressions:\n      - {key: a, operator: In, values: [x]}\n"
            "      - {key: -a, operator: Exists}\n",
            12,
            15,
            "spec.robots.matchExpressions[1].key: '-a' is not a label key",
        ),
        (
            "    matchExpressions:\n      - {operator: Exists}\n",
            11,
            9,
            "spec.robots.matchExpressions[0]: missing required field 'key'",
        ),
        (
            "    matchExpressions:\n      - {key: a, op: Exists}\n",
            11,
            18,
            "spec.robots.matchExpressions[0].op: unknown field",
        ),
        ("    matchExpressions: [3]\n", 10, 24, "spec.robots.matchExpressions[0]: must be a"),
    ],
)
def test_a_bad_spec_robots_is_told_where_it_is(
    body: str, line: int, col: int, message: str
) -> None:
    specs_, diagnostics = parsed(HEAD + body)
    assert specs_ == []
    found = [(d.location.line, d.location.col, d.message) for d in diagnostics]
    assert any((ln, c) == (line, col) and m.startswith(message) for ln, c, m in found), found
    assert all(m.startswith("spec.robots") for _, _, m in found), found
    assert all(d.severity == "error" and d.location.path == "f.yaml" for d in diagnostics)


def test_every_problem_of_spec_robots_is_told_at_once() -> None:
    body = """\
    matchLabels: {site: 'hall a'}
    matchExpressions:
      - {key: a, operator: Sometimes}
      - {key: b, operator: In}
"""
    _, diagnostics = parsed(HEAD + body)
    assert [(d.location.line, d.message.split(":")[0]) for d in diagnostics] == [
        (10, "spec.robots.matchLabels.site"),
        (12, "spec.robots.matchExpressions[0].operator"),
        (13, "spec.robots.matchExpressions[1].values"),
    ]


INSTANCE = """apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata:
  name: robots.speed.amr-7
  labels:
    app: demo
    edgerv.io/robot: ROBOT
spec:
  assertion: always (speed < 100)
  signals:
    speed: {topic: /amr_7/speed, type: std_msgs/msg/Float64}
  placement: {tier: edge, migrate: pinned}
"""


def instance_text(robot: str) -> str:
    return INSTANCE.replace("ROBOT", robot)


def test_an_instance_documents_label_is_its_robot() -> None:
    (spec,), diagnostics = parsed(instance_text("amr-7"))
    assert diagnostics == []
    assert spec.placement == Placement("edge", "pinned", None, "amr-7")
    (spec,), _ = parsed(INSTANCE.replace("    edgerv.io/robot: ROBOT\n", ""))
    assert spec.placement.robot is None  # no such label: no robot
    (spec,), _ = parsed(INSTANCE.replace("edgerv.io/robot: ROBOT", "example.com/robot: amr-7"))
    assert spec.placement.robot is None  # another label than the instance's


@pytest.mark.parametrize(
    ("robot", "message"),
    [
        ("Amr-7", "metadata.labels.edgerv.io/robot: 'Amr-7' is not a robot's name"),
        ("7amr", "metadata.labels.edgerv.io/robot: '7amr' is not a robot's name"),
        ("'amr_7'", "metadata.labels.edgerv.io/robot: 'amr_7' is not a robot's name"),
        ("7", "metadata.labels.edgerv.io/robot: must be one of: str"),
        ("[amr-7]", "metadata.labels.edgerv.io/robot: must be a single value"),
    ],
)
def test_a_bad_instance_label_is_told_where_it_is(robot: str, message: str) -> None:
    specs_, diagnostics = parsed(instance_text(robot))
    assert specs_ == []
    assert [(d.location.line, d.location.col, d.message) for d in diagnostics] == [(7, 22, message)]


def test_read_monitors_gives_the_robots_of_a_file(tmp_path: Path) -> None:
    text = instance_text("amr-8") + "---\n" + HEAD + "    matchLabels: {site: hall-a}\n"
    (instance, fleet), diagnostics = read_monitors(write(tmp_path, "m.yaml", text))
    assert diagnostics == []
    assert instance.placement.robot == "amr-8" and instance.robots is None
    assert fleet.placement.robot is None and fleet.robots == Selector({"site": "hall-a"})


# Fuzzing spec.robots: random structures where a selector goes, near ones and far ones.
# The parser never raises: it accepts a valid selector (read as written) and says of
# anything else where it is wrong (a line, a column and a field path under spec.robots).

_DNS = r"[a-z0-9]([-a-z0-9]*[a-z0-9])?(\.[a-z0-9]([-a-z0-9]*[a-z0-9])?)*"
_NAME = r"[A-Za-z0-9]([-A-Za-z0-9_.]{0,61}[A-Za-z0-9])?"


def label_key(k: object) -> bool:
    """A Kubernetes label key: an optional DNS subdomain prefix (at most 253) and '/',
    then a name of at most 63 alphanumerics, '-', '_', '.', alphanumeric at both ends."""
    if not isinstance(k, str):
        return False
    prefix, slash, name = k.rpartition("/")
    if slash and not (len(prefix) <= 253 and re.fullmatch(_DNS, prefix)):
        return False
    return re.fullmatch(_NAME, name) is not None


def label_value(v: object) -> bool:
    return isinstance(v, str) and (v == "" or re.fullmatch(_NAME, v) is not None)


def reference_valid(robots: object) -> bool:
    """Whether ``robots`` is a label selector as Kubernetes' API reads one."""
    if not isinstance(robots, dict) or not set(robots) <= {"matchLabels", "matchExpressions"}:
        return False
    labels = robots.get("matchLabels", {})
    if not isinstance(labels, dict):
        return False
    if not all(label_key(k) and label_value(v) for k, v in labels.items()):
        return False
    expressions = robots.get("matchExpressions", [])
    if not isinstance(expressions, list):
        return False
    for r in expressions:
        if not isinstance(r, dict) or not {"key", "operator"} <= set(r) <= {
            "key",
            "operator",
            "values",
        }:
            return False
        if not label_key(r["key"]):
            return False
        values = r.get("values")
        if r["operator"] in ("In", "NotIn"):
            if not isinstance(values, list) or not values:
                return False
        elif r["operator"] in ("Exists", "DoesNotExist"):
            if values not in (None, []) or ("values" in r and values is None):
                return False
        else:
            return False
        if values is not None and not all(label_value(v) for v in values):
            return False
    return True


# (no string ending in a line break: see test_a_trailing_line_break_is_no_label_or_name)
TEXT = st.text(max_size=10).filter(lambda s: not s.endswith("\n"))
WORDS = st.sampled_from(
    [
        "site",
        "hall-a",
        "edgerv.io/robot",
        "a.b/c",
        "Ab_c.d",
        "-x",
        "x-",
        "a/b/c",
        "/x",
        "x/",
        "",
        "In",
        "NotIn",
        "Exists",
        "DoesNotExist",
        "in",
        "key",
        "values",
        "operator",
        "matchLabels",
        "matchExpressions",
        "a" * 63,
        "a" * 64,
        "é",
    ]
)
SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-3, 2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    WORDS,
    TEXT,
)
ANYTHING = st.recursive(
    SCALARS,
    lambda kids: (
        st.lists(kids, max_size=3)
        | st.dictionaries(st.one_of(WORDS, TEXT, st.integers(0, 3), st.none()), kids, max_size=3)
    ),
    max_leaves=12,
)
GOOD = st.from_regex(
    r"([a-z0-9]([-a-z0-9.]{0,8}[a-z0-9])?/)?[A-Za-z0-9]([-A-Za-z0-9_.]{0,8}[A-Za-z0-9])?",
    fullmatch=True,
)  # label keys, and (without a '/') label values
STRINGS = st.one_of(WORDS, TEXT, GOOD)
REQUIREMENTS = st.fixed_dictionaries(
    {},
    optional={
        "key": st.one_of(STRINGS, ANYTHING),
        "operator": st.one_of(st.sampled_from(["In", "NotIn", "Exists", "DoesNotExist"]), ANYTHING),
        "values": st.one_of(st.lists(STRINGS, max_size=3), ANYTHING),
        "other": ANYTHING,
    },
)
NEAR = st.fixed_dictionaries(
    {},
    optional={
        "matchLabels": st.one_of(st.dictionaries(STRINGS, STRINGS, max_size=3), ANYTHING),
        "matchExpressions": st.one_of(st.lists(REQUIREMENTS, max_size=3), ANYTHING),
        "matchFields": ANYTHING,
    },
)


def base_document(robots: object) -> dict[str, Any]:
    return monitor_doc("m", "always (speed < 100)", {"speed": "float"}, robots=robots)


@props(150)
@given(st.one_of(selectors(), NEAR, ANYTHING), st.sampled_from([False, True, None]))
def test_fuzzed_spec_robots_is_accepted_as_written_or_told_where_it_is_wrong(
    robots: object, flow: bool | None
) -> None:
    text = yaml.safe_dump(base_document(robots), default_flow_style=flow, sort_keys=False)
    specs_, diagnostics = parsed(text)  # never raises
    for d in diagnostics:
        assert d.location.line is not None and d.location.col is not None, d
        assert d.message.startswith("spec.robots"), d
        assert 1 <= d.location.line <= text.count("\n") + 1
    if reference_valid(robots):
        assert diagnostics == [], (robots, diagnostics)
        assert isinstance(robots, dict)
        (spec,) = specs_
        assert spec.robots == as_selector(robots)
    else:
        assert specs_ == [] and diagnostics, robots


@props(60)
@given(
    NEAR.filter(bool),
    st.lists(
        st.tuples(st.integers(0, 400), st.sampled_from(list("{}[]:,-'\" \n#&*!?|>x"))), max_size=4
    ),
)
def test_mutated_spec_robots_text_never_raises(
    robots: dict[str, Any], edits: list[tuple[int, str]]
) -> None:
    text = yaml.safe_dump(base_document(robots), sort_keys=False)
    start = text.index("  robots:")
    chars = list(text)
    for at, ch in edits:  # the mutations fall within spec.robots (it is last)
        chars.insert(start + at % (len(text) - start), ch)
    mutated = "".join(chars)
    specs_, diagnostics = parsed(mutated)
    assert specs_ or diagnostics
    for d in diagnostics:
        if d.message.startswith("spec.robots"):
            assert d.location.line is not None and d.location.col is not None, d


def refused_robot_label() -> bool:
    return fleet_of({"n": {ROBOT_LABEL: "amr-7\n"}}).robots == {}


def refused_instance_label() -> bool:
    return parsed(instance_text('"amr-7\\n"'))[1] != []


def refused_label_value() -> bool:
    return parsed(HEAD + '    matchLabels: {site: "hall-a\\n"}\n')[1] != []


def refused_setting() -> bool:
    try:
        OperatorConfig.from_env({**ENV, "EDGERV_ROBOT_LABEL": "edgerv.io/robot\n"})
    except ConfigError:
        return True
    return False


# A known bug: ROBOT_NAME, LABEL_KEY and LABEL_VALUE (edgerv.core.robots) are anchored
# with '$' and used with re.match, and '$' matches before a final line break too (the
# tier label's check used fullmatch before). Each case passes once that is fixed; strict:
# then its marker must go.
@pytest.mark.parametrize(
    "refused",
    [refused_robot_label, refused_instance_label, refused_label_value, refused_setting],
)
def test_a_trailing_line_break_is_no_label_or_name(refused: Callable[[], bool]) -> None:
    assert refused()


# -- the wire: an instance's robot in its placement -----------------------------------------


@props(50)
@given(
    st.sampled_from([None, "edge", "cloud"]),
    st.sampled_from(["auto", "pinned"]),
    st.one_of(st.none(), st.floats(0.5, 1e4)),
    st.one_of(st.none(), ROBOT_NAMES),
)
def test_a_placement_and_its_robot_cross_the_wire(
    tier: str | None, migrate: Any, budget: float | None, robot: str | None
) -> None:
    p = Placement(tier, migrate, budget, robot)
    j = placement_json(p)
    assert ("robot" in j) is (robot is not None)  # said only of an instance
    assert placement_from_json(j) == p
    assert placement_from_json(json.loads(json.dumps(j))) == p  # as JSON carries it


def test_an_odd_robot_on_the_wire_reads_as_none() -> None:
    assert placement_json(Placement()) == {"tier": None, "migrate": "auto", "maxLatencyMs": None}
    assert placement_json(Placement(robot="amr-7"))["robot"] == "amr-7"
    for odd in (None, 7, ["amr-7"], {"name": "amr-7"}):
        assert placement_from_json({"robot": odd}).robot is None
    load = parse_load(
        {
            "handler": "h",
            "monotonic": 1.0,
            "cpuSeconds": 0.5,
            "monitors": {
                "ns.m.amr-7": {
                    "active": True,
                    "events": 3,
                    "migrationWanted": False,
                    "placement": {"tier": "edge", "robot": "amr-7"},
                },
                "ns.m": {"active": True, "events": 3, "migrationWanted": False},
            },
        }
    )
    assert load["monitors"]["ns.m.amr-7"]["placement"].get("robot") == "amr-7"
    assert "robot" not in load["monitors"]["ns.m"]["placement"]


# -- the operator: an instance's document, and the robot label it reads ---------------------

OPERATOR_SPEC: dict[str, Any] = {
    "assertion": "always (running -> speed < limit)",
    "signals": {
        "running": {"topic": "/running", "type": "std_msgs/msg/Bool"},
        "speed": {"topic": "speed", "type": "std_msgs/msg/Float64"},
    },
    "parameters": {"limit": 100},
    "placement": {"tier": "edge"},
    "onViolation": {
        "publish": {"topic": "/stop", "type": "std_msgs/msg/Bool", "message": {"data": True}},
        "call": {"service": "/halt", "type": "std_srvs/srv/Trigger"},
    },
    "robots": {"matchExpressions": [{"key": "site", "operator": "In", "values": ["hall-a"]}]},
}


def test_an_instance_document_is_named_labelled_and_reads_its_robots_graph() -> None:
    before = copy.deepcopy(OPERATOR_SPEC)
    doc = instance_document("robots", "speed-limit", OPERATOR_SPEC, "amr-7")
    assert before == OPERATOR_SPEC
    assert doc["metadata"] == {
        "name": "robots.speed-limit.amr-7",
        "labels": {INSTANCE_LABEL: "amr-7"},
    }
    assert doc["spec"] == instance_spec(OPERATOR_SPEC, "amr-7")
    spec, errors = read(doc)
    assert errors == [] and spec is not None
    assert spec.name == "robots.speed-limit.amr-7"
    assert spec.placement == Placement("edge", "auto", None, "amr-7")
    assert spec.robots is None  # an instance has chosen
    assert [s.topic for s in spec.signals.values()] == ["/amr_7/running", "/amr_7/speed"]
    assert spec.on_violation is not None
    assert spec.on_violation.publish is not None and spec.on_violation.call is not None
    assert spec.on_violation.publish.topic == "/amr_7/stop"
    assert spec.on_violation.call.service == "/amr_7/halt"
    assert yaml.safe_load(document_text(doc)) == doc
    # for no robot: the Monitor's own document, spec.robots and all
    alone = instance_document("robots", "speed-limit", OPERATOR_SPEC, None)
    assert alone == monitor_document("robots", "speed-limit", OPERATOR_SPEC)
    spec, errors = read(alone)
    assert errors == [] and spec is not None and spec.placement.robot is None
    assert spec.robots == Selector(expressions=(Requirement("site", "In", ("hall-a",)),))
    assert spec.signals["speed"].topic == "/speed"


def test_two_robots_instances_differ_in_name_label_and_topics_only() -> None:
    a = instance_document("ns", "m", OPERATOR_SPEC, "amr-1")
    b = instance_document("ns", "m", OPERATOR_SPEC, "amr-2")
    text_a, text_b = document_text(a), document_text(b)
    assert text_a != text_b
    assert text_a.replace("amr_1", "amr_2").replace("amr-1", "amr-2") == text_b


ENV = {"EDGERV_TOKEN": "t", "EDGERV_NAMESPACE": "edgerv", "EDGERV_PLAIN_HTTP": "true"}


def test_the_robot_label_is_a_setting_of_its_own() -> None:
    assert "EDGERV_ROBOT_LABEL" in VARIABLES
    assert OperatorConfig.from_env(ENV).robot_label == ROBOT_LABEL == "edgerv.io/robot"
    cfg = OperatorConfig.from_env({**ENV, "EDGERV_ROBOT_LABEL": "example.com/robot"})
    assert cfg.robot_label == "example.com/robot" and cfg.tier_label == "edgerv.io/tier"
    cfg = OperatorConfig.from_env(
        {**ENV, "EDGERV_ROBOT_LABEL": "edgerv.io/tier", "EDGERV_TIER_LABEL": "example.com/tier"}
    )
    assert (cfg.robot_label, cfg.tier_label) == ("edgerv.io/tier", "example.com/tier")
    for env, error in [
        ({"EDGERV_ROBOT_LABEL": "not a key"}, "EDGERV_ROBOT_LABEL: 'not a key' is not a label key"),
        ({"EDGERV_ROBOT_LABEL": ""}, "EDGERV_ROBOT_LABEL: '' is not a label key"),
        ({"EDGERV_ROBOT_LABEL": "Example.com/robot"}, "EDGERV_ROBOT_LABEL: 'Example.com/robot'"),
        ({"EDGERV_ROBOT_LABEL": "edgerv.io/tier"}, "EDGERV_ROBOT_LABEL: 'edgerv.io/tier' is the"),
        (
            {"EDGERV_ROBOT_LABEL": "site", "EDGERV_TIER_LABEL": "site"},
            "EDGERV_ROBOT_LABEL: 'site' is the tier label too",
        ),
        ({"EDGERV_TIER_LABEL": "a b"}, "EDGERV_TIER_LABEL: 'a b' is not a label key"),
    ]:
        with pytest.raises(ConfigError, match=re.escape(error)):
            OperatorConfig.from_env({**ENV, **env})
