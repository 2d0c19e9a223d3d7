"""The handler's /diagnostics statuses (edgerv.handler.health), from a real Engine driven
without ROS on a clock the tests move: levels, their precedence, the hold of a
violation, staleness, the messages and the values."""

from __future__ import annotations

import argparse
import time
from typing import Any

import pytest

from edgerv.core.deadline import MakespanWindow
from edgerv.handler import engine as engine_module
from edgerv.handler.engine import Engine
from edgerv.handler.health import (
    BREATH_SECONDS,
    CHECK_SECONDS,
    MONITOR_PREFIX,
    Breather,
    DiagnosticsConfig,
    Health,
    Level,
    Pacer,
    Status,
    alarm_counts,
    read_engine,
    stamp_text,
    worst,
)
from edgerv.handler.main import add_arguments
from kit.documents import compiled
from kit.engines import ManualClock

S = 1_000_000_000  # ns


class Rig:
    """An engine and its health, on one manual clock; the health is a verdict sink, as
    the handler makes it."""

    def __init__(self, sink: bool = True, **config: Any) -> None:
        self.clock = ManualClock()
        self.engine = Engine("edge", clock=self.clock)
        self.health = Health("edge", DiagnosticsConfig(**config), clock=self.clock)
        if sink:
            self.engine.sinks.append(self.health)
        self.stamp = 1_700_000_000 * S

    def put(
        self, assertion: str = "always (speed < 100)", active: bool = True, **spec: Any
    ) -> None:
        spec.setdefault("name", "cap")
        spec.setdefault("sortThreshold", 1)
        self.engine.put(compiled(assertion, {"speed": "float"}, **spec), active=active)

    def send(self, *speeds: float) -> None:
        """Messages on /speed, a millisecond of stamps apart, evaluated at once."""
        for speed in speeds:
            self.stamp += S // 1000
            self.engine.ingest([(self.stamp, "/speed", [speed])])
        self.engine.emit(self.engine.tick())

    def later(self, seconds: float) -> None:
        self.clock.advance(seconds)

    def check(self, **ros: Any) -> dict[str, Level]:
        return self.health.check(read_engine(self.engine, **ros), self.clock.monotonic())

    def statuses(self, **ros: Any) -> dict[str, Status]:
        self.check(**ros)
        return {s.name: s for s in self.health.statuses()}

    def monitor(self, name: str = "cap", **ros: Any) -> Status:
        return self.statuses(**ros)[f"edgerv: {name}"]

    def handler(self, **ros: Any) -> Status:
        return self.statuses(**ros)["edgerv handler: edge"]


def values(status: Status) -> dict[str, str]:
    return dict(status.values)


# -- names, values, OK ---------------------------------------------------------------------


def test_one_status_per_active_monitor_and_one_for_the_handler() -> None:
    rig = Rig()
    rig.put(name="a")
    rig.put(name="b")
    rig.put(name="idle", active=False)
    got = rig.statuses()
    assert list(got) == ["edgerv handler: edge", "edgerv: a", "edgerv: b"]
    assert all(s.hardware_id == "edge" for s in got.values())  # the handler that runs it
    assert all(s.level == Level.OK for s in got.values())
    assert got["edgerv: a"].message == "pending"
    handler = got["edgerv handler: edge"]
    assert handler.message == "2 of 3 monitors active, 0.0 messages/s"


def test_a_monitors_values() -> None:
    rig = Rig()
    rig.put(bufferCapacity=200, placement={"tier": "edge", "migrate": "pinned"})
    rig.send(1.0, 2.0, 150.0, 3.0)
    v = values(rig.monitor())
    violated = rig.engine.slots["cap"].last_verdict
    assert violated is not None
    assert v == {
        "state": "pending",
        "step": "4",
        "last verdict": "violated at step 3",
        "last verdict stamp": stamp_text(violated.stamp),
        "violations": "1",
        "satisfactions": "0",
        "events": "4",
        "events per second": "0.0",  # no time has passed on this clock
        "buffer fill": "0% (0 of 200)",
        "dropped events": "0",
        "late events": "0",
        "migration wanted": "no",
        "tier": "edge (pinned)",
        "epoch": "0",
        "migrations": "0 here, 0 away",
        "topics": "/speed",
        "reactions": "off",
    }
    assert stamp_text(1_700_000_000_003_000_000) == "1700000000.003000000"


