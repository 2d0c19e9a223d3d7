"""ROS 2 message type introspection without rclpy.

Field types come from the message definitions that ``rosbags`` ships for ROS 2
Jazzy (std_msgs, geometry_msgs, nav_msgs, sensor_msgs, diagnostic_msgs, ...),
so the core can check a signal's ``type`` and ``field`` before any ROS node
exists. Any other type -- a robot's own package -- is read from its ``.msg``
file, looked up as ``<pkg>/msg/<Type>.msg`` under each directory of
``$EDGERV_MSG_PATH`` and under ``share/`` of each ROS install prefix
(``$AMENT_PREFIX_PATH`` and this Python environment's own prefix).

A field path is dotted (``twist.twist.linear.x``) with ``[i]`` for an element
of an array or sequence (``ranges[0]``).

Services: a service's events, the messages ``ros2 bag record --all-services`` records on
``/<service>/_service_event`` (service introspection, Jazzy), are of the type
``pkg/srv/Name_Event``: ``service_msgs/msg/ServiceEventInfo info``,
``Name_Request[<=1] request``, ``Name_Response[<=1] response``. The three types are made
from the service's definition: the one a bag carries (rosbag2 writes the ``.srv`` text
after an ``SRV: pkg/srv/Name`` line, then its dependencies), else its ``.srv`` file,
found as ``<pkg>/srv/<Name>.srv`` where ``.msg`` files are.

Optionals: a sequence of at most one element (``T[<=1]``, ROS's idiom for an optional,
as a service event's ``request`` and ``response``) is read through its element
(``request[0].a``). When it is empty, a reader gives :data:`ABSENT` for every field
inside it (:func:`optional_steps` says which steps of a path are such optionals), and
the pipeline leaves that signal's update out of the event: it holds its value.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Literal

ValueKind = Literal["bool", "int", "float", "string"]

_BASE_KINDS: dict[str, ValueKind] = {
    "bool": "bool",
    "float32": "float",
    "float64": "float",
    "string": "string",
    "wstring": "string",
    **{t: "int" for t in ("byte", "char", "octet")},
    **{f"{s}int{n}": "int" for s in ("", "u") for n in (8, 16, 32, 64)},
}

_PART = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)$")
_TYPE = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)/(?:(msg|srv)/)?([A-Za-z_][A-Za-z0-9_]*)$")
SERVICE_PARTS = ("_Request", "_Response", "_Event")  # the types a service pkg/srv/Name makes
SEPARATOR = "=" * 80 + "\n"  # between the definitions a bag concatenates (rosbag2's)
_EMPTY_MEMBER = ("structure_needs_at_least_one_member", (1, ("uint8", 0)))
_EVENT_INFO = "service_msgs/msg/ServiceEventInfo"
# std_srvs' services (Jazzy's std_srvs 5.3, comments left out), known without ROS installed
# (the operator's image) as the message packages are: a reaction calls them (spec.onViolation).
# test_reactions.py keeps them equal to the installed .srv files.
STD_SRVS: Final = {
    "std_srvs/srv/Empty": "---\n",
    "std_srvs/srv/SetBool": "bool data\n---\nbool success\nstring message\n",
    "std_srvs/srv/Trigger": "---\nbool success\nstring message\n",
}


class _Absent:
    """The type of :data:`ABSENT` (one instance)."""

    __slots__ = ()

    def __repr__(self) -> str:
        return "ABSENT"

    def __reduce__(self) -> str:
        return "ABSENT"


# What a reader gives for a field inside an empty optional (a sequence of at most one
# element, ``T[<=1]``): the message has no value for it, and the signal reading it holds
# the one it had (docs/semantics.md, section 2).
ABSENT: Final = _Absent()


class FieldError(Exception):
    """A message type or field that does not exist; ``hint`` says what does."""

    def __init__(
        self, message: str, hint: str | None = None, about: Literal["type", "field"] = "field"
    ) -> None:
        super().__init__(message)
        self.hint = hint
        self.about = about


@dataclass(frozen=True)
class FieldStep:
    """One step of a resolved field path: an attribute name, then zero or more indexes."""

    name: str
    indexes: tuple[int, ...]


_REGISTER = threading.Lock()
# ROS 2 Jazzy's standard definitions as rosbags' store for Jazzy holds them, written out
# (write_snapshot): read in a millisecond, where the store takes 120 ms to build (it makes
# a class per type), a quarter of a short check's startup. Used only with the rosbags
# release it was written from (test_msgtypes.py keeps it equal to that store).
SNAPSHOT = Path(__file__).with_name("jazzy_types.json")
_store: Any = None  # rosbags' store, made when a message is first decoded whole
_known: dict[str, Any] | None = None  # fielddefs()


def _rosbags_release() -> str | None:
    """The installed rosbags' version, from its dist-info directory's name (importlib's
    metadata costs 60 ms to import)."""
    import importlib.util

    spec = importlib.util.find_spec("rosbags")
    if spec is None or not spec.submodule_search_locations:
        return None
    site = Path(next(iter(spec.submodule_search_locations))).parent
    with os.scandir(site) as entries:
        for entry in entries:
            name = entry.name
            if name.startswith("rosbags-") and name.endswith(".dist-info"):
                return name[len("rosbags-") : -len(".dist-info")]
    return None


def _tuples(value: Any) -> Any:
    return tuple(map(_tuples, value)) if isinstance(value, list) else value


def _snapshot() -> dict[str, Any] | None:
    """The snapshot's definitions, if it was written from the installed rosbags."""
    with contextlib.suppress(OSError, ValueError, KeyError, TypeError):
        snapshot = json.loads(SNAPSHOT.read_text(encoding="utf-8"))
        if snapshot["rosbags"] == _rosbags_release():
            return {name: _tuples(d) for name, d in snapshot["types"].items()}
    return None


