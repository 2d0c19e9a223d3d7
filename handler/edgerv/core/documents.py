"""Monitor documents: the YAML a user applies with kubectl, validated into :class:`MonitorSpec`.

Errors name the file, line and column of the offending node and its field path
(``spec.signals.speed.type``). All documents of a file are checked, and all
errors are reported together.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, cast

import yaml

from edgerv.core.diagnostics import Diagnostic, InputError, Location, did_you_mean
from edgerv.core.msgtypes import FieldError, ValueKind, field_kind, normalize_type, require_type
from edgerv.core.reactions import (
    DEFAULT_CALL_TIMEOUT,
    Call,
    Fields,
    Publish,
    Reaction,
    request_type,
    value_fits,
)
from edgerv.core.robots import (
    INSTANCE_LABEL,
    LABEL_KEY,
    LABEL_VALUE,
    OPERATORS,
    ROBOT_NAME,
    Operator,
    Requirement,
    Selector,
)

API_VERSION = "edgerv.io/v1alpha1"
KIND = "Monitor"
DEFAULT_SORT_THRESHOLD = 1
DEFAULT_BUFFER_CAPACITY = 4096

Value = bool | int | float | str
OnVerdict = Literal["reset", "halt"]

_NAME = re.compile(r"^[a-z0-9]([-a-z0-9.]{0,251}[a-z0-9])?$")  # Kubernetes object name
_IDENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_TIER = re.compile(r"^[a-z0-9]([-a-z0-9]{0,61}[a-z0-9])?$")  # a label value, e.g. edge, cloud
_SERVICE_TYPE = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)/(?:srv/)?([A-Za-z_][A-Za-z0-9_]*)$")
_TOPIC = re.compile(r"^/?[A-Za-z_~{][A-Za-z0-9_/{}~]*$")

# Words of the assertion language that cannot name a signal or a parameter.
RESERVED = frozenset(
    {
        "G",
        "F",
        "X",
        "U",
        "W",
        "R",
        "M",
        "xor",
        "true",
        "false",
        "always",
        "never",
        "next",
        "next_a",
        "next_e",
        "eventually",
        "until",
        "until_",
        "before",
        "before_",
        "abort",
    }
)


Reliability = Literal["auto", "reliable", "best_effort"]
Durability = Literal["auto", "volatile", "transient_local"]


@dataclass(frozen=True)
class QosSpec:
    """How the handler subscribes to a signal's topic; ``auto`` follows the publishers."""

    reliability: Reliability = "auto"
    durability: Durability = "auto"
    depth: int = 1000


@dataclass(frozen=True)
class SignalSpec:
    name: str
    topic: str
    msg_type: str
    field: str
    kind: ValueKind
    initial: Value | None
    location: Location
    qos: QosSpec = dataclasses.field(default_factory=QosSpec)


@dataclass(frozen=True)
class Placement:
    """``spec.placement``: where a monitor runs (the control plane's policy reads it)."""

    tier: str | None = None  # home tier: where it starts and comes back to (default: lowest)
    migrate: Literal["auto", "pinned"] = "auto"
    max_latency_ms: float | None = None
    # the robot whose instance it is (its document's label INSTANCE_LABEL): it runs on that
    # robot's handlers and the shared ones only (edgerv.core.robots.may_host); None: any
    robot: str | None = None


@dataclass(frozen=True)
class MonitorSpec:
    name: str
    assertion: str
    signals: dict[str, SignalSpec]
    parameters: dict[str, Value]
    sort_threshold: int
    on_verdict: OnVerdict
    buffer_capacity: int
    location: Location
    # Maps (offset, length) in the assertion text to its place in the file.
    locate_assertion: Callable[[int, int], Location] = field(repr=False, compare=False)
    placement: Placement = field(default_factory=Placement)
    on_violation: Reaction | None = None  # off unless written
    # ``spec.robots``: the robots the operator runs an instance for (None: every robot)
    robots: Selector | None = None

    @functools.cached_property  # read per message during a handoff: computed once
    def topics(self) -> list[str]:
        """The topics this monitor reads, in order of first use by its signals."""
        return list(dict.fromkeys(s.topic for s in self.signals.values()))


