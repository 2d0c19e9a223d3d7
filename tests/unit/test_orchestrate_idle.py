"""Why a round of `edgerv orchestrate` moves nothing (docs/handler.md, "Why nothing
moves"): the reason from the policy's own inputs, as tests/unit/test_placement.py tests the
policy; said once each time the reason changes, not every round; the command prints it
on stderr against real handler APIs."""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from typing import Any

import pytest
from prometheus_client import CollectorRegistry

from edgerv.control import orchestrate_command
from edgerv.control.client import HandlerClient
from edgerv.control.orchestrate import Idle, Orchestrator, Target, why_nothing_moves
from edgerv.control.placement import (
    DeadlineReading,
    HandlerReport,
    MonitorLoad,
    Move,
    PolicyConfig,
    PolicyMemory,
    plan,
)
from edgerv.core.documents import Placement
from edgerv.handler.api import ControlApi
from edgerv.handler.engine import Engine
from kit.documents import compiled

CONFIG = PolicyConfig(tiers=("edge", "cloud"), tier_latency_ms={"edge": 0.0, "cloud": 40.0})


def busy(rate: float, active: bool = True, wanted: bool = False) -> MonitorLoad:
    return MonitorLoad(active=active, events_per_second=rate, migration_wanted=wanted)


def edge(
    cpu: float = 0.1,
    p95_ms: float | None = None,
    count: int = 40,
    lag: float = 0.0,
    **monitors: MonitorLoad,
) -> HandlerReport:
    """The edge handler; ``p95_ms`` (or ``count``) set: it measures a 125 ms deadline."""
    deadline = None
    if p95_ms is not None or count != 40:
        deadline = DeadlineReading(0.125, None if p95_ms is None else p95_ms / 1000, count)
    return HandlerReport("edge-1", "edge", cpu, lag, monitors=monitors, deadline=deadline)


def cloud(cpu: float = 0.1, **monitors: MonitorLoad) -> HandlerReport:
    return HandlerReport("cloud-1", "cloud", cpu, monitors=monitors)


def why(
    reports: list[HandlerReport],
    placements: dict[str, Placement] | None = None,
    memory: PolicyMemory | None = None,
    now: float = 0.0,
    **context: Any,
) -> Idle:
    """The reason, after the policy ran on the same inputs and found nothing to do."""
    memory = memory or PolicyMemory()
    placements = placements or {}
    assert plan(reports, placements, CONFIG, memory, now) == []
    return why_nothing_moves(reports, placements, CONFIG, memory, now, **context)


def test_no_deadline_signal_yet() -> None:
    idle = why([edge(count=0, a=busy(100)), cloud(a=busy(0, active=False))])
    assert (idle.kind, idle.text) == (
        "no deadline signal",
        "no deadline signal yet: edge-1 has 0 makespan(s) in its window, 4 needed (2 if all "
        "miss) (is the --deadline topic published, its header stamped with the robot's clock?)",
    )
    assert why([edge(p95_ms=500, count=3, a=busy(100)), cloud()]).kind == "no deadline signal"


def test_the_deadline_met_with_margin_gives_the_numbers() -> None:
    idle = why([edge(p95_ms=80, a=busy(100)), cloud()])
    assert (idle.kind, idle.text) == (
        "deadline met",
        "the deadline is met with margin: edge-1's p95 makespan 80.0 ms, 64% of its 125 ms "
        "budget (monitors move up at 100%, --deadline-high)",
    )
    narrow = why([edge(p95_ms=122, a=busy(100)), cloud()])  # between the marks
    assert narrow.text == (
        "the deadline is met narrowly: edge-1's p95 makespan 122.0 ms, 98% of its 125 ms "
        "budget (monitors move up at 100%, --deadline-high; the handler is calm at 95% or "
        "less, --deadline-low)"
    )
    assert narrow.key == idle.key


def test_under_deadline_pressure_monitors_without_traffic_free_nothing() -> None:
    reports = [edge(p95_ms=140, a=busy(0), b=busy(0)), cloud()]
    idle = why(reports)
    assert (idle.kind, idle.text) == (
        "no traffic",
        "the monitors carry no traffic: edge-1's deadline is at risk (p95 makespan 140.0 ms, "
        "112% of its 125 ms budget, high mark 100%), but a, b read no event since the last "
        "poll: the deadline moves the busiest monitors, and idle ones would free nothing",
    )
    first = why(reports, unknown_rates={"edge-1"})  # the first poll: no rate known yet
    assert first.kind == "no traffic" and "rates are not known yet (its first poll)" in first.text
    assert first.key != idle.key  # said again once the rates are known


