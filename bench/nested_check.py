"""The offline check of a nested timed monitor, whole job against whole job: `edgerv
check` on a JSON Lines file beside RTAMT's dense-time STL over the same file
(bench/peers/rtamt_nested.py), and the floor of any Python checker (a process that only
scans the file: bench/peers/scan_floor.py), each a process of its own, in turn.

The property, reach-and-hold: a new goal is reached within 2 s and the robot then stays
there 500 ms, `always (goal -> F[0..2s] (at & G[0..500ms] at))` (issue 34), over 500,000
messages at 100 Hz: a goal every 3 s, the robot reaching it after a while and now and
then leaving early. Each side prints the number of stretches of time where it fails
(edgerv: its violated steps, with reset, one per failing stretch read 2.5 s late).
Each side also runs on the file's first three lines alone: its start (interpreter,
imports, the property compiled), taken off its time to give its cost per message.

The second row is the same monitor live: the messages of the same file through the live
handler's per-message path (:meth:`Engine.ingest` in the batches its take loop hands
over, the scheduler's evaluation after each batch; no ROS, the engine's clock stopped, as
bench/evaluate.py measures the live pipeline), beside untimed monitors of the same size
on the same messages, in turn, each the best of its rounds:

* the same atoms and automaton states: ``always (goal -> at)`` reads goal and at, and its
  automaton has 3 states, as the nested one's; it has none of the nested one's five
  derived placeholders (the time-bounded operators read late as timed past ones);
* the same placeholders: seven (goal, at and five untimed past operators) and 3 states.
"""

from __future__ import annotations

import json
import math
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

NESTED = "always (goal -> F[0..2s] (at & G[0..500ms] at))"
MONITOR = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: reach-and-hold}
spec:
  assertion: "%s"
  signals:
    goal: {topic: /goal, type: std_msgs/msg/Bool}
    at: {topic: /at, type: std_msgs/msg/Bool}