class _Doc:
    """One YAML document: its composed node tree, for positions, and the file text."""

    def __init__(self, path: str, text: str, lines: list[str], root: yaml.Node) -> None:
        self.path = path
        self.lines = lines  # the file's lines, shared by its documents
        self.text = text
        self.root = root
        self.diagnostics: list[Diagnostic] = []

    def loc(self, node: yaml.Node | None, length: int = 1) -> Location:
        if node is None:
            return Location(self.path)
        mark = node.start_mark
        src = self.lines[mark.line] if mark.line < len(self.lines) else None
        return Location(self.path, mark.line + 1, mark.column + 1, length, src)

    def error(
        self, node: yaml.Node | None, where: str, message: str, hint: str | None = None
    ) -> None:
        length = 1
        if isinstance(node, yaml.ScalarNode) and node.start_mark.line == node.end_mark.line:
            length = max(1, node.end_mark.column - node.start_mark.column)
        self.diagnostics.append(
            Diagnostic(self.loc(node, length), f"{where}: {message}", hint=hint)
        )

    def scalar_locator(self, node: yaml.ScalarNode) -> Callable[[int, int], Location]:
        """Locate characters of a scalar's value in the file, whatever its quoting style.

        The value's characters appear in the raw text in order (escapes and folded
        line breaks aside), so a greedy alignment of value to raw text finds them.
        """
        raw_start = node.start_mark.index
        raw = self.text[raw_start : node.end_mark.index]
        value = str(node.value)
        index_of: list[int] = []
        j = 0
        for ch in value:
            k = raw.find(ch, j)
            if k < 0:
                index_of.append(index_of[-1] if index_of else 0)
                continue
            index_of.append(k)
            j = k + 1
        index_of.append(j)
        # The closure keeps the file's text and lines (shared by its documents), not the
        # document's YAML node tree: a monitor lives as long as its handler runs.
        text, lines, path, size = self.text, self.lines, self.path, len(value)

        def locate(offset: int, length: int) -> Location:
            offset = min(max(offset, 0), size)
            absolute = raw_start + index_of[offset]
            line = text.count("\n", 0, absolute)
            col = absolute - (text.rfind("\n", 0, absolute) + 1)
            src = lines[line] if line < len(lines) else None
            return Location(path, line + 1, col + 1, max(1, length), src)

        return locate


def _mapping(node: yaml.Node) -> dict[str, tuple[yaml.Node, yaml.Node]]:
    assert isinstance(node, yaml.MappingNode)
    return {str(k.value): (k, v) for k, v in node.value}


def _construct(node: yaml.Node) -> Any:
    return yaml.SafeLoader("").construct_object(node, deep=True)


def _check_keys(
    doc: _Doc, node: yaml.Node, where: str, allowed: set[str], required: set[str]
) -> dict[str, tuple[yaml.Node, yaml.Node]]:
    if not isinstance(node, yaml.MappingNode):
        doc.error(node, where, "must be a mapping")
        return {}
    items = _mapping(node)
    for key, (knode, _) in items.items():
        if key not in allowed:
            doc.error(knode, f"{where}.{key}", "unknown field", did_you_mean(key, allowed))
    for key in sorted(required - items.keys()):
        doc.error(node, where, f"missing required field '{key}'")
    return items


def _parse_value(
    doc: _Doc, node: yaml.Node, where: str, kinds: tuple[type, ...] = (bool, int, float, str)
) -> Value | None:
    if not isinstance(node, yaml.ScalarNode):
        doc.error(node, where, "must be a single value")
        return None
    try:
        value = _construct(node)
    except yaml.YAMLError as exc:
        doc.error(node, where, f"invalid value: {exc}")
        return None
    except ValueError:  # Python reads no integer of more than 4,300 digits
        doc.error(node, where, "invalid value: a number too long to read")
        return None
    if not isinstance(value, kinds) or (isinstance(value, float) and math.isnan(value)):
        doc.error(node, where, f"must be one of: {', '.join(k.__name__ for k in kinds)}")
        return None
    return cast(Value, value)


def topic_name(text: str) -> str | None:
    """The ROS topic name ``text`` names, absolute (``/cmd_vel`` for ``cmd_vel``), or None."""
    if not _TOPIC.match(text):
        return None
    return text if text.startswith("/") else "/" + text


def _parse_signal(doc: _Doc, name: str, knode: yaml.Node, node: yaml.Node) -> SignalSpec | None:
    where = f"spec.signals.{name}"
    if not _IDENT.match(name) or name in RESERVED:
        doc.error(
            knode,
            where,
            f"'{name}' cannot name a signal",
            "use a letter or _ then letters, digits or _, not an operator such as G or until",
        )
        return None
    items = _check_keys(
        doc, node, where, {"topic", "type", "field", "initial", "qos"}, {"topic", "type"}
    )
    if not items or "topic" not in items or "type" not in items:
        return None
    topic = _parse_value(doc, items["topic"][1], f"{where}.topic", (str,))
    msg_type = _parse_value(doc, items["type"][1], f"{where}.type", (str,))
    fld: Value | None = "data"
    if "field" in items:
        fld = _parse_value(doc, items["field"][1], f"{where}.field", (str,))
    if not isinstance(topic, str) or not isinstance(msg_type, str) or not isinstance(fld, str):
        return None
    absolute = topic_name(topic)
    if absolute is None:
        doc.error(items["topic"][1], f"{where}.topic", f"'{topic}' is not a ROS topic name")
        return None
    topic = absolute
    try:
        kind = field_kind(msg_type, fld)
        msg_type = normalize_type(msg_type)
    except FieldError as exc:
        about = exc.about if exc.about == "type" or "field" in items else "type"
        doc.error(items[about][1], f"{where}.{about}", str(exc), exc.hint)
        return None
    initial: Value | None = None
    if "initial" in items:
        initial = _parse_value(doc, items["initial"][1], f"{where}.initial")
        if initial is not None and not value_fits(initial, kind):
            doc.error(
                items["initial"][1],
                f"{where}.initial",
                f"{initial!r} is not a {kind} value, but {msg_type} field '{fld}' is {kind}",
            )
            return None
    qos = _parse_qos(doc, items["qos"][1], f"{where}.qos") if "qos" in items else QosSpec()
    return SignalSpec(name, topic, msg_type, fld, kind, initial, doc.loc(knode, len(name)), qos)


