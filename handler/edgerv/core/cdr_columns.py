"""Reading a few fields of many serialized (CDR) ROS 2 messages at once, into NumPy columns.

``edgerv check`` on a large bag reads the same few fields of millions of messages. The
per-message reader of :mod:`edgerv.core.cdr` costs about a microsecond a message, nearly
all of it Python; this module's reader walks the same encoding (XCDR1, little-endian, each
primitive aligned to its size relative to the payload, strings and sequences skipped by
their length prefix) for a whole batch of messages at once, a NumPy operation a step.

The walk is planned when the reader is compiled. The offset into each payload is a part
common to every message, a Python int known from the type alone, plus, once a string or a
sequence has been passed, a per-message int64 array; what is known of that array's
alignment decides, when compiling, whether aligning the offset is integer arithmetic or an
operation on the array. What remains for a batch is a few operations per string, sequence
and wanted value: a ``nav_msgs/Odometry`` costs about as much as the two strings in its
header. Bytes at any offset are gathered by one fancy index into an overlapping view of the
buffer (a dtype of their size with a stride of 1 byte), values within 32 bytes of each other
at once (a header's encapsulation, stamp and frame_id length: one gather), then widened to
bool, int64 (every signed kind and unsigned up to 32 bits), uint64 or float64, so that
``.tolist()`` of a column gives exactly the values the per-message reader gives (a scalar
``byte`` signed, an element of a ``byte`` array unsigned, float32 widened exactly).

A batch is read only if every message in it is: when one is not plain little-endian CDR
(the per-message reader deserializes those in full), or would make the per-message reader
raise (a read running past its end, a count its payload cannot hold, a wanted index beyond
a sequence's count), the reader returns None and the caller reads that batch a message at
a time, which finds the one at fault. Each read is checked against every message's length
before its gather, and gathered offsets are clipped to the buffer besides: no bytes make a
reader raise or read outside a message. A hostile length (2^32 - 1) costs what any other
does: a count is refused as it is read, a string's length at the next read past it.

A value inside an optional (a sequence of at most one element, ``T[<=1]``: a service
event's ``request[0].a``) is read column-wise too: the optional's element is walked as if
every message had one, where what each step checks and moves counts only for the messages
whose optional holds it (a mask), and after it each message goes on from where its own
walk is (past the element, or past the count of an empty optional). Its column holds
Python objects: the values, and :data:`~edgerv.core.msgtypes.ABSENT` where the optional is
empty, as the per-message reader gives them. A count above 1 refuses the batch (the
per-message reader reads the first element).

:func:`compile_column_reader` returns None for paths it cannot read column-wise: a wanted
string (not a fixed-size column), a wanted value inside an array or sequence of messages
(but an optional's), an optional inside an optional (but one of fixed size),
a path that names no primitive, and anything after a skipped array or sequence whose
elements vary in size (strings, sequences) or a wstring. Skipped arrays and sequences of
fixed-size messages are read exactly: where an element ends depends only on where it
starts modulo its largest alignment, and from the second element on it moves a multiple of
that alignment.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from edgerv.core.cdr import (
    _ARRAY,
    _BASE,
    _NAME,
    _PRIMITIVES,
    _SEQUENCE,
    _paths,
    fields_to_walk,
    min_size,
)
from edgerv.core.msgtypes import (
    ABSENT,
    FieldError,
    ensure_type,
    fielddefs,
    normalize_type,
    starts_with_header,
)

Int64s = npt.NDArray[np.int64]


class Columns(NamedTuple):
    """A batch's values: one array per path, of one value per message, and the header
    stamps in ns (0 for a header nobody stamped), None for a type without a header."""

    values: list[npt.NDArray[Any]]
    stamps: npt.NDArray[np.int64] | None


ColumnReader = Callable[[npt.NDArray[np.uint8], Int64s, Int64s], "Columns | None"]

# struct format (cdr._PRIMITIVES) -> the dtype its bytes are gathered as; the column's dtype
_GATHER: dict[str, np.dtype[Any]] = {
    f: np.dtype(d)
    for f, d in {
        "?": "u1",
        "b": "i1",
        "B": "u1",
        "h": "<i2",
        "H": "<u2",
        "i": "<i4",
        "I": "<u4",
        "q": "<i8",
        "Q": "<u8",
        "f": "<f4",
        "d": "<f8",
    }.items()
}
_COLUMN: dict[str, type[np.generic]] = {
    "?": np.bool_,
    "Q": np.uint64,
    "f": np.float64,
    "d": np.float64,
}
_SPAN = 32  # values this close are gathered together
_ANY = 1 << 62  # the alignment of an offset known to be 0
_MAX_WALKED = 1 << 16  # elements of fixed arrays of messages walked when compiling


class _Unsupported(Exception):
    pass


_Key = tuple[int, int, str]  # a value read: the plan's version of arr, offset, struct format


class _Batch:
    """The messages being read; the offset into each payload is ``arr`` (None: 0) plus a
    part common to every message, which the operations know from the plan."""

    def __init__(self, buf: npt.NDArray[np.uint8], starts: Int64s, ends: Int64s) -> None:
        self.buf = buf
        self.start4 = starts + 4  # where each payload starts in buf
        self.plen = ends - self.start4  # each payload's length (< 0: no encapsulation)
        self.values: list[npt.NDArray[Any]] = []
        self.fields: dict[_Key, npt.NDArray[Any]] = {}  # as gathered
        self.count: Int64s = self.plen  # the count of the sequence last read
        self.arr: Int64s | None = None
        self._base: Int64s | None = self.start4  # start4 + arr
        self._room: Int64s | None = self.plen  # plen - arr
        self._room_min: int | None = None
        self._views: dict[np.dtype[Any], npt.NDArray[Any]] = {}
        # inside an optional: the messages whose optional holds its element, and the
        # offset (its full value) each message goes on from when it does not
        self.mask: npt.NDArray[np.bool_] | None = None
        self.start: Int64s | int = 0
        self.masks: list[npt.NDArray[np.bool_]] = []  # each optional's, in order

    def set(self, arr: Int64s) -> None:
        self.arr = arr
        self._base = self._room = self._room_min = None

    def add(self, var: Int64s) -> None:
        self.set(var if self.arr is None else self.arr + var)

    def full(self, const: int) -> Int64s | int:
        return const if self.arr is None else self.arr + const

    def room(self) -> Int64s:
        """What is left of each payload after ``arr``."""
        if self._room is None:
            assert self.arr is not None
            self._room = self.plen - self.arr
        return self._room

    def room_min(self) -> int:
        if self._room_min is None:
            self._room_min = int(self.room().min())
        return self._room_min

    def gather(self, dtype: np.dtype[Any], offset: int) -> npt.NDArray[Any]:
        """The ``dtype`` at ``arr + offset`` of every payload (the caller has checked that
        it lies within the message)."""
        size = dtype.itemsize
        view = self._views.get(dtype)
        if view is None:  # overlapping, unaligned: element i starts at byte i
            n = max(len(self.buf) - size + 1, 0)
            view = self._views[dtype] = np.ndarray((n,), dtype, buffer=self.buf, strides=(1,))
        if self._base is None:
            assert self.arr is not None
            self._base = self.start4 + self.arr
        pos = self._base + offset  # >= 0: starts and arr are, offset >= -3
        np.minimum(pos, len(self.buf) - size, out=pos)
        values: npt.NDArray[Any] = view[pos]
        return values

    def ints(self, key: _Key) -> Int64s:
        return self.fields[key].astype(np.int64)


# -- what a reader does to a batch: each returns False to refuse it ---------------------------

_Op = Callable[[_Batch], bool]


class _Fits:
    """Every payload has ``need`` bytes past ``arr``: raised, as it is compiled, to what the
    reads of this ``arr`` need (a read past a message's end refuses the batch wherever it
    is checked, as the batch is read whole or not at all)."""

    def __init__(self) -> None:
        self.need = 0

    def __call__(self, batch: _Batch) -> bool:
        return self.need <= 0 or batch.room_min() >= self.need


class _Gather:
    """The values read at one ``arr``, gathered after its :class:`_Fits`: those within
    ``_SPAN`` bytes of each other by one gather of their bytes together (a header's
    encapsulation, stamp and frame_id's length: one)."""

    def __init__(self, version: int) -> None:
        self.version = version
        self.wanted: set[tuple[int, str]] = set()
        # (offset, dtype, the bytes' dtype or None, [(key, field of the record or None)])
        self.groups: list[
            tuple[int, np.dtype[Any], np.dtype[Any] | None, list[tuple[_Key, str | None]]]
        ] = []

    def add(self, offset: int, fmt: str) -> _Key:
        self.wanted.add((offset, fmt))
        return (self.version, offset, fmt)

    def finish(self) -> None:
        runs: list[list[tuple[int, str]]] = []
        for offset, fmt in sorted(self.wanted):
            if runs and offset + _GATHER[fmt].itemsize - runs[-1][0][0] <= _SPAN:
                runs[-1].append((offset, fmt))
            else:
                runs.append([(offset, fmt)])
        for run in runs:
            start, fmt = run[0]
            if len(run) == 1:
                self.groups.append(
                    (start, _GATHER[fmt], None, [((self.version, start, fmt), None)])
                )
                continue
            names = [f"f{i}" for i in range(len(run))]
            record = np.dtype(
                {
                    "names": names,
                    "formats": [_GATHER[f] for _, f in run],
                    "offsets": [o - start for o, _ in run],
                    "itemsize": max(o + _GATHER[f].itemsize for o, f in run) - start,
                }
            )
            keys: list[tuple[_Key, str | None]] = [
                ((self.version, o, f), name) for (o, f), name in zip(run, names, strict=True)
            ]
            self.groups.append((start, record, np.dtype(f"V{record.itemsize}"), keys))

    def __call__(self, batch: _Batch) -> bool:
        for start, dtype, raw, keys in self.groups:
            if raw is None:
                batch.fields[keys[0][0]] = batch.gather(dtype, start)
            else:  # the bytes, then a record view of them (gathering records is slow)
                records = batch.gather(raw, start).view(dtype)
                for key, name in keys:
                    batch.fields[key] = records[name]
        return True


class _MaskedFits(_Fits):
    """:class:`_Fits` inside an optional: the payloads whose optional holds its element."""

    def __call__(self, batch: _Batch) -> bool:
        if self.need <= 0:
            return True
        assert batch.mask is not None
        room = batch.room()[batch.mask]
        return not len(room) or int(room.min()) >= self.need


class _MaskedGather(_Gather):
    """:class:`_Gather` inside an optional: where no message holds its element, what is
    gathered is never read (nor can the buffer hold it: zeros)."""

    def __call__(self, batch: _Batch) -> bool:
        assert batch.mask is not None
        if batch.mask.any():
            return super().__call__(batch)
        n = len(batch.plen)
        for _, dtype, _, keys in self.groups:
            for key, name in keys:
                batch.fields[key] = np.zeros(n, dtype if name is None else dtype[name])
        return True


def _masked(values: Int64s, batch: _Batch) -> Int64s:
    """``values`` where a message's optional holds its element, else 0."""
    assert batch.mask is not None
    return np.where(batch.mask, values, 0)


def _little_endian(key: _Key) -> _Op:
    """Every encapsulation is CDR_LE (0x0001; the per-message reader deserializes the
    others in full)."""
    return lambda batch: not bool((batch.fields[key] != 1).any())


def _read(key: _Key, slots: list[int]) -> _Op:
    fmt = key[2]
    column = _COLUMN.get(fmt, np.int64)

    def op(batch: _Batch) -> bool:
        raw = batch.fields[key]
        # struct's "?" is True for any byte but 0
        value = raw != 0 if fmt == "?" else np.ascontiguousarray(raw, dtype=column)
        for slot in slots:
            batch.values[slot] = value
        return True

    return op


def _string(key: _Key) -> _Op:
    """Past a string whose length is ``key``."""

    def op(batch: _Batch) -> bool:
        batch.add(batch.ints(key))
        return True

    return op


def _masked_string(key: _Key) -> _Op:
    """:func:`_string` inside an optional."""

    def op(batch: _Batch) -> bool:
        batch.add(_masked(batch.ints(key), batch))
        return True

    return op


def _align(const: int, size: int) -> _Op:
    def op(batch: _Batch) -> bool:
        assert batch.arr is not None
        batch.set((batch.arr + (const + size - 1)) & -size)
        return True

    return op


def _count(key: _Key, elem_min: int) -> _Op:
    """A sequence's count ``key``, refused when its elements (``elem_min`` bytes at least
    each) cannot fit in what is left of a payload, as cdr.py's ``fits``."""
    after = key[1] + 4

    def op(batch: _Batch) -> bool:
        n = batch.ints(key)
        left = batch.room() - after
        too_many = n * elem_min > left if elem_min < 1 << 30 else n > left // elem_min
        if too_many.any():
            return False
        batch.count = n
        return True

    return op


def _masked_count(key: _Key, elem_min: int) -> _Op:
    """:func:`_count` inside an optional: 0 where the optional is empty."""
    after = key[1] + 4

    def op(batch: _Batch) -> bool:
        n = _masked(batch.ints(key), batch)
        left = batch.room() - after
        too_many = n * elem_min > left if elem_min < 1 << 30 else n > left // elem_min
        if (too_many & (n > 0)).any():
            return False
        batch.count = n
        return True

    return op


def _at_least(count: int) -> _Op:
    return lambda batch: bool(batch.count.min() >= count)


def _masked_at_least(count: int) -> _Op:
    def op(batch: _Batch) -> bool:
        assert batch.mask is not None
        held = batch.count[batch.mask]
        return not len(held) or bool(held.min() >= count)

    return op


def _enter_optional(const: int) -> _Op:
    """Into an optional whose count was just read: the messages that hold its element
    (a count above 1 refuses the batch), and where the others go on from."""

    def op(batch: _Batch) -> bool:
        n = batch.count
        if bool((n > 1).any()):
            return False
        batch.mask = n == 1
        batch.start = batch.full(const)
        return True

    return op


def _leave_optional(const: int) -> _Op:
    """Past an optional: each message from where its own walk is."""

    def op(batch: _Batch) -> bool:
        mask = batch.mask
        assert mask is not None
        batch.set(np.where(mask, batch.full(const), batch.start) - const)
        batch.masks.append(mask)
        batch.mask = None
        return True

    return op


def _add_count(size: int) -> _Op:
    """Past ``count`` elements of ``size`` bytes, the offset aligned to it already."""

    def op(batch: _Batch) -> bool:
        batch.add(batch.count * size if size > 1 else batch.count)
        return True

    return op


def _skip_primitives(const: int, size: int) -> _Op:
    """Past ``count`` primitives of ``size``, aligned to it only when there are any."""

    def op(batch: _Batch) -> bool:
        n = batch.count
        full = batch.full(const)
        aligned = (full + (size - 1)) & -size
        batch.set(np.where(n > 0, aligned + n * size, full) - const)
        return True

    return op


def _skip_messages(const: int, modulo: int, first: list[int], then: list[int]) -> _Op:
    """Past ``count`` fixed-size messages, the first of which, from ``p % modulo == r``,
    takes ``first[r]`` bytes, and every next ``then[r]``."""
    first_np, then_np = np.array(first, np.int64), np.array(then, np.int64)

    def op(batch: _Batch) -> bool:
        n = batch.count
        full = batch.full(const)
        r = full & (modulo - 1)
        head, each = (first[r], then[r]) if isinstance(r, int) else (first_np[r], then_np[r])
        batch.set(np.where(n > 0, full + head - each + n * each, full) - const)
        return True

    return op


def _skip_fixed(const: int, modulo: int, moved: list[int]) -> _Op:
    """Past a value of fixed layout that takes ``moved[p % modulo]`` bytes from ``p``."""
    moved_np = np.array(moved, np.int64)

    def op(batch: _Batch) -> bool:
        assert batch.arr is not None
        full = batch.arr + const
        batch.set(full + moved_np[full & (modulo - 1)] - const)
        return True

    return op


# -- values of fixed layout: how far skipping one moves the offset ------------------------------


def _fixed(node: tuple[Any, Any]) -> bool:
    kind, payload = int(node[0]), node[1]
    if kind == _BASE:
        return bool(payload[0] in _PRIMITIVES)
    if kind == _NAME:
        return _fixed_message(payload)
    return kind == _ARRAY and _fixed(payload[0])


@functools.cache
def _fixed_message(msg_type: str) -> bool:
    return all(_fixed(node) for _, node in fielddefs()[msg_type][1])


def _largest(node: tuple[Any, Any]) -> int:
    """The largest alignment inside a value of fixed layout."""
    kind, payload = int(node[0]), node[1]
    if kind == _BASE:
        return _PRIMITIVES[payload[0]][1]
    if kind == _NAME:
        return max((_largest(n) for _, n in fielddefs()[payload][1]), default=1)
    return _largest(payload[0])


def _walk_fixed(node: tuple[Any, Any], p: int, budget: list[int]) -> int:
    """Where skipping a value of fixed layout from ``p`` ends, as cdr.py's ``skip``."""
    kind, payload = int(node[0]), node[1]
    if kind == _BASE:
        size = _PRIMITIVES[payload[0]][1]
        return ((p + size - 1) & -size) + size
    if kind == _NAME:
        for _, field in fielddefs()[payload][1]:
            p = _walk_fixed(field, p, budget)
        return p
    elem, count = payload
    if int(elem[0]) == _BASE:
        size = _PRIMITIVES[elem[1][0]][1]
        return ((p + size - 1) & -size) + count * size if count else p
    budget[0] -= count
    if budget[0] < 0:
        raise _Unsupported("too many elements to walk")
    for _ in range(count):
        p = _walk_fixed(elem, p, budget)
    return p


def _moves(node: tuple[Any, Any]) -> tuple[int, list[int]]:
    """The largest alignment in a value of fixed layout, and how many bytes skipping it
    moves from each offset modulo that."""
    modulo = _largest(node)
    budget = [_MAX_WALKED]
    return modulo, [_walk_fixed(node, r, budget) - r for r in range(modulo)]


# -- compiling: cdr.py's _Gen, with the offset's common part worked out -----------------------


class _Plan:
    """The operations reading a batch; ``const`` is the offset's common part, ``var`` whether
    it has a per-message part (``arr``), a multiple of ``var_align``."""

    def __init__(self) -> None:
        self.ops: list[_Op] = []
        self.formats: dict[int, str] = {}  # slot -> struct format of its column
        self.const = 0
        self.var = False
        self.var_align = _ANY
        self.version = 0  # of arr, counted as it changes
        self.gathers: list[_Gather] = []
        self.check: _Fits | None = None  # of this version's reads
        self.gather: _Gather | None = None
        self.masked = False  # walking an optional's element
        self.optionals: dict[int, int] = {}  # slot -> the optional it is read inside
        self.left = 0  # optionals walked
        # (the encapsulation's second byte, 3 bytes before the payload, is checked first)
        self.ops.append(_little_endian(self.field(-3, "B")))
        self.first, self.start = self.check, self.gather  # at the payload's start

    def changed(self, align: int) -> None:
        """``arr`` is new: a multiple of ``align``."""
        self.var_align = min(self.var_align, align) if self.var else align
        self.var = True
        self.new_version()

    def new_version(self) -> None:
        self.version += 1
        self.check = self.gather = None

    def field(self, offset: int, fmt: str) -> _Key:
        """A value read at ``arr + offset``."""
        if self.check is None or self.gather is None:
            if self.masked:
                self.check, self.gather = _MaskedFits(), _MaskedGather(self.version)
            else:
                self.check, self.gather = _Fits(), _Gather(self.version)
            self.ops += [self.check, self.gather]
            self.gathers.append(self.gather)
        self.check.need = max(self.check.need, offset + _GATHER[fmt].itemsize)
        return self.gather.add(offset, fmt)

    def known_align(self) -> int:
        """What is known of the alignment of every message's offset."""
        align = self.var_align if self.var else _ANY
        return min(align, self.const & -self.const) if self.const else align

    def align(self, size: int) -> None:
        if size <= 1:
            return
        if not self.var or size <= self.var_align:
            self.const = (self.const + size - 1) & -size
        else:
            self.ops.append(_align(self.const, size))
            self.const = 0
            self.var_align = size
            self.new_version()

    def count(self, elem: tuple[Any, Any]) -> None:
        self.align(4)
        counted = _masked_count if self.masked else _count
        self.ops.append(counted(self.field(self.const, "I"), min_size(elem)))
        self.const += 4

    def skip(self, node: tuple[Any, Any]) -> None:
        kind, payload = int(node[0]), node[1]
        if kind == _BASE:
            base = payload[0]
            if base == "string":
                self.align(4)
                passed = _masked_string if self.masked else _string
                self.ops.append(passed(self.field(self.const, "I")))
                self.const += 4
                self.changed(1)
            elif base in _PRIMITIVES:
                size = _PRIMITIVES[base][1]
                self.align(size)
                self.const += size
            else:
                raise _Unsupported(base)
        elif kind == _NAME:
            for _, field in fielddefs()[payload][1]:
                self.skip(field)
        elif kind in (_ARRAY, _SEQUENCE):
            elem, count = payload
            primitive = int(elem[0]) == _BASE and elem[1][0] in _PRIMITIVES
            if not primitive and not _fixed(elem) and kind == _SEQUENCE and count == 1:
                self.optional(elem, {}, ())  # an optional: walked where it holds its element
                return
            if not primitive and not _fixed(elem):
                raise _Unsupported(f"elements of varying size: {elem}")
            if kind == _ARRAY and primitive:
                if count:
                    size = _PRIMITIVES[elem[1][0]][1]
                    self.align(size)
                    self.const += count * size
            elif kind == _ARRAY:
                modulo, moved = _moves(node)
                if not self.var or self.var_align >= modulo:
                    self.const += moved[self.const & (modulo - 1)]
                else:
                    self.ops.append(_skip_fixed(self.const, modulo, moved))
                    self.changed(1)
            elif primitive:
                self.count(elem)
                size = _PRIMITIVES[elem[1][0]][1]
                if size == 1 or self.known_align() >= size:  # aligned with or without any
                    self.ops.append(_add_count(size))
                    self.changed(size)
                else:
                    self.ops.append(_skip_primitives(self.const, size))
                    self.changed(min(size, self.known_align()))
            else:
                self.count(elem)
                modulo, first = _moves(elem)
                then = [first[(r + first[r]) % modulo] for r in range(modulo)]
                if any(t % modulo for t in then):  # (each element ends alike: never)
                    raise _Unsupported(f"elements of no period: {elem}")
                self.ops.append(_skip_messages(self.const, modulo, first, then))
                self.changed(1)
        else:
            raise _Unsupported(str(node))

    def walk(
        self,
        msg_type: str,
        wanted: dict[tuple[Any, ...], list[int]],
        prefix: tuple[Any, ...],
        top: bool = False,
    ) -> None:
        for node, under, here in fields_to_walk(msg_type, wanted, prefix, top):
            if under:
                self.value(node, under, here)
            else:
                self.skip(node)

    def value(
        self,
        node: tuple[Any, Any],
        wanted: dict[tuple[Any, ...], list[int]],
        here: tuple[Any, ...],
    ) -> None:
        kind, payload = int(node[0]), node[1]
        if kind == _BASE:
            base = payload[0]
            if base not in _PRIMITIVES or set(wanted) != {here}:
                raise _Unsupported(f"not a column: {base}")
            fmt, size = _PRIMITIVES[base]
            self.align(size)
            self.read(fmt, self.const, wanted[here])
            self.const += size
        elif kind == _NAME:
            if here in wanted:
                raise _Unsupported("a message is not a value")
            self.walk(payload, wanted, here)
        elif kind in (_ARRAY, _SEQUENCE):
            elem, count = payload
            depth = len(here)
            if (
                kind == _SEQUENCE
                and count == 1
                and all(len(p) > depth for p in wanted)
                and {p[depth] for p in wanted} == {0}
            ):  # an optional
                self.optional(elem, wanted, (*here, 0))
                return
            if int(elem[0]) != _BASE or elem[1][0] not in _PRIMITIVES:
                raise _Unsupported(f"a value inside an array of {elem}")
            if any(len(p) != depth + 1 or not isinstance(p[depth], int) for p in wanted):
                raise _Unsupported("an array is not a value")
            highest = max(p[depth] for p in wanted)
            if kind == _SEQUENCE:
                self.count(elem)
                self.ops.append((_masked_at_least if self.masked else _at_least)(highest + 1))
            elif count <= highest:  # every message would raise IndexError
                raise _Unsupported(f"index {highest} of an array of {count}")
            fmt, size = _PRIMITIVES[elem[1][0]]
            fmt = "B" if elem[1][0] == "byte" else fmt
            self.align(size)
            for path, slots in sorted(wanted.items()):
                self.read(fmt, self.const + path[depth] * size, slots)
            if kind == _SEQUENCE:
                self.ops.append(_add_count(size))
                self.changed(size)
            else:
                self.const += count * size
        else:
            raise _Unsupported(str(node))

    def optional(
        self, elem: tuple[Any, Any], wanted: dict[tuple[Any, ...], list[int]], here: tuple[Any, ...]
    ) -> None:
        """An optional's element (``here``: its path), read where the optional holds it
        (none ``wanted``: skipped so)."""
        if self.masked:
            raise _Unsupported("an optional inside an optional")
        self.count(elem)
        self.ops.append(_enter_optional(self.const))
        self.new_version()
        self.masked = True
        before = set(self.formats)
        if wanted:
            self.value(elem, wanted, here)
        else:
            self.skip(elem)
        self.masked = False
        self.ops.append(_leave_optional(self.const))
        self.changed(1)
        for slot in set(self.formats) - before:
            self.optionals[slot] = self.left  # (the mask its _leave_optional keeps)
        self.left += 1

    def read(self, fmt: str, offset: int, slots: list[int]) -> None:
        self.ops.append(_read(self.field(offset, fmt), slots))
        for slot in slots:
            self.formats[slot] = fmt


def compile_column_reader(msg_type: str, paths: Sequence[str]) -> ColumnReader | None:
    """A function: (buf, starts, ends) -> :class:`Columns` of the values at ``paths`` of
    the messages ``buf[starts[i]:ends[i]]`` (each from its 4-byte encapsulation header on),
    or None when one of them must be read alone (:func:`edgerv.core.cdr.compile_reader`,
    which raises at a malformed one); None also for offsets outside ``buf``.

    None instead of a function when the paths cannot be read column-wise (module doc).
    """
    try:
        msg_type = normalize_type(msg_type)
        if not ensure_type(msg_type):
            return None
        header = starts_with_header(msg_type)
        wanted: dict[tuple[Any, ...], list[int]] = {}
        for slot, path in enumerate(_paths(paths)):
            wanted.setdefault(path, []).append(slot)
        plan = _Plan()
        plan.walk(msg_type, wanted, (), top=True)
        if len(plan.formats) != len(paths):  # a path naming no field
            return None
    except (_Unsupported, FieldError, KeyError):
        return None
    stamp: tuple[_Key, _Key] | None = None
    if header:  # int32 sec, uint32 nanosec at the payload's start
        assert plan.first is not None and plan.start is not None
        plan.first.need = max(plan.first.need, 8)
        stamp = (plan.start.add(0, "i"), plan.start.add(4, "I"))
    for gather in plan.gathers:
        gather.finish()
    ops = tuple(plan.ops)
    formats = [plan.formats[slot] for slot in range(len(paths))]
    optionals = tuple(plan.optionals.items())

    def read(buf: npt.NDArray[np.uint8], starts: Int64s, ends: Int64s) -> Columns | None:
        batch = _batch(buf, starts, ends)
        if batch is None:
            return None
        if not len(batch.plen):
            return Columns(
                [
                    np.empty(0, object if s in plan.optionals else _COLUMN.get(f, np.int64))
                    for s, f in enumerate(formats)
                ],
                np.empty(0, np.int64) if header else None,
            )
        batch.values = [batch.plen] * len(formats)
        for op in ops:
            if not op(batch):
                return None
        for slot, optional in optionals:  # Python values, ABSENT where it is empty
            held = batch.values[slot].astype(object)
            held[~batch.masks[optional]] = ABSENT
            batch.values[slot] = held
        if stamp is None:
            return Columns(batch.values, None)
        sec = batch.ints(stamp[0])
        return Columns(batch.values, sec * 1_000_000_000 + batch.fields[stamp[1]])

    return read


def _batch(buf: npt.NDArray[np.uint8], starts: Int64s, ends: Int64s) -> _Batch | None:
    """The messages, or None when one of them is not plain little-endian CDR (or is not
    within ``buf``)."""
    buf = np.ascontiguousarray(buf, dtype=np.uint8).reshape(-1)
    starts = np.asarray(starts, dtype=np.int64)
    ends = np.asarray(ends, dtype=np.int64)
    if starts.ndim != 1 or starts.shape != ends.shape:
        return None
    if len(starts):
        if int(starts.min()) < 0 or int(ends.max()) > len(buf):
            return None
        if int((ends - starts).min()) < 2:  # not even the encapsulation's first 2 bytes
            return None
    return _Batch(buf, starts, ends)