def test_hysteresis_says_how_long_until_a_monitor_may_come_down() -> None:
    memory = PolicyMemory()
    hot = [edge(cpu=0.95, a=busy(600)), cloud()]
    assert [m.monitor for m in plan(hot, {}, CONFIG, memory, now=0)] == ["a"]
    calm = [edge(cpu=0.2), cloud(a=busy(600))]
    idle = why(calm, memory=memory, now=10)  # calm since 10 s, moved at 0 s
    assert (idle.kind, idle.text) == (
        "hysteresis",
        "hysteresis holds: a may come down from cloud-1 to edge-1 in 50 s (edge-1 calm for "
        "0 s of --calm 30 s; it moved 10 s ago: --cooldown 60 s)",
    )
    later = why(calm, memory=memory, now=45)
    assert later.text == (
        "hysteresis holds: a may come down from cloud-1 to edge-1 in 15 s (it moved 45 s ago: "
        "--cooldown 60 s)"
    )
    assert later.key == idle.key  # the same reason: not said again
    between = why([edge(cpu=0.6), cloud(a=busy(600))], memory=PolicyMemory())
    assert between.text == (
        "hysteresis holds: a comes down from cloud-1 once edge-1 is calm (CPU 60%, calm at "
        "50% or less)"
    )


def test_after_a_deadline_shed_the_wait_is_hysteresis_too() -> None:
    memory = PolicyMemory()
    mon = {"a": busy(400), "b": busy(300)}
    assert len(plan([edge(p95_ms=150, **mon), cloud()], {}, CONFIG, memory, 0)) == 1
    idle = why([edge(p95_ms=150, b=busy(300)), cloud(a=busy(400))], memory=memory, now=0.5)
    assert idle.kind == "hysteresis"
    assert idle.text.startswith(
        "hysteresis holds: edge-1's deadline is at risk (p95 makespan 150.0 ms, 120% of its "
        "125 ms budget, high mark 100%), but monitors were moved for its deadline: it counts "
        "again in 1.5 s, once its window holds makespans measured since the handoff"
    ), idle.text


def test_everything_movable_where_it_would_go() -> None:
    idle = why([edge(cpu=0.3, a=busy(10)), cloud(a=busy(0, active=False))])
    assert (idle.kind, idle.text) == (
        "placed",
        "everything movable is already where it would go: no handler is under pressure "
        "(edge-1 CPU 30%, ingest lag 0.00 s; cloud-1 CPU 10%, ingest lag 0.00 s; monitors "
        "move up at CPU 85% or lag 0.5 s), and no monitor runs above its home tier; no "
        "handler measures a deadline (edgerv handler --deadline TOPIC=DURATION)",
    )
    home = why([edge(cpu=0.1), cloud(a=busy(10))], {"a": Placement(tier="cloud")})
    assert home.kind == "placed"  # above the lowest tier, but at its home


def test_pinned_monitors() -> None:
    pinned = {"a": Placement(migrate="pinned"), "b": Placement(max_latency_ms=10)}
    idle = why([edge(cpu=0.95, a=busy(600), b=busy(300)), cloud()], pinned)
    assert (idle.kind, idle.text) == (
        "pinned",
        "pinned monitors: edge-1 is under pressure (CPU 95%, high mark 85%), but none of its "
        "monitors may move up to cloud: a pinned (placement.migrate: pinned); b held by "
        "placement.maxLatencyMs (tier cloud is 40 ms from the robot)",
    )
    up = why([edge(cpu=0.1), cloud(a=busy(10))], {"a": Placement(migrate="pinned")})
    assert up.kind == "pinned" and up.text.startswith("pinned monitors: a on cloud-1 runs above")


