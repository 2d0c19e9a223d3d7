"""The control API on the wire: its JSON payloads, typed, and the protocol's constants.
What the handler's server answers (:mod:`edgerv.handler.api`, rendered by
:mod:`edgerv.handler.reading`) and what its callers read (:mod:`edgerv.control.client`: the
operator, ``edgerv migrate``, ``edgerv orchestrate``).

docs/handler.md describes each field; these types are the one place both sides name them.
A load report (``GET /v1/load``) is read by :func:`parse_load`, which checks its shape.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any, Literal, NotRequired, TypedDict

from edgerv.core.deadline import DeadlineLoad
from edgerv.core.documents import Placement

HANDOFF_EXPIRES = 120.0  # seconds a handoff may wait for its next step before it is undone


class PlacementJson(TypedDict):
    """A monitor's placement as the API and the Monitor resource spell it."""

    tier: str | None
    migrate: Literal["auto", "pinned"]
    maxLatencyMs: float | None
    robot: NotRequired[str | None]  # an instance's robot (its document's label; reported)


def placement_json(p: Placement) -> PlacementJson:
    """The placement as the API and the Monitor resource spell it."""
    out: PlacementJson = {"tier": p.tier, "migrate": p.migrate, "maxLatencyMs": p.max_latency_ms}
    if p.robot is not None:
        out["robot"] = p.robot
    return out


def placement_from_json(d: Mapping[str, object]) -> Placement:
    """A placement as the API (or a Monitor resource's ``spec.placement``) spells it;
    what is missing or of another type reads as the default."""
    tier, migrate, budget = d.get("tier"), d.get("migrate", "auto"), d.get("maxLatencyMs")
    robot = d.get("robot")
    return Placement(
        tier if isinstance(tier, str) else None,
        "pinned" if migrate == "pinned" else "auto",
        float(budget) if isinstance(budget, int | float) else None,
        robot if isinstance(robot, str) else None,
    )


class LastVerdict(TypedDict):
    """A monitor's newest verdict on this handler."""

    verdict: str  # "violated" or "satisfied"
    stamp: int  # the deciding event's stamp, nanoseconds
    step: int  # the steps evaluated when it was reached


class BufferReport(TypedDict):
    events: int
    letters: int
    capacity: int
    fill: float  # buffered / capacity


class MonitorReport(TypedDict):
    """``GET /v1/monitors/{name}``, and each item of ``GET /v1/monitors``."""

    name: str
    handler: str
    active: bool  # it runs here (or is held here for a handoff)
    state: str  # "pending", "violated", "satisfied", or "inactive"
    assertion: str
    topics: list[str]
    automatonState: int | None
    step: int
    buffer: BufferReport
    events: int
    droppedEvents: int
    lateEvents: int
    verdicts: dict[str, int]  # "violated"/"satisfied" -> how many reached here
    lastVerdict: LastVerdict | None
    migrationWanted: bool
    handoff: str | None  # the handoff step it is in, if any
    epoch: int  # the newest handoff it took part in here
    peer: str | None
    placement: PlacementJson


class MonitorListing(TypedDict):
    """``GET /v1/monitors``; with ``?since=CURSOR`` only the reports changed since the
    cursor, and ``since`` (the cursor honoured) and ``removed`` (the names gone since)."""

    handler: str
    monitors: list[MonitorReport]
    cursor: NotRequired[str]  # read from here next time (an older handler: none)
    since: NotRequired[str]
    removed: NotRequired[list[str]]


class ErrorItem(TypedDict, total=False):
    message: str  # always there
    location: str  # FILE:LINE:COL of a document's problem
    hint: str | None
    severity: str


class ErrorBody(TypedDict):
    """Every 4xx/5xx answer."""

    errors: list[ErrorItem]


# -- the handoff's steps (docs/protocol.md) ------------------------------------------------


class HandoffRequest(TypedDict):
    """``POST /v1/handoff/{hold,receive,cut,release,commit,abort}``: one step for a batch
    of monitors under one epoch (``adopt``'s body is the snapshots' bundle instead)."""

    epoch: int
    monitors: list[str]
    peer: NotRequired[str]  # hold: the receiver's address, kept for settling
    cuts: NotRequired[dict[str, int]]  # release: each monitor's cut, nanoseconds
    quiet: NotRequired[dict[str, list[str]]]  # release: the topics the receiver vouched for
    grace: NotRequired[float]  # release: seconds
    wait: NotRequired[float]  # release: seconds it may wait for events past the cut


