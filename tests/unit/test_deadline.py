"""--deadline: the option, the stamp out of the CDR bytes, the makespan window, its reports."""

from __future__ import annotations

import json
import random
import time

import pytest
from prometheus_client import generate_latest

from edgerv.core.cdr import header_stamp_ns
from edgerv.core.deadline import DeadlineOption, MakespanWindow, parse_deadline, percentile
from edgerv.core.diagnostics import InputError
from edgerv.core.documents import load_monitors_text
from edgerv.core.monitor import CompiledMonitor, compile_monitor
from edgerv.core.msgtypes import starts_with_header, typestore
from edgerv.handler.engine import Engine
from edgerv.handler.metrics import build_registry
from edgerv.handler.reading import load_report
from edgerv_operator.documents import document_text, instance_document

MS = 1_000_000
S = 1_000_000_000


def test_the_option_reads_a_topic_and_a_duration_of_the_assertion_language() -> None:
    assert parse_deadline("/cmd_vel=125ms") == DeadlineOption("/cmd_vel", 125 * MS)
    # a relative name: the robot's (a handler running no robot's monitors: the root's)
    assert parse_deadline("cmd_vel = 0.1s") == DeadlineOption("/cmd_vel", 100 * MS, True)
    assert parse_deadline("/a/b=1500us") == DeadlineOption("/a/b", 1_500_000)


@pytest.mark.parametrize(
    ("text", "error"),
    [
        ("/cmd_vel", "--deadline: error: '/cmd_vel' is not TOPIC=DURATION"),
        ("/cmd_vel=", "--deadline: error: '/cmd_vel=' is not TOPIC=DURATION"),
        ("=125ms", "--deadline: error: '=125ms' is not TOPIC=DURATION"),
        ("/cmd vel=125ms", "--deadline: error: '/cmd vel' is not a ROS topic name"),
        ("/cmd_vel=125", "--deadline: error: '125' is not a duration"),
        ("/cmd_vel=125 ms", "--deadline: error: '125 ms' is not a duration"),
        ("/cmd_vel=2h", "--deadline: error: '2h' is not a duration"),
        ("/cmd_vel=0ms", "--deadline: error: the deadline of /cmd_vel must be longer than 0"),
    ],
)
def test_a_bad_option_is_a_located_error(text: str, error: str) -> None:
    with pytest.raises(InputError) as exc:
        parse_deadline(text)
    assert str(exc.value).startswith(error)


def test_a_duration_error_lists_the_units() -> None:
    with pytest.raises(InputError, match=r"hint: a number and its unit .*ns, us, ms, s, min"):
        parse_deadline("/cmd=fast")


def twist_stamped(sec: int, nanosec: int, little_endian: bool = True) -> bytes:
    store = typestore()
    t = store.types
    vector = t["geometry_msgs/msg/Vector3"]
    msg = t["geometry_msgs/msg/TwistStamped"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id="camera"
        ),
        twist=t["geometry_msgs/msg/Twist"](
            linear=vector(x=0.5, y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=0.1)
        ),
    )
    return bytes(
        store.serialize_cdr(msg, "geometry_msgs/msg/TwistStamped", little_endian=little_endian)
    )


@pytest.mark.parametrize("little_endian", [True, False])
def test_the_stamp_is_read_from_the_cdr_bytes_in_either_byte_order(little_endian: bool) -> None:
    raw = twist_stamped(1_700_000_000, 999_999_999, little_endian)
    assert header_stamp_ns(raw) == 1_700_000_000 * S + 999_999_999
    assert header_stamp_ns(twist_stamped(-2, 5, little_endian)) == -2 * S + 5
    with pytest.raises(ValueError, match="at least 12 bytes"):
        header_stamp_ns(raw[:11])


def test_only_types_that_start_with_a_header_carry_the_stamp() -> None:
    assert starts_with_header("geometry_msgs/msg/TwistStamped")
    assert starts_with_header("sensor_msgs/LaserScan")
    assert not starts_with_header("geometry_msgs/msg/Twist")
    assert not starts_with_header("std_msgs/msg/Header")  # it is one, it does not start with one
    assert starts_with_header("nav_msgs/msg/Path")
    assert not starts_with_header("nosuch_msgs/msg/Thing")
    assert not starts_with_header("not a type")


