"""The chart's ``handler.useSimTime``: every handler DaemonSet runs ``edgerv handler
--use-sim-time`` (ROS time from /clock) when it is true, none when it is false (the
default), and the values' schema refuses what is not a boolean. Offline: `helm template`
only (helm as tests/cluster/build.sh builds it, or $HELM)."""

from __future__ import annotations

import subprocess
from typing import Any

import yaml

from kit.chart import CHART, helm


def template(*values: str) -> subprocess.CompletedProcess[str]:
    args = [helm(), "template", "r", str(CHART)]
    for value in values:
        args += ["--set", value]
    return subprocess.run(args, capture_output=True, text=True, timeout=120)


def handler_args(*values: str) -> list[list[str]]:
    done = template(*values)
    assert done.returncode == 0, done.stderr
    docs: list[dict[str, Any]] = [d for d in yaml.safe_load_all(done.stdout) if d]
    return [
        d["spec"]["template"]["spec"]["containers"][0]["args"]
        for d in docs
        if d["kind"] == "DaemonSet"
    ]


def test_use_sim_time_puts_the_flag_on_every_tier() -> None:
    tiers = handler_args("handler.useSimTime=true", "operator.tiers={edge,cloud}")
    assert len(tiers) == 2
    assert all(args.count("--use-sim-time") == 1 for args in tiers)


def test_the_system_clock_by_default() -> None:
    assert all("--use-sim-time" not in args for args in handler_args())


def test_a_value_that_is_not_a_boolean_is_refused() -> None:
    done = template("handler.useSimTime=sometimes")
    assert done.returncode != 0
    assert "useSimTime" in done.stderr and "want boolean" in done.stderr
