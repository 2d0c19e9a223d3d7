"""Recorded runs: JSON Lines traces and rosbag2 bags (MCAP or sqlite3), streamed.

A JSON Lines trace holds one event per line::

    {"topic": "/speed", "stamp": 1700000000023000000, "msg": {"data": 17.3}}

``stamp`` is integer nanoseconds; it may be left out when ``msg.header.stamp``
is present, which takes precedence either way (the same rule as the live
handler: a message's own header stamp, else when it was published).
"""

from __future__ import annotations

import contextlib
import difflib
import itertools
import json
from collections import Counter
from collections.abc import Callable, Collection, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import compress, repeat
from operator import attrgetter, contains, itemgetter
from pathlib import Path
from typing import Any, BinaryIO, cast

import msgspec
import numpy as np
import numpy.typing as npt

from edgerv.core import mcap_stream
from edgerv.core.bags import Bag, BagError, Message, looks_like_bag
from edgerv.core.cdr import compile_reader
from edgerv.core.cdr_columns import compile_column_reader
from edgerv.core.diagnostics import Diagnostic, InputError, Location
from edgerv.core.msgtypes import normalize_type, register_definition, starts_with_header, typestore
from edgerv.core.pipeline import header_stamp

Progress = Callable[[int], None]  # advance by n units (bytes or messages)
STAMPS = range(-(2**63), 2**63)  # a stamp is signed 64-bit nanoseconds, as ROS time is
# A JSON trace is read this much at a time (about 8,000 short lines: the work per block,
# not per line, took a sixth of a check of 300,000 robot events in blocks of 32 KiB), a
# bag's (or any stream's) events handed on this many at a time. Small: a chunk's messages
# live until it is checked, and what outlives a few thousand allocations moves to the
# cycle collector's oldest generation, whose collections walk every object (a bag's check
# took 30% longer in chunks of 4,096, in a process holding 200,000 other objects).
BLOCK_BYTES = 1 << 17
CHUNK_EVENTS = 512
_COLUMN_READS = 4096  # messages whose fields one column read gathers
# json.loads' own parser (the C scanner that JSONDecoder.raw_decode calls), without the checks
# and the whitespace matching around it: a line is parsed exactly as json.loads parses it
_SCAN: Callable[[str, int], tuple[Any, int]] = json.JSONDecoder().scan_once  # type: ignore[attr-defined]
_FIRST_STAMP, _LAST_STAMP = STAMPS[0], STAMPS[-1]
_UNREAD = object()  # a line the quick reading did not parse


class _Record(msgspec.Struct):
    """A JSON Lines record as msgspec decodes it: its message left undecoded."""

    topic: str
    msg: msgspec.Raw
    stamp: int | None = None


class _Headed(msgspec.Struct):
    """A message as far as its header: the rest is skipped, not decoded."""

    header: Any = None


_LINES = msgspec.json.Decoder(_Record)
_ANY = msgspec.json.Decoder()
_HEADED = msgspec.json.Decoder(_Headed)


def _header_of(raw: bytes) -> Any:
    """A message with only its header decoded, as :func:`header_stamp` reads it."""
    try:
        return {"header": _HEADED.decode(raw).header}
    except msgspec.ValidationError:  # not an object: decoded whole
        return _ANY.decode(raw)


def _other_stamp(record: _Record) -> int | None:
    """The time a record of a topic no monitor reads shows: its header's stamp, else its
    ``stamp``; None when neither is a stamp in range. Its message is decoded only as far
    as its header, and only if it may hold one."""
    stamp, held = record.stamp, bytes(record.msg)
    if b"header" in held or b"\\" in held:  # (a key spelled with escapes)
        stamped = header_stamp(_header_of(held))
        stamp = stamp if stamped is None else stamped
    if stamp is None or not _FIRST_STAMP <= stamp <= _LAST_STAMP:
        return None
    return stamp


_FIRST, _SECOND = itemgetter(0), itemgetter(1)
_HAS: Callable[[Any, str], bool] = contains
_TOPIC, _MSG, _STAMP = attrgetter("topic"), attrgetter("msg"), attrgetter("stamp")


@dataclass(frozen=True)
class TraceEvent:
    topic: str
    stamp: int
    msg: Any
    where: Location  # the line of a JSON trace, or the message's index in a bag


