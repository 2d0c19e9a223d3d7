"""A Monitor's status and Events from its handlers' reports (the operator's pure part,
edgerv_operator.status), as a user reads them with `kubectl get/describe monitor`."""

from __future__ import annotations

from typing import Any

from edgerv_operator.documents import HandlerPod
from edgerv_operator.status import Survey, invalid, moved, refreshed, tally

EDGE = HandlerPod("edge-1", "edge", "10.0.0.1:8470", "h-edge", "uid-e/0")
CLOUD = HandlerPod("cloud-1", "cloud", "10.0.0.2:8470", "h-cloud", "uid-c/0")
NOW = "2026-11-24T01:00:00Z"


def report(
    active: bool,
    violated: int = 0,
    events: int = 10,
    handoff: str | None = None,
    last: tuple[str, int, int] | None = None,
) -> dict[str, Any]:
    return {
        "active": active,
        "handoff": handoff,
        "state": "violated" if active and violated else "inactive",
        "events": events,
        "verdicts": {"violated": violated, "satisfied": 0},
        "lastVerdict": dict(zip(("verdict", "stamp", "step"), last, strict=True)) if last else None,
    }


def refresh(
    previous: dict[str, Any], reports: dict[HandlerPod, Any], at: float = 1000.0, **kw: Any
) -> tuple[dict[str, Any], list[Any]]:
    return refreshed(previous, Survey(reports, kw.get("silent", ())), 3, NOW, at)


def test_running_on_one_handler_reads_as_a_user_expects() -> None:
    s, events = refresh({}, {EDGE: report(True, 2, 50, last=("violated", 900, 40)), CLOUD: None})
    assert s["phase"] == "Running" and s["tier"] == "edge"
    assert s["handler"] == {"pod": "h-edge", "node": "edge-1", "incarnation": "uid-e/0"}
    assert s["verdicts"] == {"violated": 2, "satisfied": 0} and s["events"] == 50
    assert s["lastVerdict"] == {"verdict": "violated", "stamp": 900, "step": 40}
    ready = {c["type"]: c for c in s["conditions"]}
    assert ready["Valid"]["status"] == "True" and ready["Ready"]["status"] == "True"
    assert ready["Ready"]["observedGeneration"] == 3 and ready["Ready"]["lastTransitionTime"] == NOW
    assert [(e.type, e.reason) for e in events] == [("Warning", "Violated")]
    assert "violated 2 more times (2 in all); the last at step 40, stamp 900" in events[0].message


def test_violated_events_are_rate_limited_and_say_how_many_since() -> None:
    s, events = refresh({}, {EDGE: report(True, 1)}, at=1000.0)
    assert len(events) == 1
    s, events = refresh(s, {EDGE: report(True, 5)}, at=1030.0)  # within a minute: none
    assert events == []
    s, events = refresh(s, {EDGE: report(True, 5)}, at=1070.0)
    assert [e.message.split(" (")[0] for e in events] == ["violated 4 more times"]
    s, events = refresh(s, {EDGE: report(True, 5)}, at=1200.0)  # no new violation: none
    assert events == []


def test_a_status_refresh_with_nothing_new_posts_nothing_and_keeps_transition_times() -> None:
    s, _ = refresh({}, {EDGE: report(True)})
    again, events = refreshed(s, Survey({EDGE: report(True)}), 3, "2026-11-24T02:00:00Z", 2000.0)
    assert events == []
    assert [c["lastTransitionTime"] for c in again["conditions"]] == [NOW, NOW]


def test_counts_never_go_down_when_a_handler_restarts_or_redefines() -> None:
    s, _ = refresh({}, {EDGE: report(True, 3, 100), CLOUD: report(False, 4, 20)})
    assert s["verdicts"]["violated"] == 7 and s["events"] == 120
    restarted = HandlerPod("edge-1", "edge", "10.0.0.1:8470", "h-edge", "uid-e/1")
    s, _ = refresh(s, {restarted: report(True, 1, 5), CLOUD: report(False, 4, 20)})
    assert s["verdicts"]["violated"] == 3 + 4 + 1 and s["events"] == 125
    s, _ = refresh(s, {restarted: report(True, 0, 2), CLOUD: report(False, 4, 20)})  # redefined
    assert s["verdicts"]["violated"] == 3 + 1 + 4 + 0 and s["events"] == 127
    silent, _ = refresh(s, {CLOUD: report(False, 4, 20)}, silent=[restarted])
    assert silent["verdicts"] == s["verdicts"] and silent["events"] == s["events"]