def test_the_handlers_values_and_rates_over_the_last_period() -> None:
    rig = Rig()
    rig.put()
    rig.check()
    for _ in range(10):  # 20 messages in one second
        rig.later(0.1)
        rig.send(1.0, 2.0)
    handler = rig.handler(bad={"/speed": 0})
    v = values(handler)
    assert v["monitors active"] == "1" and v["monitors defined"] == "1"
    assert v["messages"] == "20" and v["messages per second"] == "20.0"
    assert v["messages lost"] == "0" and v["bad messages"] == "0"
    assert v["ingest lag"] == "0.000 s"
    assert v["log lines not sent to /rosout"] == "0"
    assert "deadline" not in v  # without --deadline
    assert handler.message == "1 of 1 monitors active, 20.0 messages/s"
    assert values(rig.monitor())["events per second"] == "20.0"


def test_rates_count_over_the_last_period_only() -> None:
    rig = Rig(period=1.0)
    rig.put()
    rig.check()
    rig.later(0.5)
    rig.send(*[1.0] * 50)  # a burst, then quiet
    assert values(rig.monitor())["events per second"] == "100.0"  # 50 in 0.5 s
    rig.later(0.75)
    rig.check()
    rig.later(0.75)  # the burst is more than a period ago now
    assert values(rig.monitor())["events per second"] == "0.0"


# -- ERROR: a violation, held; halted after one --------------------------------------------


def test_a_violation_is_error_for_the_hold_then_ok_again() -> None:
    rig = Rig(hold=10.0, stale=0)
    rig.put()
    rig.send(1.0)
    assert rig.monitor().level == Level.OK
    rig.send(150.0, 2.0)  # violated at step 2; reset: pending again at step 3
    violation = rig.engine.slots["cap"].last_verdict
    assert violation is not None and violation.step == 2
    error = rig.monitor()
    assert error.level == Level.ERROR
    assert error.message == (
        f"violated at step 2 (stamp {stamp_text(violation.stamp)}), within the last 10 s"
    )
    assert values(error)["state"] == "pending"  # one step only: the hold makes it seen
    rig.later(9.9)
    rig.send(1.0)
    assert rig.monitor().message == error.message  # (no age that changes by itself)
    rig.later(0.1)  # 10 s since it was reached
    ok = rig.monitor()
    assert ok.level == Level.OK
    assert (
        ok.message
        == f"pending (last verdict: violated at step 2 (stamp {stamp_text(violation.stamp)}))"
    )


def test_the_hold_counts_from_the_newest_violation() -> None:
    rig = Rig(hold=10.0, stale=0)
    rig.put()
    rig.send(150.0)
    rig.later(6.0)
    rig.send(150.0, 1.0)  # again, at step 2
    rig.later(6.0)  # 12 s after the first, 6 after the second
    status = rig.monitor()
    assert status.level == Level.ERROR and status.message.startswith("violated at step 2 ")
    rig.later(4.0)
    assert rig.monitor().level == Level.OK


def test_the_hold_counts_from_when_the_handler_reached_it_not_from_the_next_reading() -> None:
    rig = Rig(hold=10.0, stale=0)
    rig.put()
    rig.check()
    rig.send(150.0)  # noted by the sink now
    rig.later(3.0)
    rig.check()  # the reading that first sees it: 3 s after it was reached
    rig.later(6.9)
    assert rig.monitor().level == Level.ERROR
    rig.later(0.1)  # 10 s after it was reached, 7 after the reading
    assert rig.monitor().level == Level.OK


def test_a_violation_seen_only_in_the_counts_is_held_too() -> None:
    """Without the sink (a verdict reached between two readings is in the monitor's
    counts): held from the reading that saw it."""
    rig = Rig(sink=False, hold=10.0, stale=0)
    rig.put()
    rig.check()
    rig.send(1.0, 150.0, 1.0)
    rig.later(1.0)
    assert rig.monitor().level == Level.ERROR
    rig.later(9.9)
    assert rig.monitor().level == Level.ERROR
    rig.later(1.0)
    assert rig.monitor().level == Level.OK


