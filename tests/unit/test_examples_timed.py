"""examples/timed.yaml: each monitor on a run that keeps it and one that breaks it,
with the instant each failure is reported (docs/semantics.md, "Time", "Nesting")."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from edgerv.core.documents import load_monitors
from edgerv.core.monitor import compile_monitor
from kit.checks import events, run, verdicts

EXAMPLES = Path(__file__).parents[2] / "examples" / "timed.yaml"
MS = 1_000_000
S = 1000 * MS

# name: (messages (topic, stamp, value) of a run that keeps it, of one that breaks it,
# the stamp of the first violation of the latter)
RUNS: dict[str, tuple[list[tuple[str, int, Any]], list[tuple[str, int, Any]], int]] = {
    "reach-and-hold": (
        [("/goal", 0, True), ("/at_goal", 0, False), ("/goal", 1, False),
         ("/at_goal", 1500 * MS, True), ("/goal", 4 * S, False)],
        [("/goal", 0, True), ("/at_goal", 0, False), ("/goal", 1, False),
         ("/at_goal", 1500 * MS, True), ("/at_goal", 1800 * MS, False), ("/goal", 4 * S, False)],
        2500 * MS,  # the obligation opened at 0 is certain to fail at 2 s + 500 ms
    ),
    "stop-and-stay": (
        [("/obstacle", 0, True), ("/speed", 0, 1.0), ("/obstacle", 1, False),
         ("/speed", 150 * MS, 0.0), ("/obstacle", 3 * S, False)],
        [("/obstacle", 0, True), ("/speed", 0, 1.0), ("/obstacle", 1, False),
         ("/speed", 150 * MS, 0.0), ("/speed", 900 * MS, 0.5), ("/obstacle", 3 * S, False)],
        1200 * MS,  # no instant of [0, 200ms] starts a stopped second: known at 1.2 s
    ),
    "answer-that-lasts": (
        [("/request", 0, True), ("/ack", 0, False), ("/refused", 0, False),
         ("/request", 1, False), ("/ack", 250 * MS, True), ("/request", 1 * S, False)],
        [("/request", 0, True), ("/ack", 0, False), ("/refused", 0, False),
         ("/request", 1, False), ("/ack", 250 * MS, True), ("/ack", 300 * MS, False),
         ("/request", 1 * S, False)],
        400 * MS,  # its horizon (300 ms + 100 ms) after the request
    ),
    "either-sensor": (
        [("/scan_ok", 0, True), ("/frame_ok", 0, False), ("/scan_ok", 1, False),
         ("/frame_ok", 900 * MS, True), ("/frame_ok", 900 * MS + 1, False),
         ("/scan_ok", 1800 * MS, True), ("/scan_ok", 1800 * MS + 1, False),
         ("/frame_ok", 2500 * MS, False)],
        [("/scan_ok", 0, True), ("/frame_ok", 0, False), ("/scan_ok", 1, False),
         ("/frame_ok", 1500 * MS, True), ("/frame_ok", 2500 * MS, False)],
        1 * S + 1,  # at 1 ns neither comes within a second: certain 1 s later
    ),
    "steady-aim": (
        [("/fire", 0, False), ("/aim", 0, True), ("/fire", 2 * S, True)],
        [("/fire", 0, False), ("/aim", 0, True), ("/aim", 1 * S, False),
         ("/aim", 1300 * MS, True), ("/fire", 2 * S, True)],
        2 * S,
    ),
    "busy-until-done": (
        [("/go", 0, True), ("/busy", 0, True), ("/ok", 0, True), ("/done", 0, False),
         ("/go", 1, False), ("/done", 500 * MS, True), ("/busy", 500 * MS, False),
         ("/ok", 2 * S, True)],  # done, then not busy: one message a step
        [("/go", 0, True), ("/busy", 0, True), ("/ok", 0, True), ("/done", 0, False),
         ("/go", 1, False), ("/ok", 400 * MS, False), ("/done", 500 * MS, True),
         ("/ok", 2 * S, True)],
        400 * MS,  # healthy no more while the obligation waits
    ),
    "warm-up": (
        [("/warming", 0, True), ("/ready", 0, False), ("/ready", 3 * S, True),
         ("/warming", 6 * S, False)],
        [("/warming", 0, True), ("/ready", 0, False), ("/warming", 3 * S, False),
         ("/ready", 4 * S, True)],
        3 * S,
    ),
}  # fmt: skip


def test_every_example_has_its_runs() -> None:
    assert {s.name for s in load_monitors(str(EXAMPLES))} == set(RUNS)


@pytest.mark.parametrize("name", sorted(RUNS))
def test_an_example_keeps_and_breaks_where_it_should(name: str) -> None:
    (spec,) = [s for s in load_monitors(str(EXAMPLES)) if s.name == name]
    keeps, breaks, at = RUNS[name]
    assert [v for v in verdicts(run([compile_monitor(spec)], events(keeps))[0])
            if v[0] == "violated"] == []  # fmt: skip
    violated = [stamp for v, _, stamp in verdicts(run([compile_monitor(spec)], events(breaks))[0])
                if v == "violated"]  # fmt: skip
    assert violated[:1] == [at]
