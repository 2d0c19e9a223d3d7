"""Typed verdicts (issue #19): a real ``edgerv handler`` publishes each verdict as an
``edgerv_msgs/msg/Verdict`` on /edgerv/verdict and, per handler, the last verdict of each
of its monitors as an ``edgerv_msgs/msg/VerdictArray`` on /edgerv/last_verdicts, both
transient local: a subscriber that comes late still gets the last verdict of every
monitor. This test's own rclpy node listens, as ``ros2 topic echo`` or any ROS 2 language
would; edgerv_msgs is the package interfaces/build.sh built (`make install`).
"""

from __future__ import annotations

import json
import os
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

rclpy = pytest.importorskip("rclpy")

# edgerv_msgs: `make install` builds and installs it (interfaces/build.sh); not skipped
# when missing: a build that silently stopped working must fail here
from builtin_interfaces.msg import Time  # noqa: E402
from edgerv_msgs.msg import Verdict, VerdictArray  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from edgerv.core.cdr import compile_reader  # noqa: E402
from edgerv.core.msgtypes import field_kind, typestore  # noqa: E402
from edgerv.handler.ros.cdr_out import encode_verdict_array, encode_verdict_message  # noqa: E402
from kit.documents import monitor_yaml, monitors_yaml, speed_monitor  # noqa: E402
from kit.ros import HandlerProcess, publisher, wait_for  # noqa: E402

pytestmark = pytest.mark.integration

INTERFACES = Path(__file__).parents[2] / "interfaces"
# as a late subscriber asks (`ros2 topic echo --qos-durability transient_local`): the
# handler's own QoS is not imported, so a handler that offers less fails here
TYPED_VERDICT_QOS = QoSProfile(
    depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)
LAST_VERDICTS_QOS = QoSProfile(
    depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)

# Three monitors that reach verdicts on /speed (each resets after one: several each), and
# one that never does. The values: where each reaches its verdicts is in VALUES' comment.
MONITORS = monitors_yaml(
    speed_monitor("cap", sortThreshold=1),
    speed_monitor("floor", "always (speed > 0)", sortThreshold=1),
    speed_monitor("reach", "eventually! (speed > 150)", sortThreshold=1),
    speed_monitor("quiet", "always (speed < 1e9)", sortThreshold=1),
)
ASSERTIONS = {
    "cap": "always (speed < 100)",
    "floor": "always (speed > 0)",
    "reach": "eventually! (speed > 150)",
}
# cap violated at each 120 and 160 (4 times), floor at each -1 (3), reach satisfied at each
# 160 (2): 9 verdicts in all
SPEEDS = [50.0] * 5 + [120.0, -1.0, 160.0] + [50.0] * 10 + [-1.0, 160.0, 120.0, -1.0] + [50.0] * 10
VERDICTS_SENT = 9


def monitors(tmp: Path, text: str = MONITORS) -> Path:
    path = tmp / "monitors.yaml"
    path.write_text(text)
    return path


def finish(proc: Any) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.communicate(timeout=10)


@dataclass
class Listener:
    """This test's ROS node; it subscribes when told (to come late, or not)."""

    node: Any
    lock: threading.Lock = field(default_factory=threading.Lock)
    got: dict[str, list[Any]] = field(default_factory=dict)

    def subscribe(self, topic: str, msg_type: Any, qos: QoSProfile) -> Any:
        self.got.setdefault(topic, [])

        def received(msg: Any) -> None:
            with self.lock:
                self.got[topic].append(msg)

        return self.node.create_subscription(msg_type, topic, received, qos)

    def messages(self, topic: str) -> list[Any]:
        with self.lock:
            return list(self.got.get(topic, []))


