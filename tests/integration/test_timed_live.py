"""examples/timed.yaml's monitors (time-bounded operators nested in one another, past
operators over them, docs/semantics.md section 6, "Nesting") live: two handlers run them,
one as shipped (``onVerdict: reset``) and one with ``halt``, while a publisher plays a run
that breaks each of them in real time, and the demo's recorder (examples/robot/record.py)
records every message at its publication instant (the DDS source timestamp: the stamp
the handlers give a message without a header) in an MCAP bag. The live verdicts (kind,
step, stamp) are those `edgerv check` gives on the bag.

A bag's time ends at its last message; a live handler's goes on. The publisher's last
message is on a topic no monitor reads (/end, recorded only), a second after the runs:
the live verdicts up to its stamp are compared, once the handlers' clocks have passed it.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import yaml

from kit.ros import HandlerProcess, ros_env

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples" / "timed.yaml"
RECORDER = ROOT / "examples" / "robot" / "record.py"
FLUSH_AFTER = 0.2  # the handlers' --flush-after

# Each monitor's run that breaks it (topic, ms from the start, msg.data), with margins of
# tens of milliseconds or more: a publisher's timing is not exact.
RUNS: dict[str, list[tuple[str, int, Any]]] = {
    "reach-and-hold": [  # reached at 1.5 s, held 300 ms, reached again too late
        ("/goal", 0, True), ("/at_goal", 0, False), ("/goal", 10, False),
        ("/at_goal", 1500, True), ("/at_goal", 1800, False), ("/at_goal", 2300, True),
        ("/goal", 3500, False),
    ],
    "stop-and-stay": [  # stopped at 150 ms, moving again at 800 ms
        ("/obstacle", 0, True), ("/speed", 0, 1.0), ("/obstacle", 10, False),
        ("/speed", 150, 0.0), ("/speed", 800, 0.5), ("/obstacle", 3000, False),
    ],
    "answer-that-lasts": [  # acknowledged for 50 ms only
        ("/request", 0, True), ("/ack", 0, False), ("/refused", 0, False),
        ("/request", 10, False), ("/ack", 200, True), ("/ack", 250, False),
        ("/ack", 1000, False),
    ],
    "either-sensor": [  # nothing from 10 ms to 1.5 s: time alone decides (a clock step)
        ("/scan_ok", 0, True), ("/frame_ok", 0, False), ("/scan_ok", 10, False),
        ("/frame_ok", 1500, True), ("/frame_ok", 3000, False),
    ],
    "steady-aim": [  # aim lost 400 ms, fired 1 s later
        ("/fire", 0, False), ("/aim", 0, True), ("/aim", 500, False), ("/aim", 900, True),
        ("/fire", 1500, True), ("/fire", 1600, False),
    ],
    "busy-until-done": [  # unhealthy at 400 ms, before done
        ("/go", 0, True), ("/busy", 0, True), ("/ok", 0, True), ("/done", 0, False),
        ("/go", 10, False), ("/ok", 400, False), ("/done", 600, True), ("/ok", 2000, True),
    ],
    "warm-up": [  # warming stops at 1 s, ready only at 1.5 s
        ("/warming", 0, True), ("/ready", 0, False), ("/warming", 1000, False),
        ("/ready", 1500, True),
    ],
}  # fmt: skip
END = 4500  # ms: /end, a second after the runs' last message

# Publishes the rows (topic, ms, data) at their times from one start, each topic once its
# subscribers (argv[3]: how many a monitored topic waits for; /end waits for one, the
# recorder's) are matched; says "done" and stays, so no publisher leaves mid-run.
PLAYER = r"""
import json, sys, time, rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Bool, Float64
rows, types, subscribers = json.loads(sys.argv[1]), json.loads(sys.argv[2]), int(sys.argv[3])
rclpy.init()
node = rclpy.create_node("timed_player")
qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
cls = {"std_msgs/msg/Bool": Bool, "std_msgs/msg/Float64": Float64}
pubs = {t: node.create_publisher(cls[m], t, qos) for t, m in types.items()}
want = {t: 1 if t == "/end" else subscribers for t in pubs}
deadline = time.monotonic() + 30
while any(p.get_subscription_count() < want[t] for t, p in pubs.items()):
    if time.monotonic() > deadline:
        print("unmatched", {t: p.get_subscription_count() for t, p in pubs.items()}, flush=True)
        sys.exit(1)
    time.sleep(0.05)
