"""The handler engine without ROS: placement, buffers, flushing, pressure, shutdown."""

from __future__ import annotations

from collections.abc import Sequence

from edgerv.core.monitor import CompiledMonitor
from edgerv.core.pipeline import Verdict
from edgerv.handler import engine as engine_module
from edgerv.handler.engine import Engine
from edgerv.handler.reading import monitor_reports, read
from kit.documents import compiled


class Collect:
    def __init__(self) -> None:
        self.got: list[tuple[str, str, int]] = []

    def write(self, handler: str, verdicts: Sequence[Verdict]) -> None:
        self.got += [(v.monitor, v.verdict, v.step) for v in verdicts]


def speed_monitor(**spec):  # type: ignore[no-untyped-def]
    return compiled("always (speed < 100)", {"speed": "float"}, **spec)


def test_only_active_monitors_subscribe_and_evaluate() -> None:
    sink = Collect()
    e = Engine("edge", [sink])
    e.put(speed_monitor(), active=False)
    assert e.routes() == {}
    e.ingest([(1, "/speed", [150.0])])
    assert e.tick() == []
    e.set_active("m", True)
    assert list(e.routes()) == ["/speed"]
    e.ingest([(2, "/speed", [150.0])])
    e.emit(e.tick())
    assert sink.got == [("m", "violated", 1)]
    assert monitor_reports(e)[0]["verdicts"] == {"violated": 1, "satisfied": 0}


def test_a_partial_sort_buffer_is_released_after_flush_after() -> None:
    e = Engine("edge", flush_after=0.5)
    e.put(speed_monitor(sortThreshold=10), active=True)
    e.ingest([(1, "/speed", [150.0])], now=100.0)
    assert e.tick(now=100.2) == []
    assert [v.step for v in e.tick(now=100.6)] == [1]


def test_a_full_buffer_drops_and_counts() -> None:
    e = Engine("edge")
    e.put(speed_monitor(sortThreshold=3, bufferCapacity=3), active=True)
    e.set_active("m", True)
    # events wait in the sort buffer; letters wait for the scheduler: 3 fit, then drops
    e.ingest([(i, "/speed", [1.0]) for i in range(5)])
    (m,) = read(e).monitors
    assert (m.events, m.dropped, m.buffered) == (3, 2, 3)


def test_migration_wanted_when_the_buffer_stays_full_with_hysteresis(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    e = Engine("edge")
    e.put(speed_monitor(sortThreshold=100, bufferCapacity=100), active=True)
    slot = e.slots["m"]
    e.ingest([(i, "/speed", [1.0]) for i in range(60)], now=0.0)
    monkeypatch.setattr(e, "flush_after", 1e9)  # keep the events buffered
    e.tick(now=0.1)
    e.tick(now=0.5)
    assert not slot.migration_wanted
    e.tick(now=0.1 + engine_module.PRESSURE_SECONDS)
    assert slot.migration_wanted
    assert monitor_reports(e)[0]["migrationWanted"] is True
    # draining below the high water mark but above the low one keeps the flag (no flapping)
    slot.runtime.events[:] = slot.runtime.events[:30]
    e.tick(now=5.0)
    assert slot.migration_wanted
    slot.runtime.events[:] = slot.runtime.events[:10]
    e.tick(now=6.0)
    assert not slot.migration_wanted


def test_drain_evaluates_everything_buffered() -> None:
    sink = Collect()
    e = Engine("edge", [sink], flush_after=1e9)
    e.put(speed_monitor(sortThreshold=50), active=True)
    e.ingest([(i, "/speed", [150.0 if i == 7 else 1.0]) for i in range(10)])
    assert sink.got == []
    e.drain()
    assert sink.got == [("m", "violated", 8)]


def test_replacing_a_monitor_restarts_it_and_removing_unsubscribes() -> None:
    e = Engine("edge")
    assert e.put(speed_monitor(), active=True) is True
    e.ingest([(1, "/speed", [1.0])])
    e.tick()
    assert monitor_reports(e)[0]["step"] == 1
    assert e.put(speed_monitor(), active=True) is False
    assert monitor_reports(e)[0]["step"] == 0
    version = e.routes_version
    assert e.remove("m") and not e.remove("m")
    assert e.routes() == {} and e.routes_version > version


def test_a_failing_sink_does_not_stop_the_others() -> None:
    class Broken:
        def write(self, handler: str, verdicts: Sequence[Verdict]) -> None:
            raise OSError("disk full")

    sink = Collect()
    e = Engine("edge", [Broken(), sink])
    e.put(speed_monitor(), active=True)
    e.ingest([(1, "/speed", [500.0])])
    e.emit(e.tick())
    assert sink.got == [("m", "violated", 1)]


def odom_monitor(name: str, assertion: str, **fields: str) -> CompiledMonitor:
    """A monitor whose signals read these fields of /odom."""
    sigs = {
        s: {"topic": "/odom", "type": "nav_msgs/msg/Odometry", "field": f}
        for s, f in fields.items()
    }
    return compiled(assertion, sigs, name=name)


def test_a_batch_read_for_routes_the_engine_no_longer_has_is_refused() -> None:
    """Messages wait in the ROS layer's reorder window, read for the fields the routes
    had then; a monitor added meanwhile reads more fields of the topic. Such a batch is
    refused whole (no monitor offered anything, no IndexError), and offered once read
    again for the current routes."""
    e = Engine("edge")
    e.put(odom_monitor("x", "always (x < 100)", x="pose.pose.position.x"), active=True)
    old = e.routes_version
    assert e.ingest([(1, "/odom", [1.0])], routes_version=old) is True
    e.put(odom_monitor("w", "always (w < 1)", w="twist.twist.angular.z"), active=True)
    assert e.routes_version != old
    before = {m["name"]: m["events"] for m in monitor_reports(e)}
    assert before == {"x": 1, "w": 0}
    # read for the old route: one value, where the route now has two fields
    assert e.ingest([(2, "/odom", [2.0]), (3, "/odom", [3.0])], routes_version=old) is False
    assert {m["name"]: m["events"] for m in monitor_reports(e)} == before
    assert e.messages["/odom"] == 1
    # read again for the current route: offered to both monitors
    fields = list(e.routes()["/odom"].fields)
    assert sorted(fields) == ["pose.pose.position.x", "twist.twist.angular.z"]
    values = {"pose.pose.position.x": 2.0, "twist.twist.angular.z": 0.5}
    batch = [(2, "/odom", [values[f] for f in fields])]
    assert e.ingest(batch, routes_version=e.routes_version) is True
    assert {m["name"]: m["events"] for m in monitor_reports(e)} == {"x": 2, "w": 1}
    assert e.messages["/odom"] == 2