@dataclass
class EventChunk:
    """Consecutive events of a trace, column by column: a check takes them in one go,
    with no object made per event (200,000 events: 0.2 s less than one each)."""

    path: str
    topics: list[str] = field(default_factory=list)
    stamps: Any = field(default_factory=list)  # list[int], or an int64 array (columns)
    msgs: list[Any] = field(default_factory=list)
    places: list[int] = field(default_factory=list)  # lines of a JSON trace, indexes in a bag
    locations: list[Location] | None = None  # given instead of path and places
    parsed_json: bool = False  # the messages are what json.loads gives (dicts, lists, ...)
    # each message's field values already read (a bag's, by its topic's fields: see
    # Trace.events), its msgs then the raw bytes
    rows: list[list[Any]] | None = None
    # an MCAP file's messages read column-wise (Trace.events with fields): each topic's
    # events (positions in the chunk, ascending) and its fields' values, NumPy arrays; the
    # stamps are then an array too, and topics, msgs and places are left empty: event i
    # is the bag's message ``first + i``
    columns: dict[str, tuple[npt.NDArray[np.int64], list[Any]]] | None = None
    first: int = 1

    def __len__(self) -> int:
        return len(self.stamps)

    def where(self, i: int) -> Location:
        if self.locations is not None:
            return self.locations[i]
        if self.columns is not None:
            return Location(self.path, self.first + i)
        return Location(self.path, self.places[i])

    def topic_counts(self) -> Mapping[str, int]:
        """The events of each topic in the chunk."""
        if self.columns is not None:
            return {topic: len(at) for topic, (at, _) in self.columns.items()}
        return Counter(self.topics)

    def __iter__(self) -> Iterator[TraceEvent]:
        wheres = self.locations or map(Location, repeat(self.path), self.places)
        return map(TraceEvent, self.topics, self.stamps, self.msgs, wheres)

    def add(self, event: TraceEvent) -> None:
        self.topics.append(event.topic)
        self.stamps.append(event.stamp)
        self.msgs.append(event.msg)
        self.places.append(event.where.line or 0)


class TraceEvents(Iterator[TraceEvent]):
    """A trace's events, one by one, or (:meth:`chunks`) a chunk at a time."""

    def __init__(self, chunks: Iterator[EventChunk]) -> None:
        self._chunks = chunks
        self._events: Iterator[TraceEvent] = itertools.chain.from_iterable(chunks)

    def __next__(self) -> TraceEvent:
        return next(self._events)

    def chunks(self) -> Iterator[EventChunk]:
        """The events not taken yet, a chunk at a time (do not mix with :meth:`__next__`)."""
        return self._chunks


def chunks_of(events: Iterable[TraceEvent], size: int = CHUNK_EVENTS) -> Iterator[EventChunk]:
    """Events gathered into chunks; an error in ``events`` comes after the chunk before it."""
    chunk, stream = EventChunk("", locations=[]), iter(events)
    while True:
        try:
            event = next(stream)
        except StopIteration:
            break
        except Exception:
            if len(chunk):
                yield chunk
            raise
        chunk.add(event)
        chunk.locations.append(event.where)  # type: ignore[union-attr]
        if len(chunk) >= size:
            yield chunk
            chunk = EventChunk("", locations=[])
    if len(chunk):
        yield chunk


def _scan_lines(lines: list[str]) -> list[tuple[Any, int] | None]:
    """Each line parsed by the scanner (the JSON value at its start, and where it ends),
    None for a line it cannot parse: the lines are mapped through it in C, a run of
    parseable ones at a time (a failing line stops the map; the next run starts after
    it). What is made of a result is for the caller to check."""
    out: list[tuple[Any, int] | None] = []
    rest = iter(lines)  # one iterator: a failing line costs one step, not a new pass
    while len(out) < len(lines):
        # a StopIteration from the scanner ends the map as if the lines had; an error
        # leaves the results before it in ``out``; either way the failing line is taken
        with contextlib.suppress(ValueError, RecursionError):
            out.extend(map(_SCAN, rest, repeat(0)))
        if len(out) < len(lines):
            out.append(None)
    return out


def _blocks(handle: BinaryIO, progress: Progress | None) -> Iterator[bytes]:
    """The file's bytes a block of whole lines at a time, each ending with a newline (the
    last line gets one if it has none)."""
    rest = b""
    while block := handle.read(BLOCK_BYTES):
        cut = block.rfind(b"\n") + 1
        if not cut:  # no line ends in it: read on
            rest += block
            continue
        data, rest = rest + block[:cut], block[cut:]
        if progress:
            progress(len(data))
        yield data
    if rest:
        if progress:
            progress(len(rest))
        yield rest + b"\n"


