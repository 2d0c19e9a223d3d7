"""What the handler publishes for ROS 2's own tools: its health on /diagnostics
(diagnostic_msgs/msg/DiagnosticArray) and its log lines on /rosout (rcl_interfaces/msg/Log).

A real ``edgerv handler`` process and real publishers; this test's own rclpy node
listens as ``ros2 topic echo``, rqt_robot_monitor and rqt_console would.
"""

from __future__ import annotations

import logging
import subprocess
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402
from rcl_interfaces.msg import Log  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.serialization import deserialize_message  # noqa: E402

from edgerv.core.documents import load_monitors_text  # noqa: E402
from edgerv.core.monitor import compile_monitor  # noqa: E402
from edgerv.handler.engine import Engine  # noqa: E402
from edgerv.handler.health import DiagnosticsConfig, Health, Level, read_engine  # noqa: E402
from edgerv.handler.ros.cdr_out import encode_diagnostic_array  # noqa: E402
from edgerv.handler.ros.rosout import RosoutHandler  # noqa: E402
from kit.documents import monitor_yaml, speed_monitor  # noqa: E402
from kit.ros import HandlerProcess, own_node, publisher, wait_for  # noqa: E402

pytestmark = pytest.mark.integration

SPEED_CAP = speed_monitor("speed-cap", sortThreshold=1)
SPEED_OK = speed_monitor("speed-ok", "always (speed < 1e9)", sortThreshold=1)
NOBODY = monitor_yaml(
    "nobody-publishes",
    "always (x < 1)",
    {"x": {"topic": "/nobody", "type": "std_msgs/msg/Float64"}},
)

BAD = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: broken}
spec:
  assertion: "always (speed <"
  signals:
    speed: {topic: /speed, type: std_msgs/msg/Float64}
"""

ROSOUT_QOS = QoSProfile(  # as rqt_console and `ros2 topic echo /rosout` subscribe
    depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)


@dataclass
class Heard:
    """What the listener received, with its arrival time (monotonic)."""

    arrays: list[tuple[float, Any]] = field(default_factory=list)
    logs: list[Any] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)
    subscription: Any = None  # on /diagnostics

    def matched(self) -> bool:
        """A handler's /diagnostics publisher reaches this listener (discovery between
        processes takes a few seconds: what is published before is not heard)."""
        return bool(self.subscription.get_publisher_count() > 0)

    def statuses(self, name: str) -> list[tuple[float, Any]]:
        """Each status named ``name``, with the arrival of its array."""
        with self.lock:
            return [(at, s) for at, a in self.arrays for s in a.status if s.name == name]

    def first(self, name: str, level: bytes, after: float = 0.0) -> tuple[float, Any] | None:
        return next(
            ((at, s) for at, s in self.statuses(name) if s.level == level and at > after), None
        )

    def latest(self, name: str) -> Any:
        got = self.statuses(name)
        return got[-1][1] if got else None

    def log_lines(self) -> list[Any]:
        with self.lock:
            return list(self.logs)


@pytest.fixture
def heard(domain: int) -> Iterator[Heard]:
    """A node of this test's own on /diagnostics and /rosout (as the tools subscribe)."""
    got = Heard()

    def on_array(msg: Any) -> None:
        with got.lock:
            got.arrays.append((time.monotonic(), msg))

    def on_log(msg: Any) -> None:
        with got.lock:
            got.logs.append(msg)

    with own_node(domain, "ros_outputs_listener") as node:
        got.subscription = node.create_subscription(DiagnosticArray, "/diagnostics", on_array, 100)
        node.create_subscription(Log, "/rosout", on_log, ROSOUT_QOS)
        yield got


def values(status: Any) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def write(tmp: Path, name: str, text: str) -> Path:
    path = tmp / name
    path.write_text(text)
    return path