def _parse_choice(
    doc: _Doc,
    items: dict[str, tuple[yaml.Node, yaml.Node]],
    key: str,
    where: str,
    choices: tuple[str, ...],
) -> str | None:
    """The value of ``key`` when it is one of ``choices``; None (and an error) otherwise."""
    if key not in items:
        return None
    value = _parse_value(doc, items[key][1], f"{where}.{key}", (str,))
    if isinstance(value, str) and value in choices:
        return value
    if value is not None:
        doc.error(
            items[key][1],
            f"{where}.{key}",
            f"must be {', '.join(choices[:-1])} or {choices[-1]}, not '{value}'",
        )
    return None


def _parse_qos(doc: _Doc, node: yaml.Node, where: str) -> QosSpec:
    items = _check_keys(doc, node, where, {"reliability", "durability", "depth"}, set())
    reliability = cast(
        Reliability,
        _parse_choice(doc, items, "reliability", where, ("auto", "reliable", "best_effort"))
        or "auto",
    )
    durability = cast(
        Durability,
        _parse_choice(doc, items, "durability", where, ("auto", "volatile", "transient_local"))
        or "auto",
    )
    depth = QosSpec.depth
    if "depth" in items:
        value = _parse_value(doc, items["depth"][1], f"{where}.depth", (int,))
        if isinstance(value, int) and not isinstance(value, bool):
            if 1 <= value <= 1_000_000:
                depth = value
            else:
                doc.error(items["depth"][1], f"{where}.depth", "must be from 1 to 1000000")
    return QosSpec(reliability, durability, depth)


def _parse_placement(doc: _Doc, node: yaml.Node) -> Placement:
    where = "spec.placement"
    items = _check_keys(doc, node, where, {"tier", "migrate", "maxLatencyMs"}, set())
    tier = None
    if "tier" in items:
        value = _parse_value(doc, items["tier"][1], f"{where}.tier", (str,))
        if isinstance(value, str):
            if _TIER.match(value):
                tier = value
            else:
                doc.error(
                    items["tier"][1],
                    f"{where}.tier",
                    f"'{value}' is not a tier name",
                    "use the name the handlers' tier label has, e.g. edge or cloud",
                )
    migrate = _parse_choice(doc, items, "migrate", where, ("auto", "pinned")) or "auto"
    budget = None
    if "maxLatencyMs" in items:
        value = _parse_value(doc, items["maxLatencyMs"][1], f"{where}.maxLatencyMs", (int, float))
        if isinstance(value, int | float):
            if not isinstance(value, bool) and value > 0 and math.isfinite(value):
                budget = float(value)
            else:
                doc.error(
                    items["maxLatencyMs"][1], f"{where}.maxLatencyMs", "must be a number above 0"
                )
    return Placement(tier, cast(Literal["auto", "pinned"], migrate), budget)


def _parse_label(
    doc: _Doc, knode: yaml.Node, vnode: yaml.Node, where: str
) -> tuple[str, str] | None:
    """A label's key and value (each checked as Kubernetes checks them)."""
    key = _parse_value(doc, knode, where, (str,))
    value = _parse_value(doc, vnode, where, (str,))
    if isinstance(key, str) and not LABEL_KEY.match(key):
        doc.error(knode, where, f"'{key}' is not a label key", "e.g. edgerv.io/robot or site")
        return None
    if isinstance(value, str) and not LABEL_VALUE.match(value):
        doc.error(
            vnode,
            where,
            f"'{value}' is not a label value",
            "up to 63 letters, digits, '-', '_' and '.', starting and ending alphanumeric",
        )
        return None
    return (key, value) if isinstance(key, str) and isinstance(value, str) else None


def _sequence(doc: _Doc, node: yaml.Node, where: str, what: str) -> list[yaml.Node]:
    """The items of a YAML list; none (and an error) when ``node`` is not one."""
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    doc.error(node, where, f"must be a list of {what}")
    return []


def _empty_list(node: yaml.Node) -> bool:
    return isinstance(node, yaml.SequenceNode) and not node.value


