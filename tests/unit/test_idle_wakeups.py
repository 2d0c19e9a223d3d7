"""When an idle handler works (issue 35). Its scheduler ticks every period while
messages come or something is buffered, else only at the next instant a tick can change
anything (a clock step, a sort buffer's flush), at most IDLE_TICK_SECONDS away; its
diagnostics thread skips a check of the levels that would read nothing new
(Health.settled). No timing: the plans are asked at given instants, under a system
clock whose wall time is fixed."""

from __future__ import annotations

import itertools
import threading

from edgerv.core.documents import load_monitors_text
from edgerv.core.monitor import compile_monitor
from edgerv.handler.clock import SystemClock
from edgerv.handler.engine import IDLE_TICK_SECONDS, Engine
from edgerv.handler.health import DiagnosticsConfig, Health, Level, read_engine
from edgerv.handler.ros.cdr_out import encode_diagnostic_array, restamp_diagnostic_array
from kit.engines import ManualClock

S = 1_000_000_000
MS = 1_000_000
WALL = 1_700_000_000 * S


class FixedWall(SystemClock):
    """The system clock's kind, at a wall time the test sets."""

    def __init__(self, wall_ns: int = WALL) -> None:
        self.wall = wall_ns

    def wall_ns(self) -> int:
        return self.wall


def monitor(name: str, assertion: str, extra: str = "") -> str:
    return (
        "apiVersion: edgerv.io/v1alpha1\nkind: Monitor\n"
        f"metadata: {{name: {name}}}\n"
        f'spec:\n  assertion: "{assertion}"\n{extra}'
        "  signals:\n    x: {topic: /x, type: std_msgs/msg/Float64}\n"
    )


def engine(*docs: str, clock: SystemClock | None = None) -> Engine:
    e = Engine("edge", flush_after=0.5, clock=clock or FixedWall())
    for spec in load_monitors_text("m.yaml", "---\n".join(docs)):
        e.put(compile_monitor(spec), active=True)
    e.ingested = False  # (nothing came yet)
    return e


def test_an_idle_engine_plans_no_tick_before_the_longest_doze() -> None:
    e = engine(monitor("a", "always (x < 1)"), monitor("b", "always (x > 0)"))
    assert e.next_tick_due(100.0, 0.05) == 100.0 + IDLE_TICK_SECONDS


def test_messages_since_the_last_tick_bring_the_next_one_a_period_away() -> None:
    e = engine(monitor("a", "always (x < 1)"))
    e.ingest([(WALL, "/x", [0.5])], now=100.0)
    e.evaluate()
    assert e.next_tick_due(100.0, 0.05) == 100.05
    assert e.next_tick_due(100.0, 0.05) == 100.0 + IDLE_TICK_SECONDS  # (said once: reset)


def test_letters_or_events_waiting_tick_every_period() -> None:
    sorted_ = "  sortThreshold: 3\n"
    e = engine(monitor("a", "always (x < 1)", sorted_))
    e.ingest([(WALL, "/x", [0.5])], now=100.0)  # one event in a sort buffer of 3
    e.ingested = False
    assert e.next_tick_due(100.0, 0.05) == 100.05


def test_a_clock_step_is_planned_flush_after_past_its_instant() -> None:
    e = engine(monitor("a", "always (age(x) < 200ms)"))
    e.ingest([(WALL - 100 * MS, "/x", [0.5])], now=100.0)
    e.evaluate()
    e.ingested = False
    # the step falls 200 ms after the message, taken flush_after (0.5 s) late; the wall
    # clock reads the message's stamp + 100 ms now
    due = e.next_tick_due(100.0, 0.05)
    assert abs(due - (100.0 + 0.1 + 0.5)) < 1e-6
    e.drained_at = WALL + 700 * MS
    e.advance_clocks(WALL + 700 * MS)  # the step taken: no clock step left to plan
    assert [v.verdict for v in e.evaluate()] == ["violated"]
    assert e.next_tick_due(100.0, 0.05) == 100.0 + IDLE_TICK_SECONDS


def test_a_step_not_taken_when_due_is_tried_again_a_period_later() -> None:
    e = engine(monitor("a", "always (age(x) < 200ms)"))
    e.ingest([(WALL - 10 * S, "/x", [0.5])], now=100.0)  # its step long due
    e.evaluate()
    e.ingested = False
    assert e.next_tick_due(100.0, 0.05) == 100.05


def test_under_a_clock_other_than_the_systems_it_ticks_every_period() -> None:
    e = Engine("edge", flush_after=0.5, clock=ManualClock())
    assert e.next_tick_due(100.0, 0.05) == 100.05


