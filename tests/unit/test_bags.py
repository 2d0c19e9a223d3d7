"""``edgerv check`` on the bags rosbag2 versions and recorders really write.

Every bag here is written by the test itself, with writers independent of the reader
under test (edgerv's own, :mod:`edgerv.core.bags`): sqlite3 files in rosbag2's layout
by hand (as Foxy to Jazzy wrote them: topic names with and without their slash, old
type names, with and without the ``message_definitions`` table, QoS text in
``metadata.yaml`` that differs from the file's), MCAP files by mcap-ros2-support and
by the ``mcap`` library's raw writer, truncated files. CDR bytes come from
mcap-ros2-support's serializer. Verdicts are compared with the same run checked from
JSON Lines (another reader) and, where it matters, with values computed here.
"""

from __future__ import annotations

import json
import re
import sqlite3
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml
import zstandard

from kit.cli import edgerv
from kit.documents import speed_monitor
from kit.speed_run import MONITORS, RUN, TYPES
from kit.traces import ROS_DEFS, write_jsonl, write_mcap

QOS_IN_FILE = "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 2\n"
QOS_IN_METADATA = (  # as another rosbag2 version wrote the same profile
    "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 2\n  deadline:\n"
    "    sec: 2147483647\n    nsec: 4294967295\n"
)


def cdr(msgtype: str, msg: dict[str, Any], defs: dict[str, str] = ROS_DEFS) -> bytes:
    from mcap_ros2._dynamic import serialize_dynamic

    return bytes(serialize_dynamic(msgtype, defs[msgtype])[msgtype](msg))


Rows = list[tuple[str, int, dict[str, Any]]]


def write_db3(
    path: Path,
    rows: Rows,
    name: Callable[[str], str] = lambda t: t,
    msgtype: Callable[[str], str] = lambda t: t,
    definitions: bool = False,
    compress: bool = False,
    types: dict[str, str] = TYPES,
    defs: dict[str, str] = ROS_DEFS,
) -> Path:
    """A sqlite3 file in rosbag2's layout, written with sqlite3 alone."""
    con = sqlite3.connect(path)
    con.executescript(
        """
        CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
            serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
        CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
            timestamp INTEGER NOT NULL, data BLOB NOT NULL);
        CREATE INDEX timestamp_idx ON messages (timestamp ASC);
        """
    )
    if definitions:
        con.execute(
            "CREATE TABLE message_definitions(id INTEGER PRIMARY KEY, topic_type TEXT NOT NULL,"
            " encoding TEXT NOT NULL, encoded_message_definition TEXT NOT NULL,"
            " type_description_hash TEXT NOT NULL)"
        )
        for t in sorted({types[topic] for topic, _, _ in rows}):
            con.execute(
                "INSERT INTO message_definitions(topic_type, encoding, "
                "encoded_message_definition, type_description_hash) VALUES (?, 'ros2msg', ?, '')",
                (msgtype(t), defs[t]),
            )
    ids: dict[str, int] = {}
    for topic, stamp, msg in rows:
        if topic not in ids:
            ids[topic] = len(ids) + 1
            con.execute(
                "INSERT INTO topics VALUES (?, ?, ?, 'cdr', ?)",
                (ids[topic], name(topic), msgtype(types[topic]), QOS_IN_FILE),
            )
        data = cdr(types[topic], msg, defs)
        if compress:
            data = zstandard.ZstdCompressor().compress(data)
        con.execute(
            "INSERT INTO messages(topic_id, timestamp, data) VALUES (?, ?, ?)",
            (ids[topic], stamp, data),
        )
    con.commit()
    con.close()
    return path


