"""Reading a few fields straight out of a serialized (CDR) ROS 2 message.

The live handler takes messages raw, as the bytes the publisher sent, and
needs only the fields its signals name. Decoding a whole ``nav_msgs/Odometry``
costs about 25 µs with rosbags and 110 µs with rclpy; skipping to
``twist.twist.linear.x`` costs about a microsecond. For each message type and
set of field paths this module generates a small straight-line Python function
from the type's definition (rosbags' type store): it walks the CDR encoding
(XCDR1, the ROS 2 default), aligning each primitive to its size relative to
the start of the payload, skipping strings and sequences by their length
prefix, and unpacks just the wanted values. Big-endian payloads and types it
cannot walk (wstring) fall back to full deserialization. A field inside an empty
optional (a sequence of at most one element, ``T[<=1]``, read as ``request[0].a``) is
:data:`~edgerv.core.msgtypes.ABSENT`; an index beyond any other sequence is an error.

Any bytes can arrive on a topic: a reader returns values or raises one of
:data:`MALFORMED`, quickly. A length (a string's, a sequence's count) that runs
past the end of the payload is refused as soon as it is read, so that a hostile
count cannot make a reader step through billions of elements that are not there
(tests/unit/test_hostile_properties.py, tests/fuzz/fuzz_cdr.py).
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypeVar

from edgerv.core.msgtypes import (
    ABSENT,
    fielddefs,
    make_getter,
    normalize_type,
    optional_steps,
    parse_field_path,
    starts_with_header,
    typestore,
)

# (struct format, size) of each primitive; alignment equals size in XCDR1. A scalar `byte`
# reads as signed and a `byte` array element as unsigned, exactly as rosbags decodes them,
# so that a live handler and `edgerv check` on a bag see the same values.
_PRIMITIVES: dict[str, tuple[str, int]] = {
    "bool": ("?", 1),
    "byte": ("b", 1),
    "char": ("B", 1),
    "octet": ("B", 1),
    "int8": ("b", 1),
    "uint8": ("B", 1),
    "int16": ("h", 2),
    "uint16": ("H", 2),
    "int32": ("i", 4),
    "uint32": ("I", 4),
    "int64": ("q", 8),
    "uint64": ("Q", 8),
    "float32": ("f", 4),
    "float64": ("d", 8),
}
_NAME, _BASE, _ARRAY, _SEQUENCE = 2, 1, 3, 4

Reader = Callable[[bytes], tuple[list[Any], int | None]]

# What a reader raises for bytes that are not a message of its type (truncated, a length
# running past the end, bad UTF-8, a sequence too short for a wanted index): the handler's
# take loop counts the message as malformed and goes on (tests/unit/test_hostile_properties.py).
MALFORMED: tuple[type[Exception], ...] = (ValueError, IndexError, struct.error)


class _Unsupported(Exception):
    pass


class _Gen:
    """Generates the body of a reader function; ``p`` is the offset in the payload."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.fmts: dict[str, str] = {}  # struct format -> name of its unpack_from
        self.skippers: dict[str, str] = {}  # message type -> name of its skip function
        self.helpers: list[str] = []

    def unpack(self, fmt: str) -> str:
        if fmt not in self.fmts:
            self.fmts[fmt] = f"_u{len(self.fmts)}"
        return self.fmts[fmt]

    def emit(self, line: str, indent: int) -> None:
        self.lines.append("    " * indent + line)

    def fits(self, elem: tuple[Any, Any], indent: int, out: list[str]) -> None:
        """After a sequence's count ``n``: refuse a count its elements cannot fit in what is
        left of the payload (at least ``min_size`` bytes each). A hostile count (2^32 - 1)
        must not make a reader step through billions of elements that are not there."""
        out.append(
            "    " * indent
            + f"if n * {min_size(elem)} > len(b) - 4 - p: raise ValueError(_LONG % (n, p))"
        )

    def align(self, size: int, indent: int, lines: list[str] | None = None) -> None:
        if size > 1:
            (lines if lines is not None else self.lines).append(
                "    " * indent + f"p = (p + {size - 1}) & {-size}"
            )

    # -- skipping a value without reading it ------------------------------------------------

    def skip(self, node: tuple[Any, Any], indent: int, out: list[str]) -> None:
        kind, payload = int(node[0]), node[1]
        pad = "    " * indent
        if kind == _BASE:
            base = payload[0]
            if base == "string":
                self.align(4, indent, out)
                out.append(pad + f"p += 4 + {self.unpack('<I')}(b, 4 + p)[0]")
            elif base in _PRIMITIVES:
                size = _PRIMITIVES[base][1]
                self.align(size, indent, out)
                out.append(pad + f"p += {size}")
            else:
                raise _Unsupported(base)
        elif kind == _NAME:
            out.append(pad + f"p = {self.skipper(payload)}(b, p)")
        elif kind in (_ARRAY, _SEQUENCE):
            elem, count = payload
            if kind == _SEQUENCE:
                self.align(4, indent, out)
                out.append(pad + f"n = {self.unpack('<I')}(b, 4 + p)[0]")
                out.append(pad + "p += 4")
                self.fits(elem, indent, out)
            else:
                out.append(pad + f"n = {count}")
            ekind, epay = int(elem[0]), elem[1]
            if ekind == _BASE and epay[0] in _PRIMITIVES:
                size = _PRIMITIVES[epay[0]][1]
                out.append(pad + "if n:")
                self.align(size, indent + 1, out)
                out.append(pad + f"    p += n * {size}")
            else:
                out.append(pad + "for _ in range(n):")
                self.skip(elem, indent + 1, out)
        else:
            raise _Unsupported(str(node))

    def skipper(self, msg_type: str) -> str:
        if msg_type not in self.skippers:
            name = f"_skip{len(self.skippers)}"
            self.skippers[msg_type] = name
            body: list[str] = [f"def {name}(b, p):"]
            for _, node in fielddefs()[msg_type][1]:
                self.skip(node, 1, body)
            body.append("    return p")
            self.helpers.append("\n".join(body))
        return self.skippers[msg_type]

    # -- walking to the wanted fields -------------------------------------------------------

    def walk(
        self,
        msg_type: str,
        wanted: dict[tuple[Any, ...], int],
        prefix: tuple[Any, ...],
        indent: int,
        top: bool = False,
    ) -> None:
        """Emit code reading every wanted path under ``prefix`` of a ``msg_type`` value.

        ``wanted`` maps a path (tuple of field names and indexes) to its output slot. A
        nested message is walked to its end (what follows it starts there); the top-level
        one only up to its last wanted field.
        """
        for node, under, here in fields_to_walk(msg_type, wanted, prefix, top):
            if under:
                self.value(node, under, here, indent)
            else:
                self.skip(node, indent, self.lines)

    def value(
        self,
        node: tuple[Any, Any],
        wanted: dict[tuple[Any, ...], int],
        here: tuple[Any, ...],
        indent: int,
    ) -> None:
        kind, payload = int(node[0]), node[1]
        if kind == _BASE:
            base = payload[0]
            if base == "string":
                self.align(4, indent)
                self.emit(f"n = {self.unpack('<I')}(b, 4 + p)[0]", indent)
                # (the n bytes end with a NUL; a string running past the end is refused)
                self.emit("if n > len(b) - 8 - p: raise ValueError(_LONG % (n, p))", indent)
                for slot in (s for p, s in wanted.items() if p == here):
                    self.emit(f"out[{slot}] = b[8 + p : 7 + p + n].decode()", indent)
                self.emit("p += 4 + n", indent)
                return
            if base not in _PRIMITIVES:
                raise _Unsupported(base)
            fmt, size = _PRIMITIVES[base]
            self.align(size, indent)
            for slot in (s for p, s in wanted.items() if p == here):
                self.emit(f"out[{slot}] = {self.unpack('<' + fmt)}(b, 4 + p)[0]", indent)
            self.emit(f"p += {size}", indent)
        elif kind == _NAME:
            self.walk(payload, wanted, here, indent)
        elif kind in (_ARRAY, _SEQUENCE):
            # elements are chosen by index: walk element by element up to the highest wanted
            elem, count = payload
            indexes = {p[len(here)] for p in wanted}
            if kind == _SEQUENCE:
                self.align(4, indent)
                self.emit(f"n = {self.unpack('<I')}(b, 4 + p)[0]", indent)
                self.emit("p += 4", indent)
                self.fits(elem, indent, self.lines)
            else:
                self.emit(f"n = {count}", indent)
            if kind == _SEQUENCE and count == 1 and indexes == {0}:  # an optional: when
                self.emit("if not n:", indent)  # empty, nothing under it has a value
                for slot in sorted(set(wanted.values())):
                    self.emit(f"out[{slot}] = _ABSENT", indent + 1)
                self.emit("else:", indent)
                indent += 1
            else:  # a sequence too short for a wanted index fails like a getter would
                self.emit(f"if n <= {max(indexes)}: raise IndexError({max(indexes)})", indent)
            ekind, epay = int(elem[0]), elem[1]
            if ekind == _BASE and epay[0] in _PRIMITIVES:  # fixed size: read by offset
                fmt, size = _PRIMITIVES[epay[0]]
                fmt = "B" if epay[0] == "byte" else fmt
                self.align(size, indent)
                for (*_, index), slot in wanted.items():
                    read = self.unpack("<" + fmt)
                    self.emit(f"out[{slot}] = {read}(b, 4 + p + {index * size})[0]", indent)
                self.emit(f"p += n * {size}", indent)
                return
            self.emit("for _i in range(n):", indent)
            for index in sorted(indexes):
                self.emit(f"if _i == {index}:", indent + 1)
                sub = {p: s for p, s in wanted.items() if p[len(here)] == index}
                self.value(elem, sub, (*here, index), indent + 2)
                self.emit("continue", indent + 2)
            self.skip(elem, indent + 1, self.lines)
        else:
            raise _Unsupported(str(node))