def test_a_message_wakes_a_long_doze_and_the_scheduler_ticks_every_period_again() -> None:
    e = engine(monitor("a", "always (x < 1)", "  sortThreshold: 3\n"))
    with e.lock:
        e.dozing, e.doze_until = True, 1e12  # (asleep until far away)
        e.ingest([(WALL, "/x", [0.5])], now=100.0)
        assert e.replan and not e.dozing  # woken to plan anew
    assert e.next_tick_due(100.0, 0.05) == 100.05


def test_the_scheduler_thread_evaluates_and_stops_when_idle() -> None:
    e = engine(monitor("a", "always (x < 1)"))
    got: list[str] = []

    class Sink:
        def write(self, handler: str, verdicts: object) -> None:
            got.extend(v.verdict for v in verdicts)  # type: ignore[attr-defined]
            done.set()

    e.sinks.append(Sink())
    stop, done = threading.Event(), threading.Event()
    thread = threading.Thread(target=e.run_scheduler, args=(stop,), daemon=True)
    thread.start()
    e.ingest([(WALL, "/x", [2.0])])
    assert done.wait(30)
    stop.set()
    e.wake()
    thread.join(30)
    assert got == ["violated"] and not thread.is_alive()


# -- /diagnostics: a check that would read nothing new is skipped -------------------------


def _health_rig() -> tuple[Engine, Health]:
    e = engine(monitor("a", "always (x < 1)"), monitor("b", "always (x > 0)"))
    return e, Health("edge", DiagnosticsConfig(period=1.0, hold=10.0, stale=10.0))


def _fingerprint(e: Engine) -> object:
    return e.fingerprint()


def _check(e: Engine, h: Health, now: float) -> dict[str, Level]:
    fp = _fingerprint(e)
    levels = h.check(read_engine(e, fingerprint=fp), now)
    if h.level_changed(levels) or not h._published:
        h.published(h.statuses())
    return levels


def test_checks_settle_once_one_sees_what_the_last_one_saw() -> None:
    e, h = _health_rig()
    _check(e, h, 0.0)
    assert not h.settled(_fingerprint(e), 0.25)  # (the first look: a change)
    _check(e, h, 0.25)  # its base (the reading at 0.0) has the same counts as now
    assert h.settled(_fingerprint(e), 0.5)
    assert not h.settled(None, 0.5)  # (no fingerprint: never)


def test_a_change_settles_only_when_the_last_period_began_after_it() -> None:
    e, h = _health_rig()
    for now in (0.0, 0.25, 0.5, 0.75, 1.0, 1.25):
        _check(e, h, now)
    e.ingest([(WALL, "/x", [0.5])], now=1.3)
    e.evaluate()
    for now in (1.5, 1.75, 2.0, 2.25):  # "the last period" still begins before the change
        _check(e, h, now)
        assert not h.settled(_fingerprint(e), now + 0.25)
    _check(e, h, 2.5)  # its base: the reading at 1.5, the first after the change
    assert h.settled(_fingerprint(e), 2.75)


def test_a_message_or_an_evaluation_unsettles_the_checks() -> None:
    e, h = _health_rig()
    for now in (0.0, 0.5, 1.0):
        _check(e, h, now)
    assert h.settled(_fingerprint(e), 1.25)
    e.ingest([(WALL, "/x", [0.5])], now=1.1)
    assert not h.settled(_fingerprint(e), 1.25)
    _check(e, h, 1.25)
    e.evaluate()
    assert not h.settled(_fingerprint(e), 1.5)


def test_a_monitor_going_stale_is_checked_when_it_falls_due() -> None:
    e, h = _health_rig()
    for now in (0.0, 0.5, 1.0):
        levels = _check(e, h, now)
    assert set(levels.values()) == {Level.OK}
    assert h.settled(_fingerprint(e), 9.9)
    assert not h.settled(_fingerprint(e), 10.0)  # no event for 10 s from 0.0: STALE now
    levels = _check(e, h, 10.0)
    assert levels["edgerv: a"] == Level.STALE


def test_a_level_change_not_yet_published_is_never_skipped() -> None:
    e, h = _health_rig()
    for now in (0.0, 0.5, 1.0):
        _check(e, h, now)
    fp = _fingerprint(e)
    levels = h.check(read_engine(e, fingerprint=fp), 10.0)  # STALE, not published
    assert h.level_changed(levels)
    levels = h.check(read_engine(e, fingerprint=fp), 11.0)
    assert not h.settled(fp, 11.25)
    h.published(h.statuses())
    assert h.settled(fp, 11.25)


