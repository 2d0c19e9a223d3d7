"""The control API on the wire: its JSON payloads, typed, and the protocol's constants.
What the handler's server answers (:mod:`edgerv.handler.api`, :meth:`MonitorSlot.describe`)
and what its callers read (:mod:`edgerv.control.client`: the operator, ``edgerv migrate``,
``edgerv orchestrate``).

docs/handler.md describes each field; these types are the one place both sides name them.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NotRequired, TypedDict

from edgerv.core.documents import Placement

HANDOFF_EXPIRES = 120.0  # seconds a handoff may wait for its next step before it is undone


def placement_json(p: Placement) -> dict[str, object]:
    """The placement as the API and the Monitor resource spell it."""
    return {"tier": p.tier, "migrate": p.migrate, "maxLatencyMs": p.max_latency_ms}


def placement_from_json(d: Mapping[str, object]) -> Placement:
    """A placement as the API (or a Monitor resource's ``spec.placement``) spells it;
    what is missing or of another type reads as the default."""
    tier, migrate, budget = d.get("tier"), d.get("migrate", "auto"), d.get("maxLatencyMs")
    return Placement(
        tier if isinstance(tier, str) else None,
        "pinned" if migrate == "pinned" else "auto",
        float(budget) if isinstance(budget, int | float) else None,
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
    placement: dict[str, Any]


class MonitorListing(TypedDict):
    """``GET /v1/monitors``."""

    handler: str
    monitors: list[MonitorReport]


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
    """``commit`` and ``abort``: what each monitor's step did (Engine.commit, Engine.abort)."""

    outcomes: dict[str, str]
