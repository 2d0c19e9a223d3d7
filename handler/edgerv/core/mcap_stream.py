"""An MCAP file read front to back, as a stream of its messages' bytes.

Only what a check needs, at the speed of a loop over ``struct.unpack_from``: the
Schema and Channel records (handed to the caller as they come, before the
messages that use them, as the MCAP specification orders them) and the Message
records of the channels asked for, in or out of chunks (zstd, lz4 or none). Every
other record is skipped by its length. The summary, indexes and CRCs are not
needed: a file cut short (a recording ended by a crash or a full disk) yields
every message of its whole chunks before the cut, then raises :class:`Cut`.

Record layout: https://mcap.dev/spec (opcode u8, length u64, then the fields,
little-endian; strings and byte arrays prefixed by a u32 length).
"""

from __future__ import annotations

import heapq
import struct
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, BinaryIO, NamedTuple

import numpy as np
import numpy.typing as npt

MAGIC = b"\x89MCAP0\r\n"
_SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _FOOTER, _DATA_END = 0x03, 0x04, 0x05, 0x06, 0x02, 0x0F
_HEAD = struct.Struct("<BQ")  # a record's opcode and length
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_CHUNK_HEAD = struct.Struct("<QQQI")  # start and end times, uncompressed size and CRC
_MESSAGE_HEAD = 2 + 4 + 8 + 8  # channel id, sequence, log time, publish time
_NEVER = 1 << 64  # after any log time (u64)


class Cut(Exception):
    """The file ends, or holds something unreadable, before its footer."""


class Schema(NamedTuple):
    id: int
    name: str
    encoding: str
    data: bytes


class Channel(NamedTuple):
    id: int
    schema_id: int
    topic: str
    message_encoding: str


Wanted = Callable[[Channel], "str | None"]  # a channel's topic to read it under, or None


def messages(
    path: Path,
    wanted: Wanted,
    on_schema: Callable[[Schema], None] = lambda _: None,
    starts: Sequence[int] | None = None,
) -> Iterator[tuple[str, int, bytes]]:
    """(topic, log time, data) of each message on a channel ``wanted`` names, in log-time
    order (ties in file order). Raises :class:`Cut` where the file stops making sense.

    Read front to back, a chunk at a time; MCAP does not keep a file's messages in
    log-time order (a recorder may write one topic's backlog after another's), so they
    wait in a heap until no later chunk can hold an earlier one. ``starts``: each chunk's
    first log time, in file order (the summary's chunk indexes): a message is let go
    once every chunk after it starts later. Without them (a file cut short) a chunk is
    taken to start no earlier than the one before it."""
    reading: dict[int, str | None] = {}  # channel id -> its topic, None: not read
    after = _later(starts) if starts else []  # after[i]: the earliest start of chunks >= i
    waiting: list[tuple[int, int, str, bytes]] = []  # (log time, order, topic, data)
    try:
        with path.open("rb") as f:
            yield from _ordered(f, path.stat().st_size, reading, wanted, on_schema, after, waiting)
    except Cut:  # what was read before the damage, in order, then the damage
        yield from _drain(waiting)
        raise
    yield from _drain(waiting)


def _drain(waiting: list[tuple[int, int, str, bytes]]) -> Iterator[tuple[str, int, bytes]]:
    while waiting:
        log_time, _, topic, data = heapq.heappop(waiting)
        yield topic, log_time, data