def write_metadata(
    bag: Path,
    rows: Rows,
    files: list[str],
    storage: str = "sqlite3",
    name: Callable[[str], str] = lambda t: t,
    msgtype: Callable[[str], str] = lambda t: t,
    mode: str = "",
) -> None:
    topics = sorted({t for t, _, _ in rows})
    stamps = [s for _, s, _ in rows]
    info = {
        "version": 5,
        "storage_identifier": storage,
        "relative_file_paths": files,
        "duration": {"nanoseconds": max(stamps) - min(stamps)},
        "starting_time": {"nanoseconds_since_epoch": min(stamps)},
        "message_count": len(rows),
        "topics_with_message_count": [
            {
                "topic_metadata": {
                    "name": name(t),
                    "type": msgtype(TYPES[t]),
                    "serialization_format": "cdr",
                    "offered_qos_profiles": QOS_IN_METADATA,
                },
                "message_count": sum(1 for r in rows if r[0] == t),
            }
            for t in topics
        ],
        "compression_format": "zstd" if mode else "",
        "compression_mode": mode,
    }
    (bag / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}))


def check(monitors: Path, trace: Path, *more: str) -> tuple[int, Any, str]:
    proc = edgerv("check", monitors, trace, "--json", *more)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc.returncode, json.loads(proc.stdout) if proc.stdout else None, proc.stderr


@pytest.fixture
def monitors(tmp_path: Path) -> Path:
    path = tmp_path / "monitors.yaml"
    path.write_text(MONITORS)
    return path


@pytest.fixture
def expected(monitors: Path, tmp_path: Path) -> Any:
    """The run's verdicts, read from JSON Lines: another reader than the bags'."""
    code, out, err = check(monitors, write_jsonl(tmp_path / "run.jsonl", RUN))
    assert code == 1, err
    assert out["monitors"][1]["verdicts"][0]["stamp"] == 145  # /target's header stamp
    return out


def bag_dir(tmp_path: Path, label: str) -> Path:
    d = tmp_path / label
    d.mkdir()
    return d


def test_metadata_whose_qos_text_differs_from_the_file_is_read_whole(
    monitors: Path, tmp_path: Path, expected: Any
) -> None:
    """rosbags matched connections by the QoS text and read nothing: exit 0, a pass."""
    bag = bag_dir(tmp_path, "qos")
    write_db3(bag / "qos_0.db3", RUN)
    write_metadata(bag, RUN, ["qos_0.db3"])
    code, out, err = check(monitors, bag)
    assert (code, out) == (1, expected), err
    assert "warning" not in err


@pytest.mark.parametrize("definitions", [False, True])
def test_topics_without_their_slash_and_types_in_the_old_form(
    monitors: Path, tmp_path: Path, expected: Any, definitions: bool
) -> None:
    """Early rosbag2 and some recorders wrote `speed` and `std_msgs/Float64`."""
    bag = bag_dir(tmp_path, "old")

    def name(t: str) -> str:
        return t.lstrip("/")

    def msgtype(t: str) -> str:
        return t.replace("/msg/", "/")

    write_db3(bag / "old_0.db3", RUN, name, msgtype, definitions=definitions)
    write_metadata(bag, RUN, ["old_0.db3"], name=name, msgtype=msgtype)
    code, out, err = check(monitors, bag)
    assert (code, out) == (1, expected), err


def test_a_db3_path_reads_that_file_and_a_metadata_path_reads_its_bag(
    monitors: Path, tmp_path: Path
) -> None:
    bag = bag_dir(tmp_path, "split")
    first, second = RUN[:5], RUN[5:]
    write_db3(bag / "split_0.db3", first)
    write_db3(bag / "split_1.db3", second)
    write_metadata(bag, RUN, ["split_0.db3", "split_1.db3"])
    whole_code, whole, _ = check(monitors, bag)
    via_metadata = check(monitors, bag / "metadata.yaml")
    assert via_metadata[:2] == (whole_code, whole)
    code, part, err = check(monitors, bag / "split_0.db3")
    reference_code, reference, _ = check(monitors, write_jsonl(tmp_path / "first.jsonl", first))
    assert (code, part) == (reference_code, reference), err
    assert sum(len(m["verdicts"]) for m in whole["monitors"]) > sum(
        len(m["verdicts"]) for m in part["monitors"]
    )


