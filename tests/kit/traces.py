"""One run, recorded three ways: JSON Lines, a rosbag2 MCAP file, a rosbag2 sqlite3 file.

Each writer is independent of the readers under test (edgerv.core.traces, .bags,
.mcap_stream): json, mcap-ros2-support, sqlite3 with mcap-ros2-support's CDR serializer.
Rows are (topic, stamp in ns, message as a dict); a bag logs each message at its stamp.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

SEP = "=" * 80 + "\n"  # between the definitions of a type and of the types it holds

ROS_DEFS = {  # the definitions rosbag2 records (ros2msg), in the order MCAP gets them
    "std_msgs/msg/Bool": "bool data",
    "std_msgs/msg/Float64": "float64 data",
    "std_msgs/msg/Int32": "int32 data",
    "std_msgs/msg/String": "string data",
    "geometry_msgs/msg/PointStamped": (
        f"std_msgs/Header header\ngeometry_msgs/Point point\n{SEP}MSG: std_msgs/Header\n"
        f"builtin_interfaces/Time stamp\nstring frame_id\n{SEP}MSG: builtin_interfaces/Time\n"
        f"int32 sec\nuint32 nanosec\n{SEP}MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z"
    ),
}

Rows = Sequence[tuple[str, int, dict[str, Any]]]


def write_jsonl(path: str | os.PathLike[str], rows: Rows) -> Path:
    """A JSON Lines trace, one event a line in the rows' order: its path."""
    with open(path, "w") as f:
        f.writelines(json.dumps({"topic": t, "stamp": s, "msg": m}) + "\n" for t, s, m in rows)
    return Path(path)


def write_mcap(
    path: str | os.PathLike[str],
    rows: Rows,
    types: dict[str, str],
    chunk_size: int = 1 << 20,
) -> Path:
    """A rosbag2 MCAP file by mcap-ros2-support, in the rows' order, not by the library
    edgerv reads with: its path. ``types``: each topic's message type (one of
    :data:`ROS_DEFS`; each type of ``types`` gets its schema, in ROS_DEFS' order);
    ``chunk_size`` in bytes (small: many chunks, a chunk boundary between messages of one
    stamp)."""
    from mcap_ros2.writer import Writer

    with open(path, "wb") as f:
        writer = Writer(f, chunk_size=chunk_size)
        used = set(types.values())
        schemas = {t: writer.register_msgdef(t, d) for t, d in ROS_DEFS.items() if t in used}
        for topic, stamp, msg in rows:
            schema = schemas[types[topic]]
            writer.write_message(topic, schema, msg, log_time=stamp, publish_time=stamp)
        writer.finish()  # type: ignore[no-untyped-call]
    return Path(path)


def write_db3(path: str | os.PathLike[str], rows: Rows, types: dict[str, str]) -> None:
    """A rosbag2 sqlite3 file (Jazzy's tables, with ``message_definitions``) by sqlite3
    alone, its messages inserted in the rows' order; CDR bytes from mcap-ros2-support."""
    import sqlite3

    from mcap_ros2._dynamic import serialize_dynamic

    encoders = {t: serialize_dynamic(t, ROS_DEFS[t])[t] for t in set(types.values())}
    con = sqlite3.connect(path)
    try:
        con.executescript(
            """
            CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
                serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL,
                type_description_hash TEXT NOT NULL);
            CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
                timestamp INTEGER NOT NULL, data BLOB NOT NULL);
            CREATE INDEX timestamp_idx ON messages (timestamp ASC);
            CREATE TABLE message_definitions(id INTEGER PRIMARY KEY, topic_type TEXT NOT NULL,
                encoding TEXT NOT NULL, encoded_message_definition TEXT NOT NULL,
                type_description_hash TEXT NOT NULL);
            """
        )
        for t in sorted(set(types.values())):
            con.execute(
                "INSERT INTO message_definitions(topic_type, encoding, "
                "encoded_message_definition, type_description_hash) VALUES (?, 'ros2msg', ?, '')",
                (t, ROS_DEFS[t]),
            )
        ids: dict[str, int] = {}
        for topic, stamp, msg in rows:
            if topic not in ids:
                ids[topic] = len(ids) + 1
                con.execute(
                    "INSERT INTO topics VALUES (?, ?, ?, 'cdr', '', '')",
                    (ids[topic], topic, types[topic]),
                )
            con.execute(
                "INSERT INTO messages(topic_id, timestamp, data) VALUES (?, ?, ?)",
                (ids[topic], stamp, bytes(encoders[types[topic]](msg))),
            )
        con.commit()
    finally:
        con.close()