def test_a_monitor_halted_after_a_violation_stays_error() -> None:
    rig = Rig(hold=10.0, stale=0)
    rig.put(onVerdict="halt")
    rig.send(1.0, 150.0)
    rig.later(3600.0)
    status = rig.monitor()
    assert status.level == Level.ERROR
    assert status.message.startswith("halted after it was violated at step 2 (stamp ")
    assert values(status)["state"] == "halted"


def test_a_satisfied_monitor_is_ok_with_its_verdict_halted_or_not() -> None:
    for on_verdict in ("reset", "halt"):
        rig = Rig(stale=0)
        rig.put("F (speed > 100)", onVerdict=on_verdict)
        rig.send(1.0, 150.0)
        status = rig.monitor()
        assert status.level == Level.OK
        expected = "satisfied at step 2 (stamp "
        if on_verdict == "halt":
            expected = "halted after it was " + expected
        assert status.message.startswith(expected), status.message
        assert values(status)["satisfactions"] == "1"


def test_a_violated_state_past_the_hold_is_ok_and_says_no_step_came_since() -> None:
    rig = Rig(hold=10.0, stale=0)
    rig.put()
    rig.send(150.0)
    rig.later(11.0)
    status = rig.monitor()
    assert status.level == Level.OK and values(status)["state"] == "violated"
    assert status.message.endswith("; no step since")


# -- STALE ---------------------------------------------------------------------------------


def test_stale_after_no_event_for_the_stale_seconds() -> None:
    rig = Rig(stale=10.0)
    rig.put()
    rig.send(1.0)
    rig.check()
    rig.later(9.9)
    assert rig.monitor().level == Level.OK
    rig.later(0.1)
    stale = rig.monitor()
    assert stale.level == Level.STALE and stale.message == "no event for over 10 s"
    rig.send(1.0)  # an event: fresh again
    assert rig.monitor().level == Level.OK


def test_a_monitor_that_never_had_an_event_is_stale_from_when_it_started_here() -> None:
    rig = Rig(stale=10.0)
    rig.put()
    rig.check()
    rig.later(12.0)
    assert rig.monitor().message == "no event for over 10 s"


def test_a_stale_monitors_age_steps_at_a_minute_ten_an_hour_and_a_day() -> None:
    """The age a STALE status gives changes at those instants only (next_change names
    them): between them the status stays as published (Health.due)."""
    rig = Rig(stale=10.0)
    rig.put()
    rig.check()
    start, seen = rig.clock.monotonic(), []
    for at in (10.0, 59.9, 60.0, 599.0, 600.0, 3600.0, 86399.0, 86400.0, 10 * 86400.0):
        rig.later(start + at - rig.clock.monotonic())
        seen.append(rig.monitor().message.removeprefix("no event for over "))
    assert seen == ["10 s", "10 s", "1 min", "1 min", "10 min", "1 h", "1 h", "1 d", "1 d"]
    rig.later(0)
    assert rig.health.next_change(rig.clock.monotonic()) is None
    rig = Rig(stale=90.0)  # a stale time between the steps: it, then the next step
    rig.put()
    rig.check()
    start = rig.clock.monotonic()
    rig.later(90.0)
    assert rig.monitor().message == "no event for over 90 s"
    assert rig.health.next_change(rig.clock.monotonic()) == start + 600.0


def test_dropped_events_count_as_events_for_staleness() -> None:
    """A monitor whose buffer is full still hears its topic: not stale (but WARN)."""
    rig = Rig(stale=10.0)
    rig.put(sortThreshold=3, bufferCapacity=3)
    rig.check()
    rig.later(9.0)
    rig.engine.ingest([(i, "/speed", [1.0]) for i in range(1, 6)])  # 3 taken, 2 dropped
    rig.later(1.5)
    rig.engine.ingest([(9, "/speed", [1.0])])  # dropped: the buffer is still full
    status = rig.monitor()
    assert status.level == Level.WARN
    assert "no event" not in status.message


def test_never_stale_with_0() -> None:
    rig = Rig(stale=0)
    rig.put()
    rig.check()
    rig.later(86400.0)
    assert rig.monitor().level == Level.OK