def test_no_room_above() -> None:
    full = why([edge(cpu=0.95, a=busy(600)), cloud(cpu=0.9)])
    assert (full.kind, full.text) == (
        "no room",
        "edge-1 is under pressure (CPU 95%, high mark 85%), but no handler of the tier above, "
        "cloud, can take monitors: cloud-1 is under pressure too",
    )
    top = why([edge(cpu=0.1), cloud(cpu=0.95, a=busy(600))])
    assert top.text == (
        "cloud-1 is under pressure (CPU 95%, high mark 85%) on the highest tier, cloud: there "
        "is no tier above to move its monitors to"
    )
    alone = why([edge(cpu=0.1, lag=0.7, a=busy(600))])
    assert alone.text.endswith("cloud, can take monitors: none answered this round")


def test_after_a_shed_for_its_lag_the_wait_is_hysteresis_too() -> None:
    """Ingest lag alone, the CPU below its target (a CPU budget it cannot keep up under):
    the policy sheds for the lag, then waits for the backlog to drain, and says so."""
    memory = PolicyMemory()
    mon = {"a": busy(600), "b": busy(300)}
    assert len(plan([edge(cpu=0.4, lag=0.7, **mon), cloud()], {}, CONFIG, memory, 0)) == 1
    idle = why([edge(cpu=0.4, lag=0.7, b=busy(300)), cloud(a=busy(600))], memory=memory, now=0.5)
    assert (idle.kind, idle.text) == (
        "hysteresis",
        "hysteresis holds: edge-1's ingest lags (ingest lag 0.70 s, high mark 0.5 s), but "
        "monitors were moved for that lag: it counts again in 1.5 s, once its backlog had "
        "time to drain (--deadline-wait 2 s)",
    )


def test_pressure_with_nothing_to_shed() -> None:
    empty = why([edge(cpu=0.95), cloud(a=busy(10))], {"a": Placement(tier="cloud")})
    assert empty.text == "edge-1 is under pressure (CPU 95%, high mark 85%) but runs no monitor"
    # what waits to come down to it is the reason, rather than its own pressure
    waiting = why([edge(cpu=0.95, a=busy(0, active=False)), cloud(a=busy(10))])
    assert waiting.kind == "hysteresis" and "once edge-1 is calm (CPU 95%" in waiting.text


def test_moves_held_back_by_the_round() -> None:
    reports = [edge(a=busy(0, active=False)), cloud()]
    memory = PolicyMemory()
    planned = plan(reports, {}, CONFIG, memory, 0)
    assert planned == [Move("a", "", "edge-1", "start")]
    idle = why_nothing_moves(reports, {}, CONFIG, memory, 0, planned=planned, silent=["c:1"])
    assert (idle.kind, idle.text) == (
        "not started",
        "a runs nowhere, and none is started while c:1 does not answer: it may run it",
    )
    held = [Move("a", "edge-1", "cloud-1", "pressure")]
    idle = why_nothing_moves(reports, {}, CONFIG, memory, 0, planned=held, unsettled={"a"})
    assert idle.text == (
        "a waits until the move that left it unsettled is settled (tried at the start of each "
        "round)"
    )
    assert why_nothing_moves([], {}, CONFIG, memory, 0).text == "no handler answered this round"
    assert why_nothing_moves([edge()], {}, CONFIG, memory, 0).text == "no handler defines a monitor"


def load(name: str, t: float, p95_ms: float | None, active: bool = True) -> dict[str, object]:
    """A handler's ``GET /v1/load`` (one monitor ``a``, its events not moving)."""
    return {
        "handler": name,
        "monotonic": t,
        "cpuSeconds": t * 0.1,
        "ingestLag": 0.0,
        "deadline": {"budgetMs": 125.0, "count": 40, "p95Ms": p95_ms},
        "monitors": {
            "a": {
                "active": active,
                "handoff": None,
                "events": 0,
                "migrationWanted": False,
                "placement": {},
            }
        },
    }


class Reports(HandlerClient):
    """A handler's API as the orchestrator reads it (its load report, set by the test)."""

    def __init__(self, answer: dict[str, object]) -> None:
        super().__init__("http://x", None)
        self.answer = answer

    def get(self, path: str, timeout: float = 10.0) -> object:
        return self.answer


