"""``edgerv replay`` is the run: a recorded trace with gaps, replayed at its recorded pace
with /clock saying the recorded time, into a live ``edgerv handler --use-sim-time``
running timed monitors: the live verdicts, their steps and their stamps are those of
``edgerv check`` on the same file, and a violation that time decides inside a gap is
reported during the gap, not after the replay.

Real processes, real DDS: the handler and ``edgerv replay`` as a user runs them.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from kit.ros import HandlerProcess, check_verdicts, ros_env, wait_for

pytestmark = pytest.mark.integration

# Header-stamped topics (geometry_msgs/msg/PointStamped: the stamp the handler reads is
# the header's, published as recorded) and topics without a header (std_msgs/msg/Bool:
# the instant of publication, in ROS time: the /clock the replay sent just before it).
MONITORS = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: heartbeat}
spec:
  # a beat at least every second: violated inside the 1.4 s gap, by time alone
  assertion: "always (age(beat) < 1s)"
  signals:
    beat: {topic: /beat, type: geometry_msgs/msg/PointStamped, field: point.x}
---
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: reach}
spec:
  # a goal is reached within 500 ms (a deadline, decided by time)
  assertion: "always (goal > 0 -> F[0..500ms] at > 0)"
  signals:
    goal: {topic: /goal, type: geometry_msgs/msg/PointStamped, field: point.x}
    at: {topic: /at, type: geometry_msgs/msg/PointStamped, field: point.x}
---
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: stop-and-stay}
spec:
  # examples/timed.yaml's: an obstacle stops the robot within 200 ms, stopped 1 s
  assertion: "always (obstacle -> F[0..200ms] G[0..1s] (speed < 0.01))"
  signals:
    obstacle: {topic: /obstacle, type: std_msgs/msg/Bool}
    speed: {topic: /speed, type: std_msgs/msg/Float64}
"""

BASE = 1_700_000_000 * 10**9  # a recorded run of 2023: far behind the system clock
MS = 1_000_000


def stamped(t: int, x: float) -> dict[str, Any]:
    sec, nanosec = divmod(t, 10**9)
    return {"header": {"stamp": {"sec": sec, "nanosec": nanosec}}, "point": {"x": x}}


def trace_with_gaps(path: Path) -> tuple[Path, int]:
    """The run, and the stamp of its gap's violation: beats every 100 ms with a 1.4 s gap
    from 1.0 s; goals reached late and in time; an obstacle the robot stops for and one it
    does not; an unmonitored topic's last line, after the last monitored one (time runs
    on to it: the trace's end)."""
    lines: list[dict[str, Any]] = []
    beats = [t for t in range(0, 4000, 100) if not 1000 < t < 2400]
    lines += [{"topic": "/beat", "msg": stamped(BASE + t * MS, 1.0)} for t in beats]
    for goal, reached in ((300, 600), (1200, 2000), (2600, None), (3000, 3400)):
        lines.append({"topic": "/goal", "msg": stamped(BASE + goal * MS, 1.0)})
        lines.append({"topic": "/goal", "msg": stamped(BASE + (goal + 50) * MS, 0.0)})
        if reached is not None:
            lines.append({"topic": "/at", "msg": stamped(BASE + reached * MS, 1.0)})
            lines.append({"topic": "/at", "msg": stamped(BASE + (reached + 50) * MS, 0.0)})
    for t, obstacle, speed in (
        (150, False, 0.5),
        (700, True, 0.5),
        (800, False, 0.0),  # stopped within 200 ms, and stays
        (1900, True, 0.6),
        (2050, False, 0.6),
        (2500, False, 0.0),  # not stopped within 200 ms
        (3500, False, 0.3),
    ):
        lines.append({"topic": "/obstacle", "stamp": BASE + t * MS + 1, "msg": {"data": obstacle}})
        lines.append({"topic": "/speed", "stamp": BASE + t * MS + 2, "msg": {"data": speed}})
    lines.append({"topic": "/robot_state", "stamp": BASE + 4300 * MS, "msg": {"data": "end"}})
    path.write_text("".join(json.dumps(line) + "\n" for line in lines))
    return path, BASE + 2000 * MS  # the last beat before the gap at 1.0 s, plus 1 s


