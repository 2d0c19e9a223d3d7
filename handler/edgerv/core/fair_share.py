"""A shared handler's room, shared fairly between the robots that ask for it.

A cloud handler serves many robots (docs/protocol.md, "Fleet"). When the monitors that
robots under pressure would move up to it in one round cost more than the room it has
left, the room is filled least-served robot first (progressive filling, which
approaches the max-min fair share for monitors that cannot be split): the robot that
runs least there (what it already runs counting, and what it has been given so far)
gets its next monitor, the cheapest of its own that still fits, and so on, so that the
robots' shares rise evenly and as many robots as the room allows get relief; a robot
none of whose monitors fits any more is done. What runs there already is never sent
home for it (its robot's edge is why it came).
"""

from __future__ import annotations

import heapq
from collections.abc import Mapping, Sequence


def fill(
    room: float,
    running: Mapping[str, float],
    asked: Mapping[str, Sequence[tuple[str, float]]],
) -> dict[str, list[str]] | None:
    """Which of the monitors each robot ``asked`` for ((name, cost in cores) each) go to
    a handler with ``room`` left (cores), the robots ``running`` that much there; None
    when the room holds everything asked (nobody held back). Each robot's kept names are
    in the order they were given."""
    cost = {(r, n): max(0.0, c) for r, items in asked.items() for n, c in items}
    if sum(cost.values()) <= room:
        return None
    left = max(0.0, room)
    # each robot's monitors, cheapest first: its share rises in small steps
    queue = {
        r: [n for _, n in sorted((cost[r, n], n) for n, _ in items)] for r, items in asked.items()
    }
    kept: dict[str, set[str]] = {r: set() for r in asked}
    # (what a robot runs there and was given, robot): the least served on top
    least = [(max(0.0, running.get(r, 0.0)), r) for r, q in queue.items() if q]
    heapq.heapify(least)
    while least:
        served, robot = heapq.heappop(least)
        mine = queue[robot]
        name = mine[len(kept[robot])]  # its cheapest left: when it does not fit, none does
        if cost[robot, name] > left:
            continue  # done
        kept[robot].add(name)
        left -= cost[robot, name]
        if len(kept[robot]) < len(mine):
            heapq.heappush(least, (served + cost[robot, name], robot))
    return {r: [n for n, _ in items if n in kept[r]] for r, items in asked.items()}