Slots = TypeVar("Slots")


def fields_to_walk(
    msg_type: str, wanted: dict[tuple[Any, ...], Slots], prefix: tuple[Any, ...], top: bool
) -> Iterator[tuple[tuple[Any, Any], dict[tuple[Any, ...], Slots], tuple[Any, ...]]]:
    """The fields of a ``msg_type`` value at ``prefix``, in order: each one's type node,
    the ``wanted`` paths under it (none: it is skipped) and its path. A nested message is
    walked to its end (what follows it starts there); the top-level one (``top``) only up
    to its last wanted field."""
    fields = fielddefs()[msg_type][1]
    depth = len(prefix)
    if top:
        needed = {path[depth] for path in wanted if len(path) > depth}
        last = max((i for i, (name, _) in enumerate(fields) if name in needed), default=-1)
        fields = fields[: last + 1]
    for name, node in fields:
        here = (*prefix, name)
        yield node, {p: s for p, s in wanted.items() if p[: depth + 1] == here}, here


@functools.cache
def _message_min_size(msg_type: str) -> int:
    fields: list[tuple[str, Any]] = fielddefs()[msg_type][1]
    return sum(min_size(node) for _, node in fields)


def min_size(node: tuple[Any, Any]) -> int:
    """The fewest bytes a value of this type takes in CDR (alignment aside), at least 1: a
    string or a sequence its length word, a message the sum of its fields."""
    kind, payload = int(node[0]), node[1]
    if kind == _BASE:
        return _PRIMITIVES[payload[0]][1] if payload[0] in _PRIMITIVES else 4
    if kind == _NAME:
        return max(1, _message_min_size(payload))
    if kind == _ARRAY:
        return max(1, int(payload[1]) * min_size(payload[0]))
    return 4  # a sequence: its count


