"""The offline check of a nested timed monitor, whole job against whole job: `edgerv
check` on a JSON Lines file beside RTAMT's dense-time STL over the same file
(bench/peers/rtamt_nested.py), and the floor of any Python checker (a process that only
scans the file: bench/peers/scan_floor.py), each a process of its own, in turn.

The property, reach-and-hold: a new goal is reached within 2 s and the robot then stays
there 500 ms, `always (goal -> F[0..2s] (at & G[0..500ms] at))` (issue 34), over 500,000
messages at 100 Hz: a goal every 3 s, the robot reaching it after a while and now and
then leaving early. Each side prints the number of stretches of time where it fails
(edgerv: its violated steps, with reset, one per failing stretch read 2.5 s late).
"""

from __future__ import annotations

import json
import random
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

EVENTS = 500_000
ROUNDS = 3
PEERS = Path(__file__).resolve().parent / "peers"

MONITOR = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: reach-and-hold}
spec:
  assertion: "always (goal -> F[0..2s] (at & G[0..500ms] at))"
  signals:
    goal: {topic: /goal, type: std_msgs/msg/Bool}
    at: {topic: /at, type: std_msgs/msg/Bool}
"""


def make_trace(path: Path) -> None:
    rng = random.Random(5)
    stamp, at, lines = 1_700_000_000_000_000_000, False, []
    for i in range(EVENTS):
        stamp += 10_000_000  # 100 Hz
        if i % 300 in (0, 1):  # a new goal every 3 s: /goal true, then false
            lines.append({"topic": "/goal", "stamp": stamp, "msg": {"data": i % 300 == 0}})
            at = False
            continue
        if not at and rng.random() < 0.01:  # reached, after 1 s on average
            at = True
        elif at and rng.random() < 0.004:  # and now and then left early
            at = False
        lines.append({"topic": "/at", "stamp": stamp, "msg": {"data": at}})
    path.write_text("".join(json.dumps(x) + "\n" for x in lines))


def run(argv: list[str]) -> tuple[float, str]:
    start = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True, check=False)
    return time.perf_counter() - start, done.stdout


def stretches(out: str) -> int:
    steps = [v["step"] for v in json.loads(out)["monitors"][0]["verdicts"]]
    return sum(1 for i, step in enumerate(steps) if i == 0 or steps[i - 1] != step - 1)


def main() -> list[dict[str, Any]]:
    with tempfile.TemporaryDirectory() as tmp:
        trace, monitor = Path(tmp) / "run.jsonl", Path(tmp) / "reach.yaml"
        make_trace(trace)
        monitor.write_text(MONITOR)
        argvs = {
            "edgerv": [sys.executable, "-m", "edgerv", "check", str(monitor), str(trace), "--json"],
            "rtamt": [sys.executable, str(PEERS / "rtamt_nested.py"), str(trace)],
            "floor": [sys.executable, str(PEERS / "scan_floor.py"), str(trace)],
        }
        seconds: dict[str, list[float]] = {name: [] for name in argvs}
        found: dict[str, int] = {}
        for _ in range(ROUNDS):  # in turn: a burst of load elsewhere hits all alike
            for name, argv in argvs.items():
                took, out = run(argv)
                seconds[name].append(took)
                if name == "edgerv":
                    found[name] = stretches(out)
                elif name == "rtamt":
                    found[name] = int(out.strip() or -1)
    median = {name: statistics.median(s) for name, s in seconds.items()}
    ours, peer, floor = median["edgerv"], median["rtamt"], median["floor"]
    return [
        {
            "name": "offline check of a nested timed monitor vs RTAMT (target >= 10x)",
            "detail": f"reach-and-hold, always (goal -> F[0..2s] (at & G[0..500ms] at)), "
            f"{EVENTS:,} JSON Lines messages at 100 Hz; whole process each, startup "
            f"included, the three in turn, median of {ROUNDS}; stretches of time that fail: "
            f"edgerv {found['edgerv']}, RTAMT {found['rtamt']}; the floor (a process that "
            f"only scans the file) {floor:.2f} s: 10x RTAMT is {peer / 10 / floor:.2f} of "
            "the floor's time",
            "baseline": f"RTAMT dense-time script {EVENTS / peer:,.0f} msg/s ({peer:.2f} s)",
            "measured": f"edgerv check {EVENTS / ours:,.0f} msg/s ({ours:.2f} s)",
            "ratio": f"{peer / ours:.2f}x RTAMT's speed",
        }
    ]


if __name__ == "__main__":
    for row in main():
        print(row)