def fielddefs() -> dict[str, Any]:
    """Every type known: name -> (constants, fields) in rosbags' form (node kinds as
    ints). The standard Jazzy definitions, then the types registered as found (a bag's
    own definitions, .msg files: :func:`ensure_type`, :func:`register_definition`)."""
    global _known
    if _known is None:
        loaded = _snapshot()
        if loaded is None:  # another rosbags release: its own definitions
            loaded = dict(typestore().fielddefs)
        with _REGISTER:
            if _known is None:
                _known = loaded
    return _known


_standard_packages: frozenset[str] | None = None


def standard_packages() -> frozenset[str]:
    """The message packages of ROS 2 Jazzy itself (``std_msgs``, ``nav_msgs``, ...), as
    the installed rosbags knows them: never built from a robot's own definitions."""
    global _standard_packages
    if _standard_packages is None:
        types = _snapshot()
        if types is None:  # another rosbags release: its own definitions
            from rosbags.typesys import Stores, get_typestore

            types = get_typestore(Stores.ROS2_JAZZY).fielddefs
        _standard_packages = frozenset(name.split("/", 1)[0] for name in types)
    return _standard_packages


def typestore() -> Any:
    """rosbags' type store for ROS 2 Jazzy, with every type registered here since: what
    decodes a message whole (a bag's messages in a merged check, a CDR reader's fallback)."""
    global _store
    if _store is None:
        from rosbags.typesys import Stores, get_typestore

        store = get_typestore(Stores.ROS2_JAZZY)
        with _REGISTER:
            if _store is None:
                if _known is not None:
                    extra = {k: v for k, v in _known.items() if k not in store.fielddefs}
                    if extra:
                        store.register(extra)
                _store = store
    return _store


def _register(known: dict[str, Any], types: dict[str, Any]) -> None:
    """Make ``types`` known (those not known already); the caller holds _REGISTER."""
    new = {
        k: (v if len(v[1]) else (v[0], [_EMPTY_MEMBER]))  # CDR gives an empty message a byte
        for k, v in types.items()
        if k not in known
    }
    known.update(new)
    if _store is not None and new:
        _store.register(new)


def write_snapshot(path: Path = SNAPSHOT) -> None:
    """Write the standard Jazzy definitions of the installed rosbags to ``path``
    (`python -c "from edgerv.core.msgtypes import write_snapshot; write_snapshot()"`)."""
    from rosbags.typesys import Stores, get_typestore

    types = get_typestore(Stores.ROS2_JAZZY).fielddefs
    text = json.dumps({"rosbags": _rosbags_release(), "types": types}, sort_keys=True)
    path.write_text(text + "\n", encoding="utf-8")


def definition_dirs() -> list[Path]:
    """Where .msg and .srv files are looked for: each directory of ``$EDGERV_MSG_PATH``,
    then ``share/`` of each ROS install prefix (``$AMENT_PREFIX_PATH``, this environment)."""
    dirs = [Path(d) for d in os.environ.get("EDGERV_MSG_PATH", "").split(os.pathsep) if d]
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    dirs += [Path(p) / "share" for p in [*prefixes, sys.prefix]]
    return dirs


