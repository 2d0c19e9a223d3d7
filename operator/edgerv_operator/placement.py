"""Where the operator runs a monitor, and what a change of its spec asks for.

Pure: no Kubernetes and no network (tests/unit/test_operator.py). The orchestration
policy itself (moves on pressure, back down when calm) is
:mod:`edgerv.control.placement`, shared with ``edgerv orchestrate``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Literal

from edgerv_operator.documents import HandlerPod

Change = Literal["none", "placement", "move", "redefine"]


def _ranked(handlers: Sequence[HandlerPod], tiers: Sequence[str]) -> list[HandlerPod]:
    return sorted(
        (h for h in handlers if h.tier in tiers), key=lambda h: (tiers.index(h.tier or ""), h.node)
    )


def choose(
    handlers: Sequence[HandlerPod], tier: str | None, tiers: Sequence[str]
) -> HandlerPod | None:
    """Where a monitor starts, as the placement policy starts one: on its home tier
    (``placement.tier``; the lowest tier when it names none or one not in ``tiers``),
    else on the nearest tier above that has a handler among ``handlers`` (the ready
    ones: its home tier's may still be starting; the policy brings it back down when
    that handler is calm). Never below its home tier: None when none is found."""
    home = tiers.index(tier) if tier in tiers else 0
    above = [h for h in _ranked(handlers, tiers) if tiers.index(h.tier or "") >= home]
    return above[0] if above else None


def tier_of(spec: Mapping[str, Any] | None) -> str | None:
    placement = (spec or {}).get("placement") or {}
    tier = placement.get("tier")
    return str(tier) if tier else None


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
