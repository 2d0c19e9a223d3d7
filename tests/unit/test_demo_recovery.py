"""The demo's measure of a placement policy (examples/robot/recovery.py, issue 37): from
the first missed deadline to the first of 10 frames in a row that met theirs."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parents[2] / "examples/robot"))

from recovery import RUN, percentile, recovery, settled


def frames(pattern: str, start: float = 100.0, period: float = 0.125) -> list[tuple[float, bool]]:
    """'.' a frame that met its deadline, 'x' one that missed it, one frame a period."""
    return [(start + i * period, c == ".") for i, c in enumerate(pattern)]


def move(at: float, n: int, reason: str = "deadline", ok: bool = True) -> dict[str, object]:
    return {"at": at, "from": "edge", "to": "cloud", "monitors": [f"m{i}" for i in range(n)],
            "ok": ok, "reason": reason}  # fmt: skip


def test_from_the_first_miss_to_the_first_of_ten_met_in_a_row() -> None:
    # misses at frames 3..7, one met at 8, a miss at 9, then 10 met from frame 10 on
    f = frames("..." + "xxxxx" + "." + "x" + "." * RUN + "xx")
    moves = [move(100.5, 30), move(101.0, 12), move(101.3, 0, ok=False), move(104.0, 5)]
    got = recovery(f, moves, in_cloud=42)
    assert got == {
        "seconds": round(10 * 0.125 - 3 * 0.125, 2),  # frame 10's time minus frame 3's
        "handoffs": 2,  # the failed one and the one after the loop was back do not count
        "monitorsMoved": 42,
        "deadlineMisses": 6,
        "monitorsInCloud": 42,
    }


def test_nothing_to_recover_from_and_never_back() -> None:
    assert recovery(frames("." * 30), [move(100.0, 3)], in_cloud=0) is None
    never = recovery(frames("xx" + ".." + "x" + "." * (RUN - 1)), [move(101.0, 3)], 3)
    assert never is not None
    assert never["seconds"] is None and never["deadlineMisses"] == 3 and never["handoffs"] == 1


def test_starts_are_not_handoffs() -> None:
    start = {"at": 100.2, "from": "", "to": "edge", "monitors": ["g"], "ok": True}
    got = recovery(frames("x" + "." * RUN), [start, move(100.1, 4)], in_cloud=4)
    assert got is not None and (got["handoffs"], got["monitorsMoved"]) == (1, 4)


def test_the_loop_once_settled_is_read_after_the_last_move_until_the_missions_end() -> None:
    """What the edge's headroom allowed once the policy settled: the makespans from the
    end of the last handoff made before the mission ended to its end (issue 37: "no more
    monitors in the cloud than the edge's headroom requires")."""
    spans = [(100.0 + i * 0.125, 100.0 + i) for i in range(80)]  # 100 ms, 101 ms, ...
    last = {**move(102.0, 5), "ms": 500.0}  # it ends at 102.5 s: frames 20.. count
    after_end = move(109.0, 9)  # the homecoming once parked: after the mission's end
    got = settled(spans, [move(101.0, 3), last, after_end], until=105.0, after=0.0)
    # frames 20 to 40 (102.5 s to 105.0 s): 21 makespans, 120 to 140 ms
    assert got == {"seconds": 2.5, "makespans": 21, "p95Ms": percentile(
        [100.0 + i for i in range(20, 41)], 0.95
    )}  # fmt: skip
    assert got is not None and got["p95Ms"] == 139.0  # (the demo's percentile: nearest rank)
    # by default from the policy's own wait after a move (its window refills): 104.5 s on
    later = settled(spans, [last], until=107.0)
    assert later is not None and (later["seconds"], later["makespans"]) == (2.5, 21)
    # a failed move does not count (no move: the run until then); too few: no reading
    failed = settled(spans, [move(104.9, 1, ok=False)], until=105.0)
    assert failed is not None and failed["makespans"] == 41
    assert settled(spans, [move(104.9, 1)], until=105.0, after=0.0) is None  # one since