# -- WARN ----------------------------------------------------------------------------------


def test_warn_when_the_buffer_is_half_full_and_when_the_monitor_wants_to_migrate() -> None:
    rig = Rig(stale=0)
    rig.put(sortThreshold=100, bufferCapacity=100)
    rig.engine.flush_after = 1e9  # keep the events buffered
    rig.engine.ingest([(i, "/speed", [1.0]) for i in range(1, 50)])
    assert rig.monitor().level == Level.OK  # 49%
    rig.engine.ingest([(50, "/speed", [1.0])])
    status = rig.monitor()
    assert status.level == Level.WARN and status.message == "buffer 50% full"
    rig.engine.tick()
    rig.later(engine_module.PRESSURE_SECONDS)
    rig.engine.tick()
    status = rig.monitor()
    assert values(status)["migration wanted"] == "yes"
    assert status.message == "buffer 50% full; wants to migrate (its buffer stayed half full)"


class Reactor:
    """Fails each reaction whose violation's step is in ``fail``, does the others, and
    tells the engine as the ROS reactor does (edgerv.handler.ros.reactor)."""

    def __init__(self, engine: Engine, fail: set[int]) -> None:
        self.engine, self.fail = engine, fail

    def prepare(self, reaction: Any) -> None:
        pass

    def react(self, handler: str, due: Any) -> None:
        for v, _ in due:
            failed = v.step in self.fail
            self.engine.note_reaction(v.monitor, "/estop found no server" if failed else None)


def test_warn_while_the_newest_reaction_failed_and_the_counts_in_the_values() -> None:
    rig = Rig(stale=0, hold=0)
    rig.engine.reactor = Reactor(rig.engine, fail={2})
    reaction = {"call": {"service": "/estop", "type": "std_srvs/srv/Trigger"}}
    rig.put(onViolation=reaction)
    rig.send(150.0)  # step 1: done
    status = rig.monitor()
    assert status.level == Level.OK and values(status)["reactions"] == "1 done, 0 failed"
    rig.send(150.0)  # step 2: failed
    status = rig.monitor()
    assert status.level == Level.WARN
    assert status.message == "its last reaction failed: /estop found no server"
    assert values(status)["reactions"] == "1 done, 1 failed"
    rig.send(150.0)  # step 3: done again
    status = rig.monitor()
    assert status.level == Level.OK and values(status)["reactions"] == "2 done, 1 failed"


def test_warn_for_events_dropped_in_the_last_period() -> None:
    rig = Rig(stale=0, period=1.0)
    rig.put(sortThreshold=3, bufferCapacity=3)
    rig.check()
    rig.later(0.5)
    rig.engine.ingest([(i, "/speed", [1.0]) for i in range(1, 6)])  # 3 taken, 2 dropped
    rig.engine.emit(rig.engine.tick())  # evaluated: the buffer is empty again
    status = rig.monitor()
    assert status.level == Level.WARN
    assert status.message == "2 events dropped in the last 0.5 s (buffer full)"
    assert values(status)["dropped events"] == "2"
    rig.later(1.5)  # a period without a drop
    assert rig.monitor().level == Level.OK


def test_warn_when_a_topic_has_no_publisher_or_only_incompatible_ones() -> None:
    rig = Rig(stale=0)
    rig.put()
    assert rig.monitor().level == Level.OK  # not counted yet: no warning
    assert rig.monitor(publishers={"/speed": 1}).level == Level.OK
    silent = rig.monitor(publishers={"/speed": 0})
    assert silent.level == Level.WARN and silent.message == "no publisher on /speed"
    bad = rig.monitor(publishers={"/speed": 1}, incompatible={"/speed": 1})
    assert bad.level == Level.WARN
    assert bad.message == "1 publisher(s) of /speed with incompatible QoS"


# -- which level wins ----------------------------------------------------------------------


