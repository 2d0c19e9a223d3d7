"""A Monitor's ``status`` from what its handlers report, and the Events a user must see.

Pure: no Kubernetes and no network (tests/unit/test_operator_status.py). The Kopf
glue (:mod:`edgerv_operator.handlers`) hands in the previous status, the handlers'
reports and the time, and writes what comes out; Kubernetes API conventions: a
``phase``, ``conditions`` (``Valid``, ``Ready``) with reason, message and
``lastTransitionTime``, ``observedGeneration``.

Verdict and event counts never go down: each handler's counts are kept per
*incarnation* (its pod's UID and restart count) in ``status.tally``; when an
incarnation is gone (its pod deleted, its container restarted) or its counts
fall (the monitor redefined there), what it had counted is carried into
``tally.carried``. A handler that did not answer keeps what it last counted.
"""

from __future__ import annotations

import copy
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple, TypedDict

from edgerv.control.wire import MonitorReport as MonitorReport
from edgerv_operator.documents import HandlerPod

ConditionStatus = Literal["True", "False", "Unknown"]
VIOLATION_EVENT_SECONDS = 60.0  # at most one Violated Event a minute per monitor


class Condition(TypedDict):
    type: str
    status: ConditionStatus
    reason: str
    message: str
    lastTransitionTime: str
    observedGeneration: int


class Tally(TypedDict):
    violated: int
    satisfied: int
    events: int


class TallyState(TypedDict):
    carried: Tally  # from handler incarnations that are gone
    seen: dict[str, Tally]  # incarnation -> its counts when last read


class Whereabouts(TypedDict):
    pod: str
    node: str
    incarnation: str


class MoveRecord(TypedDict):
    fromNode: str
    toNode: str
    fromTier: str
    toTier: str
    time: str
    reason: str
    durationMs: float


class Migrations(TypedDict, total=False):
    count: int
    last: MoveRecord


class Event(NamedTuple):
    """A Kubernetes Event to post on the Monitor."""

    type: Literal["Normal", "Warning"]
    reason: str
    message: str


@dataclass(frozen=True)
class Survey:
    """The handlers' reports on one monitor: ``reports`` for the handlers that answered
    (None: it does not define the monitor), ``silent`` the handlers that did not.
    ``answered``: every handler that answered, when ``reports`` holds only those that
    define the monitor (a fleet's survey: an instance is defined on its robot's handlers
    and the shared ones, of a hundred; None: the handlers of ``reports``)."""

    reports: Mapping[HandlerPod, MonitorReport | None]
    silent: Collection[HandlerPod] = ()
    answered: Collection[HandlerPod] | None = None

    def pods(self) -> Collection[HandlerPod]:
        """Every handler that answered."""
        return self.reports.keys() if self.answered is None else self.answered

    def defines(self, pod: HandlerPod) -> bool | None:
        """Whether ``pod`` defines the monitor (None: it did not answer)."""
        if pod in self.reports:
            return self.reports[pod] is not None
        return False if pod in self.pods() else None