class StepAnswer(TypedDict):
    """``hold`` and ``receive``: the monitors it took (all of them, or a 409)."""

    monitors: list[str]


class CutAnswer(TypedDict):
    """``cut``: each monitor's cut (None: not yet) and the topics it vouches for."""

    cuts: dict[str, int | None]
    quiet: dict[str, list[str]]


class WaitingAnswer(TypedDict):
    """``release`` answered 202: the monitors still waiting for events past the cut."""

    waiting: list[str]


class AdoptAnswer(TypedDict):
    """``adopt``: the monitors now running here."""

    active: list[str]


class OutcomesAnswer(TypedDict):
    """``commit`` and ``abort``: what each monitor's step did (``Engine.handoffs``'
    commit and abort)."""

    outcomes: dict[str, str]


# -- the load report (GET /v1/load) -------------------------------------------------------


class MonitorLoadReport(TypedDict):
    """A monitor's counters in the load report (counters, not rates)."""

    active: bool
    handoff: str | None  # the handoff step it is in, if any
    epoch: int
    peer: str | None
    events: int
    # CPU seconds the handler spent on it since it became active there (taking its events,
    # its share of each message it reads, evaluating them; estimated from sampled timings)
    cpuSeconds: float
    migrationWanted: bool
    placement: PlacementJson
    topics: list[str]  # the topics it reads


class TopicLoadReport(TypedDict):
    """A topic the handler subscribes to for its monitors: counters since it started."""

    messages: int  # taken and ingested
    cpuSeconds: float  # CPU the handler spent taking and decoding them


class HostLoad(TypedDict):
    """The CPUs a handler may run on (its affinity): counters since boot."""

    cores: int
    busySeconds: float
    totalSeconds: float


class LoadReport(TypedDict):
    """``GET /v1/load``: what the orchestrator and the operator's placement rounds read."""

    handler: str
    monotonic: float  # the handler's monotonic clock, seconds
    cpuSeconds: float  # the handler's process CPU time
    host: HostLoad | None  # None: unreadable there (not Linux)
    ingestLag: float  # seconds
    # how long the robot's messages take from their publication to this handler, the
    # 95th percentile of its recent rounds (handler/reach.py); None: none came yet
    reachMs: float | None
    deadline: DeadlineLoad | None  # None: the handler measures no deadline (--deadline)
    topics: dict[str, TopicLoadReport]  # the topics its monitors read
    monitors: dict[str, MonitorLoadReport]


def _number(d: Mapping[str, Any], key: str, where: str, default: float | None = None) -> float:
    value = d.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{where}{key} is not a number")
    return float(value)


def _number_or_none(d: Mapping[str, Any], key: str, where: str) -> float | None:
    return None if d.get(key) is None else _number(d, key, where)


def _whole(d: Mapping[str, Any], key: str, where: str, default: int | None = None) -> int:
    value = d.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{where}{key} is not a whole number")
    return value


def _flag(d: Mapping[str, Any], key: str, where: str) -> bool:
    value = d.get(key)
    if not isinstance(value, bool):
        raise ValueError(f"{where}{key} is not true or false")
    return value


def _text_or_none(d: Mapping[str, Any], key: str, where: str) -> str | None:
    value = d.get(key)
    if value is not None and not isinstance(value, str):
        raise ValueError(f"{where}{key} is not a string or null")
    return value


def _deadline(d: object) -> DeadlineLoad | None:
    if d is None:
        return None
    if not isinstance(d, Mapping):
        raise ValueError("deadline is not an object or null")
    w = "deadline."
    return {
        "topic": _text_or_none(d, "topic", w) or "",
        "budgetMs": _number(d, "budgetMs", w),
        "windowSeconds": _number(d, "windowSeconds", w, 0.0),
        "count": _whole(d, "count", w),
        "misses": _whole(d, "misses", w, 0),
        "p50Ms": _number_or_none(d, "p50Ms", w),
        "p95Ms": _number_or_none(d, "p95Ms", w),
        "maxMs": _number_or_none(d, "maxMs", w),
        "lastMs": _number_or_none(d, "lastMs", w),
        "serviceP95Ms": _number_or_none(d, "serviceP95Ms", w),
        "missesTotal": _whole(d, "missesTotal", w, 0),
        "messagesTotal": _whole(d, "messagesTotal", w, 0),
    }