def test_the_window_reads_count_misses_percentiles_max_and_last() -> None:
    w = MakespanWindow("/cmd", 125 * MS)
    assert w.stats(0).count == 0 and w.report(0)["p95Ms"] is None
    spans = [100, 110, 120, 130, 140, 90, 150, 100, 105, 126]  # ms, published every 50 ms
    for i, span in enumerate(spans):
        published = 10 * S + i * 50 * MS
        assert w.add(published, published - span * MS, taken_ns=i * 50 * MS)
    s = w.stats(len(spans) * 50 * MS)
    ordered = sorted(spans)
    assert (s.count, s.misses) == (10, 4)  # 126, 130, 140, 150 > 125
    assert (s.p50, s.p95, s.max, s.last) == (
        ordered[4] * MS,
        ordered[9] * MS,
        150 * MS,
        126 * MS,
    )
    assert w.report(len(spans) * 50 * MS) == {
        "topic": "/cmd",
        "budgetMs": 125.0,
        "windowSeconds": 2.0,
        "count": 10,
        "misses": 4,
        "p50Ms": 110.0,
        "p95Ms": 150.0,
        "maxMs": 150.0,
        "lastMs": 126.0,
        # outputs 50 ms apart, inputs 90-150 ms before: each waited for the one before
        # but the first (its whole 100 ms), so each is served in 50 ms
        "serviceP95Ms": 100.0,
        "missesTotal": 4,
        "messagesTotal": 10,
    }


@pytest.mark.parametrize("seed", range(8))
def test_service_times_are_the_makespans_without_the_backlog(seed: int) -> None:
    """A loop that serves its inputs one at a time, in order (an input every period,
    captured at its stamp; each served for its service time after the later of its
    capture and the previous output): while it is slower than its inputs its outputs
    queue and their makespans grow, but the window's service p95 is that of the service
    times the loop was given, whatever the backlog; and with no backlog, the makespans'."""
    rng = random.Random(seed)
    period = 125 * MS
    served = [rng.randrange(80, 170) * MS for _ in range(16)]  # some slower than the period
    w = MakespanWindow("/cmd", period, window_ns=60 * S)
    published, spans = 0, []
    for k, service in enumerate(served):
        stamp = 10 * S + k * period
        published = max(stamp, published) + service
        spans.append(published - stamp)
        w.add(published, stamp, taken_ns=k)
    got = w.stats(len(served))
    assert got.p95 == percentile(sorted(spans), 0.95)
    assert got.service_p95 == percentile(sorted(served), 0.95)
    if any(a != b for a, b in zip(spans, served, strict=True)):
        assert got.p95 is not None and got.p95 > got.service_p95  # (the backlog's)


def test_a_makespan_equal_to_the_budget_is_no_miss() -> None:
    w = MakespanWindow("/cmd", 125 * MS)
    w.add(S, S - 125 * MS, 0)
    w.add(S + 1, S + 1 - 125 * MS - 1, 0)
    assert (w.stats(0).misses, w.misses_total) == (1, 1)


def test_percentiles_are_nearest_rank() -> None:
    rng = random.Random(5)
    for n in range(1, 60):
        values = sorted(rng.randrange(1000) for _ in range(n))
        for q in (0.5, 0.95):
            p = percentile(values, q)
            # nearest rank: the smallest value with at least q of the values at or below it
            assert sum(v <= p for v in values) >= q * n
            assert sum(v < p for v in values) < q * n


def test_the_window_slides_over_two_seconds_of_publish_time() -> None:
    w = MakespanWindow("/cmd", 125 * MS)
    for i in range(60):  # 3 s at 20 Hz: 140 ms old stamps, then 50 ms old ones
        published = 100 * S + i * 50 * MS
        w.add(published, published - (140 if i < 20 else 50) * MS, taken_ns=i * 50 * MS)
        if i == 19:
            assert w.stats(i * 50 * MS).misses == 20
    s = w.stats(59 * 50 * MS)
    assert s.count == 40 and s.misses == 0 and s.p95 == 50 * MS  # the first second has left
    assert (w.misses_total, w.messages_total) == (20, 60)


def test_a_task_that_stops_publishing_leaves_the_window_by_the_handlers_clock() -> None:
    """Its clock and the robot's need not agree: the window ends at the newest publish
    time plus the time since that message was taken here."""
    w = MakespanWindow("/cmd", 125 * MS)
    robot = 1_000 * S  # the robot's clock, far from the handler's monotonic one
    for i in range(40):  # 2 s at 20 Hz
        w.add(robot + i * 50 * MS, robot + i * 50 * MS - 200 * MS, taken_ns=7 * S + i * 50 * MS)
    taken_last = 7 * S + 39 * 50 * MS
    assert w.stats(taken_last).count == 40
    assert w.stats(taken_last + S).count == 20  # a second later, half of it is 2 s old
    assert w.stats(taken_last + 2 * S).count == 0
    assert w.report(taken_last + 2 * S)["missesTotal"] == 40