def _parse_requirement(doc: _Doc, node: yaml.Node, where: str) -> Requirement | None:
    items = _check_keys(doc, node, where, {"key", "operator", "values"}, {"key", "operator"})
    if "key" not in items or "operator" not in items:
        return None
    key = _parse_value(doc, items["key"][1], f"{where}.key", (str,))
    if isinstance(key, str) and not LABEL_KEY.match(key):
        doc.error(items["key"][1], f"{where}.key", f"'{key}' is not a label key")
        key = None
    op = _parse_choice(doc, items, "operator", where, OPERATORS)
    values: list[str] = []
    if "values" in items:
        for i, v in enumerate(
            _sequence(doc, items["values"][1], f"{where}.values", "label values")
        ):
            value = _parse_value(doc, v, f"{where}.values[{i}]", (str,))
            if isinstance(value, str) and not LABEL_VALUE.match(value):
                doc.error(v, f"{where}.values[{i}]", f"'{value}' is not a label value")
            elif isinstance(value, str):
                values.append(value)
    if op in ("In", "NotIn") and "values" not in items:
        doc.error(node, f"{where}.values", f"{op} needs a non-empty list of values")
    elif op in ("In", "NotIn") and _empty_list(items["values"][1]):
        doc.error(items["values"][1], f"{where}.values", f"{op} needs a non-empty list of values")
    elif op in ("Exists", "DoesNotExist") and "values" in items:
        vnode = items["values"][1]
        if not _empty_list(vnode):
            doc.error(vnode, f"{where}.values", f"{op} takes no values", "remove values:")
    if not isinstance(key, str) or op is None:
        return None
    return Requirement(key, cast(Operator, op), tuple(values))


def _parse_robots(doc: _Doc, node: yaml.Node) -> Selector:
    """``spec.robots``: a label selector over the robots' nodes."""
    where = "spec.robots"
    items = _check_keys(doc, node, where, {"matchLabels", "matchExpressions"}, set())
    labels: dict[str, str] = {}
    if "matchLabels" in items:
        lnode = items["matchLabels"][1]
        if not isinstance(lnode, yaml.MappingNode):
            doc.error(lnode, f"{where}.matchLabels", "must map label keys to values")
        else:
            for kn, vn in lnode.value:
                key = kn.value if isinstance(kn, yaml.ScalarNode) else "?"
                label = _parse_label(doc, kn, vn, f"{where}.matchLabels.{key}")
                if label is not None:
                    labels[label[0]] = label[1]
    expressions: list[Requirement] = []
    if "matchExpressions" in items:
        enode, at = items["matchExpressions"][1], f"{where}.matchExpressions"
        for i, e in enumerate(_sequence(doc, enode, at, "requirements")):
            r = _parse_requirement(doc, e, f"{at}[{i}]")
            if r is not None:
                expressions.append(r)
    return Selector(labels, tuple(expressions))


def _parse_instance_robot(doc: _Doc, meta: dict[str, tuple[yaml.Node, yaml.Node]]) -> str | None:
    """The robot an instance document watches: its label INSTANCE_LABEL (None: none)."""
    if "labels" not in meta:
        return None
    lnode = meta["labels"][1]
    if isinstance(lnode, yaml.ScalarNode) and lnode.tag == "tag:yaml.org,2002:null":
        return None  # labels: null (as a resource may say)
    if not isinstance(lnode, yaml.MappingNode):
        doc.error(lnode, "metadata.labels", "must map label keys to values")
        return None
    for kn, vn in lnode.value:
        if kn.value != INSTANCE_LABEL:
            continue
        robot = _parse_value(doc, vn, f"metadata.labels.{INSTANCE_LABEL}", (str,))
        if isinstance(robot, str) and ROBOT_NAME.match(robot):
            return robot
        if robot is not None:
            doc.error(
                vn,
                f"metadata.labels.{INSTANCE_LABEL}",
                f"'{robot}' is not a robot's name",
                "a lower-case letter, then letters, digits and '-' (at most 63)",
            )
    return None


def _parse_fields(doc: _Doc, node: yaml.Node, where: str, msg_type: str | None) -> Fields:
    """A message's field values (nested mappings for nested messages) as dotted paths,
    each checked against ``msg_type`` (None: the type is wrong, only the shape is read)."""
    out: list[tuple[str, Any]] = []

    def walk(node: yaml.Node, prefix: str) -> None:
        if not isinstance(node, yaml.MappingNode):
            doc.error(node, where + (f".{prefix}" if prefix else ""), "must be a mapping of fields")
            return
        for key, (knode, vnode) in _mapping(node).items():
            path = f"{prefix}.{key}" if prefix else key
            if isinstance(vnode, yaml.MappingNode):
                walk(vnode, path)
                continue
            if isinstance(vnode, yaml.SequenceNode):
                doc.error(
                    vnode,
                    f"{where}.{path}",
                    "an array cannot be set in a reaction",
                    "set scalar fields; arrays keep their default (empty)",
                )
                continue
            value = _parse_value(doc, vnode, f"{where}.{path}")
            if value is None or msg_type is None:
                continue
            try:
                kind = field_kind(msg_type, path)
            except FieldError as exc:
                doc.error(knode, f"{where}.{path}", str(exc), exc.hint)
                continue
            if not value_fits(value, kind):
                problem = (
                    f"{value!r} is not a {kind} value, but {msg_type} field '{path}' is {kind}"
                )
                doc.error(vnode, f"{where}.{path}", problem)
                continue
            out.append((path, value))

    if not (isinstance(node, yaml.ScalarNode) and node.value in ("", "~", "null")):
        walk(node, "")
    return tuple(out)


