"""The case study's monitors (examples/robot): the committed YAML is what the generator
writes, every monitor loads, and the paper's goal assertion means what the README says."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from kit.cli import edgerv

ROOT = Path(__file__).parents[2]
ROBOT = ROOT / "examples/robot"
S = 1_000_000_000


def test_the_committed_monitors_are_the_generators_output(tmp_path: Path) -> None:
    out = tmp_path / "case-study.yaml"
    subprocess.run([sys.executable, str(ROBOT / "monitors.py"), str(out)], check=True)
    assert out.read_text() == (ROBOT / "case-study.yaml").read_text()


def check(monitors: Path, events: list[tuple[float, str, dict[str, object]]], tmp: Path) -> dict:
    trace = tmp / "run.jsonl"
    trace.write_text(
        "".join(
            json.dumps({"topic": t, "stamp": int(s * S), "msg": m}) + "\n" for s, t, m in events
        )
    )
    done = edgerv("check", monitors, trace, "--json")
    assert done.returncode in (0, 1), done.stderr
    return {m["name"]: m["verdicts"] for m in json.loads(done.stdout)["monitors"]}


def odom(x: float, y: float) -> dict[str, object]:
    twist = {"linear": {"x": 0.5}, "angular": {"z": 0.0}}
    return {"pose": {"pose": {"position": {"x": x, "y": y}}}, "twist": {"twist": twist}}


GOAL = {"pose": {"position": {"x": 0.0, "y": 3.0}}}


def test_all_200_load_and_the_goal_assertion_has_its_deadline(tmp_path: Path) -> None:
    """A new goal given at the start: reached within 20 s holds; not reached is violated
    exactly 20 s after the goal (a clock step at that instant)."""
    start = [(0.0, "/odom", odom(0, 0)), (0.5, "/goal", GOAL)]
    path = [(1.0 + i, "/odom", odom(0.1 * i, 0.1 * i)) for i in range(25)]
    reached = check(
        ROBOT / "case-study.yaml",
        [*start, *path[:10], (11.5, "/odom", odom(0.05, 3.0)), *path[11:]],
        tmp_path,
    )
    assert len(reached) == 200
    assert reached["goal-reached"] == []
    missed = check(ROBOT / "case-study.yaml", [*start, *path], tmp_path)
    assert [(v["verdict"], v["stamp"]) for v in missed["goal-reached"]] == [
        ("violated", int(20.5 * S))
    ]