def finish(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.communicate(timeout=10)


OK, WARN, ERROR, STALE = (bytes([level]) for level in Level)


def test_a_violation_is_error_at_once_and_ok_again_after_the_hold(
    tmp_path: Path, domain: int, heard: Heard
) -> None:
    """One violating message among good ones: the monitor's status turns ERROR as soon as
    the verdict is reached (not at the next periodic update: the period here is 60 s),
    with the violation in its message and values, and back to OK when the hold is over,
    again at once."""
    h = HandlerProcess(
        tmp_path,
        write(tmp_path, "m.yaml", SPEED_CAP),
        domain,
        "--diagnostics-period", "60", "--diagnostics-hold", "2", "--diagnostics-stale", "0",
    )  # fmt: skip
    name = "edgerv: speed-cap"
    pub = None
    try:
        assert wait_for(heard.matched, timeout=15)
        # one violation, with good messages after it: the monitor goes on stepping
        good, bad = {"data": 1.0}, {"data": 150.0}
        sent = [good] * 20 + [bad] + [good] * 300
        pub = publisher(domain, "/speed", "std_msgs/msg/Float64", sent, interval=0.02)
        verdict = wait_for(lambda: h.verdicts(), timeout=30)
        assert [(v["verdict"], v["step"]) for v in verdict] == [("violated", 21)]
        reached = time.monotonic()
        error = wait_for(lambda: heard.first(name, ERROR), timeout=10)
        assert error is not None, heard.statuses(name)
        at, status = error
        assert at - reached < 1.5  # at once: the next periodic update is a minute away
        stamp = verdict[0]["stamp"]
        stamp_text = f"{stamp // 10**9}.{stamp % 10**9:09d}"
        assert status.message.startswith(f"violated at step 21 (stamp {stamp_text})")
        assert status.hardware_id == "edge"
        v = values(status)
        assert v["violations"] == "1" and v["satisfactions"] == "0"
        assert v["last verdict"] == "violated at step 21"
        assert v["last verdict stamp"] == stamp_text
        assert int(v["events"]) >= 21 and int(v["step"]) >= 21
        assert v["dropped events"] == "0" and v["late events"] == "0"
        assert v["tier"] == "lowest" and v["epoch"] == "0" and v["topics"] == "/speed"
        assert v["migration wanted"] == "no"
        assert v["buffer fill"].endswith("of 4096)")
        # the hold (2 s) ends: OK again, published at once (the period is 60 s)
        ok = wait_for(lambda: heard.first(name, OK, after=at), timeout=10)
        assert ok is not None, heard.statuses(name)
        assert 1.5 <= ok[0] - at <= 3.5
        assert ok[1].message.startswith(
            f"pending (last verdict: violated at step 21 (stamp {stamp_text}))"
        )
        assert values(ok[1])["violations"] == "1"
    finally:
        if pub is not None:
            finish(pub)
        h.stop()


def test_a_topic_without_publisher_is_warn_then_the_silent_monitor_goes_stale(
    tmp_path: Path, domain: int, heard: Heard
) -> None:
    """A monitor whose topic nobody publishes: WARN once the handler has counted the
    topic's publishers (about a second), then STALE when it has had no event for
    --diagnostics-stale: STALE outranks WARN, whose reason stays in the message."""
    h = HandlerProcess(
        tmp_path, write(tmp_path, "m.yaml", NOBODY), domain,
        "--diagnostics-period", "0.5", "--diagnostics-stale", "4",
    )  # fmt: skip
    name = "edgerv: nobody-publishes"
    try:
        warn = wait_for(lambda: heard.first(name, WARN), timeout=15)
        assert warn is not None, heard.statuses(name)
        assert warn[1].message == "no publisher on /nobody"
        assert values(warn[1])["events"] == "0"
        stale = wait_for(lambda: heard.first(name, STALE), timeout=15)
        assert stale is not None, heard.statuses(name)
        assert stale[1].message == "no event for over 4 s; no publisher on /nobody"
        # nothing in between: it was WARN, then STALE (never OK: the topic stayed silent)
        levels = [s.level for _, s in heard.statuses(name)]
        assert OK not in levels[levels.index(WARN) :]
    finally:
        h.stop()


def test_the_handlers_own_status_comes_every_period(
    tmp_path: Path, domain: int, heard: Heard
) -> None:
    """`edgerv handler: <name>`, about once a period, with the handler's counters; a
    monitor on a topic that is published (100 messages a second, none violating) is OK,
    with its events per second."""
    h = HandlerProcess(
        tmp_path, write(tmp_path, "m.yaml", SPEED_OK), domain, "--diagnostics-period", "0.5"
    )
    pub = publisher(domain, "/speed", "std_msgs/msg/Float64", [], interval=0.01, forever=True)
    try:

        def flowing() -> bool:
            status = heard.latest("edgerv handler: edge")
            return status is not None and int(values(status)["messages"]) > 50

        assert wait_for(flowing, timeout=30)
        start = time.monotonic()
        time.sleep(3.0)
        handler = [(at, s) for at, s in heard.statuses("edgerv handler: edge") if at >= start]
        assert 4 <= len(handler) <= 8  # every 0.5 s (a level change adds one)
        status = handler[-1][1]
        assert status.level == OK and status.hardware_id == "edge"
        v = values(status)
        assert v["monitors active"] == "1" and v["monitors defined"] == "1"
        assert 40 <= float(v["messages per second"]) <= 150  # 100 a second are sent
        assert v["messages lost"] == "0" and v["bad messages"] == "0"
        assert v["ingest lag"].endswith(" s")
        assert v["log lines not sent to /rosout"] == "0"
        assert status.message.startswith("1 of 1 monitors active, ")
        monitor = heard.latest("edgerv: speed-ok")
        assert monitor.level == OK and monitor.message == "pending"
        assert 40 <= float(values(monitor)["events per second"]) <= 150
    finally:
        finish(pub)
        h.stop()


def test_the_handlers_log_lines_reach_rosout_under_the_nodes_name(
    tmp_path: Path, domain: int, heard: Heard
) -> None:
    """The error it logs for a monitor document it cannot load (at start: /rosout keeps
    lines for late subscribers) and the line it logs when a monitor is added through the
    API, with their levels, places and the node's name; stderr is as it always was."""
    monitors = tmp_path / "monitors"
    monitors.mkdir()
    write(monitors, "good.yaml", SPEED_CAP)
    write(monitors, "bad.yaml", BAD)
    h = HandlerProcess(tmp_path, monitors, domain)
    try:
        status, _ = h.request("POST", "/v1/monitors", NOBODY)
        assert status == 201

        def line(text: str) -> Any:
            return next((m for m in heard.log_lines() if text in m.msg), None)

        problem = wait_for(lambda: line("problem(s) above"), timeout=15)
        assert problem is not None, [m.msg for m in heard.log_lines()]
        assert problem.name == "edgerv_edge" and problem.level == Log.ERROR
        assert problem.file.endswith("main.py") and problem.function == "run"
        added = wait_for(lambda: line("added nobody-publishes"), timeout=15)
        assert added is not None, [m.msg for m in heard.log_lines()]
        assert added.name == "edgerv_edge" and added.level == Log.INFO
        assert added.file.endswith("api.py")
    finally:
        h.stop()
    err = h.stderr
    assert "ERROR edgerv.handler: 2 problem(s) above" in err  # Python's format, as before
    assert "INFO edgerv.handler.api: added nobody-publishes" in err
    assert "[INFO] [" not in err and "[ERROR] [" not in err  # ROS's console: not twice


# -- in this process: the CDR the handler writes, the log handler's failures ---------------


def _statuses() -> list[Any]:
    engine = Engine("bord-é")
    for spec in load_monitors_text("m.yaml", SPEED_CAP + "---\n" + NOBODY):
        engine.put(compile_monitor(spec), active=True)
    engine.ingest([(10**9 + i, "/speed", [150.0 if i == 2 else 1.0]) for i in range(5)])
    health = Health("bord-é", DiagnosticsConfig())  # a UTF-8 name: two bytes for a char
    health.write("edge", engine.tick())
    health.check(read_engine(engine, publishers={"/nobody": 0}), 0.0)
    statuses = health.statuses()
    assert {s.level for s in statuses} == {Level.OK, Level.WARN, Level.ERROR}
    return statuses


def test_the_diagnostic_array_the_handler_writes_is_the_one_rclpy_would() -> None:
    """The handler serializes its DiagnosticArray itself (at a fraction of rclpy's cost):
    rclpy reads back exactly the message built with its own classes."""
    statuses = _statuses()
    ours = deserialize_message(
        encode_diagnostic_array(statuses, 1_732_541_234_500_000_001), DiagnosticArray
    )
    expected = DiagnosticArray()
    expected.header.stamp.sec, expected.header.stamp.nanosec = 1_732_541_234, 500_000_001
    expected.status = [
        DiagnosticStatus(level=bytes([s.level]), name=s.name, message=s.message,
                         hardware_id=s.hardware_id,
                         values=[KeyValue(key=k, value=v) for k, v in s.values])
        for s in statuses
    ]  # fmt: skip
    assert ours == expected
    assert deserialize_message(encode_diagnostic_array([], 0), DiagnosticArray) == DiagnosticArray()


@pytest.fixture
def ros_logger(domain: int) -> Iterator[tuple[logging.Logger, RosoutHandler]]:
    """A Python logger forwarded to a real node's rclpy logger, as the handler's is."""
    context = rclpy.context.Context()
    rclpy.init(context=context, domain_id=domain)
    node = rclpy.create_node("rosout_handler_test", context=context)
    logger = logging.getLogger(f"edgerv.test_ros_outputs.{domain}")
    logger.setLevel(logging.DEBUG)
    logger.propagate = False
    handler = RosoutHandler(node.get_logger().name)
    logger.addHandler(handler)
    try:
        yield logger, handler
    finally:
        logger.removeHandler(handler)
        node.destroy_node()
        rclpy.shutdown(context=context)


def test_a_log_line_rosout_cannot_take_is_counted_once_on_stderr_and_never_raises(
    ros_logger: tuple[logging.Logger, RosoutHandler], capfd: pytest.CaptureFixture[str]
) -> None:
    """rclpy refuses a line that is not valid UTF-8 (a file name decoded with
    surrogateescape, say): the handler counts it, says so on stderr once (not through
    logging, which would come back to it), and the caller's log call returns as usual;
    lines after it are sent."""
    logger, handler = ros_logger
    logger.warning("cannot read %s", b"/tmp/caf\xe9.yaml".decode(errors="surrogateescape"))
    logger.warning("again: \udce9")
    logger.info("a good line")
    assert handler.failures == 2
    err = capfd.readouterr().err
    assert err.count("a log line could not be sent to /rosout") == 1


def test_a_line_logged_while_one_is_sent_is_not_sent_again(
    ros_logger: tuple[logging.Logger, RosoutHandler],
) -> None:
    """A log call made while the handler sends a line (here by its formatter) is not sent
    through it: no recursion, no failure."""
    logger, handler = ros_logger
    calls = []

    class Chatty(logging.Formatter):
        def format(self, record: logging.LogRecord) -> str:
            calls.append(record.getMessage())
            logger.warning("said while sending")  # comes back to the same handler
            return super().format(record)

    handler.setFormatter(Chatty())
    logger.warning("first")
    assert calls == ["first"] and handler.failures == 0


def test_log_calls_from_many_threads_at_once_never_fail(
    ros_logger: tuple[logging.Logger, RosoutHandler],
) -> None:
    """Eight threads logging at once, at every level: no failure, no exception."""
    logger, handler = ros_logger
    errors: list[BaseException] = []

    def chatter(i: int) -> None:
        try:
            for n in range(200):
                logger.log((logging.DEBUG, logging.INFO, logging.WARNING, logging.ERROR,
                            logging.CRITICAL)[n % 5], "thread %d line %d", i, n)  # fmt: skip
        except BaseException as exc:  # pragma: no cover - the failure this test looks for
            errors.append(exc)

    threads = [threading.Thread(target=chatter, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    assert errors == [] and handler.failures == 0


def test_a_handler_without_diagnostics_publishes_none(
    tmp_path: Path, domain: int, heard: Heard
) -> None:
    """--diagnostics-period 0: no /diagnostics at all (its log lines still go to /rosout)."""
    h = HandlerProcess(
        tmp_path, write(tmp_path, "m.yaml", SPEED_CAP), domain, "--diagnostics-period", "0"
    )
    try:
        assert wait_for(lambda: any("ready" in m.msg for m in heard.log_lines()), timeout=15)
        time.sleep(2.0)
        assert heard.statuses("edgerv handler: edge") == []
    finally:
        assert h.stop() == 0
