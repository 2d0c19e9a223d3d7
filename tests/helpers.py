"""Small builders for tests: Monitor documents from Python values, runs from event lists."""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections.abc import Iterable, Iterator, Sequence
from types import FrameType
from typing import Any

import yaml

from edgerv.core.checker import CheckRun, MonitorResult
from edgerv.core.diagnostics import Location
from edgerv.core.documents import MonitorSpec, load_monitors_text
from edgerv.core.monitor import CompiledMonitor, compile_monitor
from edgerv.core.pipeline import MonitorRuntime
from edgerv.core.traces import TraceEvent

TYPES = {
    "bool": "std_msgs/msg/Bool",
    "float": "std_msgs/msg/Float64",
    "int": "std_msgs/msg/Int32",
    "string": "std_msgs/msg/String",
}


def monitor_doc(name: str, assertion: str, signals: dict[str, Any], **spec: Any) -> dict[str, Any]:
    """A Monitor document; a signal given as a kind name ('bool', 'float', ...) reads /<name>."""
    sigs = {}
    for sname, sig in signals.items():
        sigs[sname] = {"topic": f"/{sname}", "type": TYPES[sig]} if isinstance(sig, str) else sig
    return {
        "apiVersion": "edgerv.io/v1alpha1",
        "kind": "Monitor",
        "metadata": {"name": name},
        "spec": {"assertion": assertion, "signals": sigs, **spec},
    }


# libyaml's emitter when PyYAML has it: the same text as the pure-Python one (a fifth of
# the time), and thousands of monitors are built here
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


def spec_of(assertion: str, signals: dict[str, Any], name: str = "m", **spec: Any) -> MonitorSpec:
    doc = monitor_doc(name, assertion, signals, **spec)
    text = yaml.dump(doc, Dumper=_DUMPER, sort_keys=False)
    return load_monitors_text("test.yaml", text)[0]


def compiled(assertion: str, signals: dict[str, Any], **spec: Any) -> CompiledMonitor:
    return compile_monitor(spec_of(assertion, signals, **spec))


def events(rows: Iterable[Sequence[Any]]) -> list[TraceEvent]:
    """Events from (topic, stamp, value) rows; the value becomes msg.data."""
    return [
        TraceEvent(topic, stamp, {"data": value}, Location("test", i + 1))
        for i, (topic, stamp, value) in enumerate(rows)
    ]


def run(monitors: Sequence[CompiledMonitor], evs: Iterable[TraceEvent]) -> list[MonitorResult]:
    """A check over the events; its clock ends at their last stamp (any topic), as a
    trace's does."""
    evs = list(evs)
    check = CheckRun(monitors)
    check.feed(evs)
    return check.finish(max((e.stamp for e in evs), default=None))


def truth_at(changes: list[tuple[int, bool]], t: int) -> bool:
    """A truth given as (instant, value from then on) changes, at instant ``t``."""
    value = changes[0][1]
    for at, v in changes:
        if at > t:
            break
        value = v
    return value


def step_truths(
    formula: str, signals: dict[str, Any], rows: Sequence[tuple[str, int, Any]], end: int
) -> list[tuple[int, bool]]:
    """(stamp, truth) of a formula without future operators at each step a monitor of
    ``always (formula)`` takes over the (topic, stamp, value) rows, one event each, its
    clock advanced to ``end`` (with reset, ``always`` is violated at each step where the
    formula is false)."""
    m = compiled(f"always ({formula})", signals)
    rt = MonitorRuntime(m)
    index = {name: i for i, name in enumerate(m.signal_names)}
    for seq, (topic, stamp, value) in enumerate(rows):
        rt.offer(stamp, seq, [(index[topic[1:]], value)])
    rt.advance(end)
    stamps = list(rt.stamps)
    violated = {v.step for v in rt.evaluate() if v.verdict == "violated"}
    return [(t, i + 1 not in violated) for i, t in enumerate(stamps)]


def verdicts(result: MonitorResult) -> list[tuple[str, int, int]]:
    return [(v.verdict, v.step, v.stamp) for v in result.verdicts]


class Hang(BaseException):
    """A call ran past its time (:func:`bounded`): a BaseException, so that no ``except
    Exception`` in the code under test eats it."""


