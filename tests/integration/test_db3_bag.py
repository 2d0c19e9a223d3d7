"""A rosbag2 sqlite3 bag whose messages were serialized by real ROS 2 (rclpy) gives the
same verdicts as the equivalent JSON Lines trace.

The bag is written here, by hand, in rosbag2's sqlite3 layout (tables ``topics``
and ``messages``, and ``metadata.yaml``) with CDR bytes from
``rclpy.serialization.serialize_message``: a writer independent of the
library edgerv reads bags with.
"""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from kit.speed_run import MONITORS, RUN, TYPES
from kit.traces import write_jsonl

pytestmark = pytest.mark.integration

import rclpy.serialization as rclpy_serialization  # noqa: E402  (real ROS 2 is installed)


def ros_message(msg_type: str, fields: dict[str, Any]) -> Any:
    from geometry_msgs.msg import PointStamped
    from std_msgs.msg import Bool, Float64, String

    if msg_type == "geometry_msgs/msg/PointStamped":
        m = PointStamped()
        m.header.stamp.sec = fields["header"]["stamp"]["sec"]
        m.header.stamp.nanosec = fields["header"]["stamp"]["nanosec"]
        m.header.frame_id = fields["header"]["frame_id"]
        m.point.x, m.point.y, m.point.z = (fields["point"][k] for k in "xyz")
        return m
    cls = {
        "std_msgs/msg/Bool": Bool,
        "std_msgs/msg/Float64": Float64,
        "std_msgs/msg/String": String,
    }[msg_type]
    return cls(data=fields["data"])


def write_db3_bag(directory: Path, rows: list[tuple[str, int, dict[str, Any]]]) -> Path:
    directory.mkdir()
    db = sqlite3.connect(directory / "run_0.db3")
    db.executescript(
        "CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);"
        "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,"
        " serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);"
        "CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,"
        " timestamp INTEGER NOT NULL, data BLOB NOT NULL);"
        "INSERT INTO schema VALUES (3, 'jazzy');"
    )
    topic_ids = {t: i for i, t in enumerate(TYPES, start=1)}
    for topic, i in topic_ids.items():
        db.execute("INSERT INTO topics VALUES (?, ?, ?, 'cdr', '')", (i, topic, TYPES[topic]))
    for topic, stamp, fields in rows:
        data = rclpy_serialization.serialize_message(ros_message(TYPES[topic], fields))
        db.execute(
            "INSERT INTO messages (topic_id, timestamp, data) VALUES (?, ?, ?)",
            (topic_ids[topic], stamp, data),
        )
    db.commit()
    db.close()
    counts = {t: sum(1 for r in rows if r[0] == t) for t in TYPES}
    start, end = min(r[1] for r in rows), max(r[1] for r in rows)
    topics = "".join(
        f"    - topic_metadata: {{name: {t}, type: {TYPES[t]}, serialization_format: cdr,"
        f" offered_qos_profiles: ''}}\n      message_count: {counts[t]}\n"
        for t in TYPES
    )
    (directory / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  version: 4\n  storage_identifier: sqlite3\n"
        f"  duration: {{nanoseconds: {end - start}}}\n"
        f"  starting_time: {{nanoseconds_since_epoch: {start}}}\n"
        f"  message_count: {len(rows)}\n  topics_with_message_count:\n{topics}"
        "  compression_format: ''\n  compression_mode: ''\n"
        "  relative_file_paths: [run_0.db3]\n"
    )
    return directory


def edgerv_json(monitors: Path, trace: Path) -> tuple[int, Any]:
    proc = subprocess.run(
        [sys.executable, "-m", "edgerv", "check", str(monitors), str(trace), "--json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc.returncode, json.loads(proc.stdout)


def test_db3_bag_gives_the_same_verdicts_as_jsonl(tmp_path: Path) -> None:
    monitors = tmp_path / "monitors.yaml"
    monitors.write_text(MONITORS)
    bag = write_db3_bag(tmp_path / "run_bag", RUN)
    expected = edgerv_json(monitors, write_jsonl(tmp_path / "run.jsonl", RUN))
    assert expected[0] == 1
    assert edgerv_json(monitors, bag) == expected
    assert edgerv_json(monitors, bag / "run_0.db3") == expected  # the .db3 file itself