def _parse_type(
    doc: _Doc, items: dict[str, tuple[yaml.Node, yaml.Node]], where: str, service: bool
) -> str | None:
    """The known message type (``service``: service type, ``pkg/srv/Name``) at
    ``items["type"]``, normalized; None and an error otherwise."""
    value = _parse_value(doc, items["type"][1], f"{where}.type", (str,))
    if not isinstance(value, str):
        return None
    try:
        if not service:
            return require_type(value)
        m = _SERVICE_TYPE.match(value.strip())
        if not m:
            raise FieldError(
                f"'{value}' is not a service type name",
                "write it as package/srv/Name, e.g. std_srvs/srv/Trigger",
            )
        srv_type = f"{m.group(1)}/srv/{m.group(2)}"
        try:
            require_type(request_type(srv_type))
        except FieldError:
            raise FieldError(
                f"unknown service type '{value}'",
                "edgerv knows std_srvs' services, and those of a .srv file under share/ of "
                "a ROS install prefix or under a directory of $EDGERV_MSG_PATH",
            ) from None
        return srv_type
    except FieldError as exc:
        doc.error(items["type"][1], f"{where}.type", str(exc), exc.hint)
        return None


def _parse_name(
    doc: _Doc, items: dict[str, tuple[yaml.Node, yaml.Node]], key: str, where: str, what: str
) -> str | None:
    """The ROS name (topic or service) at ``items[key]``, absolute; None and an error."""
    value = _parse_value(doc, items[key][1], f"{where}.{key}", (str,))
    absolute = topic_name(value) if isinstance(value, str) else None
    if isinstance(value, str) and absolute is None:
        doc.error(items[key][1], f"{where}.{key}", f"'{value}' is not a ROS {what} name")
    return absolute


def _parse_reaction(doc: _Doc, node: yaml.Node, read: set[str]) -> Reaction | None:
    """``spec.onViolation``; ``read``: the topics of the monitor's signals, which its
    reaction may not publish on."""
    where = "spec.onViolation"
    items = _check_keys(doc, node, where, {"publish", "call"}, set())
    if not items:
        if isinstance(node, yaml.MappingNode):
            doc.error(node, where, "names no reaction", "write publish:, call: or both")
        return None
    publish = call = None
    if "publish" in items:
        sub = f"{where}.publish"
        p = _check_keys(
            doc, items["publish"][1], sub, {"topic", "type", "message"}, {"topic", "type"}
        )
        if "topic" in p and "type" in p:
            topic = _parse_name(doc, p, "topic", sub, "topic")
            if topic in read:
                doc.error(
                    p["topic"][1],
                    f"{sub}.topic",
                    f"{topic} is a topic this monitor reads: each reaction would be an event "
                    "of its own, and could violate it again, without end",
                    "publish on a topic the monitor does not read (another monitor may read it)",
                )
            msg_type = _parse_type(doc, p, sub, service=False)
            fields = (
                _parse_fields(doc, p["message"][1], f"{sub}.message", msg_type)
                if "message" in p
                else ()
            )
            if topic is not None and msg_type is not None:
                publish = Publish(topic, msg_type, fields)
    if "call" in items:
        sub = f"{where}.call"
        c = _check_keys(
            doc,
            items["call"][1],
            sub,
            {"service", "type", "request", "timeoutMs"},
            {"service", "type"},
        )
        if "service" in c and "type" in c:
            service = _parse_name(doc, c, "service", sub, "service")
            srv_type = _parse_type(doc, c, sub, service=True)
            request = (
                _parse_fields(doc, c["request"][1], f"{sub}.request", request_type(srv_type))
                if "request" in c and srv_type is not None
                else ()
            )
            timeout = DEFAULT_CALL_TIMEOUT
            if "timeoutMs" in c:
                value = _parse_value(doc, c["timeoutMs"][1], f"{sub}.timeoutMs", (int, float))
                if isinstance(value, int | float) and not isinstance(value, bool):
                    if 0 < value <= 600_000 and math.isfinite(value):
                        timeout = value / 1000
                    else:
                        doc.error(
                            c["timeoutMs"][1],
                            f"{sub}.timeoutMs",
                            "must be above 0 and at most 600000",
                        )
            if service is not None and srv_type is not None:
                call = Call(service, srv_type, request, timeout)
    if publish is None and call is None:
        return None
    return Reaction(publish, call)


