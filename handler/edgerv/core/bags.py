"""rosbag2 recordings, read as ``edgerv check`` needs them: every layout rosbag2 has
written, the messages as the bytes that were recorded.

A bag is a directory (``metadata.yaml`` beside its storage files), or one storage
file (``.db3`` sqlite3, ``.mcap``), possibly zstd-compressed as a whole
(``.db3.zstd``, ``.mcap.zstd``: rosbag2's file compression). Its *topics* come
from the storage files themselves, not from ``metadata.yaml`` (whose QoS text and
topic list rosbag2 versions wrote in several ways); ``metadata.yaml`` gives only the
files, their order, the compression and the message counts.

What rosbag2 versions and recorders wrote differently, read alike:

* topic names without their leading slash (``chatter``): ROS 2 names are absolute,
  so the bag's ``chatter`` is ``/chatter`` (:attr:`BagTopic.recorded` keeps the
  recorded spelling for messages);
* message types in the old ``pkg/Type`` form: ``pkg/msg/Type``;
* message definitions carried by the bag (MCAP schemas, the sqlite3
  ``message_definitions`` table): :attr:`BagTopic.definition`, for types not
  installed; a service event topic's (``/<service>/_service_event``, of the type
  ``pkg/srv/Name_Event``) is its service's: rosbag2 (Jazzy) writes the ``.srv`` text
  after an ``SRV: pkg/srv/Name`` line, then its dependencies, under the encoding of
  those (``unknown`` when it has none), as the topic's MCAP schema and in
  ``message_definitions`` under the service's type ``pkg/srv/Name``;
* a truncated MCAP (a recording cut by a crash or a full disk): read as a stream,
  every message up to the damage, then :class:`BagError` says where it stopped;
* topics of other serializations than CDR, types nobody can decode: listed, and read
  only when a monitor asks for them.

ROS 1 bags are refused with the command that converts them (``rosbags-convert``).
"""

from __future__ import annotations

import contextlib
import re
import sqlite3
import tempfile
from collections.abc import Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml

from edgerv.core import mcap_stream
from edgerv.core.msgtypes import SEPARATOR

# its encoding, its text ("unknown": a service's definition of no dependency, see above)
Definition = tuple[Literal["ros2msg", "ros2idl", "unknown"], str]
Message = tuple[str, int, bytes]  # topic (as monitors name it), log time (ns), CDR bytes
# a batch of messages: an MCAP file's as arrays (with its channels' topics), else a list
Batch = tuple[mcap_stream.Batch, dict[int, str]] | list[Message]
ROWS_BATCH = 512  # messages of a list batch

_OLD_TYPE = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)/([A-Za-z_][A-Za-z0-9_]*)$")
STORAGE_SUFFIXES = (".db3", ".mcap")


class BagError(Exception):
    """An unreadable bag, or one damaged after ``read`` messages (``None``: before any)."""

    def __init__(self, message: str, hint: str | None = None, read: int | None = None) -> None:
        super().__init__(message)
        self.hint = hint
        self.read = read


@dataclass
class BagTopic:
    name: str  # as ROS 2 and the monitors name it: with its leading slash
    msgtype: str  # pkg/msg/Type (an old pkg/Type normalized); service events pkg/srv/X_Event
    serialization: str  # "cdr" for every ROS 2 recording but a few converted ones
    recorded: set[str] = field(default_factory=set)  # the names as recorded
    types: set[str] = field(default_factory=set)  # the types as recorded
    count: int | None = 0  # messages, from the bag's index; None: unknown (damaged)
    definition: Definition | None = None


def topic_name(recorded: str) -> str:
    """A recorded topic name as ROS 2 names it: absolute."""
    return recorded if recorded.startswith("/") else "/" + recorded


def type_name(recorded: str) -> str:
    """A recorded type name in today's form: ``pkg/Type`` (early rosbag2) is ``pkg/msg/Type``."""
    m = _OLD_TYPE.match(recorded.strip())
    return f"{m.group(1)}/msg/{m.group(2)}" if m else recorded.strip()


