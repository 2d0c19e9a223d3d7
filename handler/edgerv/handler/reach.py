"""How long the robot's messages take to reach this handler: from their publication (the
source timestamp the middleware carries with each) to their reception here (the
middleware's received timestamp). It is the latency of this handler's tier from the
robot, measured: the load report's ``reachMs``, which the placement policy compares
with each monitor's ``placement.maxLatencyMs`` (docs/protocol.md, "Placement"). Both
timestamps are wall clocks, of the publisher's machine and of this one: across machines
they must be synchronized (as the reorder window needs them to be); a negative reading
(a clock behind) counts as 0.

The take loop notes, for each topic that delivered in a round, the longest any of its
messages took; the reading is the 95th percentile of the newest REACH_SAMPLES of those.
Idle, it keeps the last ones: the link's latency as last seen."""

from __future__ import annotations

from array import array

REACH_SAMPLES = 256


class Reach:
    """The newest REACH_SAMPLES readings (ns), a ring written by the take loop's thread
    and read by whoever makes the load report (a reading is one array store: a reader
    sees the old or the new value of a slot, either a reading)."""

    def __init__(self, size: int = REACH_SAMPLES) -> None:
        self.samples = array("q", bytes(8 * size))
        self.size = size
        self.count = 0  # readings noted since the start

    def note(self, ns: int) -> None:
        self.samples[self.count % self.size] = ns if ns > 0 else 0
        self.count += 1

    def p95_ms(self) -> float | None:
        """The 95th percentile (nearest rank) of the newest readings, in ms; None before
        any message came."""
        n = min(self.count, self.size)
        if not n:
            return None
        kept = sorted(self.samples[:n])
        return kept[max(0, -(-95 * n // 100) - 1)] / 1e6