def _find_definition(msg_type: str) -> Path | None:
    """The .msg file of ``pkg/msg/Type``, or the .srv file of ``pkg/srv/Name``."""
    pkg, kind, name = msg_type.split("/")
    suffix = ".srv" if kind == "srv" else ".msg"
    for d in definition_dirs():
        for candidate in (d / pkg / kind / f"{name}{suffix}", d / kind / f"{name}{suffix}"):
            if candidate.is_file() and (candidate.parent.parent.name == pkg or d.name == pkg):
                return candidate
    return None


def service_of(msg_type: str) -> str | None:
    """``pkg/srv/Name`` for one of the types it makes (``pkg/srv/Name_Event``,
    ``_Request``, ``_Response``; normalized), else None."""
    pkg, kind, name = msg_type.split("/")
    if kind != "srv":
        return None
    for part in SERVICE_PARTS:
        if name.endswith(part) and len(name) > len(part):
            return f"{pkg}/srv/{name[: -len(part)]}"
    return None


def _split_service(text: str) -> tuple[str, str]:
    """A .srv text's request and response parts, on each side of its ``---`` line."""
    lines = text.split("\n")
    for i, line in enumerate(lines):
        if line.strip() == "---":
            return "\n".join(lines[:i]) + "\n", "\n".join(lines[i + 1 :]) + "\n"
    raise ValueError("no '---' line between the request and the response")


def service_types(service: str, text: str) -> dict[str, Any]:
    """The types a service's .srv ``text`` makes (``service``: ``pkg/srv/Name``):
    ``pkg/srv/Name_Request`` and ``_Response``, each part of the text as a .msg (type names
    without a package are the service package's messages), and ``pkg/srv/Name_Event``, as
    rosidl makes it for service introspection. Raises on a text that is not a .srv."""
    from rosbags.typesys import get_types_from_msg

    pkg, _, name = service.split("/")
    types: dict[str, Any] = {}
    for part, body in zip(("Request", "Response"), _split_service(text), strict=True):
        parsed = f"{pkg}/msg/{name}_{part}"  # (rosbags names no srv/ type)
        types[f"{service}_{part}"] = get_types_from_msg(body, parsed)[parsed]
    types[f"{service}_Event"] = (
        [],
        [
            ("info", (2, _EVENT_INFO)),
            ("request", (4, ((2, f"{service}_Request"), 1))),
            ("response", (4, ((2, f"{service}_Response"), 1))),
        ],
    )
    return types


def _dependencies(types: dict[str, Any]) -> list[str]:
    """The message types the fields of ``types`` name (normalized)."""
    out = []
    for _, fields in types.values():
        for _, node in fields:
            while int(node[0]) in (3, 4):  # arrays and sequences: their element type
                node = node[1][0]
            if int(node[0]) == 2:
                out.append(normalize_type(str(node[1])))
    return out


def ensure_type(msg_type: str) -> bool:
    """Make ``msg_type`` (normalized) known, reading its .msg file if need be (a service's
    request, response or event type: the service's .srv file, :func:`service_types`).

    Returns False when no definition is found. Types it refers to are resolved too.
    """
    known = fielddefs()
    if msg_type in known:
        return True
    from rosbags.typesys import get_types_from_msg

    with _REGISTER:
        pending, found = [msg_type], {}
        while pending:
            name = pending.pop()
            if name in known or name in found:
                continue
            service = service_of(name)
            path = _find_definition(service or name)
            builtin = STD_SRVS.get(service or "")
            if path is None and builtin is None:
                return False
            try:
                text = path.read_text(encoding="utf-8") if path is not None else str(builtin)
                if service is not None:
                    types = service_types(service, text)
                else:
                    types = {name: get_types_from_msg(text, name)[name]}
                pending += _dependencies(types)
            except Exception as exc:  # rosbags reports bad .msg syntax with several types
                raise FieldError(f"cannot read {path}: {exc}", about="type") from None
            found.update(types)
        _register(known, found)
    return True