@dataclass
class _Storage:
    path: Path
    compressed_messages: bool  # rosbag2's compression_mode: message (zstd per message)


class Bag:
    """A rosbag2 bag opened for reading: its topics at once, its messages streamed."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.topics: dict[str, BagTopic] = {}
        self.end: int | None = None  # the last message's log time, when the index says
        self.storages: list[_Storage] = []
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        self._metadata_counts: dict[str, int] | None = None
        self._chunk_starts: dict[Path, list[int] | None] = {}  # an MCAP's, from its index
        self._open()

    def close(self) -> None:
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __enter__(self) -> Bag:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    # -- opening ----------------------------------------------------------------------------

    def _open(self) -> None:
        path = self.path
        if path.name == "metadata.yaml":
            path = path.parent
        if path.suffix == ".bag" and path.is_file():
            raise BagError(
                "a ROS 1 bag: edgerv reads ROS 2 (rosbag2) bags",
                hint=f"convert it: rosbags-convert --src {self.path} --dst {path.with_suffix('')}",
            )
        if path.is_dir():
            self._open_directory(path)
        else:
            self._open_file(path, compressed_messages=False)
        for storage in self.storages:
            self._index(storage)
        if self._metadata_counts is not None:
            for topic in self.topics.values():
                if topic.count is None:
                    counts = [self._metadata_counts.get(r) for r in topic.recorded]
                    if None not in counts:
                        topic.count = sum(c for c in counts if c is not None)

    def _open_directory(self, path: Path) -> None:
        meta_path = path / "metadata.yaml"
        if not meta_path.exists():
            files = sorted(p for p in path.iterdir() if p.suffix in STORAGE_SUFFIXES)
            if not files:
                raise BagError(
                    f"{path} is a directory without metadata.yaml nor .db3 or .mcap files",
                    hint="give a rosbag2 bag: its directory, or its .mcap or .db3 file",
                )
            for f in files:
                self._open_file(f, compressed_messages=False)
            return
        meta = _metadata(meta_path)
        listed = meta.get("relative_file_paths")
        if isinstance(listed, list) and listed:
            names = [str(n) for n in listed]
        else:
            names = sorted(p.name for p in path.iterdir() if p.suffix in STORAGE_SUFFIXES)
        mode = str(meta.get("compression_mode") or "").lower()
        fmt = str(meta.get("compression_format") or "")
        if mode not in ("", "none") and fmt != "zstd":
            raise BagError(
                f"{meta_path}: compression format '{fmt}' (rosbag2 writes zstd only)",
                hint="decompress it with `ros2 bag convert`",
            )
        counts: dict[str, int] = {}
        for entry in meta.get("topics_with_message_count") or []:
            try:
                counts[str(entry["topic_metadata"]["name"])] = int(entry["message_count"])
            except (KeyError, TypeError, ValueError):
                counts = {}
                break
        self._metadata_counts = counts or None
        for name in names:
            f = path / Path(name).name
            if (
                not f.exists()
                and not f.name.endswith(".zstd")
                and (path / f"{f.name}.zstd").exists()
            ):
                f = path / f"{f.name}.zstd"
            if not f.exists():
                raise BagError(
                    f"{meta_path} lists {name}, which is not in {path}",
                    hint="a bag directory holds metadata.yaml and every file it lists",
                )
            self._open_file(f, compressed_messages=mode == "message")

    def _open_file(self, path: Path, compressed_messages: bool) -> None:
        if not path.exists():
            raise BagError(f"{path}: no such file or directory")
        if path.suffix == ".zstd":
            path = self._decompressed(path)
        if path.suffix not in STORAGE_SUFFIXES:
            raise BagError(
                f"{path}: not a rosbag2 storage file (.db3 or .mcap)",
                hint="give a rosbag2 bag: its directory, or its .mcap or .db3 file",
            )
        if not compressed_messages and path.suffix == ".db3":
            beside = path.parent / "metadata.yaml"
            if beside.exists():  # a file of a bag whose messages may each be compressed
                try:
                    meta = _metadata(beside)
                except BagError:
                    meta = {}
                compressed_messages = str(meta.get("compression_mode") or "").lower() == "message"
        self.storages.append(_Storage(path, compressed_messages))

    def _decompressed(self, path: Path) -> Path:
        """A file rosbag2 compressed as a whole, decompressed (streamed) into a temporary
        directory that lives as long as the bag is open."""
        import zstandard

        if self._tmp is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="edgerv-bag-")
        out = Path(self._tmp.name) / path.with_suffix("").name
        try:
            with path.open("rb") as src, out.open("wb") as dst:
                zstandard.ZstdDecompressor().copy_stream(src, dst)
        except (OSError, zstandard.ZstdError) as exc:
            raise BagError(f"{path}: cannot decompress: {exc}") from None
        return out

    def _add(
        self,
        recorded: str,
        msgtype: str,
        serialization: str,
        count: int | None,
        definition: Definition | None,
    ) -> None:
        name = topic_name(recorded)
        topic = self.topics.get(name)
        if topic is None:
            topic = self.topics[name] = BagTopic(name, type_name(msgtype), serialization or "cdr")
        topic.recorded.add(recorded)
        topic.types.add(msgtype)
        topic.count = None if topic.count is None or count is None else topic.count + count
        if topic.definition is None and definition is not None:
            topic.definition = definition

    # -- the storage plugins ----------------------------------------------------------------

    def _index(self, storage: _Storage) -> None:
        if storage.path.suffix == ".db3":
            self._index_sqlite(storage.path)
        else:
            self._index_mcap(storage.path)

    def _index_sqlite(self, path: Path) -> None:
        try:
            con = _connect(path)
        except sqlite3.Error as exc:
            raise BagError(f"{path}: cannot read it as a rosbag2 sqlite3 file: {exc}") from None
        try:
            columns = {row[1] for row in con.execute("PRAGMA table_info(topics)")}
            if not {"id", "name", "type"} <= columns:
                raise BagError(f"{path}: not a rosbag2 sqlite3 file (no topics table)")
            fmt = "serialization_format" if "serialization_format" in columns else "'cdr'"
            rows = con.execute(f"SELECT id, name, type, {fmt} FROM topics").fetchall()
            definitions = _sqlite_definitions(con)
            counts = None  # metadata.yaml's, when it has them; else counted here
            if self._metadata_counts is None:
                query = "SELECT topic_id, COUNT(*) FROM messages GROUP BY topic_id"
                counts = dict(con.execute(query).fetchall())
            end = con.execute("SELECT MAX(timestamp) FROM messages").fetchone()[0]
        except sqlite3.Error as exc:
            raise BagError(f"{path}: cannot read it as a rosbag2 sqlite3 file: {exc}") from None
        finally:
            con.close()
        for _id, name, msgtype, fmt_value in rows:
            count = None if counts is None else int(counts.get(_id, 0))
            definition = definitions.get(str(msgtype)) or definitions.get(
                _service_type(str(msgtype))
            )
            self._add(str(name), str(msgtype), str(fmt_value), count, definition)
        if end is not None:
            self.end = max(self.end or end, int(end))

    def _index_mcap(self, path: Path) -> None:
        with path.open("rb") as f:
            if f.read(len(mcap_stream.MAGIC)) != mcap_stream.MAGIC:
                raise BagError(f"{path}: not an MCAP file (it does not start as one)")
        found = mcap_stream.summary(path)
        if found is None or not found.channels:  # cut short, or no summary: read it through
            chans, schemas, end = mcap_stream.channels(path)
            counts = None  # what a damaged file holds past the damage is not known
        else:
            chans, schemas, counts, end, self._chunk_starts[path] = found
        for cid, channel in chans.items():
            schema = schemas.get(channel.schema_id)
            self._add(
                channel.topic,
                schema.name if schema else "",
                channel.message_encoding,
                None if counts is None else int(counts.get(cid, 0)),
                _schema_definition(schema),
            )
        if end is not None:
            self.end = max(self.end or end, end)

    # -- messages ---------------------------------------------------------------------------

    def messages(self, wanted: Collection[str]) -> Iterator[Message]:
        """The messages of the topics ``wanted`` (as :attr:`topics` names them), file by
        file in the bag's order (rosbag2 splits a recording in time), each file's in
        log-time order. Raises :class:`BagError` at damage, with the count of messages
        yielded before it."""
        for item in self.batches(wanted, columns=False):
            assert isinstance(item, list)
            yield from item

    def batches(self, wanted: Collection[str], columns: bool = True) -> Iterator[Batch]:
        """:meth:`messages` a batch at a time: an MCAP file's (whose messages are not
        compressed one by one) as arrays (:func:`mcap_stream.batches`) when ``columns``,
        any other's as lists of messages. At damage, what was read before it comes first."""
        read = 0
        for storage in self.storages:
            if columns and storage.path.suffix == ".mcap" and not storage.compressed_messages:
                try:
                    for batch in self._mcap_batches(storage.path, wanted):
                        read += len(batch[0])
                        yield batch
                except BagError as exc:
                    exc.read = read
                    raise
                continue
            rows: list[Message] = []
            try:
                for message in self._storage_messages(storage, wanted):
                    rows.append(message)
                    if len(rows) >= ROWS_BATCH:
                        read += len(rows)
                        yield rows
                        rows = []
            except BagError as exc:
                if rows:
                    read += len(rows)
                    yield rows
                exc.read = read
                raise
            read += len(rows)
            if rows:
                yield rows

    def _storage_messages(self, storage: _Storage, wanted: Collection[str]) -> Iterator[Message]:
        source = (
            self._sqlite_messages(storage.path, wanted)
            if storage.path.suffix == ".db3"
            else self._mcap_messages(storage.path, wanted)
        )
        for topic, stamp, data in source:
            yield topic, stamp, _unzstd(data) if storage.compressed_messages else data

    def _sqlite_messages(self, path: Path, wanted: Collection[str]) -> Iterator[Message]:
        try:
            con = _connect(path)
        except sqlite3.Error as exc:
            raise BagError(f"{path}: cannot open it: {exc}") from None
        try:
            ids = {
                int(i): topic_name(str(n))
                for i, n in con.execute("SELECT id, name FROM topics")
                if topic_name(str(n)) in wanted
            }
            if not ids:
                return
            marks = ",".join("?" * len(ids))
            cursor = con.execute(
                "SELECT topic_id, timestamp, data FROM messages "
                f"WHERE topic_id IN ({marks}) ORDER BY timestamp, id",
                tuple(ids),
            )
            for topic_id, stamp, data in cursor:
                yield ids[topic_id], int(stamp), bytes(data)
        except sqlite3.Error as exc:
            raise BagError(f"{path}: damaged: {exc}") from None
        finally:
            con.close()

    def _mcap_messages(self, path: Path, wanted: Collection[str]) -> Iterator[Message]:
        with _cut_is_damage(path):
            yield from mcap_stream.messages(
                path, _reads(wanted), starts=self._chunk_starts.get(path)
            )

    def _mcap_batches(
        self, path: Path, wanted: Collection[str]
    ) -> Iterator[tuple[mcap_stream.Batch, dict[int, str]]]:
        with _cut_is_damage(path):
            yield from mcap_stream.batches(
                path, _reads(wanted), starts=self._chunk_starts.get(path)
            )


