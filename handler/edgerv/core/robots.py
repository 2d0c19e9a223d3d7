"""A fleet: robots, the Monitor's choice of them, and one instance of a monitor per robot.

Pure (tests/unit/test_robots.py). A *robot* is the set of a cluster's nodes whose robot
label (the chart's ``fleet.robotLabel``, default ``edgerv.io/robot``) has its name as
value; a node without it is shared (a cloud node: it serves every robot). A Monitor's
``spec.robots`` is a Kubernetes label selector over the robots' nodes (absent: every
robot); it runs one *instance* per robot it selects, a Monitor document of its own:
named ``<monitor>.<robot>``, labelled with the robot (:data:`INSTANCE_LABEL`), and
reading that robot's ROS graph: its topics and services under the robot's namespace
(``/odom`` of robot ``amr-7`` is ``/amr_7/odom``). A cluster without robots runs each
Monitor once, as written (docs/protocol.md, "Fleet").
"""

from __future__ import annotations

import copy
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

ROBOT_LABEL = "edgerv.io/robot"  # the nodes' label that names their robot (chart default)
INSTANCE_LABEL = "edgerv.io/robot"  # an instance document's label: the robot it watches

# A robot's name: a DNS label starting with a letter (it becomes a Monitor's instance name
# and, '-' read as '_', a ROS namespace, whose tokens start with a letter). Each pattern
# ends at \Z, not $ (which a final line break would pass).
ROBOT_NAME = re.compile(r"^[a-z]([-a-z0-9]{0,61}[a-z0-9])?\Z")
# Kubernetes label keys and values (a key's optional prefix a DNS subdomain).
_LABEL_NAME = r"[A-Za-z0-9]([-A-Za-z0-9_.]{0,61}[A-Za-z0-9])?"
LABEL_KEY = re.compile(
    rf"^([a-z0-9]([-a-z0-9]*[a-z0-9])?(\.[a-z0-9]([-a-z0-9]*[a-z0-9])?)*/)?{_LABEL_NAME}\Z"
)
LABEL_VALUE = re.compile(rf"^({_LABEL_NAME})?\Z")

Operator = Literal["In", "NotIn", "Exists", "DoesNotExist"]
OPERATORS: tuple[Operator, ...] = ("In", "NotIn", "Exists", "DoesNotExist")


@dataclass(frozen=True)
class Requirement:
    """One of ``matchExpressions``: ``key`` ``operator`` ``values``."""

    key: str
    operator: Operator
    values: tuple[str, ...] = ()

    def matches(self, labels: Mapping[str, str]) -> bool:
        if self.operator == "Exists":
            return self.key in labels
        if self.operator == "DoesNotExist":
            return self.key not in labels
        inside = self.key in labels and labels[self.key] in self.values
        return inside if self.operator == "In" else not inside


@dataclass(frozen=True)
class Selector:
    """``spec.robots``: a label selector (all of ``match_labels`` and of ``expressions``;
    empty: everything), as Kubernetes reads one."""

    match_labels: Mapping[str, str] = field(default_factory=dict)
    expressions: tuple[Requirement, ...] = ()

    def matches(self, labels: Mapping[str, str]) -> bool:
        return all(labels.get(k) == v for k, v in self.match_labels.items()) and all(
            r.matches(labels) for r in self.expressions
        )


@dataclass(frozen=True)
class Robot:
    """A robot: its name and its nodes' labels, by node."""

    name: str
    nodes: Mapping[str, Mapping[str, str]]

    def selected_by(self, selector: Selector | None) -> bool:
        """Whether ``spec.robots`` selects it: one of its nodes matches (absent: yes)."""
        return selector is None or any(selector.matches(ls) for ls in self.nodes.values())


@dataclass(frozen=True)
class Fleet:
    """A cluster's robots, by name; the nodes whose robot label names no robot a valid
    name could (``refused``: node -> the value), which serve no robot and no one."""

    robots: Mapping[str, Robot]
    refused: Mapping[str, str] = field(default_factory=dict)
    shared: frozenset[str] = frozenset()  # nodes of no robot: they serve all

    def robot_of(self, node: str) -> str | None:
        """The robot ``node`` belongs to (None: a shared node, or refused: see
        ``refused``)."""
        for robot in self.robots.values():
            if node in robot.nodes:
                return robot.name
        return None

    def selected(self, selector: Selector | None) -> list[str]:
        """The robots ``spec.robots`` selects, by name."""
        return sorted(r.name for r in self.robots.values() if r.selected_by(selector))


def fleet_of(nodes: Mapping[str, Mapping[str, str]], label: str = ROBOT_LABEL) -> Fleet:
    """The robots of a cluster whose nodes have these labels (node -> labels)."""
    members: dict[str, dict[str, Mapping[str, str]]] = {}
    refused: dict[str, str] = {}
    shared = set()
    for node, labels in nodes.items():
        name = labels.get(label)
        if name is None:
            shared.add(node)
        elif ROBOT_NAME.match(name):
            members.setdefault(name, {})[node] = dict(labels)
        else:
            refused[node] = name
    robots = {n: Robot(n, nodes_) for n, nodes_ in members.items()}
    return Fleet(robots, refused, frozenset(shared))


def ros_namespace(robot: str) -> str:
    """The ROS namespace of a robot's graph: ``/amr_7`` for ``amr-7``."""
    return "/" + robot.replace("-", "_")


def in_namespace(name: str, robot: str) -> str:
    """A topic or service name as robot ``robot`` publishes it: ``/odom`` and ``odom``
    become ``/amr_7/odom``. A private name (``~/x``: the handler's own) and one with a
    substitution (``{node}``) are the handler's: left as they are."""
    if name.startswith("~") or "{" in name:
        return name
    return ros_namespace(robot) + "/" + name.lstrip("/")


def instance_name(monitor: str, robot: str) -> str:
    """A monitor's instance for ``robot`` (a robot's name has no '.': unambiguous)."""
    return f"{monitor}.{robot}"


def instance_spec(spec: Mapping[str, Any], robot: str) -> dict[str, Any]:
    """A Monitor's spec as its instance for ``robot`` runs it: every topic and service it
    reads or acts on in the robot's namespace, ``robots`` gone (it has chosen)."""
    out = copy.deepcopy(dict(spec))
    out.pop("robots", None)
    signals = out.get("signals")
    for signal in signals.values() if isinstance(signals, dict) else ():
        if isinstance(signal, dict) and isinstance(signal.get("topic"), str):
            signal["topic"] = in_namespace(signal["topic"], robot)
    reaction = out.get("onViolation")
    if isinstance(reaction, dict):
        for key, name in (("publish", "topic"), ("call", "service")):
            part = reaction.get(key)
            if isinstance(part, dict) and isinstance(part.get(name), str):
                part[name] = in_namespace(part[name], robot)
    return out


def may_host(monitor_robot: str | None, handler_robot: str | None) -> bool:
    """Whether a handler of ``handler_robot``'s node (None: a shared node) may run an
    instance of ``monitor_robot`` (None: a monitor of no robot, as in a cluster without
    robots): a shared handler any, a robot's own handler only its robot's."""
    return handler_robot is None or monitor_robot is None or handler_robot == monitor_robot