def register_definition(msg_type: str, encoding: str, text: str) -> bool:
    """Make known the types that a bag's own definition of ``msg_type`` describes (an
    MCAP schema, a row of rosbag2's ``message_definitions``: ``ros2msg`` text with its
    dependencies after ``MSG:`` lines, or ``ros2idl``; a service's, as rosbag2 writes
    it for a service event topic: an ``SRV:`` section, whatever the encoding it names),
    those not known already: the built-in definitions come first; a ``.msg`` or ``.srv``
    file found later (:func:`ensure_type`) does not replace one registered here, which is
    what the bag's bytes were written with. False when the text cannot be read (empty, an
    encoding not known): the type stays unknown unless installed."""
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    try:
        if text.startswith(f"{SEPARATOR}SRV: "):
            types = _service_definition(text)
        elif encoding == "ros2msg":
            types = _srv_names(dict(get_types_from_msg(text, normalize_type(msg_type))))
        elif encoding == "ros2idl":
            sep = SEPARATOR
            parts = text.split(sep)[1:] if text.startswith(f"{sep}IDL: ") else [f"\n{text}"]
            types = {}
            for part in parts:
                types.update(get_types_from_idl(part.split("\n", 1)[1]))
        else:
            return False
    except Exception:  # rosbags reports what it cannot parse with several types
        return False
    known = fielddefs()
    with _REGISTER:
        _register(known, types)
    return True


def _service_definition(text: str) -> dict[str, Any]:
    """The types of a service definition as rosbag2 (Jazzy) writes it for a service event
    topic (rosbag2_cpp's LocalMessageDefinitionSource): sections after a line of 80 ``=``,
    the first ``SRV: pkg/srv/Name`` and the .srv text, then each type it depends on,
    ``MSG: pkg/Type`` and its .msg text or ``IDL: pkg/msg/Type`` and its IDL (a type found
    only as IDL has an empty ``MSG:`` section before its ``IDL:`` one)."""
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    types: dict[str, Any] = {}
    service: tuple[str, str] | None = None
    msgs: list[tuple[str, str]] = []
    for section in text.split(SEPARATOR)[1:]:
        head, _, body = section.partition("\n")
        kind, _, name = head.partition(": ")
        if kind == "SRV" and service is None:
            pkg, _, rest = name.strip().partition("/")
            service = (f"{pkg}/srv/{rest.rpartition('/')[2]}", body)
        elif kind == "MSG":
            msgs.append((normalize_type(name.strip()), body))
        elif kind == "IDL":
            types.update(get_types_from_idl(body))
        else:
            raise ValueError(f"a section '{head}' in a service definition")
    assert service is not None
    for name, body in msgs:
        if name not in types:  # (an empty MSG: section before the IDL: one of its type)
            types[name] = get_types_from_msg(body, name)[name]
    types.update(service_types(*service))
    return types


def _srv_names(types: dict[str, Any]) -> dict[str, Any]:
    """Types rosbags parsed from a definition that names service types (``pkg/srv/X``,
    which rosbags makes ``pkg/srv/msg/X``), with their names as ROS gives them: a
    service's request, response and event ``pkg/srv/X``, any other ``pkg/msg/X``."""

    def name(old: str) -> str:
        pkg, srv, msg, rest = [*old.split("/"), "", ""][:4]
        if (srv, msg) != ("srv", "msg") or not rest:
            return old
        return f"{pkg}/srv/{rest}" if rest.endswith(SERVICE_PARTS) else f"{pkg}/msg/{rest}"

    def node(n: Any) -> Any:
        kind = int(n[0])
        if kind == 2:
            return (n[0], name(str(n[1])))
        if kind in (3, 4):
            return (n[0], (node(n[1][0]), n[1][1]))
        return n

    if not any("/srv/msg/" in k for k in types):
        return types
    return {
        name(k): (consts, [(f, node(n)) for f, n in fields])
        for k, (consts, fields) in types.items()
    }


def starts_with_header(msg_type: str) -> bool:
    """``msg_type``'s first field is a ``std_msgs/msg/Header`` named ``header`` (so a CDR
    payload starts with its stamp: int32 sec, uint32 nanosec). False for a type not known."""
    try:
        name = normalize_type(msg_type)
        if not ensure_type(name):
            return False
    except FieldError:
        return False
    fields = fielddefs()[name][1]
    return bool(fields) and fields[0][0] == "header" and fields[0][1][1] == "std_msgs/msg/Header"


def known_types() -> list[str]:
    return sorted(fielddefs())