def _copy(value: Any) -> Any:
    """A deep copy of a status (JSON: dicts, lists and scalars), five times faster than
    ``copy.deepcopy``, which a fleet's refresh did for each robot's entry of each Monitor."""
    if isinstance(value, dict):
        return {k: _copy(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_copy(v) for v in value]
    if value is None or isinstance(value, str | int | float):
        return value
    if isinstance(value, Mapping):  # (Kopf's views of a body)
        return {k: _copy(v) for k, v in value.items()}
    return copy.deepcopy(value)


def _zero() -> Tally:
    return {"violated": 0, "satisfied": 0, "events": 0}


def _tally_of(r: MonitorReport) -> Tally:
    v = r.get("verdicts") or {}
    return {
        "violated": int(v.get("violated", 0)),
        "satisfied": int(v.get("satisfied", 0)),
        "events": int(r.get("events", 0)),
    }


def _add(a: Tally, b: Tally) -> Tally:
    return {
        "violated": a["violated"] + b["violated"],
        "satisfied": a["satisfied"] + b["satisfied"],
        "events": a["events"] + b["events"],
    }


def tally(previous: Mapping[str, Any] | None, survey: Survey) -> tuple[TallyState, Tally]:
    """The counts per incarnation now, and the totals that never go down."""
    prev: Mapping[str, Any] = previous or {}
    carried: Tally = {**_zero(), **(prev.get("carried") or {})}
    seen_before: Mapping[str, Tally] = prev.get("seen") or {}
    silent = {h.incarnation for h in survey.silent}
    seen: dict[str, Tally] = {}
    for h, r in survey.reports.items():
        if r is not None:
            seen[h.incarnation] = _tally_of(r)
    for key, old in seen_before.items():
        if key in silent:
            seen[key] = dict(old)  # type: ignore[assignment]  # kept until it answers
            continue
        new = seen.get(key)
        if new is None or any(new[k] < old[k] for k in ("violated", "satisfied", "events")):
            carried = _add(carried, old)
    totals = carried
    for t in seen.values():
        totals = _add(totals, t)
    return {"carried": carried, "seen": seen}, totals


def condition(
    previous: list[Condition] | None,
    type_: str,
    status: ConditionStatus,
    reason: str,
    message: str,
    generation: int,
    now: str,
) -> list[Condition]:
    """The conditions with ``type_`` set; its transition time moves only when its
    status changes."""
    conditions = [dict(c) for c in previous or []]
    for c in conditions:
        if c.get("type") == type_:
            if c.get("status") != status:
                c["lastTransitionTime"] = now
            c.update(status=status, reason=reason, message=message, observedGeneration=generation)
            return conditions  # type: ignore[return-value]
    conditions.append(
        {
            "type": type_,
            "status": status,
            "reason": reason,
            "message": message,
            "lastTransitionTime": now,
            "observedGeneration": generation,
        }
    )
    return conditions  # type: ignore[return-value]


def valid_and(
    previous: list[Condition] | None,
    ready: str,
    reason: str,
    message: str,
    generation: int,
    now: str,
) -> list[Condition]:
    """The conditions of a spec that compiles: Valid true, and Ready as said."""
    valid = condition(previous, "Valid", "True", "Compiled", "", generation, now)
    return condition(valid, "Ready", ready, reason, message, generation, now)  # type: ignore[arg-type]


def invalid(
    previous: Mapping[str, Any], message: str, generation: int, now: str
) -> tuple[dict[str, Any], list[Event]]:
    """The status of a Monitor whose spec cannot run: phase Error, Valid False."""
    status = _copy(dict(previous))
    conditions = condition(
        status.get("conditions"), "Valid", "False", "InvalidSpec", message, generation, now
    )
    conditions = condition(
        conditions, "Ready", "False", "InvalidSpec", "the spec cannot run", generation, now
    )
    was_invalid = previous.get("phase") == "Error" and previous.get("message") == message
    status.update(
        phase="Error", message=message, observedGeneration=generation, conditions=conditions
    )
    events = [] if was_invalid else [Event("Warning", "InvalidSpec", message)]
    return status, events


def _where(h: HandlerPod) -> Whereabouts:
    return {"pod": h.pod, "node": h.node, "incarnation": h.incarnation}


def refreshed(
    previous: Mapping[str, Any],
    survey: Survey,
    generation: int,
    now: str,
    now_seconds: float,
) -> tuple[dict[str, Any], list[Event]]:
    """The status from the handlers' reports (a valid, defined Monitor), and the Events
    that this change of status calls for (none when nothing a user must see changed)."""
    status = _copy(dict(previous))
    events: list[Event] = []
    reports = survey.reports
    running = [(h, r) for h, r in reports.items() if r and r.get("active")]
    moving = [h for h, r in reports.items() if r and r.get("handoff")]
    state, totals = tally(previous.get("tally"), survey)
    status["tally"] = state
    status["verdicts"] = {"violated": totals["violated"], "satisfied": totals["satisfied"]}
    status["events"] = totals["events"]
    newest = [r["lastVerdict"] for r in reports.values() if r and r.get("lastVerdict")]
    last = previous.get("lastVerdict")
    for v in newest:
        if v is not None and (last is None or v["step"] > last["step"]):
            last = {"verdict": v["verdict"], "stamp": int(v["stamp"]), "step": int(v["step"])}
    if last is not None:
        status["lastVerdict"] = last
    was: Mapping[str, Any] | None = previous.get("handler")

    if len(running) == 1:
        h, _ = running[0]
        phase, ready, reason = "Running", "True", "Running"
        message = f"runs on {h.node} ({h.tier})" + (", moving" if moving else "")
        status.update(handler=_where(h), tier=h.tier)
        if was and was.get("incarnation") != h.incarnation and not _lost(previous):
            # it runs elsewhere than we last saw, and nobody here moved it: count the move
            status["migrations"] = _count_move(
                previous.get("migrations"), was, previous.get("tier"), h, "observed", now, 0.0
            )
    elif moving:
        phase, ready, reason, message = "Migrating", "False", "Migrating", "in a handoff"
    elif running:
        nodes = ", ".join(sorted(h.node for h, _ in running))
        phase, ready, reason = "Running", "False", "ActiveOnSeveral"
        message = f"active on several handlers: {nodes}"
    else:
        phase, ready, reason, message = "Pending", "False", "NotRunning", "no handler runs it"
        known = {h.incarnation for h in list(survey.pods()) + list(survey.silent)}
        if was and was.get("incarnation") not in known and not _lost(previous):
            step = (previous.get("lastVerdict") or {}).get("step")
            lost = (
                f"its handler {was.get('pod')} on {was.get('node')} is gone or restarted: "
                f"the monitor's state is lost"
                + (f" (it had reached step {step})" if step else "")
                + "; it starts afresh on another handler"
            )
            events.append(Event("Warning", "StateLost", lost))
            status["stateLost"] = {
                "count": int((previous.get("stateLost") or {}).get("count", 0)) + 1,
                "time": now,
                "message": lost,
            }
            status["handler"] = {**was, "lost": True}

    status["phase"] = phase
    status["message"] = message
    status["conditions"] = valid_and(
        status.get("conditions"), ready, reason, message, generation, now
    )
    events += _violations(previous, status, totals, now, now_seconds)
    return status, events


def _lost(previous: Mapping[str, Any]) -> bool:
    return bool((previous.get("handler") or {}).get("lost"))


def _violations(
    previous: Mapping[str, Any],
    status: dict[str, Any],
    totals: Tally,
    now: str,
    now_seconds: float,
) -> list[Event]:
    """A Violated Event when the count grew, at most one each VIOLATION_EVENT_SECONDS:
    it says how many since the last such Event."""
    told = previous.get("violationEvents") or {"reported": 0, "at": -1e18}
    reported, at = int(told.get("reported", 0)), float(told.get("at", -1e18))
    grown = totals["violated"] - reported
    if grown <= 0 or now_seconds - at < VIOLATION_EVENT_SECONDS:
        status["violationEvents"] = {"reported": min(reported, totals["violated"]), "at": at}
        return []
    status["violationEvents"] = {"reported": totals["violated"], "at": now_seconds}
    last = status.get("lastVerdict") or {}
    where = f"; the last at step {last['step']}, stamp {last['stamp']}" if last else ""
    return [
        Event(
            "Warning",
            "Violated",
            f"violated {grown} more time{'s' if grown != 1 else ''} "
            f"({totals['violated']} in all){where}",
        )
    ]


def _count_move(
    previous: Mapping[str, Any] | None,
    source: Mapping[str, Any],
    source_tier: str | None,
    destination: HandlerPod,
    reason: str,
    now: str,
    ms: float,
) -> Migrations:
    return {
        "count": int((previous or {}).get("count", 0)) + 1,
        "last": {
            "fromNode": str(source.get("node", "")),
            "toNode": destination.node,
            "fromTier": source_tier or "",
            "toTier": destination.tier or "",
            "time": now,
            "reason": reason,
            "durationMs": round(ms, 1),
        },
    }


def moved(
    previous: Mapping[str, Any],
    source: HandlerPod,
    destination: HandlerPod,
    reason: str,
    now: str,
    ms: float,
) -> tuple[dict[str, Any], list[Event]]:
    """The status after the operator moved the monitor by the handoff, and its Event."""
    status = _copy(dict(previous))
    status["migrations"] = _count_move(
        previous.get("migrations"), _where(source), source.tier, destination, reason, now, ms
    )
    status["handler"] = _where(destination)
    status["tier"] = destination.tier
    message = (
        f"moved by the handoff from {source.node} ({source.tier}) to {destination.node} "
        f"({destination.tier}) in {ms:.0f} ms: {reason}"
    )
    return status, [Event("Normal", "Moved", message)]


# -- a fleet: a Monitor with an instance per robot (edgerv.core.robots) ------------------

# what a robot's entry in status.robots keeps of its instance's status (the rest, such as
# conditions, is the Monitor's)
ROBOT_FIELDS = (
    "phase",
    "message",
    "tier",
    "handler",
    "lastVerdict",
    "verdicts",
    "events",
    "migrations",
    "stateLost",
    "tally",
    "violationEvents",
)
# what only a Monitor of a cluster without robots has at the top of its status
SINGLE_FIELDS = ("tier", "handler", "migrations", "stateLost", "tally", "violationEvents")
# and what only a fleet's has
FLEET_FIELDS = ("robots", "desired", "running", "violated")


def robot_refreshed(instance: Mapping[str, Any]) -> dict[str, Any]:
    """A robot's entry in ``status.robots``, from its instance's refreshed status."""
    return {k: _copy(instance[k]) for k in ROBOT_FIELDS if k in instance}


def fleet_refreshed(
    previous: Mapping[str, Any],
    robots: Mapping[str, Mapping[str, Any]],
    fleet: list[str],
    generation: int,
    now: str,
    events: list[Event],
) -> tuple[dict[str, Any], list[Event]]:
    """The status of a Monitor with an instance per robot: ``robots`` (robot -> its
    entry), the totals as a DaemonSet's (``desired``, ``running``, ``violated``: robots
    whose instance runs, and that have violated it), the verdicts and events over all of
    them, the newest verdict, phase and conditions. ``fleet``: the cluster's robots (said
    when the Monitor selects none). A merge patch: robots no longer selected are None.
    The totals are over the robots selected now: a robot that leaves takes its counts."""
    status: dict[str, Any] = {}
    entries: dict[str, Any] = {r: dict(e) for r, e in robots.items()}
    for gone in (previous.get("robots") or {}).keys() - robots.keys():
        entries[gone] = None
    for single in SINGLE_FIELDS:  # from before the cluster had robots
        if single in previous:
            status[single] = None
    desired = len(robots)
    running = sum(1 for e in robots.values() if e.get("phase") == "Running")
    violated = sum(1 for e in robots.values() if (e.get("verdicts") or {}).get("violated"))
    totals = {"violated": 0, "satisfied": 0}
    for e in robots.values():
        for k in totals:
            totals[k] += int((e.get("verdicts") or {}).get(k, 0))
    last = None
    for e in robots.values():
        v = e.get("lastVerdict")
        if v is not None and (last is None or v["stamp"] > last["stamp"]):
            last = v
    status.update(
        robots=entries,
        desired=desired,
        running=running,
        violated=violated,
        verdicts=totals,
        events=sum(int(e.get("events") or 0) for e in robots.values()),
    )
    status["lastVerdict"] = dict(last) if last is not None else None  # (None: a merge removes it)
    phases = {e.get("phase") for e in robots.values()}
    if not robots:
        phase, ready, reason = "Pending", "False", "NoRobot"
        message = "spec.robots selects none of the robots: " + (", ".join(fleet) or "none")
    elif running == desired:
        phase, ready, reason = "Running", "True", "Running"
        message = f"runs on {desired} robot{'s' if desired != 1 else ''}"
    else:
        phase = "Migrating" if "Migrating" in phases else "Pending"
        ready, reason = "False", "NotAllRunning"
        others = sorted(r for r, e in robots.items() if e.get("phase") != "Running")
        message = f"runs on {running} of {desired} robots; not on {', '.join(others)}"
    status["phase"] = phase
    status["message"] = message
    status["conditions"] = valid_and(
        previous.get("conditions"), ready, reason, message, generation, now
    )
    status["observedGeneration"] = generation
    return status, events