def _ordered(
    f: BinaryIO,
    size: int,
    reading: dict[int, str | None],
    wanted: Wanted,
    on_schema: Callable[[Schema], None],
    after: list[int],
    waiting: list[tuple[int, int, str, bytes]],
) -> Iterator[tuple[str, int, bytes]]:
    """The loop of :func:`messages`: leaves in ``waiting`` what it has not let go."""
    order = chunk = 0
    if f.read(len(MAGIC)) != MAGIC:
        raise Cut("it does not start as an MCAP file")
    while True:
        head, op, length = _next_record(f, size)
        if op == _CHUNK:
            start, records = _open_chunk(f.read(length))
            bound = after[chunk] if chunk < len(after) else start
            chunk += 1
        elif op in (_SCHEMA, _CHANNEL, _MESSAGE):
            records = head + f.read(length)
            message = op == _MESSAGE and length >= _MESSAGE_HEAD  # (a short one: Cut below)
            bound = _U64.unpack_from(records, 9 + 6)[0] if message else -1
        elif op in (_FOOTER, _DATA_END):  # the summary follows: no message in it
            break
        else:
            f.seek(length, 1)
            continue
        while waiting and waiting[0][0] < bound:  # no later record holds one earlier
            log_time, _, topic, data = heapq.heappop(waiting)
            yield topic, log_time, data
        got = list(_records(records, reading, wanted, on_schema))
        if not got:
            continue
        times = [log_time for _, log_time, _ in got]
        if (  # the usual file: nothing waits, in order, and later chunks start later
            op == _CHUNK
            and after
            and not waiting
            and times[-1] < (after[chunk] if chunk < len(after) else _NEVER)
            and times == sorted(times)
        ):
            yield from got
            continue
        for (topic, log_time, data), i in zip(got, range(order, order + len(got)), strict=True):
            heapq.heappush(waiting, (log_time, i, topic, data))
        order += len(got)


def _next_record(f: BinaryIO, size: int) -> tuple[bytes, int, int]:
    """The next record's header (its bytes, opcode and length), its body whole in the file."""
    head = f.read(_HEAD.size)
    if len(head) < _HEAD.size:
        raise Cut(f"it ends at byte {size}, before its footer")
    op, length = _HEAD.unpack(head)
    if f.tell() + length > size:
        raise Cut(f"a record of {length} bytes at byte {f.tell() - 9} runs past its end")
    return head, op, length


def _later(starts: Sequence[int]) -> list[int]:
    """For each chunk, the earliest first log time of it and the chunks after it."""
    out = list(starts)
    for i in range(len(out) - 2, -1, -1):
        out[i] = min(out[i], out[i + 1])
    return out


def _open_chunk(body: bytes) -> tuple[int, bytes]:
    """A Chunk record's first log time and its records, decompressed."""
    try:
        start, _end, size, _crc = _CHUNK_HEAD.unpack_from(body, 0)
        at = _CHUNK_HEAD.size
        (n,) = _U32.unpack_from(body, at)
        compression = body[at + 4 : at + 4 + n].decode()
        at += 4 + n
        (n,) = _U64.unpack_from(body, at)
        data = body[at + 8 : at + 8 + n]
        if len(data) < n:
            raise Cut("a chunk is cut short")
    except (struct.error, UnicodeDecodeError) as exc:
        raise Cut(f"a chunk's header is unreadable ({exc})") from None
    if compression == "":
        return start, data
    try:
        if compression == "zstd":
            import zstandard

            return start, zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        if compression == "lz4":
            import lz4.frame  # type: ignore[import-untyped]

            return start, bytes(lz4.frame.decompress(data))
    except Exception as exc:  # each library has its own errors
        raise Cut(f"a {compression} chunk cannot be decompressed ({exc})") from None
    raise Cut(f"a chunk is compressed with '{compression}', which MCAP does not define")