def _parse_int(
    doc: _Doc, items: dict[str, tuple[yaml.Node, yaml.Node]], key: str, default: int, minimum: int
) -> int:
    if key not in items:
        return default
    value = _parse_value(doc, items[key][1], f"spec.{key}", (int,))
    if value is None or isinstance(value, bool) or not isinstance(value, int):
        return default
    if value < minimum:
        doc.error(items[key][1], f"spec.{key}", f"must be at least {minimum}, not {value}")
    elif value > MAX_COUNT:
        doc.error(items[key][1], f"spec.{key}", f"must be at most {MAX_COUNT}, not {value}")
    return value


def _duplicate_keys(doc: _Doc) -> None:
    """A key written twice in one mapping, at any depth, is an error at the second naming
    the first (YAML keeps only the last, without a word: ``assertion`` written twice
    would silently check the second)."""
    stack: list[tuple[yaml.Node, str]] = [(doc.root, "")]
    seen: set[int] = set()  # an alias is the node it names: walked once
    while stack:
        node, where = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        if isinstance(node, yaml.SequenceNode):
            stack.extend((v, f"{where}[{i}]") for i, v in enumerate(node.value))
        if not isinstance(node, yaml.MappingNode):
            continue
        first: dict[str, yaml.Node] = {}
        for knode, vnode in node.value:
            key = str(knode.value) if isinstance(knode, yaml.ScalarNode) else None
            path = f"{where}.{key}" if where else str(key)
            if key is not None and key != "<<":
                if key in first:
                    mark = first[key].start_mark
                    doc.error(knode, path, f"'{key}' is written twice in this mapping (first "
                              f"at line {mark.line + 1}, column {mark.column + 1})",
                              "YAML would keep only the last: remove one")  # fmt: skip
                else:
                    first[key] = knode
            stack.append((vnode, path))


def _parse_monitor(doc: _Doc) -> MonitorSpec | None:
    _duplicate_keys(doc)
    if doc.diagnostics:
        return None
    top = _check_keys(
        doc,
        doc.root,
        "document",
        {"apiVersion", "kind", "metadata", "spec", "status"},
        {"apiVersion", "kind", "metadata", "spec"},
    )
    if not top or not {"apiVersion", "kind", "metadata", "spec"} <= top.keys():
        return None
    api = _parse_value(doc, top["apiVersion"][1], "apiVersion", (str,))
    if api is not None and api != API_VERSION:
        doc.error(top["apiVersion"][1], "apiVersion", f"must be {API_VERSION}, not '{api}'")
    kind = _parse_value(doc, top["kind"][1], "kind", (str,))
    if kind is not None and kind != KIND:
        doc.error(
            top["kind"][1],
            "kind",
            f"must be {KIND}, not '{kind}'",
            "edgerv reads only Monitor documents; keep other objects in another file",
        )
    meta = _check_keys(
        doc,
        top["metadata"][1],
        "metadata",
        {
            "name",
            "namespace",
            "labels",
            "annotations",
            "uid",
            "resourceVersion",
            "generation",
            "creationTimestamp",
            "managedFields",
        },
        {"name"},
    )
    name: Value | None = None
    if "name" in meta:
        name = _parse_value(doc, meta["name"][1], "metadata.name", (str,))
        if isinstance(name, str) and not _NAME.match(name):
            doc.error(
                meta["name"][1],
                "metadata.name",
                f"'{name}' is not a valid object name",
                "use lower-case letters, digits, '-' and '.', starting and ending alphanumeric",
            )
    spec = _check_keys(
        doc,
        top["spec"][1],
        "spec",
        {
            "assertion",
            "signals",
            "parameters",
            "sortThreshold",
            "onVerdict",
            "bufferCapacity",
            "placement",
            "onViolation",
            "robots",
        },
        {"assertion", "signals"},
    )
    if not spec:
        return None
    assertion_node = spec.get("assertion", (None, None))[1]
    assertion = None
    if assertion_node is not None:
        assertion = _parse_value(doc, assertion_node, "spec.assertion", (str,))
        if isinstance(assertion, str) and not assertion.strip():
            doc.error(assertion_node, "spec.assertion", "is empty")
    signals: dict[str, SignalSpec] = {}
    if "signals" in spec:
        snode = spec["signals"][1]
        if not isinstance(snode, yaml.MappingNode) or not snode.value:
            doc.error(snode, "spec.signals", "must map each signal name to its topic and type")
        else:
            for sname, (kn, vn) in _mapping(snode).items():
                sig = _parse_signal(doc, sname, kn, vn)
                if sig is not None:
                    signals[sname] = sig
    parameters: dict[str, Value] = {}
    if "parameters" in spec:
        pnode = spec["parameters"][1]
        if not isinstance(pnode, yaml.MappingNode):
            doc.error(pnode, "spec.parameters", "must map each parameter name to a value")
        else:
            for pname, (kn, vn) in _mapping(pnode).items():
                where = f"spec.parameters.{pname}"
                if not _IDENT.match(pname) or pname in RESERVED:
                    doc.error(kn, where, f"'{pname}' cannot name a parameter")
                elif pname in signals:
                    doc.error(kn, where, f"'{pname}' names a signal too; rename one of them")
                else:
                    pvalue = _parse_value(doc, vn, where)
                    if pvalue is not None:
                        parameters[pname] = pvalue
    on_verdict = cast(
        OnVerdict, _parse_choice(doc, spec, "onVerdict", "spec", ("reset", "halt")) or "reset"
    )
    sort_threshold = _parse_int(doc, spec, "sortThreshold", DEFAULT_SORT_THRESHOLD, 1)
    buffer_capacity = _parse_int(doc, spec, "bufferCapacity", DEFAULT_BUFFER_CAPACITY, 1)
    if 1 <= buffer_capacity < sort_threshold:  # (below 1, _parse_int said so already)
        if "sortThreshold" in spec:
            key = "sortThreshold"
            problem = f"{sort_threshold} is more than bufferCapacity ({buffer_capacity})"
        else:
            key = "bufferCapacity"
            problem = f"{buffer_capacity} is less than sortThreshold ({sort_threshold})"
        doc.error(spec[key][1], f"spec.{key}", problem)
    placement = _parse_placement(doc, spec["placement"][1]) if "placement" in spec else Placement()
    on_violation = (
        _parse_reaction(doc, spec["onViolation"][1], {sig.topic for sig in signals.values()})
        if "onViolation" in spec
        else None
    )
    robots = _parse_robots(doc, spec["robots"][1]) if "robots" in spec else None
    placement = dataclasses.replace(placement, robot=_parse_instance_robot(doc, meta))
    if doc.diagnostics or not isinstance(name, str) or not isinstance(assertion, str):
        return None
    assert isinstance(assertion_node, yaml.ScalarNode)
    return MonitorSpec(
        name=name,
        assertion=assertion,
        signals=signals,
        parameters=parameters,
        sort_threshold=sort_threshold,
        on_verdict=on_verdict,
        buffer_capacity=buffer_capacity,
        location=doc.loc(meta["name"][1]),
        placement=placement,
        locate_assertion=doc.scalar_locator(assertion_node),
        on_violation=on_violation,
        robots=robots,
    )