"""
# untimed monitors of the nested one's size (module docstring)
SAME_ATOMS = "always (goal -> at)"
SAME_PLACEHOLDERS = (
    "always (goal -> ((once at) & (historically (goal | at)) | (at since goal) "
    "| once (at & historically at)))"
)
BATCHES = (1, 10, 100, 1000)  # messages the handler's take loop hands the engine at once
LIVE_BATCH = 100  # the row's ratio: bench/evaluate.py's timed row's batch


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


def offline(tmp: Path) -> dict[str, Any]:
    """The three processes on the file in turn, and each tool on its first three lines."""
    trace, monitor = tmp / "run.jsonl", tmp / "reach.yaml"
    make_trace(trace)
    monitor.write_text(MONITOR % NESTED)
    start = tmp / "start.jsonl"  # the first three lines: a message of each topic
    with trace.open() as f:
        start.write_text("".join(f.readline() for _ in range(3)))

    def edgerv(path: Path) -> list[str]:
        return [sys.executable, "-m", "edgerv", "check", str(monitor), str(path), "--json"]

    def rtamt(path: Path) -> list[str]:
        return [sys.executable, str(PEERS / "rtamt_nested.py"), str(path)]

    argvs = {
        "edgerv": edgerv(trace),
        "rtamt": rtamt(trace),
        "floor": [sys.executable, str(PEERS / "scan_floor.py"), str(trace)],
        "edgerv start": edgerv(start),
        "rtamt start": rtamt(start),
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
    our_start, peer_start = median["edgerv start"], median["rtamt start"]
    ours_each = (ours - our_start) / EVENTS * 1e6  # us a message, beyond the start
    peer_each = (peer - peer_start) / EVENTS * 1e6
    return {
        "name": "offline check of a nested timed monitor vs RTAMT (target >= 10x)",
        "detail": f"reach-and-hold, {NESTED}, {EVENTS:,} JSON Lines messages at 100 Hz; "
        f"whole process each, startup included, the five in turn, median of {ROUNDS}; "
        f"stretches of time that fail: edgerv {found['edgerv']}, RTAMT {found['rtamt']}; "
        f"the floor (a process that only scans the file) {floor:.2f} s: 10x RTAMT is "
        f"{peer / 10 / floor:.2f} of the floor's time and {peer / 10 / our_start:.2f} of "
        f"edgerv's start alone ({our_start:.2f} s: the same check of the file's first three "
        f"lines; RTAMT's {peer_start:.2f} s); beyond each one's start, a message costs "
        f"edgerv {ours_each:.2f} us and RTAMT {peer_each:.2f} us "
        f"({peer_each / ours_each:.1f}x)",
        "baseline": f"RTAMT dense-time script {EVENTS / peer:,.0f} msg/s ({peer:.2f} s)",
        "measured": f"edgerv check {EVENTS / ours:,.0f} msg/s ({ours:.2f} s)",
        "ratio": f"{peer / ours:.2f}x RTAMT's speed; {peer_each / ours_each:.1f}x beyond "
        "each one's start",
    }


def messages_of(trace: Path) -> list[tuple[int, str, list[Any]]]:
    """The file's messages as the live handler's reader hands them to the engine: stamp,
    topic, the values of the fields its routes read (here each message's one field)."""
    out = []
    with trace.open("rb") as f:
        for line in f:
            event = json.loads(line)
            out.append((event["stamp"], event["topic"], [event["msg"]["data"]]))
    return out


def live(assertion: str, messages: list[tuple[int, str, list[Any]]], batch: int) -> float:
    """Seconds for the live pipeline to take ``messages`` in batches of ``batch``:
    :meth:`Engine.ingest`, the scheduler's evaluation after each batch, then a drain."""
    from edgerv.core.documents import load_monitors_text
    from edgerv.core.monitor import compile_monitor
    from edgerv.handler.engine import Engine
    from evaluate import StoppedClock

    monitor = compile_monitor(load_monitors_text("live.yaml", MONITOR % assertion)[0])
    engine = Engine("bench", flush_after=3600.0, clock=StoppedClock())
    engine.put(monitor, active=True)
    start = time.perf_counter()
    for i in range(0, len(messages), batch):
        engine.ingest(messages[i : i + batch])
        engine.evaluate()  # a scheduler round
    engine.drain()
    return time.perf_counter() - start


def sizes(assertion: str) -> str:
    from edgerv.core.documents import load_monitors_text
    from edgerv.core.monitor import compile_monitor

    m = compile_monitor(load_monitors_text("live.yaml", MONITOR % assertion)[0])
    return f"{m.table.bits} placeholders ({len(m.past)} derived), {m.table.states} states"


def per_event(tmp: Path) -> dict[str, Any]:
    """The nested monitor's live cost per message beside the untimed ones', in turn."""
    messages = messages_of(tmp / "run.jsonl")
    monitors = {"nested": NESTED, "atoms": SAME_ATOMS, "placeholders": SAME_PLACEHOLDERS}
    best = {(name, batch): math.inf for name in monitors for batch in BATCHES}
    for _ in range(ROUNDS):  # in turn; each its best round
        for batch in BATCHES:
            for name, assertion in monitors.items():
                took = live(assertion, messages, batch)
                best[name, batch] = min(best[name, batch], took)
    ns = {key: took / len(messages) * 1e9 for key, took in best.items()}

    def by_batch(name: str) -> str:
        return ", ".join(f"{b}: {ns[name, b]:,.0f}" for b in BATCHES)

    def ratios(name: str) -> str:
        return ", ".join(f"{b}: {ns['nested', b] / ns[name, b]:.2f}x" for b in BATCHES)

    at = LIVE_BATCH
    return {
        "name": "a nested timed monitor's live cost per message (target within 2x of an "
        "untimed one of the same size)",
        "detail": f"{NESTED} ({sizes(NESTED)}) on the {len(messages):,} messages of the "
        "row above, through the live handler's per-message path without ROS: "
        f"Engine.ingest in batches of {'/'.join(map(str, BATCHES))} messages (field values, "
        "as the CDR reader gives them; the engine's clock stopped), the scheduler's "
        "evaluation after each batch, the three monitors in turn, best of "
        f"{ROUNDS}; untimed of the same size: the same atoms and states, {SAME_ATOMS} "
        f"({sizes(SAME_ATOMS)}), and the same placeholders, {SAME_PLACEHOLDERS} "
        f"({sizes(SAME_PLACEHOLDERS)})",
        "baseline": f"ns a message by batch: same atoms and states {by_batch('atoms')}; "
        f"same placeholders {by_batch('placeholders')}",
        "measured": f"nested timed, ns a message by batch: {by_batch('nested')}",
        "ratio": f"{ns['nested', at] / ns['atoms', at]:.2f}x the cost of the same atoms and "
        f"states, {ns['nested', at] / ns['placeholders', at]:.2f}x the same placeholders' at "
        f"batch {at}; by batch: {ratios('atoms')} (same atoms); {ratios('placeholders')} "
        "(same placeholders)",
    }


def main() -> list[dict[str, Any]]:
    with tempfile.TemporaryDirectory() as tmp:
        return [offline(Path(tmp)), per_event(Path(tmp))]


if __name__ == "__main__":
    for row in main():
        print(row)
