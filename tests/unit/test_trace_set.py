"""Several traces checked as one run (``edgerv check monitors a.mcap b.jsonl dir/``).

The reference is the same run written as one JSON Lines file, read by the
single-trace reader: the traces' events merged in stamp order must give its verdicts.
"""

from __future__ import annotations

import json
import random
from pathlib import Path
from typing import Any

import pytest

from kit.cli import edgerv
from kit.speed_run import MONITORS, TYPES
from kit.traces import write_jsonl, write_mcap

Row = tuple[str, int, dict[str, Any]]


def random_run(seed: int, n: int = 300) -> list[Row]:
    """A run in stamp order, every stamp distinct (the merge's order is then the run's)."""
    rng = random.Random(seed)
    rows: list[Row] = []
    stamp = 1_000
    for _ in range(n):
        stamp += rng.randint(1, 40)
        topic = rng.choice(["/running", "/speed", "/speed", "/stop", "/target"])
        if topic == "/speed":
            msg: dict[str, Any] = {"data": rng.choice([20.0, 95.0, 120.0])}
        elif topic == "/target":
            msg = {
                "header": {"stamp": {"sec": 0, "nanosec": stamp}, "frame_id": "map"},
                "point": {"x": rng.choice([1.0, 9.0, 10.0]), "y": 0.0, "z": 0.0},
            }
        else:
            msg = {"data": rng.random() < (0.8 if topic == "/running" else 0.2)}
        rows.append((topic, stamp, msg))
    return rows


def check(monitors: Path, *traces: Path) -> tuple[int, Any, str]:
    """Exit code, --json output and stderr of a check of ``traces``."""
    proc = edgerv("check", "--json", monitors, *traces)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc.returncode, json.loads(proc.stdout) if proc.stdout else None, proc.stderr


@pytest.fixture
def monitors(tmp_path: Path) -> Path:
    return write_text(tmp_path / "monitors.yaml", MONITORS)