_LONG = "a length of %d at offset %d runs past the end of the message"


def _paths(paths: Sequence[str]) -> list[tuple[Any, ...]]:
    out = []
    for path in paths:
        flat: list[Any] = []
        for step in parse_field_path(path):
            flat.append(step.name)
            flat += list(step.indexes)
        out.append(tuple(flat))
    return out


def compile_reader(msg_type: str, paths: Sequence[str]) -> Reader:
    """A function: CDR bytes -> (the values at ``paths``, header stamp in ns or None).

    The stamp is None without a header and 0 for a header nobody stamped.
    """
    msg_type = normalize_type(msg_type)
    header = starts_with_header(msg_type)
    try:
        gen = _Gen()
        wanted = {p: i for i, p in enumerate(_paths(paths))}
        gen.walk(msg_type, wanted, (), 1, top=True)
        stamp = (
            f"{gen.unpack('<i')}(b, 4)[0] * 1000000000 + {gen.unpack('<I')}(b, 8)[0]"
            if header
            else "None"
        )
        source = "\n".join(
            [
                *gen.helpers,
                "def read(b):",
                "    if b[1] != 1:",
                "        return _fallback(b)",
                f"    out = [None] * {len(paths)}",
                "    p = 0",
                *gen.lines,
                f"    return out, {stamp}",
            ]
        )
    except _Unsupported:
        return _fallback_reader(msg_type, paths, header)
    namespace: dict[str, Any] = {f: struct.Struct(fmt).unpack_from for fmt, f in gen.fmts.items()}
    namespace["_fallback"] = _fallback_reader(msg_type, paths, header)
    namespace["_LONG"] = _LONG
    namespace["_ABSENT"] = ABSENT
    exec(compile(source, f"<cdr reader {msg_type}>", "exec"), namespace)
    reader: Reader = namespace["read"]
    return reader


def _fallback_reader(msg_type: str, paths: Sequence[str], header: bool) -> Reader:
    getters = [make_getter(p, optional_steps(msg_type, p)) for p in paths]

    def read(b: bytes) -> tuple[list[Any], int | None]:
        try:  # (rosbags' store is made at its first use: most readers never need it)
            msg = typestore().deserialize_cdr(b, msg_type)
        except Exception as exc:  # rosbags' SerdeError and what it wraps: one of MALFORMED
            raise ValueError(f"not a {msg_type}: {exc}") from None
        values = [g(msg) for g in getters]
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec if header else None
        return values, stamp

    return read


_STAMP_LE, _STAMP_BE = struct.Struct("<iI"), struct.Struct(">iI")


def header_stamp_ns(data: bytes) -> int:
    """The ``header.stamp`` (ns) of a CDR payload whose type starts with a
    ``std_msgs/msg/Header`` (:func:`~edgerv.core.msgtypes.starts_with_header`): after the
    4-byte encapsulation header, int32 sec and uint32 nanosec, little-endian when the
    encapsulation's second byte is odd (CDR_LE, PL_CDR_LE), else big-endian.
    Raises ValueError when the payload is too short."""
    if len(data) < 12:
        raise ValueError(f"a stamped message is at least 12 bytes, not {len(data)}")
    sec, nanosec = (_STAMP_LE if data[1] & 1 else _STAMP_BE).unpack_from(data, 4)
    return int(sec) * 1_000_000_000 + int(nanosec)
