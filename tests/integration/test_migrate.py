"""Moving a monitor between two live handlers mid-stream (loopback, one ROS domain).

Both handlers hold the same monitors; the sender runs them, the receiver only
defines them. While a trace is replayed as real ROS messages, `edgerv migrate`
moves a monitor there and back. Together, the two verdict logs must hold the
very verdicts `edgerv check` gives on the trace: nothing lost, nothing twice.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from kit.documents import write
from kit.odom_run import MONITORS, random_trace
from kit.ros import (
    TOKEN,
    HandlerProcess,
    live_verdicts,
    migrate,
    offline_verdicts,
    replay_command,
    ros_env,
    wait_for,
)

pytestmark = pytest.mark.integration


def test_migrating_mid_stream_loses_and_repeats_nothing(tmp_path: Path, domain: int) -> None:
    monitors = write(tmp_path, "monitors.yaml", MONITORS)
    trace = random_trace(tmp_path / "run.jsonl", 1200, seed=5)
    # a window well above the default 20 ms: under the tests' load on 2 cores, topics can
    # reach a handler further apart, and merged out of order they give other letters
    window = ("--reorder-window", "0.25")
    edge = HandlerProcess(tmp_path, monitors, domain, *window, name="edge")
    cloud = HandlerProcess(tmp_path, monitors, domain, "--active", "none", *window, name="cloud")
    try:
        replay = subprocess.Popen(
            replay_command(monitors, trace, 0.006),
            env=ros_env(domain),
            stderr=subprocess.PIPE,
            text=True,
        )
        assert wait_for(
            lambda: (edge.metric("edgerv_events_total", monitor="speed-limit") or 0) > 60,
            timeout=30,
        )
        there = migrate(edge, cloud, "speed-limit", domain)
        assert there.returncode == 0, there.stderr
        assert "speed-limit runs on" in there.stderr
        time.sleep(1.0)
        back = migrate(cloud, edge, "speed-limit", domain)
        assert back.returncode == 0, back.stderr
        assert replay.wait(timeout=120) == 0, replay.stderr
        time.sleep(1.0)
        _, listing = edge.request("GET", "/v1/monitors")
        assert [m["active"] for m in listing["monitors"]] == [True, True]
        _, listing = cloud.request("GET", "/v1/monitors")
        assert [m["active"] for m in listing["monitors"]] == [False, False]
        unevaluated = {  # what the handlers could not evaluate: said in a failure
            f"{h.name} {metric}": h.metric(f"edgerv_{metric}_total", monitor="speed-limit")
            for h in (edge, cloud)
            for metric in ("late_events", "events_dropped")
        }
    finally:
        assert edge.stop() == 0, edge.stderr
        assert cloud.stop() == 0, cloud.stderr
    live, offline = live_verdicts(edge, cloud), offline_verdicts(monitors, trace)
    if live != offline:  # all of it, in the report's captured output (not cut short there)
        for h in (edge, cloud):
            steps = [
                (v["step"], v["verdict"]) for v in h.verdicts() if v["monitor"] == "speed-limit"
            ]
            print(f"== {h.name}: speed-limit verdicts {steps}\n{h.stderr}")
        print(f"== migrate there:\n{there.stderr}\n== migrate back:\n{back.stderr}")
    assert live == offline, unevaluated
    assert any(v["monitor"] == "speed-limit" for v in cloud.verdicts()), "cloud ran it"


def test_a_failed_migration_leaves_the_monitor_where_it_was(tmp_path: Path, domain: int) -> None:
    monitors = write(tmp_path, "monitors.yaml", MONITORS)
    edge = HandlerProcess(tmp_path, monitors, domain, name="edge")
    try:
        env = ros_env(domain) | {"EDGERV_TOKEN": TOKEN}
        gone = subprocess.run(
            [
                sys.executable,
                "-m",
                "edgerv",
                "migrate",
                "--from",
                f"127.0.0.1:{edge.port}",
                "--to",
                "127.0.0.1:9",
                "--monitor",
                "speed-limit",
                "--timeout",
                "5",
            ],
            env=env,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert gone.returncode == 1
        assert "speed-limit stays on" in gone.stderr and "unreachable" in gone.stderr
        _, listing = edge.request("GET", "/v1/monitors")
        assert [(m["name"], m["active"], m["handoff"]) for m in listing["monitors"]] == [
            ("speed-limit", True, None),
            ("no-stop-while-fast", True, None),
        ]
    finally:
        assert edge.stop() == 0