def _reads(wanted: Collection[str]) -> mcap_stream.Wanted:
    """An MCAP channel's topic as monitors name it, when one of them is ``wanted``."""

    def reads(channel: mcap_stream.Channel) -> str | None:
        name = topic_name(channel.topic)
        return name if name in wanted else None

    return reads


@contextlib.contextmanager
def _cut_is_damage(path: Path) -> Iterator[None]:
    try:
        yield
    except mcap_stream.Cut as exc:
        raise BagError(
            f"{path}: the recording is damaged or cut short: {exc}",
            hint="the verdicts cover the messages before it (a recording cut by a crash "
            "or a full disk ends this way; `ros2 bag reindex` may recover the rest)",
        ) from None


def _metadata(path: Path) -> dict[str, Any]:
    """``metadata.yaml``'s ``rosbag2_bagfile_information``, or a :class:`BagError` that
    names the file."""
    try:
        text = path.read_text(encoding="utf-8")
        data = yaml.safe_load(text)
    except (OSError, UnicodeDecodeError) as exc:
        raise BagError(f"{path}: cannot read it: {exc}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f":{mark.line + 1}:{mark.column + 1}" if mark is not None else ""
        raise BagError(f"{path}{where}: not valid YAML: {getattr(exc, 'problem', exc)}") from None
    info = data.get("rosbag2_bagfile_information") if isinstance(data, dict) else None
    if not isinstance(info, dict):
        raise BagError(
            f"{path}: {'empty' if data is None else 'not'} rosbag2 metadata "
            "(no rosbag2_bagfile_information)",
            hint="give the bag's .db3 or .mcap file instead; `ros2 bag reindex` rewrites "
            "the metadata",
        )
    return info


def _connect(path: Path) -> sqlite3.Connection:
    """Read-only, reading a write-ahead log a recording left beside it (rosbag2's resilient
    preset writes one); where that cannot be opened (a read-only directory), the file as
    it is."""
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        con.execute("SELECT 1 FROM sqlite_master LIMIT 1").fetchall()
        return con
    except sqlite3.OperationalError:
        return sqlite3.connect(f"file:{path}?mode=ro&immutable=1", uri=True)


def _sqlite_definitions(con: sqlite3.Connection) -> dict[str, Definition]:
    """The ``message_definitions`` table (rosbag2 since Iron), by type as recorded."""
    tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    if "message_definitions" not in tables:
        return {}
    out: dict[str, Definition] = {}
    query = "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"
    for msgtype, encoding, text in con.execute(query):
        definition = _definition(str(encoding), text)
        if definition is not None:
            out[str(msgtype)] = definition
    return out


def _service_type(msgtype: str) -> str:
    """A service event's type ``pkg/srv/Name_Event``: the service's, ``pkg/srv/Name``
    (under which rosbag2 keeps its definition); any other type as it is."""
    head, srv, name = msgtype.rpartition("/srv/")
    if srv and name.endswith("_Event") and len(name) > len("_Event"):
        return f"{head}/srv/{name[: -len('_Event')]}"
    return msgtype


def _definition(encoding: str, text: Any) -> Definition | None:
    """A definition as a bag keeps it, if it holds one: ``ros2msg`` or ``ros2idl`` text,
    or a service's (its ``SRV:`` section first), whatever the encoding it names."""
    if not text or not isinstance(text, str):
        return None
    if encoding == "ros2msg":
        return ("ros2msg", text)
    if encoding == "ros2idl":
        return ("ros2idl", text)
    if text.startswith(f"{SEPARATOR}SRV: "):
        return ("unknown", text)
    return None


def _schema_definition(schema: mcap_stream.Schema | None) -> Definition | None:
    if schema is None or not schema.data:
        return None
    try:
        text = schema.data.decode("utf-8")
    except UnicodeDecodeError:
        return None
    return _definition(schema.encoding, text)


def _unzstd(data: bytes) -> bytes:
    import zstandard

    try:
        return bytes(zstandard.ZstdDecompressor().decompress(data))
    except zstandard.ZstdError as exc:
        raise BagError(f"a compressed message cannot be decompressed: {exc}") from None


def looks_like_bag(path: Path) -> bool:
    """Whether ``path`` names a bag rather than a JSON Lines trace."""
    name = path.name
    return (
        path.is_dir()
        or path.suffix in (*STORAGE_SUFFIXES, ".bag")
        or name == "metadata.yaml"
        or name.endswith((".db3.zstd", ".mcap.zstd"))
    )
