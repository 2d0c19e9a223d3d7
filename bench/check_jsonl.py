"""`edgerv check` on a JSON Lines trace against the scripts a user of Reelay or RTAMT
would write for the same job (bench/peers/): each reads the same file with Python's json,
keeps the signals' values and counts the steps where "whenever running, speed < 100"
fails. Whole process against whole process (startup included), the three in turn, three
rounds, medians.

The trace: the first ``EDGERV_BENCH_JSONL_EVENTS`` (default 300,000) events of the robot
recording of bench/robot_bag.py, every topic (/odom's full messages too), as `edgerv
check` reads JSON Lines. edgerv's monitor is `always (running -> speed < 100)` (reset after
each verdict, so every violating step is reported, `--json`); the scripts monitor its
past-time form, restarted after each violation (see their docstrings). The three counts
of violating steps are compared: a mismatch is written into the rows, loudly.
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

from check_bag import checked, edgerv_command, run_process
from robot_bag import write_jsonl

EVENTS = int(os.environ.get("EDGERV_BENCH_JSONL_EVENTS", "300000"))
ROUNDS = 3
PEERS = Path(__file__).resolve().parent / "peers"

MONITOR = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: speed-limit}
spec:
  assertion: "always (running -> speed < 100)"
  signals:
    running: {topic: /running, type: std_msgs/msg/Bool}
    speed: {topic: /speed, type: std_msgs/msg/Float64}
"""


def edgerv_violations(stdout: str) -> int:
    (monitor,) = json.loads(stdout)["monitors"]
    return sum(v["verdict"] == "violated" for v in monitor["verdicts"])


def main() -> list[dict[str, Any]]:
    edgerv = edgerv_command()
    with tempfile.TemporaryDirectory() as tmp:
        trace, monitor = Path(tmp) / "run.jsonl", Path(tmp) / "speed-limit.yaml"
        counts = write_jsonl(trace, EVENTS)
        monitor.write_text(MONITOR)
        size = trace.stat().st_size / 2**20
        tools = {
            "edgerv": ([edgerv, "check", str(monitor), str(trace), "--json"], (0, 1)),
            "Reelay": ([sys.executable, str(PEERS / "reelay_check.py"), str(trace)], (0,)),
            "RTAMT": ([sys.executable, str(PEERS / "rtamt_check.py"), str(trace)], (0,)),
            "floor": ([sys.executable, str(PEERS / "scan_floor.py"), str(trace)], (0,)),
        }
        seconds: dict[str, list[float]] = {name: [] for name in tools}
        found: dict[str, set[int]] = {name: set() for name in tools}
        for _ in range(ROUNDS):  # in turn: a burst of load elsewhere hits all alike
            for name, (argv, codes) in tools.items():
                run = checked(run_process(argv, keep_stdout=True), name, codes)
                seconds[name].append(run.seconds)
                if name == "edgerv":
                    found[name].add(edgerv_violations(run.stdout))
                elif name != "floor":  # (it checks nothing: it counts the lines)
                    found[name].add(int(run.stdout.strip()))
    median = {name: statistics.median(s) for name, s in seconds.items()}
    said = {name: "/".join(map(str, sorted(n))) for name, n in found.items()}
    agree = len(set().union(*(n for name, n in found.items() if name != "floor"))) == 1
    counted = ", ".join(f"{name} {said[name]}" for name in tools if name != "floor")
    verdict = (
        f"violating steps: {counted} (agree)"
        if agree
        else f"!!! MISMATCH: THE TOOLS DISAGREE ON THE VIOLATING STEPS: {counted} !!!"
    )
    steps = counts["/running"] + counts["/speed"]
    ours = median["edgerv"]
    rows = []
    for peer, target in (("Reelay", 10), ("RTAMT", 100)):
        rows.append(
            {
                "name": f"offline check vs the {peer} script, JSON Lines (target >= {target}x)",
                "detail": f"always (running -> speed < 100) on {EVENTS:,} events of the robot "
                f"recording ({size:,.0f} MiB; {steps:,} on /running and /speed), "
                f"bench/peers/{peer.lower()}_check.py beside `edgerv check --json`; whole "
                f"process each, startup included, the three in turn, median of {ROUNDS}; "
                f"{verdict}",
                "baseline": f"{peer} script {EVENTS / median[peer]:,.0f} events/s "
                f"({median[peer]:.2f} s)",
                "measured": f"edgerv check {EVENTS / ours:,.0f} events/s ({ours:.2f} s)",
                "ratio": f"{median[peer] / ours:.1f}x {peer}'s speed",
            }
        )
    floor = median["floor"]
    rows.append(
        {
            "name": "the floor of a Python check of that file: the targets above, against a "
            "process that only scans it",
            "detail": "bench/peers/scan_floor.py: the interpreter's start, then msgspec's "
            "decoder over every line (messages left undecoded), nothing checked; in turn "
            f"with the three above, median of {ROUNDS}. 10x Reelay and 100x RTAMT mean "
            f"{median['Reelay'] / 10:.2f} s and {median['RTAMT'] / 100:.3f} s for the whole "
            "process: a ratio below 1 here means no Python tool can reach that target",
            "baseline": f"scan alone {floor:.2f} s ({median['Reelay'] / floor:.1f}x Reelay's "
            f"speed, {median['RTAMT'] / floor:.1f}x RTAMT's)",
            "measured": f"edgerv check {ours:.2f} s",
            "ratio": f"10x Reelay is {median['Reelay'] / 10 / floor:.2f} of the floor's time, "
            f"100x RTAMT {median['RTAMT'] / 100 / floor:.2f}; edgerv takes "
            f"{ours / floor:.1f}x the floor",
        }
    )
    return rows


if __name__ == "__main__":
    for row in main():
        print(row)
