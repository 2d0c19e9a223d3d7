"""A fleet's status (issue 36): a Monitor with an instance per robot reads as a
DaemonSet does, ``desired``, ``running`` and ``violated`` robots, each robot's entry in
``status.robots``, the verdicts over all of them, the newest verdict, one phase
(edgerv_operator.status.robot_refreshed, fleet_refreshed). One instance's status:
tests/unit/test_operator_status.py."""

from __future__ import annotations

import copy
from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from edgerv_operator.documents import HandlerPod
from edgerv_operator.status import (
    ROBOT_FIELDS,
    SINGLE_FIELDS,
    Event,
    Survey,
    fleet_refreshed,
    refreshed,
    robot_refreshed,
)
from kit.counts import props

NOW = "2026-11-24T01:00:00Z"
LATER = "2026-11-24T02:00:00Z"


def entry(
    phase: str = "Running",
    violated: int = 0,
    satisfied: int = 0,
    events: int = 10,
    last: tuple[str, int, int] | None = None,
) -> dict[str, Any]:
    """A robot's entry in status.robots, as robot_refreshed makes it."""
    out: dict[str, Any] = {
        "phase": phase,
        "message": f"{phase.lower()} somewhere",
        "verdicts": {"violated": violated, "satisfied": satisfied},
        "events": events,
    }
    if last is not None:
        out["lastVerdict"] = dict(zip(("verdict", "stamp", "step"), last, strict=True))
    return out


def fleet(
    robots: dict[str, dict[str, Any]],
    previous: dict[str, Any] | None = None,
    cluster: list[str] | None = None,
    events: list[Event] | None = None,
    now: str = NOW,
) -> tuple[dict[str, Any], list[Event]]:
    return fleet_refreshed(previous or {}, robots, cluster or sorted(robots), 4, now, events or [])