_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml when PyYAML has it
MAX_DOCUMENT_CHARS = 4 << 20  # a Monitor file, or a request's documents
MAX_NESTING = 64  # levels of YAML/JSON nesting, blocks and brackets together
MAX_COUNT = 10**8  # sortThreshold, bufferCapacity: events a monitor may hold


def _check_shape(path: str, text: str) -> None:
    """Refuse a document too large or nested too deep before any YAML parser sees it:
    libyaml's composer recurses in C, and 50,000 nested brackets crash the process."""
    if len(text) > MAX_DOCUMENT_CHARS:
        problem = f"the file is larger than {MAX_DOCUMENT_CHARS} characters"
        hint = "a Monitor file holds a few documents: split it"
        raise InputError([Diagnostic(Location(path), problem, hint=hint)])
    depth = 0
    indents: list[int] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.lstrip(" ")
        if stripped and not stripped.startswith("#") and depth == 0:
            indent = len(line) - len(stripped)
            while indents and indents[-1] >= indent:
                indents.pop()
            indents.append(indent)  # block nesting: one level per deeper indentation
        quote = None
        for col, ch in enumerate(line, start=1):
            if quote:
                quote = None if ch == quote else quote
            elif ch in "\"'":
                quote = ch
            elif ch == "#" and (col == 1 or line[col - 2] in " \t"):
                break  # a comment
            elif ch in "[{":
                depth += 1
            elif ch in "]}":
                depth = max(0, depth - 1)
            if depth + len(indents) > MAX_NESTING:
                loc = Location(path, lineno, col, 1, line[:200])
                problem = f"nested more than {MAX_NESTING} levels deep"
                hint = "a Monitor document needs a few levels"
                raise InputError([Diagnostic(loc, problem, hint=hint)])