def test_error_outranks_stale_which_outranks_warn_and_every_reason_is_given() -> None:
    assert worst([Level.WARN, Level.STALE, Level.OK]) == Level.STALE
    assert worst([Level.STALE, Level.ERROR, Level.WARN]) == Level.ERROR
    assert worst([]) == Level.OK
    rig = Rig(hold=30.0, stale=10.0)
    rig.put()
    rig.send(150.0)
    rig.check()
    rig.later(12.0)
    status = rig.monitor(publishers={"/speed": 0})
    assert status.level == Level.ERROR
    reasons = status.message.split("; ")
    assert reasons[0].startswith("violated at step 1 ")
    assert reasons[1:] == ["no event for over 10 s", "no publisher on /speed"]
    rig.later(20.0)  # the hold is over
    status = rig.monitor(publishers={"/speed": 0})
    assert status.level == Level.STALE
    assert status.message == "no event for over 10 s; no publisher on /speed"


# -- the handler's status ------------------------------------------------------------------


def test_the_handler_warns_while_messages_were_lost_in_the_last_period() -> None:
    rig = Rig(period=1.0)
    rig.put()
    rig.check()
    rig.later(0.25)
    rig.engine.lost["/imu"] = 5  # as the ROS layer counts them
    status = rig.handler()
    assert status.level == Level.WARN
    assert status.message == (
        "5 messages lost before the handler took them in the last 0.2 s (/imu 5)"
    )
    assert values(status)["messages lost"] == "5"
    rig.later(0.5)
    assert rig.handler().level == Level.WARN  # (still within a period)
    rig.later(1.0)
    status = rig.handler()
    assert status.level == Level.OK and values(status)["messages lost"] == "5"


def test_the_handler_warns_about_messages_it_could_not_read() -> None:
    rig = Rig()
    rig.check(bad={"/odom": 1})
    rig.later(0.5)
    status = rig.handler(bad={"/odom": 4})
    assert status.level == Level.WARN
    assert status.message == "3 messages could not be read in the last 0.5 s (/odom 3)"
    assert values(status)["bad messages"] == "4"


def test_the_deadline_window_in_the_handlers_values_and_its_pressure() -> None:
    rig = Rig()
    window = MakespanWindow("/cmd_vel", 125_000_000)
    rig.engine.deadline = window
    now = time.monotonic_ns()  # (taken when the ROS layer reads it)
    for i in range(20):
        window.add(i * 10**8 + 100_000_000, i * 10**8, now)
    v = values(rig.handler())
    assert v["deadline topic"] == "/cmd_vel" and v["deadline"] == "125 ms"
    assert v["deadline makespans in window"] == str(window.report(0)["count"])
    assert v["deadline makespan p95"] == "100 ms" and v["deadline misses in window"] == "0"
    assert rig.handler().level == Level.OK
    for i in range(20, 60):
        window.add(i * 10**8 + 130_000_000, i * 10**8, now)
    status = rig.handler()
    assert status.level == Level.WARN
    assert status.message == (
        "deadline pressure: /cmd_vel's makespan p95 130 ms reaches its 125 ms deadline"
    )


# -- when to publish -----------------------------------------------------------------------


def test_a_change_of_level_is_told_from_the_levels_last_published() -> None:
    rig = Rig(hold=10.0, stale=0)
    rig.put()
    levels = rig.check()
    assert not rig.health.level_changed(levels)  # a new status waits for the next update
    rig.health.published(rig.health.statuses())
    assert not rig.health.level_changed(rig.check())
    rig.send(150.0)
    assert rig.health.changed.is_set()  # the sink wakes the diagnostics thread
    assert rig.health.level_changed(rig.check())
    rig.health.published(rig.health.statuses())  # ERROR, published
    rig.health.changed.clear()
    rig.send(150.0)  # violated again: still ERROR, nothing to wake it for
    assert not rig.health.changed.is_set()
    assert not rig.health.level_changed(rig.check())


def test_the_next_change_by_time_alone() -> None:
    rig = Rig(hold=10.0, stale=30.0)
    rig.put()
    rig.send(1.0)
    start = rig.clock.monotonic()
    rig.check()
    assert rig.health.next_change(start) == start + 30.0  # stale then
    rig.later(5.0)
    rig.send(150.0)
    rig.check()
    assert rig.health.next_change(rig.clock.monotonic()) == start + 15.0  # the hold ends


def test_a_redefined_monitor_starts_afresh() -> None:
    rig = Rig(hold=10.0, stale=0)
    rig.put()
    rig.send(150.0)
    assert rig.monitor().level == Level.ERROR
    rig.put()  # the same definition again: a restart
    status = rig.monitor()
    assert status.level == Level.OK and values(status)["violations"] == "0"


