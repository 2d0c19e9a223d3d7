"""How a placement policy brought the robot's control loop back under its deadline.

Issue 37's measure of a policy, from what the robot and ``edgerv orchestrate`` wrote:
the seconds from the first missed deadline (of a frame the real-time stage received: the
demo gives the frames from its first command on) to the first of ``RUN`` frames in a row
that met theirs, the handoffs and monitor moves the policy made until then, the deadlines
missed meanwhile, and how many monitors were in the cloud once it had settled.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

RUN = 10  # frames in a row that met their deadline: the loop is back under it
SETTLED_MIN = 16  # makespans (2 s at 8 Hz) for a reading of the loop once settled
# seconds after a handoff before the loop counts as settled: the policy's own wait for a
# deadline's window to refill after a move (edgerv orchestrate --deadline-wait)
SETTLED_AFTER = 2.0


def percentile(values: Sequence[float], q: float) -> float | None:
    """The demo's percentile: the nearest rank at or above ``q`` (None: no values)."""
    if not values:
        return None
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def recovery(
    frames: Sequence[tuple[float, bool]],
    moves: Sequence[Mapping[str, Any]],
    in_cloud: int | None,
    run: int = RUN,
) -> dict[str, Any] | None:
    """``frames``: (wall seconds, met its deadline) in time order; ``moves``: the
    orchestrator's records (``at`` wall seconds, ``monitors``, ``ok``, ``from``: a move,
    not a start); ``in_cloud``: monitors in the cloud once the policy settled (the demo:
    at the mission's end, before the robot parks; without a mission, the phase's). None when
    no deadline was missed (nothing to recover from); ``seconds`` None when the loop never
    met ``run`` deadlines in a row after the first miss (then the moves and misses are
    those of the whole run)."""
    first = next((i for i, (_, met) in enumerate(frames) if not met), None)
    if first is None:
        return None
    start = frames[first][0]
    back: float | None = None
    misses, streak = 0, 0
    for i in range(first, len(frames)):
        if frames[i][1]:
            streak += 1
            if streak == run:
                back = frames[i - run + 1][0]
                break
        else:
            misses += 1
            streak = 0
    made = [
        m
        for m in moves
        if m.get("ok") and m.get("from") and (back is None or float(m["at"]) <= back)
    ]
    return {
        "seconds": None if back is None else round(back - start, 2),
        "handoffs": len(made),
        "monitorsMoved": sum(len(m["monitors"]) for m in made),
        "deadlineMisses": misses,
        "monitorsInCloud": in_cloud,
    }


def settled(
    makespans: Sequence[tuple[float, float]],
    moves: Sequence[Mapping[str, Any]],
    until: float,
    minimum: int = SETTLED_MIN,
    after: float = SETTLED_AFTER,
) -> dict[str, Any] | None:
    """The loop once the policy settled, which says whether the monitors left in the
    cloud are what the edge's headroom requires: ``makespans`` (wall seconds, ms) from
    ``after`` seconds past the end of the last handoff made before ``until`` (the
    mission's end; a handoff ends at its ``at`` plus its ``ms``) to ``until``: how long
    that is, how many, and their 95th percentile. A p95 above the policy's calm mark
    means the edge had no room for more; below it, the policy's hysteresis was still
    waiting. None with fewer than ``minimum``: the policy moved too late in the mission
    for a reading."""
    ends = [
        float(m["at"]) + float(m.get("ms") or 0.0) / 1000 + after
        for m in moves
        if m.get("ok") and float(m["at"]) <= until
    ]
    since = max(ends, default=float("-inf"))
    spans = [ms for at, ms in makespans if since <= at <= until]
    if len(spans) < minimum:
        return None
    first = min(at for at, _ in makespans if since <= at <= until)
    return {
        "seconds": round(until - max(since, first), 2),
        "makespans": len(spans),
        "p95Ms": percentile(spans, 0.95),
    }
