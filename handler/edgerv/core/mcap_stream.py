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
from typing import BinaryIO, NamedTuple

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
        head = f.read(_HEAD.size)
        if len(head) < _HEAD.size:
            raise Cut(f"it ends at byte {size}, before its footer")
        op, length = _HEAD.unpack(head)
        if f.tell() + length > size:
            raise Cut(f"a record of {length} bytes at byte {f.tell() - 9} runs past its end")
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