def test_message_and_file_compression(monitors: Path, tmp_path: Path, expected: Any) -> None:
    by_message = bag_dir(tmp_path, "message")
    write_db3(by_message / "message_0.db3", RUN, compress=True)
    write_metadata(by_message, RUN, ["message_0.db3"], mode="message")
    assert check(monitors, by_message)[:2] == (1, expected)
    by_file = bag_dir(tmp_path, "file")
    plain = write_db3(tmp_path / "file_0.db3", RUN)
    (by_file / "file_0.db3.zstd").write_bytes(
        zstandard.ZstdCompressor().compress(plain.read_bytes())
    )
    write_metadata(by_file, RUN, ["file_0.db3.zstd"], mode="file")
    before = set(Path(tempfile.gettempdir()).glob("edgerv-bag-*"))
    assert check(monitors, by_file)[:2] == (1, expected)
    assert check(monitors, by_file / "file_0.db3.zstd")[:2] == (1, expected)
    assert set(Path(tempfile.gettempdir()).glob("edgerv-bag-*")) <= before  # no copy left behind


BATTERY = "float32 voltage\nuint8 percent"
BATTERY_MONITOR = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: battery}
spec:
  assertion: "always (percent > 20)"
  signals:
    percent: {topic: /battery, type: robot_msgs/msg/Battery, field: percent}