# -- a few messages while the scheduler dozes: evaluated by the ingest thread ------------


def test_a_dozing_scheduler_is_not_woken_for_letters_that_reach_no_verdict() -> None:
    e = engine(monitor("a", "always (x < 1)"))
    with e.lock:
        e.dozing, e.doze_until = True, 100.04  # (a period away: no replan)
        e.ingest([(WALL, "/x", [0.5])], now=100.0)
        assert e.dozing and not e.waiting  # evaluated here; still asleep
    assert e.slots["a"].runtime is not None and e.slots["a"].runtime.step == 1
    assert e.evaluate() == []


def test_a_verdict_reached_by_ingest_wakes_the_scheduler_which_hands_it_on_in_order() -> None:
    e = engine(monitor("a", "always (x < 1)", "  onVerdict: reset\n"))
    with e.lock:
        e.dozing, e.doze_until = True, 100.04
        e.ingest([(WALL, "/x", [2.0])], now=100.0)
        assert not e.dozing  # woken: a verdict to hand on
        e.dozing = True
        e.ingest([(WALL + 1, "/x", [3.0])], now=100.0)
    assert [(v.verdict, v.step) for v in e.evaluate()] == [("violated", 1), ("violated", 2)]
    assert e.evaluate() == []


def test_many_monitors_with_letters_are_left_to_the_scheduler() -> None:
    from edgerv.handler.engine import INLINE_MONITORS

    # (a past operator: its letters wait to be evaluated; a plain monitor walks its own)
    docs = [monitor(f"m{i}", "always (x < 1 | once x > 5)") for i in range(INLINE_MONITORS + 1)]
    e = engine(*docs)
    with e.lock:
        e.dozing, e.doze_until = True, 100.04
        e.ingest([(WALL, "/x", [0.5])], now=100.0)
        assert not e.dozing and len(e.waiting) == INLINE_MONITORS + 1  # woken to evaluate


def test_an_idle_monitors_status_values_are_made_once_and_anew_after_a_change() -> None:
    e, h = _health_rig()
    _check(e, h, 0.0)
    first = {s.name: s for s in h.statuses()}
    _check(e, h, 12.0)  # stale now: another level and message, the same values
    later = {s.name: s for s in h.statuses()}
    a, b = first["edgerv: a"], later["edgerv: a"]
    assert b.level == Level.STALE and b.message == "no event for over 10 s"
    assert b.values is a.values  # (kept, not made again)
    e.ingest([(WALL, "/x", [0.5])], now=12.5)
    e.evaluate()
    _check(e, h, 13.0)
    after = {s.name: s for s in h.statuses()}["edgerv: a"]
    assert dict(after.values)["events"] == "1" and dict(after.values)["step"] == "1"
    assert after.level == Level.OK


# -- /diagnostics: an idle handler's update is the statuses last published ---------------


def test_an_idle_update_sends_the_statuses_last_published_as_a_reading_would_give_them() -> None:
    """Health.due at each look of the diagnostics thread (every CHECK_SECONDS, an update
    every period) over two idle minutes, with a violation held, monitors going stale and
    their age passing a minute: each update equals what a full reading gives at that
    instant (a second Health that reads every time), and most are the very statuses last
    published, read from nothing."""
    e = engine(monitor("a", "always (x < 1)"), monitor("b", "always (x > 0)"))
    config = DiagnosticsConfig(period=1.0, hold=10.0, stale=10.0)
    clock = ManualClock()  # (when the sinks note a violation)
    h, reference = Health("edge", config, clock), Health("edge", config, clock)
    e.sinks += [h, reference]
    sent: list[object] = []
    for quarter in range(4 * 130):
        now = clock.offset = quarter * 0.25
        if quarter == 21:  # a is violated at 5.25 s: held for 10 s
            e.ingest([(WALL, "/x", [2.0])], now=now)
            e.emit(e.evaluate())
        update = quarter % 4 == 0
        statuses = h.due(
            lambda fp, names: read_engine(e, fingerprint=fp, names=names),
            e.fingerprint(),
            now,
            update,
        )
        if statuses is None:
            assert not update
            continue
        h.published(statuses)
        if update:
            reference.check(read_engine(e), now)
            expected = reference.statuses()
            reference.published(expected)
            assert statuses == expected, now
            sent.append(statuses)
    texts = {s.message for statuses in sent for s in statuses}  # type: ignore[attr-defined]
    assert {"no event for over 10 s", "no event for over 1 min"} <= texts
    assert any(m.startswith("violated at step 1 ") for m in texts)
    again = sum(a is b for a, b in itertools.pairwise(sent))
    assert again >= 100, again  # of 129 updates: only those after a change are made anew