def conditions(status: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {c["type"]: c for c in status["conditions"]}


# -- a robot's entry -------------------------------------------------------------------------


def test_a_robots_entry_keeps_its_instances_own_fields_only() -> None:
    edge = HandlerPod("amr-7-a", "edge", "10.0.0.1:8470", "h-edge", "uid-e/0", "amr-7")
    report = {
        "active": True,
        "handoff": None,
        "state": "violated",
        "events": 40,
        "verdicts": {"violated": 2, "satisfied": 1},
        "lastVerdict": {"verdict": "violated", "stamp": 900, "step": 40},
    }
    instance, _ = refreshed({}, Survey({edge: report}), 4, NOW, 1000.0)  # type: ignore[dict-item]
    out = robot_refreshed(instance)
    assert set(out) == set(ROBOT_FIELDS) & set(instance)
    assert "conditions" not in out and "observedGeneration" not in out  # the Monitor's
    assert out["phase"] == "Running" and out["tier"] == "edge"
    assert out["handler"] == {"pod": "h-edge", "node": "amr-7-a", "incarnation": "uid-e/0"}
    assert out["verdicts"] == {"violated": 2, "satisfied": 1} and out["events"] == 40
    assert out["lastVerdict"] == {"verdict": "violated", "stamp": 900, "step": 40}
    assert {"tally", "violationEvents"} <= set(out)  # its bookkeeping goes with it
    # a copy: the entry and the instance's status are not shared
    before = copy.deepcopy(instance)
    out["verdicts"]["violated"] = 99
    out["handler"]["pod"] = "x"
    assert instance == before
    assert robot_refreshed({"phase": "Pending", "conditions": [], "robots": {}}) == {
        "phase": "Pending"
    }


# -- the totals ------------------------------------------------------------------------------


def test_the_totals_count_robots_and_add_up_their_verdicts() -> None:
    robots = {
        "amr-1": entry("Running", violated=2, satisfied=1, events=50),
        "amr-2": entry("Running", violated=0, satisfied=3, events=20),
        "amr-3": entry("Pending", violated=1, events=5),
    }
    s, _ = fleet(robots)
    assert (s["desired"], s["running"], s["violated"]) == (3, 2, 2)
    assert s["verdicts"] == {"violated": 3, "satisfied": 4}
    assert s["events"] == 75
    assert s["robots"] == robots and s["robots"] is not robots
    assert s["observedGeneration"] == 4


def test_the_last_verdict_is_the_newest_by_stamp_across_robots() -> None:
    robots = {
        "amr-1": entry(last=("violated", 900, 50)),  # the most steps, not the newest
        "amr-2": entry(last=("satisfied", 1000, 3)),
        "amr-3": entry(),  # none yet
    }
    s, _ = fleet(robots)
    assert s["lastVerdict"] == {"verdict": "satisfied", "stamp": 1000, "step": 3}
    robots["amr-1"] = entry(last=("violated", 1001, 51))
    assert fleet(robots)[0]["lastVerdict"]["stamp"] == 1001
    assert fleet({"amr-3": entry()})[0]["lastVerdict"] is None  # a merge patch removes it


# -- the phase -------------------------------------------------------------------------------


def test_every_robot_running_is_running_and_ready() -> None:
    s, _ = fleet({"amr-1": entry(), "amr-2": entry()})
    assert (s["phase"], s["message"]) == ("Running", "runs on 2 robots")
    ready = conditions(s)
    assert ready["Ready"]["status"] == "True" and ready["Ready"]["reason"] == "Running"
    assert ready["Valid"]["status"] == "True" and ready["Valid"]["reason"] == "Compiled"
    assert ready["Ready"]["observedGeneration"] == 4 and ready["Ready"]["message"] == s["message"]
    one, _ = fleet({"amr-1": entry()})
    assert one["message"] == "runs on 1 robot"


def test_a_robot_not_running_makes_it_pending_or_migrating_and_says_which() -> None:
    s, _ = fleet({"amr-1": entry(), "amr-3": entry("Pending"), "amr-2": entry("Pending")})
    assert s["phase"] == "Pending"
    assert s["message"] == "runs on 1 of 3 robots; not on amr-2, amr-3"
    ready = conditions(s)["Ready"]
    assert (ready["status"], ready["reason"]) == ("False", "NotAllRunning")
    s, _ = fleet({"amr-1": entry("Migrating"), "amr-2": entry("Pending")})
    assert s["phase"] == "Migrating"
    assert s["message"] == "runs on 0 of 2 robots; not on amr-1, amr-2"
    s, _ = fleet({"amr-1": entry("Migrating"), "amr-2": entry()})
    assert (s["phase"], s["running"]) == ("Migrating", 1)


def test_selecting_no_robot_is_pending_and_names_the_robots_there_are() -> None:
    s, _ = fleet({}, cluster=["amr-1", "amr-2"])
    assert (s["phase"], s["desired"], s["running"], s["violated"]) == ("Pending", 0, 0, 0)
    assert s["message"] == "spec.robots selects none of the robots: amr-1, amr-2"
    ready = conditions(s)["Ready"]
    assert (ready["status"], ready["reason"]) == ("False", "NoRobot")
    assert ready["message"] == s["message"]
    assert fleet({}, cluster=[])[0]["message"] == "spec.robots selects none of the robots: none"
    assert s["verdicts"] == {"violated": 0, "satisfied": 0} and s["events"] == 0


def test_the_ready_condition_moves_its_transition_time_only_when_it_changes() -> None:
    first, _ = fleet({"amr-1": entry(), "amr-2": entry("Pending")})
    again, _ = fleet({"amr-1": entry(), "amr-2": entry("Pending")}, previous=first, now=LATER)
    assert [c["lastTransitionTime"] for c in again["conditions"]] == [NOW, NOW]
    ready, _ = fleet({"amr-1": entry(), "amr-2": entry()}, previous=again, now=LATER)
    times = {c["type"]: c["lastTransitionTime"] for c in ready["conditions"]}
    assert times == {"Valid": NOW, "Ready": LATER}
    assert conditions(ready)["Ready"]["status"] == "True"


# -- a merge patch: what is gone is None -----------------------------------------------------


def test_a_robot_no_longer_selected_is_removed_by_the_merge_patch() -> None:
    before, _ = fleet({"amr-1": entry(), "amr-2": entry(violated=3)})
    s, _ = fleet({"amr-1": entry()}, previous=before)
    assert s["robots"] == {"amr-1": entry(), "amr-2": None}
    assert (s["desired"], s["running"], s["violated"]) == (1, 1, 0)
    assert s["verdicts"] == {"violated": 0, "satisfied": 0}  # its own counts went with it
    # once removed (the patch applied: no key) it is not said again
    applied = {**s, "robots": {"amr-1": entry()}}
    assert fleet({"amr-1": entry()}, previous=applied)[0]["robots"] == {"amr-1": entry()}
    # none selected now: every entry goes
    none, _ = fleet({}, previous=before, cluster=["amr-1", "amr-2"])
    assert none["robots"] == {"amr-1": None, "amr-2": None}


def test_the_single_instances_fields_are_removed_once_there_are_robots() -> None:
    edge = HandlerPod("edge-1", "edge", "10.0.0.1:8470", "h-edge", "uid-e/0")
    report = {"active": True, "handoff": None, "events": 5, "verdicts": {"violated": 1}}
    single, _ = refreshed({}, Survey({edge: report}), 3, NOW, 1000.0)  # type: ignore[dict-item]
    assert {"tier", "handler", "tally", "violationEvents"} <= set(single)
    s, _ = fleet({"amr-1": entry()}, previous=single)
    for name in SINGLE_FIELDS:
        if name in single:
            assert name in s and s[name] is None, name
        else:
            assert name not in s, name  # never there: nothing to remove
    assert s["phase"] == "Running" and s["robots"] == {"amr-1": entry()}


def test_its_inputs_are_left_as_they_were_and_events_pass_through() -> None:
    previous, _ = fleet({"amr-1": entry(), "amr-2": entry()})
    previous["tier"] = "edge"
    robots = {"amr-1": entry(violated=1, last=("violated", 5, 1))}
    told = [Event("Warning", "Violated", "robot amr-1: violated 1 more time (1 in all)")]
    before = copy.deepcopy((previous, robots, told))
    s, events = fleet(robots, previous=previous, events=told)
    assert events == told
    assert (previous, robots, told) == before
    s["robots"]["amr-1"]["phase"] = "Pending"
    assert robots["amr-1"]["phase"] == "Running"


# -- the totals, over random fleets ------------------------------------------------------------

PHASES = st.sampled_from(["Running", "Pending", "Migrating"])
ENTRIES = st.builds(
    entry,
    PHASES,
    st.integers(0, 5),
    st.integers(0, 5),
    st.integers(0, 100),
    st.one_of(
        st.none(),
        st.tuples(
            st.sampled_from(["violated", "satisfied"]), st.integers(0, 10**6), st.integers(0, 99)
        ),
    ),
)
FLEETS = st.dictionaries(st.sampled_from(["amr-1", "amr-2", "amr-3", "amr-4"]), ENTRIES)


@props(100)
@given(FLEETS, FLEETS)
def test_the_totals_and_the_phase_over_random_fleets(
    before: dict[str, dict[str, Any]], robots: dict[str, dict[str, Any]]
) -> None:
    previous, _ = fleet(before)
    s, _ = fleet(robots, previous=previous, cluster=["amr-1", "amr-2", "amr-3", "amr-4"])
    running = [r for r, e in robots.items() if e["phase"] == "Running"]
    assert s["desired"] == len(robots) and s["running"] == len(running)
    assert s["violated"] == sum(1 for e in robots.values() if e["verdicts"]["violated"] > 0)
    for k in ("violated", "satisfied"):
        assert s["verdicts"][k] == sum(e["verdicts"][k] for e in robots.values())
    assert s["events"] == sum(e["events"] for e in robots.values())
    stamps = [e["lastVerdict"]["stamp"] for e in robots.values() if "lastVerdict" in e]
    if stamps:
        assert s["lastVerdict"]["stamp"] == max(stamps)
        assert s["lastVerdict"] in [e.get("lastVerdict") for e in robots.values()]
    else:
        assert s["lastVerdict"] is None  # (a merge patch removes one from before)
    assert {r for r, e in s["robots"].items() if e is None} == set(before) - set(robots)
    assert {r: e for r, e in s["robots"].items() if e is not None} == robots
    ready = conditions(s)["Ready"]["status"]
    if not robots:
        assert s["phase"] == "Pending" and ready == "False"
    elif len(running) == len(robots):
        assert s["phase"] == "Running" and ready == "True"
    else:
        migrating = any(e["phase"] == "Migrating" for e in robots.values())
        assert s["phase"] == ("Migrating" if migrating else "Pending") and ready == "False"
        assert all(r in s["message"] for r in robots if r not in running)