@pytest.fixture
def listener(domain: int, monkeypatch: pytest.MonkeyPatch) -> Iterator[Listener]:
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")  # as kit.ros' processes
    context = rclpy.context.Context()
    rclpy.init(context=context, domain_id=domain)
    node = rclpy.create_node("typed_verdicts_listener", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        yield Listener(node)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
        spinner.join(timeout=5)


def fields(msg: Any) -> dict[str, Any]:
    """A Verdict message as the verdict log's record, plus assertion and epoch."""
    return {
        "monitor": msg.monitor,
        "verdict": msg.verdict,
        "stamp": msg.stamp.sec * 10**9 + msg.stamp.nanosec,
        "step": msg.step,
        "handler": msg.handler,
        "assertion": msg.assertion,
        "epoch": msg.epoch,
    }


def logged(record: dict[str, Any]) -> dict[str, Any]:
    """A verdict log line as the typed message must carry it (no handoff here: epoch 0)."""
    return {**record, "assertion": ASSERTIONS[record["monitor"]], "epoch": 0}


def last_of_each(records: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per monitor, the verdict with the highest step (the merge rule)."""
    last: dict[str, dict[str, Any]] = {}
    for r in records:
        if r["monitor"] not in last or r["step"] > last[r["monitor"]]["step"]:
            last[r["monitor"]] = r
    return last


def test_each_verdict_arrives_typed_with_every_field(
    tmp_path: Path, domain: int, listener: Listener
) -> None:
    """Subscribed from the start: every verdict the handler logged arrives on
    /edgerv/verdict, in order, each field equal to the log's (the stamp to the ns), with
    the monitor's assertion and epoch; the JSON on /edgerv/verdicts goes on as before."""
    typed = listener.subscribe("/edgerv/verdict", Verdict, TYPED_VERDICT_QOS)
    json_qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    listener.subscribe("/edgerv/verdicts", String, json_qos)
    h = HandlerProcess(tmp_path, monitors(tmp_path), domain)
    pub = None
    try:
        assert wait_for(lambda: typed.get_publisher_count() > 0, timeout=15)
        pub = publisher(domain, "/speed", "std_msgs/msg/Float64", [{"data": s} for s in SPEEDS])
        assert wait_for(lambda: len(h.verdicts()) >= VERDICTS_SENT, timeout=30), h.verdicts()
        log = h.verdicts()
        assert len(log) == VERDICTS_SENT, log
        got = wait_for(lambda: len(listener.messages("/edgerv/verdict")) >= len(log), timeout=10)
        assert got, listener.messages("/edgerv/verdict")
        assert [fields(m) for m in listener.messages("/edgerv/verdict")] == [logged(r) for r in log]
        assert {r["monitor"] for r in log} == set(ASSERTIONS)  # each reached some
        kinds = {m.verdict for m in listener.messages("/edgerv/verdict")}
        assert kinds == {Verdict.SATISFIED, Verdict.VIOLATED}
        assert wait_for(lambda: len(listener.messages("/edgerv/verdicts")) >= len(log))
        assert [json.loads(m.data) for m in listener.messages("/edgerv/verdicts")] == log
    finally:
        if pub is not None:
            finish(pub)
        h.stop()


def test_a_late_subscriber_gets_the_last_verdict_of_every_monitor(
    tmp_path: Path, domain: int, listener: Listener
) -> None:
    """Two handlers, their monitors' verdicts reached before anyone listens; then a
    subscriber comes: /edgerv/last_verdicts gives it one array per handler, whose union
    is the last verdict of every monitor (a monitor without one is in none), and
    /edgerv/verdict the history (all 9 of the edge's: fewer than its depth of 100)."""
    # the cloud's monitor on a topic of its own: each publisher waits for its handler
    speed2 = {"topic": "/speed2", "type": "std_msgs/msg/Float64"}
    other = monitor_yaml("cloud-cap", "always (speed < 100)", {"speed": speed2}, sortThreshold=1)
    edge = HandlerProcess(tmp_path, monitors(tmp_path), domain, name="edge")
    (tmp_path / "cloud").mkdir()
    cloud = HandlerProcess(
        tmp_path / "cloud", monitors(tmp_path / "cloud", other), domain, name="cloud"
    )
    pubs = []
    try:
        for topic in ("/speed", "/speed2"):
            values = [{"data": s} for s in SPEEDS]
            pubs.append(publisher(domain, topic, "std_msgs/msg/Float64", values))
        done = wait_for(lambda: len(edge.verdicts()) >= VERDICTS_SENT and cloud.verdicts(), 30)
        assert done, (edge.verdicts(), cloud.verdicts())
        wait_for(lambda: len(cloud.verdicts()) >= 4, timeout=10)
        time.sleep(1.0)  # the arrays follow within LAST_VERDICTS_SECONDS (0.2 s)
        log = edge.verdicts() + cloud.verdicts()
        assert len(edge.verdicts()) == VERDICTS_SENT and len(cloud.verdicts()) == 4, log

        # now a late subscriber, as `ros2 topic echo --qos-durability transient_local`
        arrays = listener.subscribe("/edgerv/last_verdicts", VerdictArray, LAST_VERDICTS_QOS)
        listener.subscribe("/edgerv/verdict", Verdict, TYPED_VERDICT_QOS)

        def one_array_each() -> dict[str, Any]:
            newest = {a.handler: a for a in listener.messages("/edgerv/last_verdicts")}
            return newest if set(newest) == {"edge", "cloud"} else {}

        newest = wait_for(one_array_each, timeout=15)
        assert newest, (listener.messages("/edgerv/last_verdicts"), arrays.get_publisher_count())
        time.sleep(0.5)
        # depth 1, nothing new since: exactly the newest array of each handler
        assert len(listener.messages("/edgerv/last_verdicts")) == 2
        # the merge rule: per monitor, the highest step over the handlers' arrays
        union = last_of_each([fields(v) for a in newest.values() for v in a.verdicts])
        expected = last_of_each(log)
        assert union == {
            name: {**r, "assertion": ASSERTIONS[name.removeprefix("cloud-")], "epoch": 0}
            for name, r in expected.items()
        }
        assert set(union) == {"cap", "floor", "reach", "cloud-cap"}  # not "quiet"
        for handler, array in newest.items():
            assert {v.handler for v in array.verdicts} <= {handler}
            assert array.stamp.sec > 0  # when it was published
        assert len(newest["edge"].verdicts) == 3 and len(newest["cloud"].verdicts) == 1

        history = wait_for(
            lambda: len(listener.messages("/edgerv/verdict")) >= len(log), timeout=10
        )
        assert history, listener.messages("/edgerv/verdict")
        by_handler = [
            [fields(m) for m in listener.messages("/edgerv/verdict") if m.handler == name]
            for name in ("edge", "cloud")
        ]
        assert by_handler == [
            [logged(r) for r in edge.verdicts()],
            [{**r, "assertion": ASSERTIONS["cap"], "epoch": 0} for r in cloud.verdicts()],
        ]
    finally:
        for pub in pubs:
            finish(pub)
        edge.stop()
        cloud.stop()


def test_without_edgerv_msgs_the_handler_runs_with_json_only(
    tmp_path: Path, domain: int, listener: Listener, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A Python environment without edgerv_msgs (here: shadowed by a package that fails
    to import): the handler says once how to build it, publishes no typed topic, and its
    verdicts go on as JSON on /edgerv/verdicts."""
    shadow = tmp_path / "shadow" / "edgerv_msgs"
    shadow.mkdir(parents=True)
    (shadow / "__init__.py").write_text("raise ImportError('hidden by the test')\n")
    # first on the path: what follows it (this checkout's edgerv, if given) is still used
    monkeypatch.setenv("PYTHONPATH", str(shadow.parent), prepend=os.pathsep)
    listener.subscribe(
        "/edgerv/verdicts", String, QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    )
    h = HandlerProcess(tmp_path, monitors(tmp_path), domain)
    pub = None
    try:
        assert h.stderr.count("edgerv_msgs is not installed") == 1, h.stderr
        assert "interfaces/build.sh" in h.stderr and "make install" in h.stderr
        pub = publisher(domain, "/speed", "std_msgs/msg/Float64", [{"data": s} for s in SPEEDS])
        assert wait_for(lambda: len(h.verdicts()) >= VERDICTS_SENT, timeout=30), h.stderr
        got = wait_for(lambda: len(listener.messages("/edgerv/verdicts")) >= VERDICTS_SENT, 10)
        assert got, h.stderr
        topics = dict(listener.node.get_topic_names_and_types())
        assert topics.get("/edgerv/verdicts") == ["std_msgs/msg/String"]
        assert "/edgerv/verdict" not in topics and "/edgerv/last_verdicts" not in topics
        assert h.proc.poll() is None  # still running
        assert h.stderr.count("edgerv_msgs is not installed") == 1
    finally:
        if pub is not None:
            finish(pub)
        assert h.stop() == 0


# -- the bytes the handler encodes itself --------------------------------------------------

CASES = [  # strings of each length modulo 4 and 8: every padding the encoder writes
    ("m", "violated", 1_700_000_000_123_456_789, 21, "edge", "always (speed < 100)", 0),
    ("mo", "satisfied", 5, 1, "edg", "G p", 2**63 + 5),
    ("mon", "violated", 0, 2**64 - 1, "", "", 1_761_000_000_000_000_000),
    ("monitor-4", "satisfied", 10**9, 7, "handler-b", "eventually (x > 1)", 3),
]


def message(f: tuple[str, str, int, int, str, str, int]) -> Any:
    sec, nanosec = divmod(f[2], 10**9)
    return Verdict(
        monitor=f[0], verdict=f[1], stamp=Time(sec=sec, nanosec=nanosec), step=f[3],
        handler=f[4], assertion=f[5], epoch=f[6],
    )  # fmt: skip


@pytest.mark.parametrize("handler", ["edge", "cloud", "h", "abcdefgh"])
def test_the_handlers_cdr_is_what_rclpy_reads_and_writes(handler: str) -> None:
    """encode_verdict_message and encode_verdict_array (the handler publishes their bytes,
    not rclpy objects) against the built package's own typesupport: rclpy reads them as
    the message meant, and writes that message in as many bytes (Fast-CDR leaves its
    padding bytes uninitialized: the padding is all that may differ)."""
    for f in CASES:
        raw = encode_verdict_message(f)
        assert deserialize_message(raw, Verdict) == message(f)
        assert len(serialize_message(message(f))) == len(raw)
    for n in range(len(CASES) + 1):
        raw = encode_verdict_array(1_700_000_000_000_000_042, handler, CASES[:n])
        expected = VerdictArray(
            stamp=Time(sec=1_700_000_000, nanosec=42),
            handler=handler,
            verdicts=[message(f) for f in CASES[:n]],
        )
        assert deserialize_message(raw, VerdictArray) == expected
        assert len(serialize_message(expected)) == len(raw)


def test_the_built_package_is_interfaces_and_edgerv_reads_its_bytes(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The installed edgerv_msgs was built from interfaces/ as it is now (else: `make
    install` rebuilds it), and what rclpy serializes with it, edgerv's CDR reader and
    rosbags read from the .msg text alone: `edgerv check` reads a recording of verdicts."""
    import sys

    for name in ("Verdict", "VerdictArray"):
        installed = Path(sys.prefix, "share", "edgerv_msgs", "msg", f"{name}.msg")
        source = INTERFACES / "edgerv_msgs" / "msg" / f"{name}.msg"
        assert installed.read_text() == source.read_text(), f"{name}.msg: run `make install`"
    monkeypatch.setenv("EDGERV_MSG_PATH", str(INTERFACES))
    field_kind("edgerv_msgs/msg/VerdictArray", "handler")
    array = VerdictArray(
        stamp=Time(sec=3, nanosec=4), handler="edge", verdicts=[message(f) for f in CASES]
    )
    raw = bytes(serialize_message(array))
    read = compile_reader(
        "edgerv_msgs/msg/VerdictArray",
        [
            "handler",
            "stamp.nanosec",
            "verdicts[2].step",
            "verdicts[1].epoch",
            "verdicts[3].assertion",
        ],
    )
    assert read(raw) == (["edge", 4, 2**64 - 1, 2**63 + 5, "eventually (x > 1)"], None)
    decoded = typestore().deserialize_cdr(raw, "edgerv_msgs/msg/VerdictArray")
    assert [
        (v.monitor, v.verdict, v.stamp.sec * 10**9 + v.stamp.nanosec, v.step, v.handler,
         v.assertion, v.epoch)
        for v in decoded.verdicts
    ] == CASES  # fmt: skip