class Trace:
    """A recorded run opened for streaming."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.is_bag = looks_like_bag(path)
        self.bag: Bag | None = None  # opened by :meth:`open`
        self.msgtypes: dict[str, str] = {}  # topic -> message type, for bags
        self.counts: Counter[str] = Counter()  # events read, per monitored topic
        self.others: set[str] = set()  # JSON Lines: the topics seen that no monitor reads
        self.warnings: list[Diagnostic] = []  # about the trace itself, found as it is read
        # The latest time the trace shows as passed: the largest stamp of any of its
        # events, read or not (a bag: also its last message's log time). Monitors with
        # timed atoms take their clock steps up to it at the end of a check.
        self.end: int | None = None
        # False: no monitor has timed atoms, so the stamps of topics no monitor reads need
        # not be read (a JSON trace's headers of other topics, decoded only for them)
        self.ends_needed = True

    def _saw(self, stamp: int) -> None:
        if self.end is None or stamp > self.end:
            self.end = stamp

    def events(
        self,
        topics: Collection[str],
        progress: Progress | None = None,
        fields: Mapping[str, Sequence[str]] | None = None,
    ) -> TraceEvents:
        """The events of ``topics``. ``fields``: for a bag, each topic's fields to read
        straight from its CDR bytes (the live handler's readers, :mod:`edgerv.core.cdr`)
        into the chunks' ``rows``, instead of decoding whole messages into ``msgs``."""
        if self.is_bag:
            return TraceEvents(self._counted(self._bag_chunks(topics, fields), progress))
        return TraceEvents(self._counted(self._jsonl_chunks(topics, progress), None))

    def _counted(
        self, chunks: Iterator[EventChunk], progress: Progress | None
    ) -> Iterator[EventChunk]:
        """The chunks, each counted per topic as it is handed on (and, for a bag, advancing
        ``progress`` by its messages: a JSON trace advances by bytes as it reads)."""
        for chunk in chunks:
            self.counts.update(chunk.topic_counts())
            if progress:
                progress(len(chunk))
            yield chunk

    # -- JSON Lines --------------------------------------------------------------------------

    def _jsonl_chunks(
        self, topics: Collection[str], progress: Progress | None
    ) -> Iterator[EventChunk]:
        """The trace's events, a block of lines at a time.

        Each block is decoded at once and each line parsed by the JSON scanner itself
        (json.loads costs twice as much a line: it checks its argument's type, decodes
        bytes and matches the whitespace around the document). A line of the usual
        shape (an object, nothing around it; topic, integer stamp, msg without a
        header) is taken as it is; any other goes through :func:`_jsonl_event`, which
        reads every line the same way this reader always did and names the place of
        what is wrong. Both read a line alike: a block is the lines it holds, decoded
        as each would be alone (no UTF-8 sequence spans a newline).
        """
        path = str(self.path)
        try:
            handle = self.path.open("rb")
        except OSError as exc:
            raise InputError(
                [Diagnostic(Location(path), f"cannot read trace: {exc.strerror}")]
            ) from None
        with handle:
            lineno = 0
            first = True  # the first block's stamps say their unit
            for data in _blocks(handle, progress):
                chunk = EventChunk(path, parsed_json=True)
                try:
                    lineno = self._read_lines(chunk, lineno, data, topics)
                except InputError:  # a bad line: the events before it are still checked
                    if len(chunk):
                        yield chunk
                    raise
                if first and len(chunk) and self.ends_needed:  # (a monitor reads time)
                    first = False
                    warning = stamp_unit_warning(path, list(chunk.stamps[:10_000]))
                    if warning is not None:
                        self.warnings.append(warning)
                if len(chunk):
                    yield chunk

    def _read_lines(
        self, chunk: EventChunk, lineno: int, data: bytes, topics: Collection[str]
    ) -> int:
        """Read the lines of ``data`` (each ending with a newline) into ``chunk``; return
        the number of the last one. Raises :class:`InputError` at a bad line, ``chunk``
        holding the events before it."""
        if lineno == 0 and data.startswith(_BOM):  # as a YAML document's: not the line's
            data = data[len(_BOM) :]
        lineno += 1  # the first line's number
        count = data.count(b"\n")
        if self._take_decoded(chunk, lineno, data, count, topics):
            return lineno + count - 1
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError as exc:  # the lines before it are read, then the error
            start = data.rfind(b"\n", 0, exc.start) + 1
            before = self._read_lines(chunk, lineno - 1, data[:start], topics) if start else 0
            raise _not_utf8(chunk.path, before + 1 if start else lineno, data, start, exc) from None
        lines = text.split("\n")
        lines.pop()  # after the last newline
        parsed = _scan_lines(lines)
        if self._take_block(chunk, lineno, lines, parsed, topics):
            return lineno + len(lines) - 1
        path, latest = chunk.path, self.end
        tops, stamps, msgs, places = chunk.topics, chunk.stamps, chunk.msgs, chunk.places
        raws: list[bytes] | None = None  # the lines as bytes, for the careful reading
        for i, line in enumerate(lines):
            scanned = parsed[i]
            record: Any = _UNREAD if scanned is None else scanned[0]
            if scanned is not None and (scanned[1] != len(line) or type(record) is not dict):
                record = _UNREAD  # more than one JSON object, or not one at all
            elif record is not _UNREAD:
                topic, msg, stamp = record.get("topic"), record.get("msg"), record.get("stamp")
                if (
                    type(topic) is str
                    and topic in topics
                    and type(msg) is dict
                    and "header" not in msg
                    and type(stamp) is int
                    and _FIRST_STAMP <= stamp <= _LAST_STAMP
                ):
                    tops.append(topic)
                    stamps.append(stamp)
                    msgs.append(msg)
                    places.append(lineno + i)
                    if latest is None or stamp > latest:
                        latest = stamp
                    continue
            # not the usual shape: read as this reader always did, errors named at their place
            self.end = latest
            try:
                if record is not _UNREAD:
                    event = _record_event(
                        path, lineno + i, line, record, topics, self._saw, self.others
                    )
                else:
                    raws = data.split(b"\n") if raws is None else raws
                    if not raws[i].strip():
                        continue
                    event = _jsonl_event(path, lineno + i, raws[i], topics, self._saw, self.others)
            finally:
                latest = self.end
            if event is not None:
                chunk.add(event)
        self.end = latest
        return lineno + len(lines) - 1

    def _take_decoded(
        self, chunk: EventChunk, lineno: int, data: bytes, count: int, topics: Collection[str]
    ) -> bool:
        """Take the whole block into ``chunk`` if msgspec's decoder reads every line as a
        record of the usual shape (a topic read: a msg object, its header's stamp or an
        integer stamp, in range; any other topic: what it shows of time); else leave it
        to the readers below. The messages of other topics are not decoded (msgspec.Raw) unless
        they may hold a header. A line msgspec refuses (JSON's NaN, a number beyond a
        float, a lone surrogate, invalid UTF-8, a blank line) sends the block below."""
        try:
            records = _LINES.decode_lines(data)
        except (msgspec.DecodeError, RecursionError, UnicodeDecodeError):  # named below
            return False
        if len(records) != count:  # a blank line, skipped: the lines' numbers
            return False
        taken = self._take_columns(chunk, lineno, records, topics)
        if taken is not None:
            return taken
        return self._take_records(chunk, lineno, records, topics)

    def _take_columns(
        self, chunk: EventChunk, lineno: int, records: list[_Record], topics: Collection[str]
    ) -> bool | None:
        """:meth:`_take_decoded` a column at a time, with no Python code per line, for a
        block whose messages read have no header (else None: read record by record). The
        messages read are decoded in one call, as one JSON array of them."""
        tops = list(map(_TOPIC, records))
        try:
            mine = list(compress(range(len(tops)), map(topics.__contains__, tops)))
        except TypeError:  # (a topic of another type than a string: not read below)
            return None
        chosen = list(map(records.__getitem__, mine))
        try:
            msgs = _ANY.decode(b"[" + b",".join(map(_MSG, chosen)) + b"]")
        except (msgspec.DecodeError, RecursionError, UnicodeDecodeError):  # named below
            return False
        if set(map(type, msgs)) - {dict} or any(map(_HAS, msgs, repeat("header"))):
            return None  # (not an object: an error named below)
        stamps: list[Any] = list(map(_STAMP, chosen))
        if None in stamps or (stamps and (min(stamps) < _FIRST_STAMP or max(stamps) > _LAST_STAMP)):
            return False  # (an error: named below)
        others = set(tops).difference(topics)
        latest = self.end
        if stamps and (latest is None or max(stamps) > latest):
            latest = max(stamps)
        if others and self.ends_needed:  # what the other topics show of time
            try:
                for i in compress(range(len(tops)), map(others.__contains__, tops)):
                    stamp = _other_stamp(records[i])
                    if stamp is not None and (latest is None or stamp > latest):
                        latest = stamp
            except (msgspec.DecodeError, RecursionError, UnicodeDecodeError):  # named below
                return False
        chunk.topics = list(map(tops.__getitem__, mine))
        chunk.stamps, chunk.msgs = stamps, msgs
        chunk.places = list(map(lineno.__add__, mine))
        self.others |= others
        self.end = latest
        return True

    def _take_records(
        self, chunk: EventChunk, lineno: int, records: list[_Record], topics: Collection[str]
    ) -> bool:
        """:meth:`_take_decoded` record by record."""
        tops: list[str] = []
        stamps: list[int] = []
        msgs: list[dict[str, Any]] = []
        places: list[int] = []
        others: set[str] = set()
        latest = self.end
        try:  # (a message's number beyond a float: refused only as it is decoded)
            for i, record in enumerate(records):
                topic, stamp = record.topic, record.stamp
                if topic in topics:
                    msg = _ANY.decode(record.msg)
                    if type(msg) is not dict:
                        return False
                    if "header" in msg:  # its stamp, when it was stamped
                        stamped = header_stamp(msg)
                        stamp = stamp if stamped is None else stamped
                    if stamp is None or not _FIRST_STAMP <= stamp <= _LAST_STAMP:
                        return False  # (an error: named below)
                    tops.append(topic)
                    stamps.append(stamp)
                    msgs.append(msg)
                    places.append(lineno + i)
                    at = stamp
                else:  # not read, but it shows that time passed
                    others.add(topic)
                    stamp = _other_stamp(record)
                    if stamp is None:
                        continue
                    at = stamp
                if latest is None or at > latest:
                    latest = at
        except (msgspec.DecodeError, RecursionError, UnicodeDecodeError):  # named below
            return False
        chunk.topics, chunk.stamps, chunk.msgs, chunk.places = tops, stamps, msgs, places
        self.others |= others
        self.end = latest
        return True

    def _take_block(
        self,
        chunk: EventChunk,
        lineno: int,
        lines: list[str],
        parsed: list[tuple[Any, int] | None],
        topics: Collection[str],
    ) -> bool:
        """Take the whole block into ``chunk`` if every line is of the usual shape (one
        object, nothing around it, a topic read, an integer stamp in range, a msg without
        a header), checked a column at a time (no Python code per line); else leave it."""
        if None in parsed:
            return False
        scanned = cast(list[tuple[Any, int]], parsed)
        if list(map(_SECOND, scanned)) != list(map(len, lines)):
            return False
        records: list[Any] = list(map(_FIRST, scanned))
        if set(map(type, records)) != {dict}:
            return False
        tops: list[Any] = list(map(dict.get, records, repeat("topic")))
        try:
            if not all(map(topics.__contains__, set(tops))):
                return False
        except TypeError:  # a topic that is not a string: not even hashable
            return False
        msgs: list[Any] = list(map(dict.get, records, repeat("msg")))
        if set(map(type, msgs)) != {dict} or any(map(_HAS, msgs, repeat("header"))):
            return False
        stamps: list[Any] = list(map(dict.get, records, repeat("stamp")))
        if set(map(type, stamps)) != {int}:
            return False
        if min(stamps) < _FIRST_STAMP or max(stamps) > _LAST_STAMP:
            return False
        chunk.topics, chunk.stamps, chunk.msgs = tops, stamps, msgs
        chunk.places = list(range(lineno, lineno + len(lines)))
        self._saw(max(stamps))
        return True

    # -- rosbag2 -----------------------------------------------------------------------------

    def open(self) -> None:
        """Open a bag's index: its topics and their types (``msgtypes``), and the message
        definitions it carries made known (types not installed). Nothing for JSON Lines."""
        if not self.path.exists():
            raise InputError([Diagnostic(Location(str(self.path)), "no such file or directory")])
        if not self.is_bag or self.bag is not None:
            return
        try:
            self.bag = Bag(self.path)
        except BagError as exc:
            raise InputError(
                [Diagnostic(Location(str(self.path)), f"cannot read bag: {exc}", hint=exc.hint)]
            ) from None
        for topic in self.bag.topics.values():
            self.msgtypes[topic.name] = topic.msgtype
            if topic.definition is not None:
                register_definition(topic.msgtype, *topic.definition)
        if self.bag.end is not None:
            self._saw(self.bag.end)

    def close(self) -> None:
        """Remove what reading made on disk (a compressed bag's decompressed copy)."""
        if self.bag is not None:
            self.bag.close()

    def inspect(self, topics: Collection[str]) -> int:
        """Open the trace (:meth:`open`); return the progress total: bytes for a JSON trace,
        the monitored messages for a bag (0 when its index does not say: a damaged file).
        A monitored topic that a bag records in another serialization than CDR is an error."""
        self.open()
        if self.bag is None:
            return self.path.stat().st_size
        found = [self.bag.topics[t] for t in topics if t in self.bag.topics]
        foreign = [t for t in found if t.serialization != "cdr"]
        if foreign:
            raise InputError(
                [
                    Diagnostic(
                        Location(str(self.path)),
                        f"{t.name} is recorded in the '{t.serialization}' serialization; "
                        "edgerv reads ROS 2's CDR",
                        hint="convert the bag with `ros2 bag convert`, or monitor other topics",
                    )
                    for t in foreign
                ]
            )
        counts = [t.count for t in found]
        return 0 if None in counts else sum(c for c in counts if c is not None)

    def _bag_chunks(
        self,
        topics: Collection[str],
        fields: Mapping[str, Sequence[str]] | None = None,
    ) -> Iterator[EventChunk]:
        self.inspect(topics)
        bag = self.bag
        assert bag is not None
        path = str(self.path)
        types = {t: bag.topics[t].msgtype for t in topics if t in bag.topics}
        reading = _BagReading(path, types, fields)
        index = 0  # the messages read
        try:
            for batch in bag.batches(types, columns=fields is not None):
                if not isinstance(batch, list):
                    chunk = reading.columns(batch, index)
                    if chunk is not None:
                        index += len(chunk)
                        self._saw(int(chunk.stamps.max()))
                        yield chunk
                        continue
                    batch = _messages_of(batch)  # read one by one: an error at its place
                for chunk in reading.rows(batch, index, self._saw):
                    index += len(chunk)
                    yield chunk
        except BagError as exc:
            where = Location(path, index + 1) if index else Location(path)
            raise InputError(
                [Diagnostic(where, f"bag is damaged after message {index}: {exc}", hint=exc.hint)]
            ) from None

    # -- what was read -------------------------------------------------------------------------

    def unread(self, readers: Mapping[str, Collection[str]]) -> list[Diagnostic]:
        """A warning for each monitored topic (``readers``: topic -> the monitors reading
        it) of which no event was read, saying what the trace has instead."""
        out = []
        for topic in sorted(readers):
            if self.counts[topic]:
                continue
            names = ", ".join(sorted(readers[topic]))
            out.append(
                Diagnostic(
                    Location(str(self.path)),
                    f"no message on {topic} was read (monitors reading it: {names})",
                    severity="warning",
                    hint=self.instead(topic),
                )
            )
        return out

    def instead(self, topic: str) -> str:
        """What the trace has instead of ``topic`` (a hint for a topic it gave no event of)."""
        if self.bag is not None:
            recorded = self.bag.topics.get(topic)
            if recorded is not None:
                return (
                    f"the bag records {topic} as {recorded.msgtype} with no message on it"
                    if not recorded.count
                    else f"the bag has {recorded.count} messages on {topic}, none read: "
                    "please report this bag"
                )
            have = {t.name: t.msgtype for t in self.bag.topics.values()}
        else:
            have = {t: "" for t in self.others | {t for t, n in self.counts.items() if n}}
        if not have:
            return "the trace holds no message of any topic"
        close = difflib.get_close_matches(topic, list(have), n=3, cutoff=0.6)
        shown = close or sorted(have)[:8]
        listed = ", ".join(f"{t} ({have[t]})" if have[t] else t for t in shown)
        more = "" if close or len(have) <= 8 else f" and {len(have) - 8} more"
        return ("it has " if close else "it has no such topic; it has ") + listed + more


def _jsonl_event(
    path: str,
    lineno: int,
    raw: bytes,
    topics: Collection[str],
    saw: Callable[[int], None],
    others: set[str] | None = None,
) -> TraceEvent | None:
    """One line read with care: the event, None for a topic not read, or the located error."""
    try:
        text = raw.decode("utf-8").rstrip("\r\n")
    except UnicodeDecodeError as exc:
        raise _not_utf8(path, lineno, raw, 0, exc) from None
    try:
        record = json.loads(text)
    except json.JSONDecodeError as exc:
        raise _bad_line(path, lineno, text, f"invalid JSON: {exc.msg}", exc.pos + 1) from None
    except ValueError:  # Python reads no integer of more than 4,300 digits
        raise _bad_line(path, lineno, text, "invalid JSON: a number too long to read") from None
    except RecursionError:  # Python's parser recurses per level: thousands are too many
        raise _bad_line(
            path, lineno, text, "nested too deep to read (a message has a few levels)"
        ) from None
    return _record_event(path, lineno, text, record, topics, saw, others)


_BOM = b"\xef\xbb\xbf"  # a UTF-8 byte order mark, as some editors begin a file


def _not_utf8(
    path: str, lineno: int, data: bytes, start: int, exc: UnicodeDecodeError
) -> InputError:
    """The located error for bytes that are not UTF-8 in the line starting at ``start``."""
    end = data.find(b"\n", exc.start)
    line = data[start : len(data) if end < 0 else end].decode("utf-8", errors="replace")
    col = len(data[start : exc.start].decode("utf-8", errors="replace")) + 1
    byte = data[exc.start : exc.start + 1].hex()
    return _bad_line(
        path, lineno, line, f"invalid UTF-8 (byte 0x{byte}): a trace is UTF-8 text", col
    )


def _not_a_stamp(stamp: Any) -> str:
    """Why a record's ``stamp`` is none, and what it must be."""
    must = "a stamp is integer nanoseconds (of ROS time, or since the run began)"
    if stamp is None:
        return "missing 'stamp' (integer nanoseconds) and msg has no header.stamp"
    if isinstance(stamp, float):
        ns = f"{stamp * 1e9:.0f}" if abs(stamp) < 1e10 else "its seconds times 1000000000"
        return (f"stamp {stamp!r} is not an integer: {must}; if it is in seconds, "
                f"{stamp!r} s is {ns}")  # fmt: skip
    shown = json.dumps(stamp)
    shown = shown if len(shown) <= 40 else shown[:37] + "..."
    return f'stamp {shown} is not a number: {must}, e.g. "stamp": 1500000000'


MIN_GAP = 100_000  # ns: a run's stamps closer than this (10 kHz) are seldom nanoseconds


def stamp_unit_warning(path: str, stamps: Sequence[int]) -> Diagnostic | None:
    """A warning at the trace's first line when its first stamps are so close together
    that they are likely seconds or milliseconds, read as nanoseconds (a 2 s gap read as
    2 ns passes a freshness monitor): their median gap under :data:`MIN_GAP`. Asked only
    where a monitor reads time (age(), a time bound): other verdicts do not depend on
    the unit, only on the stamps' order."""
    distinct = sorted(set(stamps))
    gaps = [b - a for a, b in itertools.pairwise(distinct)]
    if len(gaps) < 2:
        return None
    median = sorted(gaps)[len(gaps) // 2]
    if median >= MIN_GAP:
        return None
    return Diagnostic(
        Location(path, 1),
        f"stamps are integer nanoseconds, and these are {median} ns apart (the median of "
        f"the first {len(stamps):,}): the run would last {distinct[-1] - distinct[0]:,} ns; "
        "they look like seconds or milliseconds",
        severity="warning",
        hint="write each stamp in nanoseconds (1.5 s is 1500000000), or the verdicts of "
        "timed monitors (age(), time bounds) are about nanoseconds",
    )


def _bad_line(
    path: str, lineno: int, text: str, message: str, col: int | None = None
) -> InputError:
    loc = Location(path, lineno, col, 1, text if col else None)
    return InputError([Diagnostic(loc, message)])


def _record_event(
    path: str,
    lineno: int,
    text: str,
    record: Any,
    topics: Collection[str],
    saw: Callable[[int], None],
    others: set[str] | None = None,
) -> TraceEvent | None:
    """The event a parsed line holds, None for a topic not read (added to ``others``), or
    the located error."""

    def fail(message: str) -> InputError:
        return _bad_line(path, lineno, text, message)

    if not isinstance(record, dict):
        raise fail("each line must be a JSON object with topic, stamp and msg")
    topic = record.get("topic")
    if not isinstance(topic, str):
        raise fail("missing 'topic' (a string such as \"/speed\")")
    if topic not in topics:  # not read, but it shows that time passed
        if others is not None:
            others.add(topic)
        other = record.get("msg")
        shown = header_stamp(other) if isinstance(other, dict) else None
        shown = record.get("stamp") if shown is None else shown
        if isinstance(shown, int) and not isinstance(shown, bool) and shown in STAMPS:
            saw(shown)
        return None
    msg = record.get("msg")
    if not isinstance(msg, dict):
        raise fail("missing 'msg' (the message as a JSON object, e.g. {\"data\": 1.5})")
    stamp = header_stamp(msg)
    if stamp is None:
        stamp = record.get("stamp")
        if isinstance(stamp, bool) or not isinstance(stamp, int):
            raise fail(_not_a_stamp(stamp))
    if stamp not in STAMPS:
        raise fail(f"stamp {stamp} is out of the range of 64-bit nanoseconds")
    saw(stamp)
    return TraceEvent(topic, stamp, msg, Location(path, lineno))


class _BagReading:
    """How a check reads a bag's messages: each topic's fields straight from the CDR
    bytes, column-wise for a batch of an MCAP file (:mod:`edgerv.core.cdr_columns`),
    one by one otherwise (:mod:`edgerv.core.cdr`); without ``fields``, whole messages."""

    def __init__(
        self, path: str, types: Mapping[str, str], fields: Mapping[str, Sequence[str]] | None
    ) -> None:
        self.path = path
        self.types = types
        self.fields = fields
        self.readers = (
            None if fields is None else {t: compile_reader(m, fields[t]) for t, m in types.items()}
        )
        self.column_readers = (
            {}
            if fields is None
            else {t: compile_column_reader(m, fields[t]) for t, m in types.items()}
        )

    def columns(
        self, batch: tuple[mcap_stream.Batch, dict[int, str]], index: int
    ) -> EventChunk | None:
        """A batch of an MCAP file read column-wise, or None where it must be read one
        message at a time (a message that is not what its type says, a field that has
        no column reader, a log time beyond 64-bit nanoseconds)."""
        b, channels = batch
        if len(b) and int(b.log_time.max()) > _LAST_STAMP:
            return None
        stamps = b.log_time.astype(np.int64)
        by_topic: dict[str, list[int]] = {}
        for cid, topic in channels.items():
            by_topic.setdefault(topic, []).append(cid)
        columns: dict[str, tuple[npt.NDArray[np.int64], list[Any]]] = {}
        for topic, cids in by_topic.items():
            mine = b.channel == cids[0] if len(cids) == 1 else np.isin(b.channel, cids)
            at = np.flatnonzero(mine)
            if not len(at):
                continue
            read = self._topic_columns(topic, b, at)
            if read is None:
                return None
            values, stamped = read
            if stamped is not None:  # a header nobody stamped: its publication
                stamps[at] = np.where(stamped != 0, stamped, stamps[at])
            columns[topic] = (at, values)
        return EventChunk(self.path, stamps=stamps, columns=columns, first=index + 1)

    def _topic_columns(
        self, topic: str, b: mcap_stream.Batch, at: npt.NDArray[np.int64]
    ) -> tuple[list[Any], npt.NDArray[np.int64] | None] | None:
        reader = self.column_readers.get(topic)
        if reader is None:  # (a string field) one by one, into columns of Python values
            return self._topic_rows(topic, b, at)
        starts, ends = b.start[at], b.end[at]
        if len(at) <= _COLUMN_READS:
            got = reader(b.buffer, starts, ends)
            return None if got is None else (got.values, got.stamps)
        parts = []  # a few thousand messages a call: each read's bytes still in the cache
        for i in range(0, len(at), _COLUMN_READS):
            got = reader(b.buffer, starts[i : i + _COLUMN_READS], ends[i : i + _COLUMN_READS])
            if got is None:
                return None
            parts.append(got)
        values = [np.concatenate(c) for c in zip(*(p.values for p in parts), strict=True)]
        stamps = None if parts[0].stamps is None else np.concatenate([p.stamps for p in parts])
        return values, stamps

    def _topic_rows(
        self, topic: str, b: mcap_stream.Batch, at: npt.NDArray[np.int64]
    ) -> tuple[list[Any], npt.NDArray[np.int64] | None] | None:
        """A topic's messages of a batch read one by one (:mod:`edgerv.core.cdr`) into
        columns of Python objects; None at a message that cannot be read."""
        assert self.readers is not None
        read, buffer = self.readers[topic], b.buffer
        rows, stamps = [], []
        try:
            for start, end in zip(b.start[at].tolist(), b.end[at].tolist(), strict=True):
                values, stamp = read(buffer[start:end].tobytes())
                rows.append(values)
                stamps.append(stamp or 0)
        except Exception:
            return None
        columns = []
        for held in zip(*rows, strict=True):
            column = np.empty(len(held), object)
            column[:] = held
            columns.append(column)
        stamped = (
            None
            if self.readers is None or not _stamped(self.types[topic])
            else np.array(stamps, np.int64)
        )
        return columns, stamped

    def rows(
        self, messages: list[Message], index: int, saw: Callable[[int], None]
    ) -> Iterator[EventChunk]:
        """Messages read one by one, in chunks; a message that cannot be read is an
        error at its place, after the chunk of those before it."""
        path, types, readers = self.path, self.types, self.readers
        # decoded whole only without readers (rosbags' store: made at its first use)
        deserialize = typestore().deserialize_cdr if readers is None else None
        chunk = EventChunk(path, rows=None if readers is None else [])
        for topic, log_time, raw in messages:
            index += 1
            try:
                if readers is not None:
                    values, stamp = readers[topic](raw)
                    msg: Any = raw
                else:
                    assert deserialize is not None
                    msg = deserialize(raw, types[topic])
                    stamp = header_stamp(msg)
            except Exception as exc:
                error = f"message {index} on {topic} cannot be read as {types[topic]}: {exc}"
                hint = "verdicts above cover the messages before it"
                yield from _nonempty(chunk)
                raise InputError([Diagnostic(Location(path, index), error, hint=hint)]) from None
            stamp = stamp or log_time  # a header nobody stamped: its publication
            if stamp not in STAMPS:
                error = (
                    f"message {index} on {topic} is stamped {stamp} ns, "
                    "out of the range of 64-bit nanoseconds"
                )
                yield from _nonempty(chunk)
                raise InputError([Diagnostic(Location(path, index), error)])
            saw(stamp)
            chunk.topics.append(topic)
            chunk.stamps.append(stamp)
            chunk.msgs.append(msg)
            chunk.places.append(index)
            if chunk.rows is not None:
                chunk.rows.append(values)
            if len(chunk) >= CHUNK_EVENTS:
                yield chunk
                chunk = EventChunk(path, rows=None if readers is None else [])
        yield from _nonempty(chunk)


def _stamped(msg_type: str) -> bool:
    """Whether messages of the type carry a header stamp."""
    return starts_with_header(normalize_type(msg_type))


def _nonempty(chunk: EventChunk) -> Iterator[EventChunk]:
    if len(chunk):
        yield chunk


def _messages_of(batch: tuple[mcap_stream.Batch, dict[int, str]]) -> list[Message]:
    """A batch's messages one by one: (topic, log time, CDR bytes)."""
    b, channels = batch
    buffer = b.buffer
    return [
        (channels[channel], log_time, buffer[start:end].tobytes())
        for channel, log_time, start, end in zip(
            b.channel.tolist(), b.log_time.tolist(), b.start.tolist(), b.end.tolist(), strict=True
        )
    ]