def test_an_unstamped_header_is_not_measured() -> None:
    w = MakespanWindow("/cmd", 125 * MS)
    assert not w.add(5 * S, 0, 0)
    assert (w.unstamped, w.messages_total, w.stats(0).count) == (1, 0, 0)


def test_the_window_is_bounded() -> None:
    w = MakespanWindow("/cmd", 125 * MS, max_entries=100)
    for i in range(1000):
        w.add(S + i * 1000, S + i * 1000 - MS, 0)
    assert w.stats(0).count == 100 and w.messages_total == 1000


def test_the_load_report_and_the_metrics_carry_the_reading() -> None:
    plain = Engine("h")
    assert load_report(plain)["deadline"] is None
    assert b"edgerv_deadline" not in generate_latest(build_registry(plain, dict))
    window = MakespanWindow("/cmd_vel", 125 * MS)
    engine = Engine("h", deadline=window)
    now = time.monotonic_ns()
    for i in range(10):
        published = 50 * S + i * 50 * MS
        window.add(published, published - (140 if i % 2 else 100) * MS, now)
    load = json.loads(json.dumps(load_report(engine)))
    assert load["deadline"]["topic"] == "/cmd_vel"
    assert (load["deadline"]["count"], load["deadline"]["misses"]) == (10, 5)
    assert load["deadline"]["p95Ms"] == 140.0
    text = generate_latest(build_registry(engine, dict)).decode()
    assert 'edgerv_deadline_makespan_p95_seconds{topic="/cmd_vel"} 0.14' in text
    assert 'edgerv_deadline_misses_total{topic="/cmd_vel"} 5.0' in text
    assert 'edgerv_deadline_messages_total{topic="/cmd_vel"} 10.0' in text
    assert 'edgerv_deadline_budget_seconds{topic="/cmd_vel"} 0.125' in text


def instance(robot: str) -> CompiledMonitor:
    """An instance of a Monitor for ``robot``, as the operator writes it."""
    signal = {"topic": "/a", "type": "std_msgs/msg/Bool"}
    spec = {"assertion": "always (data)", "signals": {"data": signal}}
    text = document_text(instance_document("lab", "m", spec, robot))
    return compile_monitor(load_monitors_text("instance.json", text)[0])


def test_a_relative_topic_is_measured_in_the_namespace_of_the_robot_whose_monitors_run(
) -> None:  # fmt: skip
    """``--deadline cmd_vel=125ms`` on a fleet's edge handler: the robot's /amr_7/cmd_vel,
    the robot being the one whose instances the handler runs (a handler running no robot's
    monitors, or several robots': the root's /cmd_vel). An absolute name is as given."""
    option = parse_deadline("cmd_vel=125ms")
    assert option.relative and not parse_deadline("/cmd_vel=125ms").relative
    window = MakespanWindow(option.topic, option.budget_ns, relative=True)
    assert (window.resolved(None), window.resolved("/amr_7")) == ("/cmd_vel", "/amr_7/cmd_vel")
    assert MakespanWindow("/cmd_vel", 125 * MS).resolved("/amr_7") == "/cmd_vel"
    engine = Engine("edge", flush_after=1e9)
    assert engine.robot_namespace() is None
    engine.put(instance("amr-7"), active=False)
    assert engine.robot_namespace() == "/amr_7"
    engine.put(instance("amr-8"), active=True)
    assert engine.robot_namespace() is None  # several robots': a shared handler's
    engine.remove("lab.m.amr-8")
    assert engine.robot_namespace() == "/amr_7"


def test_a_window_moved_to_another_topic_starts_empty_and_keeps_its_totals() -> None:
    window = MakespanWindow("/cmd_vel", 100 * MS, relative=True)
    now = time.monotonic_ns()
    window.add(10 * S, 10 * S - 150 * MS, now)
    window.retarget("/amr_7/cmd_vel")
    report = window.report(now)
    assert (report["topic"], report["count"], report["missesTotal"]) == ("/amr_7/cmd_vel", 0, 1)
    assert window.name == "/cmd_vel"  # as --deadline named it