def write_text(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.mark.parametrize("seed", range(4))
def test_traces_split_by_topic_and_by_time_give_the_verdicts_of_the_whole(
    monitors: Path, tmp_path: Path, seed: int
) -> None:
    rows = random_run(seed)
    whole = check(monitors, write_jsonl(tmp_path / "whole.jsonl", rows))
    assert len(whole[1]["monitors"][0]["verdicts"]) >= 3, whole  # the run decides something
    # by topic: one recorder per subsystem, some bags, some JSON Lines
    rng = random.Random(seed)
    parts: list[Path] = []
    for topic in ["/running", "/speed", "/stop", "/target"]:
        mine = [r for r in rows if r[0] == topic]
        name = topic.strip("/")
        if rng.random() < 0.5:
            parts.append(write_mcap(tmp_path / f"{name}.mcap", mine, TYPES))
        else:
            parts.append(write_jsonl(tmp_path / f"{name}.jsonl", mine))
    rng.shuffle(parts)  # the order named matters only between equal stamps: none here
    assert check(monitors, *parts) == whole
    # by time: consecutive recordings, named in any order
    cut = len(rows) // 3
    first = write_mcap(tmp_path / "first.mcap", rows[:cut], TYPES)
    second = write_jsonl(tmp_path / "second.jsonl", rows[cut:])
    assert check(monitors, second, first) == whole


def test_a_directory_of_bags_is_checked_as_one_run(monitors: Path, tmp_path: Path) -> None:
    rows = random_run(7)
    whole = check(monitors, write_jsonl(tmp_path / "whole.jsonl", rows))
    recordings = tmp_path / "recordings"
    recordings.mkdir()
    for i, topic in enumerate(["/running", "/speed", "/stop"]):
        bag = recordings / f"rosbag2_{i}"
        bag.mkdir()
        write_mcap(bag / f"rosbag2_{i}_0.mcap", [r for r in rows if r[0] == topic], TYPES)
    write_jsonl(recordings / "target.jsonl", [r for r in rows if r[0] == "/target"])
    (recordings / "notes.txt").write_text("not a trace: left alone\n")
    assert check(monitors, recordings) == whole


def test_equal_stamps_go_in_the_order_the_traces_are_named(monitors: Path, tmp_path: Path) -> None:
    # speed 120 and stop at the same instant: which comes first decides the verdict
    base: list[Row] = [("/running", 10, {"data": True}), ("/speed", 20, {"data": 50.0})]
    a = write_jsonl(tmp_path / "a.jsonl", [("/speed", 30, {"data": 120.0})])
    b = write_jsonl(tmp_path / "b.jsonl", [("/stop", 30, {"data": True})])
    start = write_jsonl(tmp_path / "start.jsonl", base)
    for named in ([start, a, b], [start, b, a]):
        rows = base + [r for p in named[1:] for r in _read(p)]
        reference = check(monitors, write_jsonl(tmp_path / "ref.jsonl", rows))
        assert check(monitors, *named)[:2] == reference[:2]  # (stderr: /target is absent)
    assert check(monitors, start, a, b)[1] != check(monitors, start, b, a)[1]


def _read(path: Path) -> list[Row]:
    return [
        (r["topic"], r["stamp"], r["msg"]) for r in map(json.loads, path.read_text().splitlines())
    ]


def test_a_topic_recorded_as_two_types_is_an_error_naming_both(
    monitors: Path, tmp_path: Path
) -> None:
    from mcap_ros2.writer import Writer

    other = tmp_path / "other.mcap"
    with other.open("wb") as f:
        writer = Writer(f)
        schema = writer.register_msgdef("std_msgs/msg/Int32", "int32 data")
        writer.write_message(
            topic="/speed", schema=schema, message={"data": 3}, log_time=5, publish_time=5
        )
        writer.finish()
    mine = write_mcap(tmp_path / "mine.mcap", random_run(1), TYPES)
    code, out, err = check(monitors, mine, other)
    assert code == 2 and out is None
    assert "/speed is recorded as std_msgs/msg/Int32 here and as std_msgs/msg/Float64" in err
    assert str(other) in err and str(mine) in err


def test_what_no_trace_has_is_named_once_and_strict_refuses_it(
    monitors: Path, tmp_path: Path
) -> None:
    rows = [r for r in random_run(2) if r[0] in ("/running", "/speed")]
    a = write_jsonl(tmp_path / "a.jsonl", [r for r in rows if r[0] == "/running"])
    b = write_mcap(tmp_path / "b.mcap", [r for r in rows if r[0] == "/speed"], TYPES)
    code, out, err = check(monitors, a, b)
    assert code in (0, 1) and out is not None
    assert err.count("no message on /target was read from any of the 2 traces") == 1, err
    assert "/stop" in err and "/running was read" not in err and "/speed was read" not in err
    strict = edgerv("check", monitors, a, b, "--strict")
    assert strict.returncode == 2, strict.stderr


def test_bad_input_among_several_traces_is_named_at_its_place(
    monitors: Path, tmp_path: Path
) -> None:
    rows = random_run(3)
    good = write_mcap(tmp_path / "good.mcap", [r for r in rows if r[0] != "/speed"], TYPES)
    speeds = [r for r in rows if r[0] == "/speed"]
    bad = tmp_path / "speed.jsonl"
    lines = [json.dumps({"topic": t, "stamp": s, "msg": m}) for t, s, m in speeds]
    lines[10] = '{"topic": "/speed", "stamp": 99999, "msg": {"data": "fast"}}'
    bad.write_text("\n".join(lines) + "\n")
    code, out, err = check(monitors, good, bad)
    assert code == 2, err
    assert f"{bad}:11" in err and "the verdicts above cover the events before it" in err
    assert out is not None  # the verdicts up to the error
    for args, message in (
        ((tmp_path / "empty",), "a directory without metadata.yaml"),
        ((good, good), "named twice"),
        ((tmp_path / "absent.mcap",), "no such file"),
    ):
        (tmp_path / "empty").mkdir(exist_ok=True)
        proc = edgerv("check", monitors, *args)
        assert proc.returncode == 2 and message in proc.stderr, proc.stderr
        assert "Traceback" not in proc.stderr