def _string(buf: bytes, at: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(buf, at)
    end = at + 4 + n
    if end > len(buf):
        raise Cut("a string runs past its record")
    return buf[at + 4 : end].decode(), end


def _records(
    buf: bytes,
    reading: dict[int, str | None],
    wanted: Wanted,
    on_schema: Callable[[Schema], None],
) -> Iterator[tuple[str, int, bytes]]:
    """The messages read among ``buf``'s records (a chunk's, or one record alone)."""
    pos, end = 0, len(buf)
    head, u16, u64 = _HEAD.unpack_from, _U16.unpack_from, _U64.unpack_from
    get = reading.get
    while pos < end:
        try:
            op, length = head(buf, pos)
        except struct.error:
            raise Cut("a record's header is cut short") from None
        body, pos = pos + 9, pos + 9 + length
        if pos > end:
            raise Cut(f"a record of {length} bytes runs past its chunk")
        if op == _MESSAGE:
            if length < _MESSAGE_HEAD:
                raise Cut("a message record is shorter than its header")
            topic = get(u16(buf, body)[0])
            if topic is not None:
                yield topic, u64(buf, body + 6)[0], buf[body + _MESSAGE_HEAD : pos]
        elif op == _CHANNEL:
            try:
                (cid,) = u16(buf, body)
                (sid,) = u16(buf, body + 2)
                topic_name, at = _string(buf, body + 4)
                encoding, _ = _string(buf, at)
            except (struct.error, UnicodeDecodeError) as exc:
                raise Cut(f"a channel record is unreadable ({exc})") from None
            reading[cid] = wanted(Channel(cid, sid, topic_name, encoding))
        elif op == _SCHEMA:
            try:
                (sid,) = u16(buf, body)
                name, at = _string(buf, body + 2)
                encoding, at = _string(buf, at)
                (n,) = _U32.unpack_from(buf, at)
                data = buf[at + 4 : at + 4 + n]
            except (struct.error, UnicodeDecodeError) as exc:
                raise Cut(f"a schema record is unreadable ({exc})") from None
            on_schema(Schema(sid, name, encoding, data))


def channels(path: Path) -> tuple[dict[int, Channel], dict[int, Schema], int | None]:
    """A file's channels and schemas, and its last message's log time, read through up to
    its end or its damage (for a file whose summary cannot be read)."""
    found: dict[int, Channel] = {}
    schemas: dict[int, Schema] = {}
    last: list[int] = []

    def note(channel: Channel) -> str:
        found[channel.id] = channel
        return ""

    try:
        for _, log_time, _ in messages(path, note, lambda s: schemas.__setitem__(s.id, s)):
            if not last or log_time > last[0]:
                last[:] = [log_time]
    except Cut:
        pass
    return found, schemas, last[0] if last else None


_STATISTICS, _CHUNK_INDEX = 0x0B, 0x08
_FOOTER_SIZE = 9 + 8 + 8 + 4  # opcode, length, summary start, summary offset start, CRC
_STATS = struct.Struct("<QHIIIIQQ")  # counts, then the first and last message's log time


class Summary(NamedTuple):
    channels: dict[int, Channel]
    schemas: dict[int, Schema]
    counts: dict[int, int] | None  # messages per channel id (the Statistics record)
    end: int | None  # the last message's log time
    starts: list[int] | None  # each chunk's first log time, in file order (chunk indexes)


def summary(path: Path) -> Summary | None:
    """The file's summary section (channels, schemas, statistics), read from its footer;
    None when it has none or its end is not a footer (a file cut short)."""
    size = path.stat().st_size
    if size < len(MAGIC) * 2 + _FOOTER_SIZE:
        return None
    with path.open("rb") as f:
        f.seek(size - len(MAGIC) - _FOOTER_SIZE)
        tail = f.read()
        if tail[-len(MAGIC) :] != MAGIC or tail[0] != _FOOTER:
            return None
        (start,) = _U64.unpack_from(tail, 9)
        if start == 0 or start >= size:
            return None
        f.seek(start)
        buf = f.read(size - len(MAGIC) - _FOOTER_SIZE - start)
    chans: dict[int, Channel] = {}
    schemas: dict[int, Schema] = {}
    stats: list[tuple[dict[int, int], int | None]] = []
    chunks: list[tuple[int, int]] = []  # (offset, first log time)

    def note(channel: Channel) -> None:
        chans[channel.id] = channel

    try:
        for _ in _records(buf, {}, note, lambda s: schemas.__setitem__(s.id, s)):
            pass
        pos = 0
        while pos < len(buf):  # the Statistics record, which _records skips
            op, length = _HEAD.unpack_from(buf, pos)
            if op == _STATISTICS:
                body = pos + 9
                fields = _STATS.unpack_from(buf, body)
                at = body + _STATS.size
                (n,) = _U32.unpack_from(buf, at)
                counts = {
                    _U16.unpack_from(buf, i)[0]: _U64.unpack_from(buf, i + 2)[0]
                    for i in range(at + 4, at + 4 + n, 10)
                }
                stats.append((counts, fields[7] if fields[0] else None))
            elif op == _CHUNK_INDEX:  # its first log time, and where the chunk is
                body = pos + 9
                chunks.append((_U64.unpack_from(buf, body + 16)[0], _U64.unpack_from(buf, body)[0]))
            pos += 9 + length
    except (Cut, struct.error):
        return None
    starts = [start for _, start in sorted(chunks)] or None
    if not stats:
        return Summary(chans, schemas, None, None, starts)
    return Summary(chans, schemas, stats[0][0], stats[0][1], starts)


# -- column-wise: a chunk's messages as arrays ------------------------------------------------

_MESSAGE_INDEX = 0x07
BATCH_MESSAGES = 65_536  # messages gathered before a batch is handed on


class Batch(NamedTuple):
    """Messages in log-time order (ties in file order), as arrays: message i is
    ``buffer[start[i]:end[i]]`` (its CDR bytes) on channel ``channel[i]``, logged at
    ``log_time[i]`` (u64, as the file holds it)."""

    buffer: npt.NDArray[np.uint8]  # the chunks the messages are in, one after the other
    channel: npt.NDArray[np.int64]
    log_time: npt.NDArray[np.uint64]
    start: npt.NDArray[np.int64]
    end: npt.NDArray[np.int64]

    def __len__(self) -> int:
        return len(self.start)


def batches(
    path: Path,
    wanted: Wanted,
    starts: Sequence[int] | None = None,
    size: int = BATCH_MESSAGES,
) -> Iterator[tuple[Batch, dict[int, str]]]:
    """:func:`messages` as arrays: the same messages in the same order, a batch of about
    ``size`` at a time, with the topics of the channels read. No object is made per
    message: a chunk's message records are found from its message indexes (the records
    an MCAP writer puts after each chunk, with each message's offset in it) when they
    cover every channel read, else by a walk over its records; their fields are taken
    with NumPy. Raises :class:`Cut` after the messages read before the damage."""
    reading: dict[int, str | None] = {}
    order = _Order(_later(starts) if starts else [], size)
    try:
        with path.open("rb") as f:
            yield from _chunk_columns(f, path.stat().st_size, reading, wanted, order)
    except Cut:
        yield from order.drain(reading)
        raise
    yield from order.drain(reading)


class _Order:
    """What :func:`_ordered` does with its heap, an array at a time: messages wait until
    no later record can hold an earlier one, then leave sorted by (log time, file order)."""

    def __init__(self, after: list[int], size: int) -> None:
        self.after = after
        self.size = size
        self.chunk = 0
        self.buffers: dict[int, npt.NDArray[np.uint8]] = {}
        self.next_buffer = 0
        self.waiting: list[_Columns] = []  # not let go yet (in arrival order)
        self.ready: list[_Columns] = []  # let go, in order, not handed on yet
        self.ready_buffers: set[int] = set()  # the chunks they are in
        self.ready_count = 0

    def add(
        self, buf: npt.NDArray[np.uint8], cols: _Columns | None, bound: int, chunk: bool
    ) -> None:
        """A record's messages (``cols``, buffer ids still 0) after letting go those logged
        before ``bound``."""
        self._release(bound)
        if cols is None or not len(cols[0]):
            return
        ident = self.next_buffer
        self.next_buffer += 1
        self.buffers[ident] = buf
        cols = (np.full(len(cols[0]), ident, np.int64), *cols[1:])
        times = cols[2]
        limit = self.after[self.chunk] if chunk and self.chunk < len(self.after) else _NEVER
        if (  # the usual file: nothing waits, in order, and later chunks start later
            chunk
            and self.after
            and not self.waiting
            and int(times[-1]) < limit
            and not bool(np.any(times[1:] < times[:-1]))
        ):
            self._hand(cols, {ident})
            return
        self.waiting.append(cols)

    def _release(self, bound: int) -> None:
        if not self.waiting or bound <= 0:
            return
        cols = _sorted(_concat(self.waiting))
        times = cols[2]
        cut = int(np.searchsorted(times, np.uint64(min(bound, _NEVER - 1)), side="left"))
        if cut == 0:
            self.waiting = [cols]
            return
        self._hand(tuple(c[:cut] for c in cols))  # type: ignore[arg-type]
        rest = tuple(c[cut:] for c in cols)
        self.waiting = [rest] if len(rest[0]) else []  # type: ignore[list-item]

    def _hand(self, cols: _Columns, buffers: set[int] | None = None) -> None:
        self.ready.append(cols)
        self.ready_buffers |= set(np.unique(cols[0]).tolist()) if buffers is None else buffers
        self.ready_count += len(cols[0])

    def full(self) -> bool:
        return self.ready_count >= self.size

    def take(self, reading: dict[int, str | None]) -> tuple[Batch, dict[int, str]]:
        """The messages let go so far, their chunks' bytes joined in one buffer."""
        cols = _concat(self.ready)
        used = sorted(self.ready_buffers)
        self.ready, self.ready_buffers, self.ready_count = [], set(), 0
        base = np.zeros(used[-1] + 1, np.int64)  # where each chunk starts in the buffer
        at = 0
        for i in used:
            base[i] = at
            at += len(self.buffers[i])
        buffer = (
            self.buffers[used[0]]
            if len(used) == 1
            else np.concatenate([self.buffers[i] for i in used])
        )
        held = set(np.unique(_concat(self.waiting)[0]).tolist()) if self.waiting else set()
        for i in used:
            if i not in held:
                del self.buffers[i]
        shift = base[cols[0]]
        batch = Batch(buffer, cols[1], cols[2], cols[3] + shift, cols[4] + shift)
        return batch, {c: t for c, t in reading.items() if t is not None}

    def drain(self, reading: dict[int, str | None]) -> Iterator[tuple[Batch, dict[int, str]]]:
        if self.waiting:
            self._hand(_sorted(_concat(self.waiting)))
            self.waiting = []
        if self.ready_count:
            yield self.take(reading)


# buffer id, channel id, log time, data start, data end: one array each
_Columns = tuple[
    npt.NDArray[np.int64],
    npt.NDArray[np.int64],
    npt.NDArray[np.uint64],
    npt.NDArray[np.int64],
    npt.NDArray[np.int64],
]


def _concat(parts: list[_Columns]) -> _Columns:
    if len(parts) == 1:
        return parts[0]
    return tuple(np.concatenate(c) for c in zip(*parts, strict=True))  # type: ignore[return-value]


def _sorted(cols: _Columns) -> _Columns:
    """Sorted by log time, ties in arrival order (a stable sort)."""
    times = cols[2]
    if not bool(np.any(times[1:] < times[:-1])):
        return cols
    order = np.argsort(times, kind="stable")
    return tuple(c[order] for c in cols)  # type: ignore[return-value]


def _chunk_columns(
    f: BinaryIO,
    size: int,
    reading: dict[int, str | None],
    wanted: Wanted,
    order: _Order,
) -> Iterator[tuple[Batch, dict[int, str]]]:
    """The loop of :func:`batches`, :func:`_ordered`'s twin. A chunk waits for the message
    indexes that follow it before it is read."""
    if f.read(len(MAGIC)) != MAGIC:
        raise Cut("it does not start as an MCAP file")
    pending: tuple[bytes, int] | None = None  # a chunk's records and first log time
    indexes: dict[int, bytes] = {}  # its message indexes: channel id -> (time, offset) pairs

    def settle() -> None:
        nonlocal pending
        if pending is not None:
            records, start = pending
            bound = order.after[order.chunk] if order.chunk < len(order.after) else start
            cols = _chunk_messages(records, reading, wanted, indexes)
            order.chunk += 1
            order.add(np.frombuffer(records, np.uint8), cols, bound, chunk=True)
            pending = None
            indexes.clear()

    try:
        while True:
            head, op, length = _next_record(f, size)
            if op == _MESSAGE_INDEX and pending is not None:
                body = f.read(length)
                if len(body) >= 6:
                    indexes[_U16.unpack_from(body, 0)[0]] = body[2:]
                continue
            settle()
            if order.full():
                yield order.take(reading)
            if op == _CHUNK:
                start, records = _open_chunk(f.read(length))
                pending = (records, start)
            elif op in (_SCHEMA, _CHANNEL, _MESSAGE):
                record = head + f.read(length)
                message = op == _MESSAGE and length >= _MESSAGE_HEAD
                bound = _U64.unpack_from(record, 9 + 6)[0] if message else -1
                cols = _chunk_messages(record, reading, wanted, {})
                order.add(np.frombuffer(record, np.uint8), cols, bound, chunk=False)
            elif op in (_FOOTER, _DATA_END):  # the summary follows: no message in it
                break
            else:
                f.seek(length, 1)
    except Cut:
        indexes.clear()  # they may be cut short: the chunk is walked instead
        settle()
        raise
    settle()


def _chunk_messages(
    records: bytes,
    reading: dict[int, str | None],
    wanted: Wanted,
    indexes: dict[int, bytes],
) -> _Columns | None:
    """The messages of the channels read among ``records`` (a chunk's, or one record), in
    file order; None when there is none. From the chunk's message indexes when every
    channel they name is known and each index is whole, else by walking the records."""
    buf = np.frombuffer(records, np.uint8)
    found = None
    if indexes and all(c in reading for c in indexes):
        found = _indexed(buf, indexes)
    if found is None:
        offsets, lengths = _walk(records, reading, wanted)
        if bool(np.any(lengths < _MESSAGE_HEAD)):
            raise Cut("a message record is shorter than its header")
        heads = _heads(buf, offsets)
    else:
        offsets, heads = found
    if not len(offsets):
        return None
    channel = heads["channel"].astype(np.int64)
    read = np.array([c for c, topic in reading.items() if topic is not None], np.int64)
    mine = np.isin(channel, read)
    if not bool(mine.all()):
        offsets, channel, heads = offsets[mine], channel[mine], heads[mine]
    start = offsets + (9 + _MESSAGE_HEAD)
    size = heads["length"].astype(np.int64) - _MESSAGE_HEAD
    return (np.zeros(len(start), np.int64), channel, heads["log_time"], start, start + size)


# A message record after its opcode: its length, then channel id, sequence and log time.
_MESSAGE_RECORD = np.dtype(
    {
        "names": ["length", "channel", "log_time"],
        "formats": ["<u8", "<u2", "<u8"],
        "offsets": [0, 8, 14],
        "itemsize": 22,
    }
)


def _heads(buf: npt.NDArray[np.uint8], offsets: npt.NDArray[np.int64]) -> Any:
    """The heads of the message records at ``offsets`` (each whole in ``buf``)."""
    return _gather(buf, offsets + 1, "V22").view(_MESSAGE_RECORD)


def _indexed(buf: npt.NDArray[np.uint8], indexes: dict[int, bytes]) -> Any:
    """The offsets of the chunk's message records, in file order, from its message
    indexes, and the records' heads; None unless the indexes hold exactly what the
    chunk holds: each offset a whole message record, none overlapping another, and
    between them only records of other kinds (a lost or damaged index must not lose a
    message: the chunk is then walked)."""
    parts = []
    for body in indexes.values():
        if len(body) < 4:
            return None
        (n,) = _U32.unpack_from(body, 0)
        if n % 16 or 4 + n > len(body):
            return None
        parts.append(np.frombuffer(body, "<u8", n // 8, 4)[1::2])
    offsets = np.sort(np.concatenate(parts))
    if not len(offsets) or int(offsets[-1]) > len(buf) - 9 - _MESSAGE_HEAD:
        return None
    offsets = offsets.astype(np.int64)
    if not bool(np.all(buf[offsets] == _MESSAGE)):
        return None
    heads = _heads(buf, offsets)
    lengths = heads["length"]
    if bool(np.any(lengths > len(buf))) or bool(np.any(lengths < _MESSAGE_HEAD)):
        return None
    ends = offsets + 9 + lengths.astype(np.int64)
    if bool(np.any(ends[:-1] > offsets[1:])) or int(ends[-1]) > len(buf):
        return None
    gaps = np.flatnonzero(np.concatenate(([offsets[0] > 0], ends[:-1] < offsets[1:])))
    for i in gaps.tolist():  # what no index names: records that are none of those below
        if not _nothing_to_take(buf, int(ends[i - 1]) if i else 0, int(offsets[i])):
            return None
    if int(ends[-1]) < len(buf) and not _nothing_to_take(buf, int(ends[-1]), len(buf)):
        return None
    return offsets, heads


_TAKEN = (_MESSAGE, _CHANNEL, _SCHEMA)  # what a walk takes: a chunk holding one is walked


def _nothing_to_take(buf: npt.NDArray[np.uint8], pos: int, end: int) -> bool:
    """Whether the bytes from ``pos`` to ``end`` are whole records, none a message, a
    channel or a schema (a channel registered in a chunk read from its indexes would
    be lost, and its messages in the chunks after it with it)."""
    while pos < end:
        if pos + 9 > end or int(buf[pos]) in _TAKEN:
            return False
        pos += 9 + int(_gather(buf, np.array([pos + 1]), "<u8")[0])
    return pos == end


def _walk(records: bytes, reading: dict[int, str | None], wanted: Wanted) -> tuple[Any, Any]:
    """The offsets and lengths of the message records among ``records``, read one by one
    (the schema and channel records among them are taken as :func:`_records` takes them)."""
    offsets: list[int] = []
    lengths: list[int] = []
    pos, end = 0, len(records)
    u64 = _U64.unpack_from
    while pos < end:
        op = records[pos]
        if pos + 9 > end:
            raise Cut("a record's header is cut short")
        (length,) = u64(records, pos + 1)
        nxt = pos + 9 + length
        if nxt > end:
            raise Cut(f"a record of {length} bytes runs past its chunk")
        if op == _MESSAGE:
            offsets.append(pos)
            lengths.append(length)
        elif op in (_SCHEMA, _CHANNEL):
            for _ in _records(records[pos:nxt], reading, wanted, _no_schema):
                pass
        pos = nxt
    return np.array(offsets, np.int64), np.array(lengths, np.uint64)


def _no_schema(_: Schema) -> None:
    pass


def _gather(buf: npt.NDArray[np.uint8], at: npt.NDArray[np.int64], dtype: str) -> Any:
    """The little-endian values of ``dtype`` at byte offsets ``at`` of ``buf``: one fancy
    index into a view of ``buf`` whose elements start at every byte (unaligned reads)."""
    width = np.dtype(dtype).itemsize
    if len(buf) < width:
        return np.zeros(0, dtype)[at]  # (an IndexError for any offset, as for any past the end)
    every = np.ndarray((len(buf) - width + 1,), dtype, buf, 0, (1,))
    return every[at]