def test_tally_keeps_a_silent_handler_and_carries_a_gone_one() -> None:
    state, totals = tally(None, Survey({EDGE: report(True, 2, 9)}))
    assert totals == {"violated": 2, "satisfied": 0, "events": 9}
    state, totals = tally(state, Survey({}, [EDGE]))
    assert state["carried"]["events"] == 0 and totals["events"] == 9
    state, totals = tally(state, Survey({CLOUD: None}))
    assert state["carried"]["events"] == 9 and state["seen"] == {} and totals["events"] == 9


def test_a_handler_gone_with_the_monitor_is_state_lost_once() -> None:
    s, _ = refresh({}, {EDGE: report(True, 0, 40, last=("satisfied", 5, 12))})
    restarted = HandlerPod("edge-1", "edge", "10.0.0.1:8470", "h-edge", "uid-e/1")
    s, events = refresh(s, {restarted: None, CLOUD: None})
    assert [(e.type, e.reason) for e in events] == [("Warning", "StateLost")]
    assert "h-edge on edge-1 is gone or restarted" in events[0].message
    assert "step 12" in events[0].message
    assert s["stateLost"]["count"] == 1 and s["phase"] == "Pending"
    s, events = refresh(s, {restarted: None, CLOUD: None})
    assert events == []  # said once
    s, events = refresh(s, {restarted: None, CLOUD: report(True)})
    assert events == [] and s["phase"] == "Running" and s.get("migrations") is None
    assert s["handler"]["node"] == "cloud-1" and "lost" not in s["handler"]


def test_a_silent_handler_is_not_a_lost_one() -> None:
    s, _ = refresh({}, {EDGE: report(True)})
    s, events = refresh(s, {CLOUD: None}, silent=[EDGE])
    assert events == [] and "stateLost" not in s


def test_a_move_by_the_operator_is_recorded_and_said_once() -> None:
    s, _ = refresh({}, {EDGE: report(True)})
    s, events = moved(s, EDGE, CLOUD, "spec.placement.tier is cloud", NOW, 123.4)
    assert [(e.type, e.reason) for e in events] == [("Normal", "Moved")]
    assert (
        "from edge-1 (edge) to cloud-1 (cloud) in 123 ms: spec.placement.tier" in events[0].message
    )
    assert s["migrations"]["count"] == 1
    assert (
        s["migrations"]["last"]["toTier"] == "cloud"
        and s["migrations"]["last"]["durationMs"] == 123.4
    )
    s, events = refresh(s, {EDGE: report(False), CLOUD: report(True)})
    assert events == [] and s["migrations"]["count"] == 1 and s["tier"] == "cloud"


def test_a_move_made_by_someone_else_is_counted_as_observed() -> None:
    s, _ = refresh({}, {EDGE: report(True)})
    s, events = refresh(s, {EDGE: report(False), CLOUD: report(True)})
    assert s["migrations"]["count"] == 1 and s["migrations"]["last"]["reason"] == "observed"
    assert events == []


def test_migrating_and_active_twice_are_not_ready() -> None:
    s, _ = refresh(
        {}, {EDGE: report(False, handoff="released"), CLOUD: report(False, handoff="receiving")}
    )
    assert s["phase"] == "Migrating"
    s, _ = refresh({}, {EDGE: report(True), CLOUD: report(True)})
    ready = {c["type"]: c for c in s["conditions"]}["Ready"]
    assert (ready["status"], ready["reason"]) == ("False", "ActiveOnSeveral")
    assert "edge-1, cloud-1" in ready["message"] or "cloud-1, edge-1" in ready["message"]


def test_an_invalid_spec_is_an_error_with_its_field_said_once() -> None:
    message = "spec.assertion, column 17: unknown signal or parameter 'limt'"
    s, events = invalid({}, message, 2, NOW)
    assert s["phase"] == "Error" and s["observedGeneration"] == 2
    valid = {c["type"]: c for c in s["conditions"]}["Valid"]
    assert (valid["status"], valid["reason"], valid["message"]) == ("False", "InvalidSpec", message)
    assert [(e.type, e.reason, e.message) for e in events] == [("Warning", "InvalidSpec", message)]
    _, events = invalid(s, message, 2, NOW)
    assert events == []