def live(handler: HandlerProcess) -> list[tuple[str, str, int, int]]:
    return sorted((v["monitor"], v["verdict"], v["step"], v["stamp"]) for v in handler.verdicts())


def replay(monitors: Path, trace: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "edgerv", "replay", "--monitors", str(monitors), str(trace),
            *extra]  # fmt: skip


def test_replay_at_the_recorded_pace_gives_check_verdicts_and_stamps_live(
    tmp_path: Path, domain: int
) -> None:
    monitors = tmp_path / "timed.yaml"
    monitors.write_text(MONITORS)
    trace, in_gap = trace_with_gaps(tmp_path / "run.jsonl")
    offline = check_verdicts(monitors, trace)
    assert ("heartbeat", "violated", 12, in_gap) in offline  # a clock step inside the gap
    assert {m for m, *_ in offline} == {"heartbeat", "reach", "stop-and-stay"}
    handler = HandlerProcess(tmp_path, monitors, domain, "--use-sim-time")
    try:
        errors = (tmp_path / "replay.err").open("w")
        proc = subprocess.Popen(
            replay(monitors, trace), env=ros_env(domain), stderr=errors, text=True
        )
        # the gap's violation is decided by time 2.0 s into the run, which ends at 4.3 s
        # (then /clock says the end for 0.5 s more): it comes live about --flush-after
        # (0.5 s) after that instant, well before the replay ends
        assert wait_for(
            lambda: any(v["monitor"] == "heartbeat" for v in handler.verdicts()), timeout=30
        ), handler.stderr
        seen = time.monotonic()
        assert proc.poll() is None, "the gap's violation came only after the replay ended"
        assert proc.wait(timeout=60) == 0, (tmp_path / "replay.err").read_text()
        ended = time.monotonic()
        said = (tmp_path / "replay.err").read_text()
        assert "4.300 s of the recording in 4.3" in said, said  # the recorded pace
        # the monitors reach the trace's end --flush-after (0.5 s) after /clock did
        wait_for(lambda: len(handler.verdicts()) >= len(offline), timeout=10)
        time.sleep(1.0)  # (nothing more may come)
    finally:
        assert handler.stop() == 0, handler.stderr
    assert live(handler) == offline, handler.stderr
    assert ended - seen > 1.5  # 2.3 s of run after the instant, 1 s of ending, less 0.5 s
    # and each violation on the handler's console: monitor, step, stamp and topics
    line = f"monitor heartbeat violated at step 12 (stamp {in_gap // 10**9}.{in_gap % 10**9:09d})"
    assert f"{line} on /beat" in handler.stderr


def test_replay_faster_than_recorded_gives_the_same_verdicts_under_sim_time(
    tmp_path: Path, domain: int
) -> None:
    """--rate 4: a quarter of the time, the same verdicts and stamps (the handler's time
    is the recorded time /clock says, whatever its pace)."""
    monitors = tmp_path / "timed.yaml"
    monitors.write_text(MONITORS)
    trace, _ = trace_with_gaps(tmp_path / "run.jsonl")
    offline = check_verdicts(monitors, trace)
    handler = HandlerProcess(tmp_path, monitors, domain, "--use-sim-time", "--quiet-violations")
    try:
        done = subprocess.run(
            replay(monitors, trace, "--rate", "4"),
            env=ros_env(domain),
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert done.returncode == 0, done.stderr
        took = float(done.stderr.split("of the recording in ")[1].split(" s")[0])
        assert 4.3 / 4 <= took < 4.3 / 2
        wait_for(lambda: len(handler.verdicts()) >= len(offline), timeout=10)
        time.sleep(1.0)
    finally:
        assert handler.stop() == 0, handler.stderr
    assert live(handler) == offline, handler.stderr
    assert "violated at step" not in handler.stderr  # --quiet-violations