def test_read_engine_takes_active_monitors_in_chunks(monkeypatch: pytest.MonkeyPatch) -> None:
    from edgerv.handler import reading as reading_module

    monkeypatch.setattr(reading_module, "READ_CHUNK", 3)
    rig = Rig()
    for i in range(10):
        rig.put(name=f"m{i}", active=i != 4)
    reading = read_engine(rig.engine, publishers={"/speed": 2})
    assert [m.name for m in reading.monitors] == [f"m{i}" for i in range(10) if i != 4]
    assert reading.defined == 10 and reading.publishers == {"/speed": 2}


def test_the_pacer_updates_every_period_checks_between_and_keeps_to_its_budget() -> None:
    p = Pacer(period=1.0, budget=0.05, start=100.0)
    assert p.update_due(100.0) and p.wait(100.0, None) == 0.0
    p.worked(100.0, 0.001, updated=True)  # 1 ms: the budget leaves it alone
    assert not p.update_due(100.5) and p.update_due(101.0)
    assert p.wait(100.0, None) == pytest.approx(CHECK_SECONDS)
    assert p.wait(100.0, 100.1) == pytest.approx(0.1)  # a hold ends then
    p.worked(101.0, 0.2, updated=True)  # 200 ms of CPU: 3.8 s idle after it
    assert p.wait(101.0, 101.1) == pytest.approx(3.8)
    assert not p.update_due(104.0) and p.update_due(104.8)


def test_the_pacer_does_not_make_a_check_wait_again_for_what_it_breathed() -> None:
    p = Pacer(period=1.0, budget=0.05, start=100.0)
    p.worked(101.0, 0.2, updated=True, paid=0.15)  # 150 ms followed by sleeps already
    assert p.wait(101.0, 101.1) == pytest.approx(0.05 * 19)
    p.worked(102.0, 0.2, updated=True, paid=0.2)
    assert p.wait(102.0, 102.1) == pytest.approx(0.1)  # (a hold ends then)


class Waits:
    """A stop event that never stops: what a Breather asks it to wait, noted."""

    def __init__(self) -> None:
        self.asked: list[float] = []

    def wait(self, seconds: float) -> bool:
        self.asked.append(seconds)
        return False


def test_a_breather_keeps_a_long_piece_of_work_to_its_budget_as_it_goes() -> None:
    cpu = [10.0]
    stop = Waits()
    b = Breather(stop, budget=0.05, cpu=lambda: cpu[0])  # type: ignore[arg-type]
    b()
    cpu[0] += BREATH_SECONDS / 2
    b()  # less than a breath of CPU: no sleep
    assert stop.asked == [] and b.paid == 0.0
    cpu[0] += BREATH_SECONDS
    b()  # 1.5 breaths since the start: 19 times that asleep (5% of the stretch)
    assert stop.asked == [pytest.approx(1.5 * BREATH_SECONDS * 19)]
    assert b.paid == pytest.approx(1.5 * BREATH_SECONDS)
    cpu[0] += BREATH_SECONDS
    b.begin()  # a new piece of work: nothing paid, the CPU counted from here
    b()
    assert b.paid == 0.0 and len(stop.asked) == 1