"""
BATTERY_RUN = [("/battery", 100 + i, {"voltage": 24.0, "percent": 30 - i}) for i in range(15)]


def test_a_type_defined_only_in_the_bag_is_read_from_it(tmp_path: Path) -> None:
    """MCAP schemas and sqlite3's message_definitions carry the .msg text: no
    EDGERV_MSG_PATH needed. Each message with percent <= 20 is a violation."""
    doc = tmp_path / "battery.yaml"
    doc.write_text(BATTERY_MONITOR)
    want = [
        {"verdict": "violated", "stamp": stamp, "step": i + 1}
        for i, (_, stamp, msg) in enumerate(BATTERY_RUN)
        if not msg["percent"] > 20
    ]
    assert len(want) == 5
    from mcap_ros2.writer import Writer

    mcap = tmp_path / "battery.mcap"
    with mcap.open("wb") as f:
        w = Writer(f)
        schema = w.register_msgdef("robot_msgs/msg/Battery", BATTERY)
        for topic, stamp, msg in BATTERY_RUN:
            w.write_message(topic=topic, schema=schema, message=msg, log_time=stamp)
        w.finish()
    code, out, err = check(doc, mcap)
    assert (code, out["monitors"][0]["verdicts"]) == (1, want), err
    db3 = write_db3(
        tmp_path / "battery.db3",
        BATTERY_RUN,
        definitions=True,
        types={"/battery": "robot_msgs/msg/Battery"},
        defs={"robot_msgs/msg/Battery": BATTERY},
    )
    code, out, err = check(doc, db3)
    assert (code, out["monitors"][0]["verdicts"]) == (1, want), err
    bare = write_db3(
        tmp_path / "bare.db3",
        BATTERY_RUN,
        types={"/battery": "robot_msgs/msg/Battery"},
        defs={"robot_msgs/msg/Battery": BATTERY},
    )
    code, _, err = check(doc, bare)  # no definition anywhere: the type is unknown
    assert code == 2 and "unknown message type 'robot_msgs/msg/Battery'" in err


Channel = tuple[str, str, str, str, bytes]


def channels_of(types: dict[str, str]) -> list[Channel]:
    return [(t, "cdr", ty, "ros2msg", ROS_DEFS[ty].encode()) for t, ty in types.items()]


def raw_mcap(
    path: Path, channels: list[Channel], rows: list[tuple[str, int, Any]], **options: Any
) -> Path:
    """An MCAP file by the mcap library's own writer: channels (topic, message
    encoding, schema name, schema encoding, schema text) and rows of messages (dicts,
    serialized to CDR as their channel's schema says, or bytes as they are); ``options``
    for the writer (compression, chunking, summary)."""
    from mcap.writer import Writer

    with path.open("wb") as f:
        w = Writer(f, **options)
        w.start(profile="ros2", library="test")
        ids, schemas = {}, {}
        for topic, encoding, schema, schema_encoding, text in channels:
            sid = w.register_schema(schema, schema_encoding, text)
            ids[topic], schemas[topic] = w.register_channel(topic, encoding, sid), schema
        for topic, stamp, msg in rows:
            data = cdr(schemas[topic], msg) if isinstance(msg, dict) else msg
            w.add_message(ids[topic], log_time=stamp, data=data, publish_time=stamp)
        w.finish()
    return path


@pytest.mark.parametrize(
    "options",
    [
        {"compression": "lz4"},
        {"compression": "none", "chunk_size": 64},
        {"use_chunking": False},
        {"use_statistics": False, "use_summary_offsets": False, "index_types": 0},
    ],
    ids=["lz4", "uncompressed-small-chunks", "unchunked", "no-statistics-no-index"],
)
def test_mcap_files_written_every_way_the_format_allows(
    monitors: Path, tmp_path: Path, expected: Any, options: dict[str, Any]
) -> None:
    from mcap.writer import CompressionType, IndexType

    if "compression" in options:
        options["compression"] = CompressionType[options["compression"].upper()]
    if "index_types" in options:
        options["index_types"] = IndexType(options["index_types"])
    bag = raw_mcap(tmp_path / "any.mcap", channels_of(TYPES), RUN, **options)
    assert check(monitors, bag)[:2] == (1, expected)


def test_an_mcap_written_out_of_log_time_order_is_read_in_it(tmp_path: Path) -> None:
    """A recorder that writes each topic's backlog in turn (as the demo's does, logging
    publication instants) leaves chunks whose times overlap: their messages are merged by
    log time, as rosbag2's own reader does with the file's chunk indexes."""
    doc = tmp_path / "alternate.yaml"
    doc.write_text(
        "apiVersion: edgerv.io/v1alpha1\nkind: Monitor\nmetadata: {name: alternate}\nspec:\n"
        '  assertion: "always (a -> b)"\n'
        "  signals:\n"
        "    a: {topic: /running, type: std_msgs/msg/Bool, initial: false}\n"
        "    b: {topic: /stop, type: std_msgs/msg/Bool, initial: false}\n"
    )
    # /running and /stop alternate in time; written a topic's 50 messages at a time
    rows: Rows = []
    for batch in range(4):
        for topic, offset in (("/running", 0), ("/stop", 5)):
            rows += [
                (topic, 1000 * (batch * 50 + i) + offset, {"data": i % 3 == 0}) for i in range(50)
            ]
    bag = raw_mcap(tmp_path / "backlogs.mcap", channels_of(TYPES), rows, chunk_size=200)
    in_time = sorted(rows, key=lambda r: r[1])
    assert in_time != rows
    code, out, err = check(doc, bag)
    reference_code, reference, _ = check(doc, write_jsonl(tmp_path / "in_time.jsonl", in_time))
    assert (code, out) == (reference_code, reference), err
    assert out["monitors"][0]["verdicts"], "a property that the order decides"


@pytest.mark.parametrize(
    ("encoding", "text"),
    [
        ("unknown", b""),  # rosbag2 finds no .msg nor .idl of a pkg/srv/X_Event type
        ("ros2msg", b"int64 a\nint64 b\n---\nint64 sum\n"),  # a .srv's text
    ],
)
def test_a_bag_with_service_events_is_read_for_its_topics(
    monitors: Path, tmp_path: Path, expected: Any, encoding: str, text: bytes
) -> None:
    """`ros2 bag record --all` in Jazzy records service events (pkg/srv/Name_Event), with
    a schema nobody can parse (rosbags refused the whole bag: KeyError 'unknown')."""
    event = "/add_two_ints/_service_event"
    channels = [
        *channels_of(TYPES),
        (event, "cdr", "example_interfaces/srv/AddTwoInts_Event", encoding, text),
    ]
    rows = [*RUN[:3], (event, 116, b"\x00\x01\x00\x00"), *RUN[3:]]
    bag = raw_mcap(tmp_path / "services.mcap", channels, rows)
    assert check(monitors, bag)[:2] == (1, expected)


def test_a_topic_in_another_serialization_is_refused_when_monitored(
    monitors: Path, tmp_path: Path
) -> None:
    channels = channels_of(TYPES)
    channels[2] = ("/speed", "json", "std_msgs/msg/Float64", "jsonschema", b"{}")
    rows: list[tuple[str, int, Any]] = [(t, s, m) for t, s, m in RUN if t != "/speed"]
    rows.append(("/speed", 200, b'{"data": 1.0}'))
    code, _, err = check(monitors, raw_mcap(tmp_path / "json.mcap", channels, rows))
    assert code == 2 and "/speed is recorded in the 'json' serialization" in err


def test_a_truncated_mcap_gives_the_verdicts_up_to_the_cut(tmp_path: Path) -> None:
    """A recording cut by a crash: no summary, no end magic, its last chunk cut. The
    verdicts cover every message of the chunks before the cut."""
    doc = tmp_path / "speed.yaml"
    doc.write_text(speed_monitor("speed", onVerdict="halt"))
    # 99 up to the 300th message, then 500: violated at step 301
    rows: Rows = [("/speed", 1000 + i, {"data": 99.0 if i < 300 else 500.0}) for i in range(400)]
    from mcap_ros2.writer import Writer

    bag = tmp_path / "cut.mcap"
    with bag.open("wb") as f:
        w = Writer(f, chunk_size=256)
        schema = w.register_msgdef("std_msgs/msg/Float64", "float64 data")
        for topic, stamp, msg in rows:
            w.write_message(topic=topic, schema=schema, message=msg, log_time=stamp)
        w.finish()
    data = bag.read_bytes()
    bag.write_bytes(data[: int(len(data) * 0.95)])  # only its summary is cut: all is there
    code, out, err = check(doc, bag)
    _, whole, _ = check(doc, write_jsonl(tmp_path / "whole.jsonl", rows))
    assert (code, out) == (1, whole), err
    bag.write_bytes(data[: int(len(data) * 0.6)])  # in the data: indexes make a third
    code, out, err = check(doc, bag)
    assert code == 2 and "damaged or cut short" in err, err
    m = re.search(r"damaged after message (\d+)", err)
    assert m, err
    read = int(m.group(1))
    assert 301 <= read < 400  # the violation's chunk is whole, the file's end is not
    _, reference, _ = check(doc, write_jsonl(tmp_path / "prefix.jsonl", rows[:read]))
    assert out == reference
    assert out["monitors"][0]["verdicts"][0] == {"verdict": "violated", "stamp": 1300, "step": 301}


def test_a_monitored_topic_without_messages_is_named_with_what_the_bag_has(
    monitors: Path, tmp_path: Path
) -> None:
    rows = [("/sped" if t == "/speed" else t, s, m) for t, s, m in RUN]
    types = {("/sped" if t == "/speed" else t): ty for t, ty in TYPES.items()}
    bag = raw_mcap(tmp_path / "typo.mcap", channels_of(types), rows)
    code, out, err = check(monitors, bag)
    assert code == 0, err  # target-reached still reads /target, and is satisfied
    assert out["monitors"][0]["state"] == "pending"  # speed-limit saw only /running, /stop
    assert "warning: no message on /speed was read (monitors reading it: speed-limit)" in err
    assert "it has /sped (std_msgs/msg/Float64)" in err
    strict, _, err = check(monitors, bag, "--strict")
    assert strict == 2 and "--strict" in err


def test_nothing_read_is_never_a_pass(monitors: Path, tmp_path: Path) -> None:
    rows = [("/ignored", 100 + i, {"data": "x"}) for i in range(3)]
    code, out, err = check(monitors, write_jsonl(tmp_path / "other.jsonl", rows))
    assert code == 2 and "nothing was checked" in err
    assert all(m["state"] == "pending" for m in out["monitors"])
    assert "it has no such topic; it has /ignored" in err
    bag = write_mcap(tmp_path / "other.mcap", rows, TYPES)
    code, _, err = check(monitors, bag)
    assert code == 2 and "nothing was checked" in err


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("", "empty rosbag2 metadata"),
        ("just: text\n", "not rosbag2 metadata"),
        ("rosbag2_bagfile_information: [\n", "not valid YAML"),
    ],
)
def test_bad_metadata_is_named(monitors: Path, tmp_path: Path, content: str, message: str) -> None:
    bag = bag_dir(tmp_path, "bad")
    write_db3(bag / "bad_0.db3", RUN)
    (bag / "metadata.yaml").write_text(content)
    code, _, err = check(monitors, bag)
    assert code == 2 and message in err and "metadata.yaml" in err, err


def test_a_ros1_bag_is_refused_with_the_way_to_convert_it(monitors: Path, tmp_path: Path) -> None:
    bag = tmp_path / "old.bag"
    bag.write_bytes(b"#ROSBAG V2.0\n")
    code, _, err = check(monitors, bag)
    assert code == 2 and "rosbags-convert" in err


def test_fields_read_from_cdr_give_what_decoded_messages_give(tmp_path: Path) -> None:
    """`edgerv check` reads a bag's fields straight from CDR (the live handler's readers);
    decoding whole messages (rosbags) gives the same verdicts, header stamps included."""
    from edgerv.core.checker import CheckRun
    from edgerv.core.documents import load_monitors_text
    from edgerv.core.monitor import compile_monitor
    from edgerv.core.traces import Trace

    monitors = [compile_monitor(s) for s in load_monitors_text("m.yaml", MONITORS)]
    bag = write_mcap(tmp_path / "run.mcap", RUN, TYPES)

    def verdicts(cdr: bool) -> list[list[tuple[str, int, int]]]:
        run = CheckRun(monitors)
        trace = Trace(bag)
        run.feed(trace.events(run.topics, fields=run.fields() if cdr else None))
        return [[(v.verdict, v.stamp, v.step) for v in r.verdicts] for r in run.finish(trace.end)]

    assert verdicts(cdr=True) == verdicts(cdr=False)
    assert verdicts(cdr=True)[1] == [("satisfied", 145, 2)]  # /target's header stamp


def test_messages_left_in_a_write_ahead_log_are_read(monitors: Path, tmp_path: Path) -> None:
    """A recording killed with sqlite3's write-ahead log not yet merged (rosbag2's
    resilient preset writes one): the messages in the log are part of the bag."""
    import shutil

    first, later = RUN[:4], RUN[4:]
    db = write_db3(tmp_path / "live.db3", first)
    writer = sqlite3.connect(db)
    writer.execute("PRAGMA journal_mode=WAL")
    ids = dict(writer.execute("SELECT name, id FROM topics"))
    for topic, stamp, msg in later:
        if topic not in ids:
            ids[topic] = len(ids) + 1
            writer.execute(
                "INSERT INTO topics VALUES (?, ?, ?, 'cdr', '')", (ids[topic], topic, TYPES[topic])
            )
        writer.execute(
            "INSERT INTO messages(topic_id, timestamp, data) VALUES (?, ?, ?)",
            (ids[topic], stamp, cdr(TYPES[topic], msg)),
        )
    writer.commit()
    crashed = bag_dir(tmp_path, "crashed")
    for suffix in ("", "-wal", "-shm"):  # as the killed recorder left them
        shutil.copy(f"{db}{suffix}", crashed / f"run_0.db3{suffix}")
    writer.close()
    code, out, err = check(monitors, crashed / "run_0.db3")
    reference = check(monitors, write_jsonl(tmp_path / "all.jsonl", RUN))
    assert (code, out) == reference[:2], err


@pytest.mark.parametrize("name", ["junk.db3", "junk.mcap", "junk.mcap.zstd"])
def test_a_file_that_is_no_bag_is_named(monitors: Path, tmp_path: Path, name: str) -> None:
    junk = tmp_path / name
    junk.write_bytes(b"this is not a recording\n" * 100)
    code, out, err = check(monitors, junk)
    assert code == 2 and out is None and "cannot read bag" in err and name in err, err
