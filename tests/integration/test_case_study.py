"""The paper's case study, shortened: ``examples/robot/demo.py --short`` (``make demo``).

A simulated robot's 8 Hz loop shares one CPU with the edge handler. The test
checks the shape the demo exists to show, as the demo measured it on real ROS 2
traffic: the loop is slower with every monitor on the edge than with none;
the orchestration policy, seeing the loop's deadline pressure, moved monitors to
the cloud handler; the loop was faster after; once the robot parked at its goal,
the policy brought monitors back down; and the live verdicts of every monitor,
across the handlers and the moves both ways, equal ``edgerv check`` on the
phase's recorded MCAP bag (no event lost or doubled).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.integration

ROOT = Path(__file__).parents[2]


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, dict[str, Any], str]:
    out = tmp_path_factory.mktemp("demo")
    demo = [sys.executable, str(ROOT / "examples/robot/demo.py"), "--short", "--plain"]
    done = subprocess.run(
        [*demo, "--out", str(out), "--domain", "77"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    text = done.stdout + done.stderr
    summary_path = out / "summary.json"
    assert summary_path.exists(), text
    return done.returncode, json.loads(summary_path.read_text()), text


def test_monitors_on_the_edge_slow_the_loop_and_moving_them_brings_it_back(
    run: tuple[int, dict[str, Any], str],
) -> None:
    _, summary, text = run
    phases = summary["phases"]
    base, edge, orch = phases["baseline"], phases["edgeOnly"], phases["orchestrated"]
    assert edge["medianMs"] > base["medianMs"], text
    assert edge["medianMs"] > orch["medianMs"], text
    assert edge["deadlineMisses"] > orch["deadlineMisses"], text
    total = summary["raisedLoad"]["monitors"]  # the paper's 200 and those that raise the load
    assert total > 200
    assert edge["monitorsOnEdge"] == total
    assert orch["monitorsOnEdge"] < total
    assert base["goalReached"], text
    # what the demo is for (issue 37): the orchestrated robot reaches its goal, its loop
    # back under the deadline (test_the_policy_brings_the_loop_back_under_its_deadline...)
    assert orch["goalReached"], text


def test_the_moves_were_decided_by_the_policy_on_deadline_pressure(
    run: tuple[int, dict[str, Any], str],
) -> None:
    _, summary, text = run
    assert summary["migrations"] >= 1, text
    assert "deadline" in summary["migrationReasons"], text


def test_the_policy_brings_the_loop_back_under_its_deadline_and_says_how_fast(
    run: tuple[int, dict[str, Any], str],
) -> None:
    """Issue 37's measure: from the first missed deadline to the first of 10 frames in a
    row that met theirs, the handoffs and moves it took, the misses meanwhile."""
    _, summary, text = run
    recovery = summary["phases"]["orchestrated"]["recovery"]
    assert recovery["seconds"] is not None, (recovery, text)  # the loop came back under it
    assert 1 <= recovery["handoffs"] <= summary["migrations"], recovery
    assert 0 < recovery["monitorsMoved"] <= summary["monitorsMoved"], recovery
    assert recovery["deadlineMisses"] >= 1, recovery
    on_edge = summary["raisedLoad"]["monitors"] - recovery["monitorsInCloud"]
    assert recovery["monitorsInCloud"] > 0 and on_edge >= 0, recovery
    # today's rule on the same load, in the same run (edgerv orchestrate --no-plan): measured
    # the same way, for the README's comparison (how much better is the machine's to say)
    rule = summary["heuristicBaseline"]
    assert rule["recovery"] is not None and rule["migrations"] >= 1, rule


def test_once_the_robot_parks_the_policy_brings_monitors_back_down(
    run: tuple[int, dict[str, Any], str],
) -> None:
    """Parked at its goal, the robot's loop idles: the deadline pressure is gone, and after
    the policy's calm and cooldown the monitors come back to the edge by the handoff."""
    _, summary, text = run
    assert "calm below" in summary["migrationReasons"], text
    parked = summary["phases"]["orchestrated"]["parked"]
    assert summary["monitorsMovedBack"] == parked["monitorsBack"] > 0, text
    # The policy's hysteresis (--calm 8, --cooldown 10) is its own, tested in
    # test_placement.py. Not asserted here: that the first move back comes 8 s after the
    # arrival. The loop, once shed, can be calm (p95 under 0.95 of its deadline) in the
    # robot's last seconds to its goal, and then the first move back comes with the
    # policy's first decision after it parks (0.1 s after, seen on 2026-11-25).
    assert parked["firstBackAfterSeconds"] is not None, parked


def test_live_verdicts_across_moves_equal_edgerv_check_on_the_recorded_bag(
    run: tuple[int, dict[str, Any], str],
) -> None:
    """Every monitor's live verdicts equal the recording's, except where a handler counted
    messages the middleware lost on a topic the monitor reads (a starved edge handler
    whose publisher's history overflowed: counted and logged, never silent; the robot's
    history of 10 s makes it rare). A difference nothing explains fails."""
    _, summary, _ = run
    for phase in ("edgeOnly", "heuristicBaseline", "orchestrated"):
        check = summary["verdictChecks"][phase]
        assert check["monitors"] == summary["raisedLoad"]["monitors"]
        assert check["verdictsOffline"] > 0, (phase, check)
        assert check["unexplainedMonitors"] == [], (phase, check)
        if not check["messagesLost"]:
            assert check["verdictsLive"] == check["verdictsOffline"], (phase, check)
            assert check["mismatchedMonitors"] == [], (phase, check)