def test_checks_and_statuses_breathe_as_they_go(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every BREATH_EVERY monitors (here 3) a check and the statuses of a reading call
    the health's breather, and so does encoding them; with or without, the same."""
    from edgerv.handler import health as health_module
    from edgerv.handler.ros import cdr_out

    monkeypatch.setattr(health_module, "BREATH_EVERY", 3)  # (health.breathing's)
    rigs = [Rig(), Rig()]
    breaths: list[int] = []
    rigs[1].health.breathe = lambda: breaths.append(1)
    for rig in rigs:
        for i in range(10):
            rig.put(name=f"m{i}")
        rig.send(150.0, 5.0)
    levels = [rig.check() for rig in rigs]
    assert levels[0] == levels[1] and len(breaths) == 3  # 10 monitors: after 3, 6, 9
    statuses = [rig.health.statuses() for rig in rigs]
    assert statuses[0] == statuses[1] and len(breaths) == 6
    encoded = [cdr_out.encode_diagnostic_array(s, 1) for s in statuses]
    assert cdr_out.encode_diagnostic_array(statuses[1], 1, rigs[1].health.breathe) == encoded[0]
    assert len(breaths) == 9  # 11 statuses (the handler's first): after 3, 6, 9


def test_the_handlers_diagnostics_flags() -> None:
    p = argparse.ArgumentParser()
    add_arguments(p)
    args = p.parse_args(["--name", "edge"])
    config = (args.diagnostics_period, args.diagnostics_hold, args.diagnostics_stale)
    assert config == (1.0, 10.0, 10.0)  # DiagnosticsConfig's defaults
    args = p.parse_args(["--name", "e", "--diagnostics-period", "0", "--diagnostics-stale", "0"])
    assert (args.diagnostics_period, args.diagnostics_stale) == (0.0, 0.0)
    for flag, bad in (("--diagnostics-period", "-1"), ("--diagnostics-hold", "inf"),
                      ("--diagnostics-stale", "soon")):  # fmt: skip
        with pytest.raises(SystemExit):
            p.parse_args(["--name", "e", flag, bad])


# -- a look between two checks of every monitor reads only what woke it ------------------


def _levels_run(seed: int, alarms: bool) -> tuple[int, int, int]:
    """A busy handler's diagnostics over a minute of random traffic (violations, holds
    ending, monitors going stale and coming back, one removed and one added, some
    defined anew): the
    looks of the diagnostics thread (an update every second, a check of every monitor
    at least every CHECK_SECONDS, and looks between as a violation or the time wakes
    them: Health.due) against a reference that checks every monitor at every look.
    With ``alarms`` (as the ROS layer does), a check of every monitor between updates is
    made only when alarm_counts changed. Returns the looks made: of every monitor, of
    some, and those that read nothing."""
    import random

    rng = random.Random(seed)
    rig = Rig(period=1.0, hold=rng.choice([0.5, 2.0, 10.0]), stale=rng.choice([0.0, 1.5, 10.0]))
    reference = Health("edge", rig.health.config, clock=rig.clock)
    rig.engine.sinks.append(reference)
    names = [f"m{i}" for i in range(rng.randint(2, 12))]
    quiet = set(rng.sample(names, k=len(names) // 3))  # they read /quiet, which seldom speaks
    signal = {"speed": {"topic": "/quiet", "type": "std_msgs/msg/Float64"}}

    def define(name: str, assertion: str) -> None:
        if name in quiet:
            rig.engine.put(compiled(assertion, signal, name=name, sortThreshold=1), active=True)
        else:
            rig.put(assertion, name=name, sortThreshold=1)

    for name in names:
        define(name, f"always (speed < {rng.choice([100, 120, 150])})")
    h, start = rig.health, rig.clock.monotonic()
    whole = some = idle = 0
    next_update = start
    renewed: set[str] = set()  # redefined since h's last check of every monitor
    for step in range(rng.randint(200, 400)):
        rig.later(rng.choice([0.01, 0.05, 0.1, 0.2, 0.3]))
        now = rig.clock.monotonic()
        if rng.random() < 0.6:
            rig.send(*[rng.uniform(0, 160) for _ in range(rng.randint(1, 4))])
        if rng.random() < 0.03:
            rig.stamp += 1000
            rig.engine.ingest([(rig.stamp, "/quiet", [rng.uniform(0, 160)])])
            rig.engine.emit(rig.engine.tick())
        if step == 150:
            rig.engine.remove(names[0])
        if step == 160:
            rig.put("always (speed < 90)", name="late")
        for name in quiet:  # (their topic brings nothing: they go stale)
            slot = rig.engine.slots.get(name)
            if slot is not None and rng.random() < 0.005:
                define(name, "always (speed < 100)")  # anew
                renewed.add(MONITOR_PREFIX + name)
        update = now >= next_update
        if update:
            next_update = now + 1.0
        fingerprint = rig.engine.fingerprint()
        statuses = h.due(
            lambda fp, some_names: read_engine(rig.engine, fingerprint=fp, names=some_names),
            fingerprint,
            now,
            update,
            alarm_counts(rig.engine, h.stale_topics()) if alarms else None,
        )
        expected = reference.check(read_engine(rig.engine), now)
        made_whole = h._whole_at == now
        if statuses is None:
            idle += not made_whole
        else:
            h.published(statuses)
        whole += made_whole
        some += statuses is not None and not made_whole

        def staleness_apart(name: str, *shown: object) -> bool:
            """Stale on one side (its level, or its text), and the two noticed the
            monitor's last events at different reads (h reads it less often: "when they
            last grew" is when a read saw them grow, on each side)."""
            a, b = (x._tracks.get(name[len(MONITOR_PREFIX) :]) for x in (h, reference))
            apart = a is not None and b is not None and a.last_event != b.last_event
            stale = any(x == Level.STALE or "no event for over" in str(x) for x in shown)
            return apart and stale

        seen = {s.name: s for s in reference.statuses()}
        for s in statuses or []:  # each status published is the reference's, level and text
            if s.name.startswith("edgerv handler: "):  # (its rate is over "the last period",
                assert s.level == seen[s.name].level  # whose base the two differ on)
            elif s.name in seen and not staleness_apart(
                s.name, s.level, seen[s.name].level, s.message, seen[s.name].message
            ):
                assert (s.level, s.message) == (seen[s.name].level, seen[s.name].message)
        published = h._published
        for name, level in expected.items():
            if name not in published or staleness_apart(name, published[name], level):
                continue  # (appears with the next update)
            if made_whole:
                assert published[name] == level, (seed, step, name)
            elif published[name] != level and name not in renewed:
                # but for a monitor defined anew, only a stale monitor that an event
                # brought back waits for the next check of every monitor (no time and no
                # violation makes it OK)
                assert (published[name], level) == (Level.STALE, Level.OK), (seed, step, name)
        if made_whole:
            renewed.clear()
    return whole, some, idle


@pytest.mark.parametrize("alarms", [False, True], ids=["polled", "alarmed"])
@pytest.mark.parametrize("seed", range(12))
def test_a_look_reads_what_woke_it_and_publishes_what_a_whole_check_would(
    seed: int, alarms: bool
) -> None:
    whole, some, idle = _levels_run(seed, alarms)
    assert whole >= 10 and some + idle >= 10  # (both kinds of look were made)


def test_the_alarm_counts_change_with_what_changes_a_level_and_not_with_traffic() -> None:
    """alarm_counts, which lets a check of every monitor between updates be skipped:
    steady traffic leaves it as it is; each thing that may change a level other than a
    violation or time changes it."""
    rig = Rig()
    rig.put(name="small", sortThreshold=8, bufferCapacity=8)
    rig.put(name="cap")
    e = rig.engine
    e.flush_after = 1e9  # (its sort buffer stays full: no flush by time)
    seen = [alarm_counts(e)]

    def differs(stale: tuple[str, ...] = ()) -> None:
        now = alarm_counts(e, stale)
        assert now != seen[-1], now
        seen.append(alarm_counts(e))

    rig.send(1.0, 2.0, 3.0)  # traffic: 3 of 8 wait in the small one's sort buffer
    assert alarm_counts(e) == seen[-1]
    rig.send(4.0, 5.0)  # 5 of 8: past HIGH_WATER at the tick
    differs()
    rig.later(PRESSURE)  # full for long enough: migration wanted
    e.emit(e.tick())
    assert e.slots["small"].migration_wanted
    differs()
    rig.put(name="tiny", sortThreshold=3, bufferCapacity=3)
    seen.append(alarm_counts(e))
    e.ingest([(rig.stamp + i, "/speed", [1.0]) for i in range(1, 6)])  # 2 of 5 dropped
    assert e.slots["tiny"].dropped == 2
    differs()
    e.note_reaction("cap", "the service did not answer")
    differs()
    e.lost["/speed"] = 3
    differs()
    rig.put(name="other")  # a monitor defined
    differs()
    e.remove("other")
    differs()
    stale = alarm_counts(e, ("/speed",))
    rig.send(1.0)  # a message on a stale monitor's topic
    assert alarm_counts(e, ("/speed",)) != stale


PRESSURE = engine_module.PRESSURE_SECONDS