def test_a_reason_is_said_once_each_time_it_changes() -> None:
    said: list[Idle] = []
    targets = [Target("edge", "e:1"), Target("cloud", "c:1")]
    o = Orchestrator(targets, CONFIG, token=None, on_idle=said.append)
    edge_api, cloud_api = Reports(load("edge-1", 1, 80)), Reports(load("cloud-1", 1, None))
    cloud_api.answer["deadline"] = None
    cloud_api.answer["monitors"]["a"]["active"] = False  # type: ignore[index]
    o.clients = dict(zip(targets, [edge_api, cloud_api], strict=True))  # type: ignore[arg-type]
    for t, p95 in ((1, 80), (2, 81), (3, 79.5)):  # the numbers change, the reason does not
        edge_api.answer = load("edge-1", t, p95)
        assert o.round() == []
    assert [i.kind for i in said] == ["deadline met"]
    assert "80.0 ms" in said[0].text
    edge_api.answer = load("edge-1", 4, None)  # the task stopped publishing
    assert o.round() == [] and o.round() == []
    assert [i.kind for i in said] == ["deadline met", "no deadline signal"]
    edge_api.answer = load("edge-1", 5, 82)
    o.round()
    assert [i.kind for i in said] == ["deadline met", "no deadline signal", "deadline met"]


@pytest.fixture
def handlers() -> Iterator[list[ControlApi]]:
    """An edge and a cloud handler's APIs on loopback (plain HTTP), the edge running m."""
    edge_engine, cloud_engine = Engine("edge-1", flush_after=1e9), Engine("cloud-1")
    monitor = compiled("always (a -> x < 5)", {"a": "bool", "x": "float"})
    edge_engine.put(monitor, active=True)
    cloud_engine.put(monitor, active=False)
    apis = []
    for e in (edge_engine, cloud_engine):
        api = ControlApi(e, CollectorRegistry(), "t", on_change=lambda: None)
        api.start("127.0.0.1", 0)
        apis.append(api)
    yield apis
    for api in apis:
        api.stop()


def test_the_command_says_why_on_stderr(
    handlers: list[ControlApi],
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("EDGERV_TOKEN", "t")
    parser = argparse.ArgumentParser()
    orchestrate_command.add_arguments(parser)
    edge, cloud = (f"127.0.0.1:{api.port}" for api in handlers)
    args = parser.parse_args(
        ["--handlers", f"edge={edge},cloud={cloud}", "--once", "--interval", "0.05"]
    )
    assert orchestrate_command.run(args) == 0
    out, err = capsys.readouterr()
    assert out == ""  # no action: stdout has one JSON line per action only
    assert err.startswith(
        "edgerv orchestrate: nothing to move: everything movable is already where it would "
        "go: no handler is under pressure (edge-1 CPU "
    ), err
    assert err.count("\n") == 1


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["--handlers", "edge=a:x"], "--handlers: error: item 1 'edge=a:x': 'a:x': the port"),
        (["--handlers", "edge=a:1,cloud=a:1"], "item 2 'cloud=a:1': a:1 is listed already"),
        (["--handlers", "edge=a:1", "--interval", "0"],
         "argument --interval: '0' is not a number of seconds above 0"),
        (["--handlers", "edge=a:1", "--calm", "-1"],
         "argument --calm: '-1' is not a number of seconds from 0"),
        (["--handlers", "edge=a:1", "--tier-latency", "edge=inf"],
         "--tier-latency: error: 'edge=inf' is not NAME=NUMBER (a number from 0)"),
        (["--handlers", "edge=a:1", "--tier-latency", "clod=4"],
         "--tier-latency: error: tier clod is not one of the tiers edge"),
        (["--handlers", "edge=a:1", "--deadline-high", "nan"],
         "argument --deadline-high: 'nan' is not a number above 0"),
        (["--handlers", "edge=a:1", "--deadline-high", "0.5"],
         "--deadline-high: error: need 0 < deadline_low < deadline_high (--deadline-low 0.95, "
         "--deadline-high 0.5)"),
        (["--handlers", "edge=a:1", "--timeout", "-3"],
         "argument --timeout: '-3' is not a number of seconds above 0"),
    ],
)  # fmt: skip
def test_bad_flags_exit_2_at_their_flag(
    argv: list[str], said: str, capsys: pytest.CaptureFixture[str]
) -> None:
    from edgerv.cli import main as cli_main

    try:
        code = cli_main(["orchestrate", *argv, "--once"])
    except SystemExit as exited:  # argparse's own errors
        code = int(exited.code or 0)
    err = capsys.readouterr().err
    assert code == 2 and said in err and "internal error" not in err, err
