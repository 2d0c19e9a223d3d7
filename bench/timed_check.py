"""The offline check of a timed monitor, whole job against whole job: `edgerv check` on a
JSON Lines file beside a Python program that reads the same file and feeds Reelay's
dense-time monitor (the peer with timed past operators), each a process of its own.

The property: the door may open only if the speed stayed under 0.1 for the last 2 s,
`always (door -> historically[0..2s] (speed < 0.1))` in edgerv, and the same formula
in Reelay's syntax, over 200,000 messages of /speed (100 Hz) and /door. Both read
every line, keep the signals' values and report where it fails; the number of
failing stretches each reports is printed beside the time.
"""

from __future__ import annotations

import json
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

EVENTS = 200_000
ROUNDS = 3

MONITOR = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: door-when-still}
spec:
  assertion: "always (door -> historically[0..2s] (speed < 0.1))"
  signals:
    door: {topic: /door, type: std_msgs/msg/Bool, initial: false}
    speed: {topic: /speed, type: std_msgs/msg/Float64}
"""

# The peer's whole job: read the file, hold the values, feed Reelay, count the failures.
REELAY = r"""
import json, sys, reelay
monitor = reelay.dense_timed_monitor(
    pattern="{door} -> historically[0:2000000000] {speed < 0.1}")
held, t0, failures, last = {"door": False, "speed": None}, None, 0, True
with open(sys.argv[1]) as f:
    for line in f:
        rec = json.loads(line)
        held[rec["topic"][1:]] = rec["msg"]["data"]
        if held["speed"] is None:
            continue
        t0 = rec["stamp"] if t0 is None else t0
        for out in monitor.update({"time": rec["stamp"] - t0, **held}):
            if last and not out["value"]:
                failures += 1
            last = out["value"]
print(failures)
"""


def make_trace(path: Path) -> None:
    rng = random.Random(3)
    stamp, speed, lines = 1_700_000_000_000_000_000, 0.0, []
    for i in range(EVENTS):
        stamp += 10_000_000  # 100 Hz
        if i % 50 == 0:  # now and then the door is asked to open
            lines.append({"topic": "/door", "stamp": stamp, "msg": {"data": rng.random() < 0.3}})
        else:
            if rng.random() < 0.01:  # the robot starts or stops moving
                speed = 0.05 if speed > 0.1 else 0.5
            lines.append({"topic": "/speed", "stamp": stamp, "msg": {"data": speed}})
    path.write_text("".join(json.dumps(x) + "\n" for x in lines))


def run(argv: list[str]) -> tuple[float, str]:
    start = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True, check=False)
    return time.perf_counter() - start, done.stdout


def main() -> list[dict[str, Any]]:
    with tempfile.TemporaryDirectory() as tmp:
        trace, monitor = Path(tmp) / "run.jsonl", Path(tmp) / "door.yaml"
        make_trace(trace)
        monitor.write_text(MONITOR)
        edgerv_argv = [sys.executable, "-m", "edgerv", "check", str(monitor), str(trace), "--json"]
        reelay_argv = [sys.executable, "-c", REELAY, str(trace)]
        ours = peer = float("inf")
        for _ in range(ROUNDS):  # interleaved: a burst of load elsewhere hits both alike
            seconds, out = run(edgerv_argv)
            ours = min(ours, seconds)
            steps = [v["step"] for v in json.loads(out)["monitors"][0]["verdicts"]]
            stretches = sum(1 for i, step in enumerate(steps) if i == 0 or steps[i - 1] != step - 1)
            seconds, out = run(reelay_argv)
            peer = min(peer, seconds)
            failures = int(out.strip() or -1)
    return [
        {
            "name": "offline check of a timed monitor vs Reelay (target >= 1x)",
            "detail": f"always (door -> historically[0..2s] (speed < 0.1)), {EVENTS:,} JSON "
            f"Lines messages, whole process each (best of {ROUNDS}); stretches of steps "
            f"that fail: edgerv {stretches}, Reelay {failures}",
            "baseline": f"Reelay dense monitor {EVENTS / peer:,.0f} msg/s ({peer:.2f} s)",
            "measured": f"edgerv check {EVENTS / ours:,.0f} msg/s ({ours:.2f} s)",
            "ratio": f"{peer / ours:.2f}x Reelay's speed",
        }
    ]


if __name__ == "__main__":
    for row in main():
        print(row)