def parse_deadline(value: object) -> DeadlineLoad:
    """``GET /v1/deadline``'s answer: the deadline's reading (a ValueError naming the
    field that is wrong)."""
    reading = _deadline(value)
    if reading is None:
        raise ValueError("deadline is null")
    return reading


def _host(d: object) -> HostLoad | None:
    if d is None:
        return None
    if not isinstance(d, Mapping):
        raise ValueError("host is not an object or null")
    w = "host."
    return {
        "cores": _whole(d, "cores", w),
        "busySeconds": _number(d, "busySeconds", w),
        "totalSeconds": _number(d, "totalSeconds", w),
    }


def _monitor_load(name: str, d: object) -> MonitorLoadReport:
    if not isinstance(d, Mapping):
        raise ValueError(f"monitors.{name} is not an object")
    w = f"monitors.{name}."
    placement = d.get("placement") or {}
    if not isinstance(placement, Mapping):
        raise ValueError(f"{w}placement is not an object")
    return {
        "active": _flag(d, "active", w),
        "handoff": _text_or_none(d, "handoff", w),
        "epoch": _whole(d, "epoch", w, 0),
        "peer": _text_or_none(d, "peer", w),
        "events": _whole(d, "events", w),
        "cpuSeconds": _number(d, "cpuSeconds", w, 0.0),
        "migrationWanted": _flag(d, "migrationWanted", w),
        "placement": placement_json(placement_from_json(placement)),
        "topics": _texts(d, "topics", w),
    }


def _texts(d: Mapping[str, Any], key: str, where: str) -> list[str]:
    value = d.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ValueError(f"{where}{key} is not a list of strings")
    return list(value)


def _object(d: Mapping[str, Any], key: str) -> Iterable[tuple[Any, Any]]:
    value = d.get(key, {})
    if not isinstance(value, Mapping):
        raise ValueError(f"{key} is not an object")
    return value.items()


def _topic_load(name: str, d: object) -> TopicLoadReport:
    if not isinstance(d, Mapping):
        raise ValueError(f"topics.{name} is not an object")
    w = f"topics.{name}."
    return {"messages": _whole(d, "messages", w), "cpuSeconds": _number(d, "cpuSeconds", w, 0.0)}


def parse_load(value: object) -> LoadReport:
    """A load report as JSON decoded it, checked field by field: raises
    :class:`ValueError` saying what is not as the API promises. What a handler may leave
    out reads as its default (``ingestLag`` 0, ``reachMs``, ``deadline`` and ``host``
    null, ``topics`` empty, a monitor's ``epoch`` and ``cpuSeconds`` 0, ``handoff`` and
    ``peer`` null, the
    default placement, its ``topics`` empty; a topic's ``cpuSeconds`` 0; in a
    ``deadline``, all but ``budgetMs`` and ``count``)."""
    if not isinstance(value, Mapping):
        raise ValueError("it is not an object")
    handler, monitors = value.get("handler"), value.get("monitors")
    if not isinstance(handler, str):
        raise ValueError("handler is not a string")
    if not isinstance(monitors, Mapping):
        raise ValueError("monitors is not an object")
    return {
        "handler": handler,
        "monotonic": _number(value, "monotonic", ""),
        "cpuSeconds": _number(value, "cpuSeconds", ""),
        "host": _host(value.get("host")),
        "ingestLag": _number(value, "ingestLag", "", 0.0),
        "reachMs": _number_or_none(value, "reachMs", ""),
        "deadline": _deadline(value.get("deadline")),
        "topics": {str(name): _topic_load(str(name), d) for name, d in _object(value, "topics")},
        "monitors": {str(name): _monitor_load(str(name), d) for name, d in monitors.items()},
    }
