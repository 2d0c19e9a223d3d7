"""Sim time and replay's pace, without ROS traffic: the /clock samples a handler keeps
(edgerv.handler.clock), the ROS time it reads from them, an engine stepping its timed
monitors by that time, and the schedule ``edgerv replay`` publishes by
(edgerv.handler.ros.replay.Schedule). The same with real processes and DDS:
tests/integration/test_replay_time.py and test_sim_clock.py."""

from __future__ import annotations

import contextlib
import io
import time

import pytest

from edgerv.cli import main
from edgerv.core.documents import load_monitors_text
from edgerv.core.monitor import compile_monitor
from edgerv.handler.clock import NO_TIME, ClockSamples, SimClock, clock_ns
from edgerv.handler.engine import Engine
from edgerv.handler.ros.replay import Schedule
from kit.engines import ManualClock

S = 1_000_000_000
MS = 1_000_000


# -- the samples -------------------------------------------------------------------------


def test_ros_time_is_what_the_last_clock_said_at_or_before_an_instant() -> None:
    samples = ClockSamples()
    assert samples.at_source(100) is None and samples.at_received(100) is None
    for source, received, ros in ((100, 150, 5 * S), (200, 260, 6 * S), (300, 350, 7 * S)):
        assert samples.add(source, received, ros) is None
    assert [samples.at_source(t) for t in (99, 100, 199, 200, 250, 300, 10**12)] == [
        None, 5 * S, 5 * S, 6 * S, 6 * S, 7 * S, 7 * S,
    ]  # fmt: skip
    assert [samples.at_received(t) for t in (149, 150, 259, 260, 349, 350)] == [
        None, 5 * S, 5 * S, 6 * S, 6 * S, 7 * S,
    ]  # fmt: skip
    assert samples.newest == 7 * S


def test_a_clock_that_goes_back_is_said_and_followed() -> None:
    samples = ClockSamples()
    samples.add(100, 100, 9 * S)
    assert samples.add(200, 200, 2 * S) == 9 * S  # (a reset: the time before it)
    assert samples.newest == 2 * S and samples.at_source(250) == 2 * S


def test_a_sample_of_another_publisher_a_little_behind_goes_in_its_place() -> None:
    samples = ClockSamples()
    samples.add(100, 100, 1 * S)
    samples.add(300, 300, 3 * S)
    samples.add(200, 310, 2 * S)  # published before the last one, received after it
    assert samples.at_source(250) == 2 * S and samples.at_source(300) == 3 * S
    assert samples.at_received(305) == 3 * S and samples.at_received(310) == 2 * S


def test_old_samples_are_forgotten_and_an_instant_before_them_reads_the_oldest() -> None:
    samples = ClockSamples(keep=1.0)
    for i in range(200):  # 100 ms apart: 20 s
        samples.add(i * 100 * MS, i * 100 * MS, i * S)
    assert len(samples.sources) <= 65 and samples.forgotten  # (trimmed past 64)
    assert samples.at_source(0) == samples.by_source[0]  # approximate, not None
    assert samples.at_source(199 * 100 * MS) == 199 * S


def test_a_serialized_clock_message_is_read_in_either_byte_order() -> None:
    little = b"\x00\x01\x00\x00" + (5).to_bytes(4, "little") + (7).to_bytes(4, "little")
    big = b"\x00\x00\x00\x00" + (5).to_bytes(4, "big") + (7).to_bytes(4, "big")
    assert clock_ns(little) == clock_ns(big) == 5 * S + 7
    with pytest.raises(ValueError, match="not a CDR"):
        clock_ns(b"\x00\x01")


def test_clock_ns_reads_what_rclpy_serializes() -> None:
    serialization = pytest.importorskip("rclpy.serialization")
    clock_msg = pytest.importorskip("rosgraph_msgs.msg").Clock
    msg = clock_msg()
    msg.clock.sec, msg.clock.nanosec = 1_700_000_000, 123_456_789
    raw = serialization.serialize_message(msg)
    assert clock_ns(raw) == 1_700_000_000 * S + 123_456_789


# -- the handler's time ----------------------------------------------------------------


def test_an_unstamped_message_gets_the_clock_published_last_before_it() -> None:
    clock = SimClock(0.5)
    assert clock.published(50) == 0  # before any /clock: 0, as a ROS node's clock reads
    assert clock.unclocked == 1
    clock.samples.add(100, 120, 10 * S)
    clock.samples.add(200, 220, 11 * S)
    assert clock.published(100) == 10 * S  # the /clock the replay sent just before it
    assert clock.published(199) == 10 * S
    assert clock.published(5000) == 11 * S


def test_the_engine_reads_the_clock_received_flush_after_ago_plus_flush_after() -> None:
    """So it steps its monitors up to the /clock time of --flush-after ago, in real time:
    whatever /clock's pace, and up to its last time once it stops."""
    clock = SimClock(0.5)
    now = time.time_ns()
    assert clock.ros_ns(now) == NO_TIME  # nothing received: no clock step
    clock.samples.add(now - 2 * S, now - 2 * S, 100 * S)
    clock.samples.add(now - S, now - S, 102 * S)  # twice real time
    clock.samples.add(now - 100 * MS, now - 100 * MS, 103_800 * MS)
    assert clock.ros_ns(now) == 102 * S + 500 * MS  # received 0.5 s ago: 102 s
    assert clock.ros_ns(now + 400 * MS) == 103_800 * MS + 500 * MS  # it stopped: its last
    assert clock.now_ns() == 103_800 * MS


