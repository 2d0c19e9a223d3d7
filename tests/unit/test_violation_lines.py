"""A line per violation on the handler's console (and /rosout, through the node's logger:
tests/integration/test_sim_clock.py sees one there), at most one a second per monitor,
the violations held back counted in its next line (edgerv.handler.sinks)."""

from __future__ import annotations

import logging

import pytest

from edgerv.core.pipeline import Verdict
from edgerv.handler.sinks import PerKeyLimit, ViolationLines, violation_line

S = 1_000_000_000


def test_one_line_per_key_a_period_and_the_count_of_those_held_back() -> None:
    limit = PerKeyLimit(1.0)
    assert limit.admit("a", 0.0) == 0
    assert limit.admit("a", 0.3) is None
    assert limit.admit("b", 0.3) == 0  # each monitor its own
    assert limit.admit("a", 0.9) is None
    assert limit.pending() == {"a": 2}
    assert limit.admit("a", 1.0) == 2  # a second after its last line: with the count
    assert limit.admit("a", 1.5) is None
    assert limit.admit("a", 2.6) == 1
    assert limit.admit("a", 10.0) == 0
    assert limit.pending() == {}


def test_keys_quiet_for_a_period_are_forgotten_and_write_at_once_again() -> None:
    limit = PerKeyLimit(1.0)
    limit.admit("a", 0.0)
    limit.admit("b", 0.0)
    limit.admit("b", 0.5)  # held back: kept until its next line
    limit.forget(2.0)
    assert limit.pending() == {"b": 1}
    assert limit.admit("a", 2.0) == 0 and limit.admit("b", 2.0) == 1


def test_the_line_names_monitor_verdict_step_stamp_and_topics() -> None:
    v = Verdict("speed-limit", "violated", 1_700_000_001 * S + 250_000_000, 12)
    assert violation_line(v, ["/odom", "/stop"]) == (
        "monitor speed-limit violated at step 12 (stamp 1700000001.250000000) on /odom, /stop"
    )
    assert violation_line(v, [], 3).endswith(
        "(stamp 1700000001.250000000) (3 more violations since its last line)"
    )
    assert violation_line(v, ["/odom"], 1).endswith("(1 more violation since its last line)")


class Ticks:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_the_sink_writes_violations_only_rate_limited_and_says_the_rest_at_close(
    caplog: pytest.LogCaptureFixture,
) -> None:
    ticks = Ticks()
    lines = ViolationLines(lambda m: {"a": ["/x"], "b": ["/y", "/z"]}.get(m, ()), clock=ticks)
    caplog.set_level(logging.WARNING, logger="edgerv.handler.violations")
    lines.write("h", [Verdict("a", "violated", 5, 1), Verdict("a", "satisfied", 6, 2)])
    lines.write("h", [Verdict("a", "violated", 7, 3), Verdict("a", "violated", 8, 4)])
    lines.write("h", [Verdict("b", "violated", 9, 1)])
    ticks.now = 1.2
    lines.write("h", [Verdict("a", "violated", 10, 5), Verdict("gone", "violated", 11, 1)])
    lines.write("h", [Verdict("a", "violated", 12, 6)])
    lines.close()
    got = [r.getMessage() for r in caplog.records]
    assert got == [
        "monitor a violated at step 1 (stamp 0.000000005) on /x",
        "monitor b violated at step 1 (stamp 0.000000009) on /y, /z",
        "monitor a violated at step 5 (stamp 0.000000010) on /x (2 more violations since "
        "its last line)",
        "monitor gone violated at step 1 (stamp 0.000000011)",  # (removed since)
        "monitor a: 1 more violation since its last line",
    ]
    assert {r.levelno for r in caplog.records} == {logging.WARNING}