time.sleep(0.5)
start = time.monotonic()
for topic, ms, data in rows:
    wait = start + ms / 1000 - time.monotonic()
    if wait > 0:
        time.sleep(wait)
    pubs[topic].publish(cls[types[topic]](data=data))
print("done", flush=True)
time.sleep(600)
"""


def monitors_file(tmp: Path, mode: str) -> Path:
    docs = list(yaml.safe_load_all(EXAMPLES.read_text()))
    for doc in docs:
        doc["spec"]["onVerdict"] = mode
    path = tmp / f"timed-{mode}.yaml"
    path.write_text(yaml.safe_dump_all(docs, sort_keys=False))
    return path


def offline(monitors: Path, bag: Path) -> list[tuple[str, str, int, int]]:
    """(monitor, verdict, step, stamp) of `edgerv check` on the bag, sorted."""
    done = subprocess.run(
        [sys.executable, "-m", "edgerv", "check", str(monitors), str(bag), "--json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 1, done.stderr
    return sorted(
        (m["name"], v["verdict"], v["step"], v["stamp"])
        for m in json.loads(done.stdout)["monitors"]
        for v in m["verdicts"]
    )


def live(handler: HandlerProcess, end: int) -> list[tuple[str, str, int, int]]:
    """(monitor, verdict, step, stamp) from the handler's verdict log up to ``end``, sorted."""
    return sorted(
        (v["monitor"], v["verdict"], v["step"], v["stamp"])
        for v in handler.verdicts()
        if v["stamp"] <= end
    )


def bag_end(bag: Path) -> int:
    """The last log time of the bag (its /end message)."""
    from mcap.reader import make_reader

    (path,) = bag.glob("*.mcap")
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    return int(summary.statistics.message_end_time)


def test_live_verdicts_of_nested_timed_monitors_equal_edgerv_check_on_the_recording(
    tmp_path: Path, domain: int
) -> None:
    rows = sorted(
        [(topic, ms, data) for run in RUNS.values() for topic, ms, data in run]
        + [("/end", END, True)],
        key=lambda row: row[1],
    )
    types = {
        sig["topic"]: sig["type"]
        for doc in yaml.safe_load_all(EXAMPLES.read_text())
        for sig in doc["spec"]["signals"].values()
    }
    assert {t for t, _, _ in rows} == {*types, "/end"}
    types["/end"] = "std_msgs/msg/Bool"
    files = {mode: monitors_file(tmp_path, mode) for mode in ("reset", "halt")}
    bag = tmp_path / "bag"
    recorder = subprocess.Popen(
        [sys.executable, str(RECORDER), str(bag), *(f"{t}={m}" for t, m in types.items())],
        env=ros_env(domain),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    handlers: list[HandlerProcess] = []
    player = None
    try:
        assert recorder.stdout is not None
        assert recorder.stdout.readline().strip() == "ready", recorder.stderr
        flush = ("--flush-after", str(FLUSH_AFTER))
        handlers.append(HandlerProcess(tmp_path, files["reset"], domain, *flush, name="reset"))
        handlers.append(HandlerProcess(tmp_path, files["halt"], domain, *flush, name="halt"))
        player = subprocess.Popen(
            [sys.executable, "-c", PLAYER, json.dumps(rows), json.dumps(types), "3"],
            env=ros_env(domain),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert player.stdout is not None
        said = player.stdout.readline().strip()
        assert said == "done", (said, player.stderr.read() if player.stderr else "")
        time.sleep(FLUSH_AFTER + 1.5)  # the handlers' clocks pass /end's stamp
    finally:
        if player is not None:
            player.kill()
            player.wait()
        recorder.send_signal(signal.SIGINT)
        recorded, _ = recorder.communicate(timeout=30)
        for h in handlers:
            assert h.stop() == 0, h.stderr
    counts = json.loads(recorded.strip().splitlines()[-1])["recorded"]
    assert sum(counts.values()) == len(rows), counts
    end = bag_end(bag)
    for handler, mode in zip(handlers, ("reset", "halt"), strict=True):
        got = live(handler, end)
        assert {name for name, verdict, _, _ in got if verdict == "violated"} == set(RUNS), (
            mode,
            got,
        )
        assert got == offline(files[mode], bag), (mode, handler.stderr)