def cdr_clock(ns: int) -> bytes:
    sec, nanosec = divmod(ns, S)
    return b"\x00\x01\x00\x00" + sec.to_bytes(4, "little") + nanosec.to_bytes(4, "little")


def test_samples_are_taken_where_time_is_read_and_the_nodes_clock_follows() -> None:
    """The ROS layer hands the clock a take function; each read of time takes what came
    (a bad sample counted, the rest taken at the next read), and the node's clock is
    given each newer time."""
    now = time.time_ns()
    waiting = [
        (cdr_clock(7 * S), {"source_timestamp": now - 2 * S, "received_timestamp": now - 2 * S}),
        (b"junk", {"source_timestamp": now - S, "received_timestamp": now - S}),
        (cdr_clock(8 * S), {"source_timestamp": now - S, "received_timestamp": 0}),
    ]
    followed: list[int] = []
    clock = SimClock(0.5)
    clock.attach(lambda: waiting.pop(0) if waiting else None, followed.append)
    assert clock.now_ns() == 7 * S and clock.failures == 1 and followed == [7 * S]
    assert clock.published(now - S // 2) == 8 * S  # taken at this read (received: now)
    assert followed == [7 * S, 8 * S] and not waiting
    clock.detach()
    waiting.append((cdr_clock(9 * S), {"source_timestamp": now, "received_timestamp": now}))
    assert clock.now_ns() == 8 * S  # detached (the node is going): nothing taken


TIMED = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: beat}
spec:
  assertion: "always (age(beat) < 1s)"
  signals:
    beat: {topic: /beat, type: std_msgs/msg/Bool}
"""


def test_an_engine_on_sim_time_steps_its_monitors_by_clock_not_by_the_system_clock() -> None:
    """A beat at ROS time 100 s; /clock says 100.5 s, then 101.5 s: the violation at
    101 s comes once the engine's time (the clock received --flush-after ago) passes it,
    stamped 101 s; the system clock, years ahead, plays no part."""
    (spec,) = load_monitors_text("timed.yaml", TIMED)
    clock = SimClock(0.2)
    engine = Engine("h", clock=clock, flush_after=0.2)
    engine.put(compile_monitor(spec), active=True)
    engine.ingest([(100 * S, "/beat", [True])], now=0.0)
    now = time.time_ns()
    clock.samples.add(now - S, now - S, 100_500 * MS)
    assert engine.tick() == []  # 100.5 s: not yet
    clock.samples.add(now - 300 * MS, now - 300 * MS, 101_500 * MS)  # 0.3 s ago: in
    (verdict,) = engine.tick()
    assert (verdict.verdict, verdict.step, verdict.stamp) == ("violated", 2, 101 * S)


def test_the_system_clock_engine_is_as_before() -> None:
    """Without --use-sim-time the engine reads its injected clock (here a manual one)."""
    (spec,) = load_monitors_text("timed.yaml", TIMED)
    manual = ManualClock()
    engine = Engine("h", clock=manual, flush_after=0.2)
    engine.put(compile_monitor(spec), active=True)
    start = manual.wall_ns()
    engine.ingest([(start, "/beat", [True])], now=manual.monotonic())
    manual.advance(1.3)
    (verdict,) = engine.tick()
    assert (verdict.step, verdict.stamp) == (2, start + S)


# -- replay's schedule -------------------------------------------------------------------


def test_the_recorded_pace_and_a_rate() -> None:
    stamps = [10 * S, 10 * S + 100 * MS, 11_500 * MS]
    assert [Schedule(stamps).due(i) for i in range(3)] == [0.0, 0.1, 1.5]
    assert [Schedule(stamps, rate=2).due(i) for i in range(3)] == [0.0, 0.05, 0.75]
    assert [Schedule(stamps, interval=0.01).due(i) for i in range(3)] == [0.0, 0.01, 0.02]


def test_clock_between_messages_runs_at_the_pace_and_never_reaches_the_next_stamp() -> None:
    sched = Schedule([10 * S, 12 * S], rate=2)  # 2 s recorded, 1 s replayed
    assert sched.time_at(1, 0.0) == 10 * S
    assert sched.time_at(1, 0.25) == 10_500 * MS
    assert sched.time_at(1, 5.0) == 12 * S - 1
    stretched = Schedule([10 * S, 12 * S], interval=0.1)  # 2 s in 0.1 s
    assert stretched.time_at(1, 0.05) == 11 * S


def test_time_runs_on_to_the_traces_last_stamp_after_the_last_message() -> None:
    sched = Schedule([10 * S, 11 * S], end=14 * S)
    assert sched.last == 14 * S and sched.finish == 4.0
    assert sched.time_at(2, 2.0) == 12 * S
    assert Schedule([10 * S, 11 * S], end=None).finish == 1.0
    assert Schedule([10 * S, 11 * S], interval=0.1, end=14 * S).finish == pytest.approx(0.2)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--rate", "0"], "argument --rate: '0' is not a rate above 0"),
        (["--rate", "inf"], "argument --rate: 'inf' is not a rate above 0"),
        (["--rate", "2", "--interval", "0.1"], "not allowed with argument"),
        (["--interval", "-1"], "argument --interval: '-1' is not a number of seconds from 0"),
    ],
)
def test_bad_pace_flags_exit_2_naming_the_flag(args: list[str], message: str) -> None:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), pytest.raises(SystemExit) as exit_:
        main(["replay", "--monitors", "m.yaml", "run.jsonl", *args])
    assert exit_.value.code == 2
    assert message in err.getvalue()