def normalize_type(msg_type: str) -> str:
    """``std_msgs/Bool`` and ``std_msgs/msg/Bool`` both name ``std_msgs/msg/Bool``; a
    service's event, request and response types are ``pkg/srv/Name_Event`` (``_Request``,
    ``_Response``)."""
    m = _TYPE.match(msg_type.strip())
    if not m:
        raise FieldError(
            f"'{msg_type}' is not a message type name",
            "write it as package/msg/Type, e.g. std_msgs/msg/Float64",
            about="type",
        )
    pkg, kind, name = m.groups()
    if kind != "srv":
        return f"{pkg}/msg/{name}"
    if not name.endswith(SERVICE_PARTS) or name in SERVICE_PARTS:
        raise FieldError(
            f"'{msg_type}' names a service, not a message type",
            f"a service's events (its topic /<service>/_service_event) are of the type "
            f"{pkg}/srv/{name}_Event",
            about="type",
        )
    return f"{pkg}/srv/{name}"


def parse_field_path(path: str) -> tuple[FieldStep, ...]:
    steps = []
    for part in path.split("."):
        m = _PART.match(part)
        if not m:
            raise FieldError(
                f"'{path}' is not a field path",
                "use dotted names with [i] for array elements, e.g. pose.position.x or ranges[0]",
            )
        indexes = tuple(int(i) for i in re.findall(r"\[(\d+)\]", m.group(2)))
        steps.append(FieldStep(m.group(1), indexes))
    return tuple(steps)


def require_type(msg_type: str) -> str:
    """``msg_type`` normalized, when its definition is known or found; raises
    :class:`FieldError` saying where a definition could come from."""
    known = fielddefs()
    current = normalize_type(msg_type)
    if not ensure_type(current):
        import difflib

        close = difflib.get_close_matches(current, known, n=2, cutoff=0.7)
        pkg = current.split("/", 1)[0]
        set_to = os.environ.get("EDGERV_MSG_PATH")
        own = (
            f"a package of your own: export EDGERV_MSG_PATH=DIR, DIR holding {pkg}/msg/ (a "
            "colcon workspace's src/)"
            + (
                f"; $EDGERV_MSG_PATH is {set_to}, without {pkg}/msg/"
                if set_to
                else " ($EDGERV_MSG_PATH is not set)"
            )
        )
        service = service_of(current)
        if service is not None:
            pkg, _, name = service.split("/")
            own = (
                f"a service: its definition comes from the bag, else from {pkg}/srv/{name}.srv "
                "under share/ of a ROS install prefix or under a directory of $EDGERV_MSG_PATH"
            )
        hint = (
            ("did you mean " + " or ".join(close) + "? Or, for " + own)
            if close
            else ("edgerv knows the standard ROS 2 Jazzy message packages; for " + own)
        )
        raise FieldError(f"unknown message type '{msg_type}'", hint, about="type")
    return current


def field_kind(msg_type: str, path: str) -> ValueKind:
    """The kind of value at ``path`` in ``msg_type``; raises :class:`FieldError`."""
    known = fielddefs()
    current = require_type(msg_type)
    node: tuple[Any, Any] = (2, current)  # (Nodetype.NAME, name)
    walked: list[str] = []
    steps = parse_field_path(path)
    for at, step in enumerate(steps):
        kind_code, payload = int(node[0]), node[1]
        if _optional(node):
            rest = ".".join(_spelled(s) for s in steps[at:])
            raise FieldError(
                f"field '{_spelled_path(steps[:at])}' of {msg_type} is an optional, "
                f"so it has no field '{step.name}'",
                f"{_spelled_path(steps[:at])} is an optional (a sequence of at most 1): "
                f"write {_spelled_path(steps[:at])}[0].{rest}",
            )
        if kind_code != 2:
            raise FieldError(
                f"field '{'.'.join(walked)}' of {msg_type} is not a message, "
                f"so it has no field '{step.name}'"
            )
        if payload not in known and not ensure_type(payload):
            raise FieldError(f"unknown message type '{payload}' (at '{'.'.join(walked)}')")
        fields = dict(known[payload][1])
        if step.name not in fields:
            raise FieldError(
                f"{payload} has no field '{step.name}'"
                + (f" (at '{'.'.join(walked)}')" if walked else ""),
                "its fields: " + ", ".join(fields),
            )
        node = fields[step.name]
        walked.append(step.name)
        for index in step.indexes:
            if int(node[0]) not in (3, 4):  # ARRAY, SEQUENCE
                raise FieldError(f"field '{'.'.join(walked)}' of {msg_type} is not an array")
            if _optional(node) and index:
                spelled = _spelled_path(steps[:at]) + ("." if at else "") + step.name
                raise FieldError(
                    f"field '{spelled}' of {msg_type} is an optional: it has no element [{index}]",
                    f"{spelled} is an optional (a sequence of at most 1): its element is "
                    f"{spelled}[0]",
                )
            node = node[1][0]
    kind_code, payload = int(node[0]), node[1]
    if _optional(node):
        element = node[1][0]
        example = f"{path}[0]"
        if int(element[0]) == 2 and known[element[1]][1]:
            example += "." + known[element[1]][1][0][0]
        raise FieldError(
            f"field '{path}' of {msg_type} is an optional (a sequence of at most 1), not a value",
            f"read it through its element, e.g. {example}",
        )
    if kind_code in (3, 4):
        raise FieldError(
            f"field '{path}' of {msg_type} is an array",
            f"pick one element, e.g. {path}[0]",
        )
    if kind_code == 2:
        sub = ", ".join(name for name, _ in known[payload][1])
        raise FieldError(
            f"field '{path}' of {msg_type} is a {payload} message, not a value",
            f"pick one of its fields: {sub}",
        )
    base = payload[0]
    if base not in _BASE_KINDS:
        raise FieldError(f"field '{path}' of {msg_type} has unsupported type {base}")
    return _BASE_KINDS[base]