def _documents(path: str, text: str) -> Iterator[_Doc]:
    _check_shape(path, text)
    lines = text.splitlines()
    try:
        for root in yaml.compose_all(text, Loader=_LOADER):
            if root is not None:
                yield _Doc(path, text, lines, root)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark
        lines = text.splitlines()
        loc = (
            Location(
                path,
                mark.line + 1,
                mark.column + 1,
                1,
                lines[mark.line] if mark.line < len(lines) else None,
            )
            if mark is not None
            else Location(path)
        )
        long_key = _long_json_key(text)
        if long_key is not None:  # valid JSON, which YAML reads but for keys over 1,024
            problem = (f"a key of {len(long_key):,} characters ('{long_key[:40]}...'): YAML, "
                       f"which reads this JSON, takes keys of at most {MAX_KEY:,}")  # fmt: skip
            hint = "no Monitor field is that long: check the key"
            raise InputError([Diagnostic(loc, problem, hint=hint)]) from None
        raise InputError([Diagnostic(loc, f"invalid YAML: {exc.problem}")]) from None
    except yaml.reader.ReaderError as exc:  # a character YAML does not allow (a control)
        at = min(max(0, exc.position), len(text))
        line = text.count("\n", 0, at)
        col = at - (text.rfind("\n", 0, at) + 1) + 1
        src = lines[line] if line < len(lines) else None
        char = exc.character if isinstance(exc.character, int) else ord(exc.character[:1] or "?")
        problem = f"invalid YAML: {exc.reason} (U+{char:04X})"
        raise InputError([Diagnostic(Location(path, line + 1, col, 1, src), problem)]) from None
    except yaml.YAMLError as exc:  # any other the parser raises: at least the file
        raise InputError([Diagnostic(Location(path), f"invalid YAML: {exc}")]) from None


MAX_KEY = 1024  # characters: PyYAML's limit for a key in a flow mapping (as JSON writes one)


def _long_json_key(text: str) -> str | None:
    """The first key longer than :data:`MAX_KEY` if ``text`` is JSON, else None."""
    try:
        stack: list[Any] = [json.loads(text)]
    except (ValueError, RecursionError):
        return None
    while stack:
        value = stack.pop()
        if isinstance(value, dict):
            long: str | None = next((str(k) for k in value if len(k) > MAX_KEY), None)
            if long is not None:
                return long
            stack.extend(value.values())
        elif isinstance(value, list):
            stack.extend(value)
    return None


def _unique(spec: MonitorSpec, seen: dict[str, Location], diagnostics: list[Diagnostic]) -> bool:
    """Record a monitor's name; a second definition is an error naming the first."""
    if spec.name in seen:
        diagnostics.append(
            Diagnostic(
                spec.location,
                f"metadata.name: monitor '{spec.name}' "
                f"is defined twice (first at {seen[spec.name]})",
            )
        )
        return False
    seen[spec.name] = spec.location
    return True


def parse_monitors_text(path: str, text: str) -> tuple[list[MonitorSpec], list[Diagnostic]]:
    """Every valid Monitor document of a file, and the diagnostics of the others.

    A bad document does not stop the good ones; only YAML that cannot be read
    stops the documents after it.
    """
    monitors: list[MonitorSpec] = []
    diagnostics: list[Diagnostic] = []
    seen: dict[str, Location] = {}
    try:
        for doc in _documents(path, text):
            spec = _parse_monitor(doc)
            diagnostics += doc.diagnostics
            if spec is not None and _unique(spec, seen, diagnostics):
                monitors.append(spec)
    except InputError as exc:
        diagnostics += exc.diagnostics
    if not monitors and not diagnostics:
        diagnostics.append(Diagnostic(Location(path), "no Monitor document in this file"))
    return monitors, diagnostics


def load_monitors_text(path: str, text: str) -> list[MonitorSpec]:
    """Parse and validate every Monitor document of one file; raise :class:`InputError`."""
    monitors, diagnostics = parse_monitors_text(path, text)
    if diagnostics:
        raise InputError(diagnostics)
    return monitors


def monitor_files(path: Path) -> list[Path]:
    """A file, or the ``*.yaml``/``*.yml`` files of a directory in name order."""
    if path.is_dir():
        return sorted(p for p in path.iterdir() if p.suffix in (".yaml", ".yml") and p.is_file())
    return [path]


def read_monitors(path: str | Path) -> tuple[list[MonitorSpec], list[Diagnostic]]:
    """All valid monitors of a file or directory, and the diagnostics of the others.

    Monitor names must be unique across the files: a second definition is an error.
    """
    p = Path(path)
    if not p.exists():
        return [], [Diagnostic(Location(str(p)), "no such file or directory")]
    files = monitor_files(p)
    if not files:
        return [], [Diagnostic(Location(str(p)), "no .yaml file in this directory")]
    out: list[MonitorSpec] = []
    diagnostics: list[Diagnostic] = []
    seen: dict[str, Location] = {}
    for f in files:
        try:
            text = f.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            diagnostics.append(Diagnostic(Location(str(f)), f"cannot read: {exc}"))
            continue
        specs, found = parse_monitors_text(str(f), text)
        diagnostics += found
        out += [s for s in specs if _unique(s, seen, diagnostics)]
    return out, diagnostics


def load_monitors(path: str | Path) -> list[MonitorSpec]:
    """Load all monitors from a file or a directory; raise :class:`InputError` on any error."""
    monitors, diagnostics = read_monitors(path)
    if diagnostics:
        raise InputError(diagnostics)
    return monitors
