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
from typing import Any, Literal

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
_TYPE = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)/(?:msg/)?([A-Za-z_][A-Za-z0-9_]*)$")


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
    new = {k: v for k, v in types.items() if k not in known}
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


def _definition_dirs() -> list[Path]:
    dirs = [Path(d) for d in os.environ.get("EDGERV_MSG_PATH", "").split(os.pathsep) if d]
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    dirs += [Path(p) / "share" for p in [*prefixes, sys.prefix]]
    return dirs


def _find_definition(msg_type: str) -> Path | None:
    pkg, _, name = msg_type.split("/")
    for d in _definition_dirs():
        for candidate in (d / pkg / "msg" / f"{name}.msg", d / "msg" / f"{name}.msg"):
            if candidate.is_file() and (candidate.parent.parent.name == pkg or d.name == pkg):
                return candidate
    return None


def ensure_type(msg_type: str) -> bool:
    """Make ``msg_type`` (normalized) known, reading its .msg file if need be.

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
            path = _find_definition(name)
            if path is None:
                return False
            try:
                types = get_types_from_msg(path.read_text(encoding="utf-8"), name)
            except Exception as exc:  # rosbags reports bad .msg syntax with several types
                raise FieldError(f"cannot read {path}: {exc}", about="type") from None
            found.update(types)
            fields: list[tuple[str, Any]] = list(types[name][1])
            for _, node in fields:
                while int(node[0]) in (3, 4):  # arrays and sequences: their element type
                    node = node[1][0]
                if int(node[0]) == 2:
                    pending.append(normalize_type(str(node[1])))
        _register(known, found)
    return True


def register_definition(msg_type: str, encoding: str, text: str) -> bool:
    """Make known the types that a bag's own definition of ``msg_type`` describes (an
    MCAP schema, a row of rosbag2's ``message_definitions``: ``ros2msg`` text with its
    dependencies after ``MSG:`` lines, or ``ros2idl``), those not known already: the
    built-in definitions come first; a ``.msg`` file found later (:func:`ensure_type`)
    does not replace one registered here, which is what the bag's bytes were written
    with. False when the text cannot be read (a service event's, an encoding not known):
    the type stays unknown unless installed."""
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    try:
        if encoding == "ros2msg":
            types = dict(get_types_from_msg(text, normalize_type(msg_type)))
        elif encoding == "ros2idl":
            sep = "=" * 80 + "\n"
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
    """``std_msgs/Bool`` and ``std_msgs/msg/Bool`` both name ``std_msgs/msg/Bool``."""
    m = _TYPE.match(msg_type.strip())
    if not m:
        raise FieldError(
            f"'{msg_type}' is not a message type name",
            "write it as package/msg/Type, e.g. std_msgs/msg/Float64",
            about="type",
        )
    return f"{m.group(1)}/msg/{m.group(2)}"


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


def field_kind(msg_type: str, path: str) -> ValueKind:
    """The kind of value at ``path`` in ``msg_type``; raises :class:`FieldError`."""
    known = fielddefs()
    current = normalize_type(msg_type)
    if not ensure_type(current):
        import difflib

        close = difflib.get_close_matches(current, known, n=2, cutoff=0.7)
        own = "a package of your own: put its msg/ directory under a directory of $EDGERV_MSG_PATH"
        hint = (
            ("did you mean " + " or ".join(close) + "? Or, for " + own)
            if close
            else ("edgerv knows the standard ROS 2 Jazzy message packages; for " + own)
        )
        raise FieldError(f"unknown message type '{msg_type}'", hint, about="type")
    node: tuple[Any, Any] = (2, current)  # (Nodetype.NAME, name)
    walked: list[str] = []
    for step in parse_field_path(path):
        kind_code, payload = int(node[0]), node[1]
        if kind_code != 2:
            raise FieldError(
                f"field '{'.'.join(walked)}' of {msg_type} is not a message, "
                f"so it has no field '{step.name}'"
            )
        fields = dict(known[payload][1])
        if step.name not in fields:
            raise FieldError(
                f"{payload} has no field '{step.name}'"
                + (f" (at '{'.'.join(walked)}')" if walked else ""),
                "its fields: " + ", ".join(fields),
            )
        node = fields[step.name]
        walked.append(step.name)
        for _ in step.indexes:
            if int(node[0]) not in (3, 4):  # ARRAY, SEQUENCE
                raise FieldError(f"field '{'.'.join(walked)}' of {msg_type} is not an array")
            node = node[1][0]
    kind_code, payload = int(node[0]), node[1]
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


def make_getter(path: str) -> Any:
    """A function reading ``path`` from a message given as nested dicts/lists or objects."""
    steps = parse_field_path(path)

    def get(msg: Any) -> Any:
        value = msg
        for step in steps:
            value = value[step.name] if isinstance(value, dict) else getattr(value, step.name)
            for i in step.indexes:
                value = value[i]
        # elements of arrays deserialized by rosbags are numpy scalars: make them Python values
        return value.item() if hasattr(value, "item") else value

    return get