def _optional(node: tuple[Any, Any]) -> bool:
    """A sequence of at most one element (``T[<=1]``): ROS's idiom for an optional."""
    return int(node[0]) == 4 and int(node[1][1]) == 1


def _spelled(step: FieldStep) -> str:
    return step.name + "".join(f"[{i}]" for i in step.indexes)


def _spelled_path(steps: tuple[FieldStep, ...]) -> str:
    return ".".join(map(_spelled, steps))


def path_keys(path: str) -> tuple[str | int, ...]:
    """A field path as the keys that read it: names and indexes, in order."""
    keys: list[str | int] = []
    for step in parse_field_path(path):
        keys += [step.name, *step.indexes]
    return tuple(keys)


def optional_steps(msg_type: str, path: str) -> frozenset[int]:
    """The positions in :func:`path_keys` of the indexes into an optional (a sequence of at
    most one element) along ``path`` of ``msg_type``: a message whose optional is empty
    there has no value at ``path`` (:data:`ABSENT`). Empty for an ordinary path, and for
    a type or path not known."""
    try:
        keys = path_keys(path)
        name = normalize_type(msg_type)
        if not ensure_type(name):
            return frozenset()
    except FieldError:
        return frozenset()
    known = fielddefs()
    node: Any = (2, name)
    out = []
    for at, key in enumerate(keys):
        kind = int(node[0])
        if isinstance(key, str):
            fields = dict(known[node[1]][1]) if kind == 2 and node[1] in known else {}
            if key not in fields:
                return frozenset()
            node = fields[key]
        elif kind in (3, 4):
            if _optional(node):
                out.append(at)
            node = node[1][0]
        else:
            return frozenset()
    return frozenset(out)


def make_getter(path: str, optional: frozenset[int] = frozenset()) -> Any:
    """A function reading ``path`` from a message given as nested dicts/lists or objects;
    :data:`ABSENT` where an index of ``optional`` (:func:`optional_steps`) goes into an
    empty sequence."""
    steps = parse_field_path(path)
    if optional:
        return _optional_getter(path_keys(path), optional)

    def get(msg: Any) -> Any:
        value = msg
        for step in steps:
            value = value[step.name] if isinstance(value, dict) else getattr(value, step.name)
            for i in step.indexes:
                value = value[i]
        # elements of arrays deserialized by rosbags are numpy scalars: make them Python values
        return value.item() if hasattr(value, "item") else value

    return get


def _optional_getter(keys: tuple[str | int, ...], optional: frozenset[int]) -> Any:
    def get(msg: Any) -> Any:
        value = msg
        for at, key in enumerate(keys):
            if isinstance(key, str):
                value = value[key] if isinstance(value, dict) else getattr(value, key)
            elif at in optional and not len(value):
                return ABSENT
            else:
                value = value[key]
        return value.item() if hasattr(value, "item") else value

    return get
