"""Where the operator runs a monitor, and what a change of its spec asks for.

Pure: no Kubernetes and no network (tests/unit/test_operator.py). Where a monitor starts
is the placement policy's rule (:func:`edgerv.control.placement.start_on`), the one
``edgerv orchestrate`` follows too, as are the moves on pressure and back down when calm;
the operator's own are the moves it is asked for (a tier edit, a pod going away).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Literal

from edgerv.control.placement import HandlerReport, PolicyConfig, start_on
from edgerv.control.wire import placement_from_json
from edgerv.core.documents import Placement
from edgerv.core.robots import may_host
from edgerv_operator.documents import HandlerPod

Change = Literal["none", "placement", "move", "redefine"]


def _ranked(handlers: Sequence[HandlerPod], tiers: Sequence[str]) -> list[HandlerPod]:
    return sorted(
        (h for h in handlers if h.tier in tiers), key=lambda h: (tiers.index(h.tier or ""), h.node)
    )


def choose(
    handlers: Sequence[HandlerPod],
    placement: Placement,
    config: PolicyConfig,
    seen: Mapping[HandlerPod, HandlerReport] | None = None,
) -> HandlerPod | None:
    """Where a monitor starts: the placement policy's rule (:func:`start_on`) over
    ``handlers`` (the ready ones: its home tier's may still be starting), each as the
    placement rounds last saw it in ``seen`` (one not seen yet: no load). Its home tier
    (``placement.tier``; the lowest when it names none or one not in the tiers), else the
    nearest tier above that has one and that ``placement.maxLatencyMs`` allows; there
    the least loaded, then by node. Never below its home tier: None when none is found."""
    seen = seen or {}
    reports = [
        (seen.get(h) or HandlerReport(h.node, h.tier, 0.0), h)
        for h in handlers
        if h.tier is not None and h.tier in config.tiers
    ]
    chosen = start_on(placement, [r for r, _ in reports], config)
    return next((h for r, h in reports if r is chosen), None)


def placement_of(spec: Mapping[str, Any] | None) -> Placement:
    """A Monitor resource's ``spec.placement`` (the defaults where it says nothing)."""
    placement = (spec or {}).get("placement") or {}
    return placement_from_json(placement) if isinstance(placement, Mapping) else Placement()


def tier_of(spec: Mapping[str, Any] | None) -> str | None:
    return placement_of(spec).tier or None


def change(old: Mapping[str, Any] | None, new: Mapping[str, Any]) -> Change:
    """What an edit of the spec from ``old`` to ``new`` asks of the running monitor.

    ``move``: only ``placement.tier`` changed: the monitor moves to a handler of the
    new tier by the handoff, its state kept (and the handlers' definitions get the new
    placement without a restart). ``placement``: only other placement fields changed:
    the definitions are updated in place. ``redefine``: anything else: the monitor
    restarts with the new definition (its state starts afresh). ``none``: no change."""
    if old is None:
        return "redefine"
    if dict(old) == dict(new):
        return "none"
    rest_old = {k: v for k, v in old.items() if k != "placement"}
    rest_new = {k: v for k, v in new.items() if k != "placement"}
    if rest_old != rest_new:
        return "redefine"
    return "move" if tier_of(old) != tier_of(new) else "placement"


def destination(
    handlers: Sequence[HandlerPod],
    tier: str | None,
    tiers: Sequence[str],
    leaving: HandlerPod | None = None,
) -> HandlerPod | None:
    """Where a running monitor goes: for a tier edit a handler of ``tier`` (else
    None: it stays until one is ready); for a handler that is going away (``leaving``,
    ``tier`` None) another handler of its tier, else the nearest tier above, else below."""
    ranked = [h for h in _ranked(handlers, tiers) if h != leaving]
    if tier is not None:
        return next((h for h in ranked if h.tier == tier), None)
    if leaving is None or leaving.tier not in tiers:
        return ranked[0] if ranked else None
    rank = tiers.index(leaving.tier)
    order = [rank, *range(rank + 1, len(tiers)), *range(rank - 1, -1, -1)]
    for r in order:
        for h in ranked:
            if h.tier == tiers[r]:
                return h
    return None


def drained(
    leaving: HandlerPod,
    active: Mapping[str, str | None],
    ready: Sequence[HandlerPod],
    tiers: Sequence[str],
) -> list[tuple[HandlerPod, list[str]]]:
    """Where the monitors active on a handler that is going away go (``active``: each
    one's robot, None for none): each robot's to a handler that may run its instances
    (its robot's or a shared one: :func:`edgerv.core.robots.may_host`) by
    :func:`destination`, one move per destination; those with nowhere to go stay."""
    moves: dict[HandlerPod, list[str]] = {}
    for name in sorted(active):
        mine = [h for h in ready if may_host(active[name], h.robot)]
        target = destination(mine, None, tiers, leaving=leaving)
        if target is not None:
            moves.setdefault(target, []).append(name)
    return list(moves.items())