@contextlib.contextmanager
def bounded(seconds: float) -> Iterator[None]:
    """Fail with :class:`Hang` instead of hanging (main thread only: SIGALRM)."""

    def expire(signum: int, frame: FrameType | None) -> None:
        raise Hang(f"no answer within {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


class ManualClock:
    """An engine's clock (handler.engine.Clock) that moves only when told, or, with
    ``running``, as the real one does plus what it was told."""

    def __init__(self, running: bool = False) -> None:
        self.running = running
        self.offset = 0.0 if running else 1000.0

    def monotonic(self) -> float:
        return self.offset + (time.monotonic() if self.running else 0.0)

    def wall_ns(self) -> int:
        return int(self.offset * 1e9) + (time.time_ns() if self.running else 1_700_000_000 * 10**9)

    def advance(self, seconds: float) -> None:
        self.offset += seconds


@contextlib.contextmanager
def robot_feed(engines: Sequence[Any]) -> Iterator[None]:
    """Every engine hears the robot's two topics while the block runs: /a (true) and /x
    (0 to 6) half a millisecond of stamps apart, a pair every 2 ms, from a thread."""
    stop = threading.Event()

    def publish() -> None:
        stamp = 0
        while not stop.is_set():
            stamp += 1_000_000
            batch = [(stamp, "/a", [True]), (stamp + 500_000, "/x", [float(stamp % 7)])]
            for e in engines:
                e.ingest(batch)
            time.sleep(0.002)

    feeder = threading.Thread(target=publish, daemon=True)
    feeder.start()
    try:
        yield
    finally:
        stop.set()
        feeder.join()


PROPERTY_EXAMPLES = int(os.environ.get("EDGERV_PROPERTY_EXAMPLES", "0"))


def scaled(count: int) -> int:
    """A random test's count of seeds or runs: ``count`` in the unit tier (derandomized),
    ``$EDGERV_PROPERTY_EXAMPLES`` under ``make fuzz``."""
    return PROPERTY_EXAMPLES or count


def props(examples: int) -> Any:
    """Hypothesis settings of the property tests: ``examples`` derandomized examples (CI),
    or ``$EDGERV_PROPERTY_EXAMPLES`` random ones (``make fuzz``)."""
    from hypothesis import HealthCheck, settings

    return settings(
        max_examples=PROPERTY_EXAMPLES or examples,
        deadline=None,
        derandomize=not PROPERTY_EXAMPLES,
        database=None,
        print_blob=True,
        suppress_health_check=[
            HealthCheck.too_slow,
            HealthCheck.data_too_large,
            HealthCheck.filter_too_much,
        ],
    )


# -- one run, recorded three ways: JSON Lines, a rosbag2 MCAP file, a rosbag2 sqlite3 file --
# Each writer is independent of the readers under test (edgerv.core.traces, .bags,
# .mcap_stream): json, mcap-ros2-support, sqlite3 with mcap-ros2-support's CDR serializer.
# Rows are (topic, stamp in ns, message as a dict); a bag logs each message at its stamp.
# (test_cli.py and test_bags.py have their own, with the types of their runs.)

ROS_DEFS = {  # the definitions rosbag2 records for the types of TYPES
    "std_msgs/msg/Bool": "bool data",
    "std_msgs/msg/Float64": "float64 data",
    "std_msgs/msg/Int32": "int32 data",
    "std_msgs/msg/String": "string data",
}

Rows = Sequence[tuple[str, int, dict[str, Any]]]


def write_jsonl(path: str | os.PathLike[str], rows: Rows) -> None:
    """A JSON Lines trace, one event a line in the rows' order."""
    import json

    with open(path, "w") as f:
        f.writelines(json.dumps({"topic": t, "stamp": s, "msg": m}) + "\n" for t, s, m in rows)


def write_mcap(
    path: str | os.PathLike[str],
    rows: Rows,
    types: dict[str, str],
    chunk_size: int = 1 << 20,
) -> None:
    """A rosbag2 MCAP file by mcap-ros2-support, in the rows' order; ``types``: each
    topic's message type (one of :data:`ROS_DEFS`); ``chunk_size`` in bytes (small: many
    chunks, a chunk boundary between messages of one stamp)."""
    from mcap_ros2.writer import Writer

    with open(path, "wb") as f:
        writer = Writer(f, chunk_size=chunk_size)
        schemas = {t: writer.register_msgdef(t, ROS_DEFS[t]) for t in sorted(set(types.values()))}
        for topic, stamp, msg in rows:
            schema = schemas[types[topic]]
            writer.write_message(topic, schema, msg, log_time=stamp, publish_time=stamp)
        writer.finish()  # type: ignore[no-untyped-call]


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