def test_a_tier_edit_unsettles_the_checks() -> None:
    """A definition that differs only in its placement keeps the monitor running, and its
    status shows the new tier: the fingerprint changes."""
    e, h = _health_rig()
    for now in (0.0, 0.5, 1.0):
        _check(e, h, now)
    assert h.settled(_fingerprint(e), 1.25)
    (spec,) = load_monitors_text(
        "m.yaml", monitor("a", "always (x < 1)", "  placement: {tier: cloud}\n")
    )
    assert not e.put(compile_monitor(spec), active=True)  # (the same monitor, running on)
    assert not h.settled(_fingerprint(e), 1.25)


def test_statuses_sent_again_are_the_bytes_sent_before_with_a_new_stamp() -> None:
    e, h = _health_rig()
    _check(e, h, 0.0)
    statuses = h.statuses()
    first = encode_diagnostic_array(statuses, 1_700_000_000 * S + 5)
    again = restamp_diagnostic_array(first, 1_700_000_001 * S + 999_999_999)
    assert again == encode_diagnostic_array(statuses, 1_700_000_001 * S + 999_999_999)
    assert again != first and len(again) == len(first)


def test_a_change_of_level_sends_the_handlers_status_and_the_changed_ones_only() -> None:
    e = engine(monitor("a", "always (x < 1)"), monitor("b", "always (x > 0)"))
    clock = ManualClock()
    h = Health("edge", DiagnosticsConfig(period=1.0, hold=10.0, stale=0), clock)
    e.sinks.append(h)

    def due(now: float, update: bool) -> list[str] | None:
        clock.offset = now
        statuses = h.due(
            lambda fp, names: read_engine(e, fingerprint=fp, names=names),
            e.fingerprint(),
            now,
            update,
        )
        if statuses is None:
            return None
        h.published(statuses)
        return [s.name for s in statuses]

    everything = ["edgerv handler: edge", "edgerv: a", "edgerv: b"]
    assert due(0.0, True) == everything
    assert due(0.25, False) is None
    e.ingest([(WALL, "/x", [2.0])], now=0.3)  # a violated: ERROR; b satisfied: still OK
    e.emit(e.evaluate())
    assert due(0.5, False) == ["edgerv handler: edge", "edgerv: a"]
    assert due(0.75, False) is None  # published: no change since
    assert due(1.0, True) == everything  # the update: all of them, made anew
    assert due(10.5, False) == ["edgerv handler: edge", "edgerv: a"]  # the hold ended


# -- the take loop, idle: woken when the scheduler needs to know how far it took ----------


def test_a_tick_that_finds_drained_at_out_of_date_wakes_the_take_loop() -> None:
    """An idle take loop says how far everything is taken (drained_at) only every
    IDLE_WAIT_SECONDS; a tick that finds it said so longer than STALE_DRAINED_SECONDS
    ago wakes it (a monitor's clock steps only up to drained_at), one that finds it said
    so since does not (a busy loop: waking it would tell nothing new)."""
    import time

    from edgerv.handler.engine import STALE_DRAINED_SECONDS

    e = engine(monitor("a", "always (x > 0 -> F[0..1s] x < 0)"))
    wakes: list[int] = []
    e.wake_ingest = lambda: wakes.append(1)
    e.drained_at, e.drained_said = WALL, time.monotonic()
    e.tick(100.0)
    assert wakes == []
    e.drained_said = time.monotonic() - STALE_DRAINED_SECONDS - 0.01
    e.tick(100.1)
    assert wakes == [1]


def test_an_idle_tick_that_would_change_nothing_is_planned_to_be_skipped() -> None:
    """A plan of the longest doze for monitors without a clock notes the engine's
    fingerprint: the scheduler skips that tick while it stays (nothing could change);
    a monitor with a clock is never planned so, nor one after a message."""
    e = engine(monitor("a", "always (x < 1)"))
    assert e.next_tick_due(100.0, 0.05) == 100.0 + IDLE_TICK_SECONDS
    assert e.idle_plan == e.fingerprint()
    e.ingest([(WALL, "/x", [0.5])], now=100.1)
    assert e.idle_plan != e.fingerprint()  # (the scheduler ticks then)
    e.evaluate()
    e.next_tick_due(100.2, 0.05)
    assert e.idle_plan is None  # messages came since the last plan: a period away
    timed = engine(monitor("b", "always (x > 0 -> F[0..1s] x < 0)"))
    timed.next_tick_due(100.0, 0.05)
    assert timed.idle_plan is None
