"""The orchestrator's pure parts: its flags, and load reports turned into the policy's inputs."""

from __future__ import annotations

import argparse

import pytest

from edgerv.control.client import HandlerClient
from edgerv.control.migrate import MigrationFailed
from edgerv.control.orchestrate import (
    Counters,
    Orchestrator,
    Target,
    build_reports,
    deadline_reading,
)
from edgerv.control.orchestrate_command import (
    add_arguments,
    config_from,
    parse_handlers,
    parse_pairs,
)
from edgerv.control.placement import DeadlineReading, PolicyConfig
from edgerv.control.wire import LoadReport, parse_load
from edgerv.core.diagnostics import InputError
from edgerv.core.documents import Placement


def test_handlers_flag() -> None:
    assert parse_handlers("edge=10.0.0.2:8080, cloud=10.0.0.9:8080,edge=h:1") == [
        Target("edge", "10.0.0.2:8080"),
        Target("cloud", "10.0.0.9:8080"),
        Target("edge", "h:1"),
    ]
    with pytest.raises(InputError, match="item 2 'cloud' is not TIER=HOST:PORT"):
        parse_handlers("edge=a:1,cloud")
    assert parse_pairs("edge=0, cloud=40", "--tier-latency") == {"edge": 0.0, "cloud": 40.0}
    with pytest.raises(InputError, match="--tier-latency: error: 'cloud=far' is not NAME=NUMBER"):
        parse_pairs("cloud=far", "--tier-latency")


def load(t: float, cpu: float, events: int, **extra: object) -> LoadReport:
    """A handler's load report (``GET /v1/load``), as the client reads it."""
    monitor = {
        "active": True,
        "handoff": None,
        "events": events,
        "migrationWanted": False,
        "placement": {"tier": "cloud", "migrate": "pinned", "maxLatencyMs": 20},
    }
    monitor.update(extra)
    return parse_load(
        {
            "handler": "h1",
            "monotonic": t,
            "cpuSeconds": cpu,
            "ingestLag": 0.2,
            "monitors": {"m": monitor},
        }
    )


def test_rates_come_from_two_polls() -> None:
    edge = Target("edge", "h1:1")
    previous: dict[Target, Counters] = {}
    reports, placements, where = build_reports({edge: load(10.0, 5.0, 100)}, previous)
    (r,) = reports
    assert (r.name, r.tier, r.cpu, r.ingest_lag) == ("h1", "edge", 0.0, 0.2)
    assert r.monitors["m"].events_per_second == 0.0  # nothing known yet
    assert placements == {"m": Placement("cloud", "pinned", 20.0)} and where == {"h1": edge}
    reports, _, _ = build_reports(
        {edge: load(12.0, 6.5, 1100, handoff="sending", migrationWanted=True)},
        previous,
    )
    (r,) = reports
    assert r.cpu == pytest.approx(0.75)
    m = r.monitors["m"]
    assert (m.events_per_second, m.in_handoff, m.migration_wanted) == (500.0, True, True)
    assert r.reach_ms is None  # (no message reached it yet)
    measured = {**load(13.0, 7.0, 1200), "reachMs": 21.5}
    (r,) = build_reports({edge: measured}, previous)[0]
    assert r.reach_ms == 21.5  # its tier's latency as measured (placement.measured)


class Reports(HandlerClient):
    """A handler's API as the orchestrator reads it: a load report, or silence."""

    def __init__(self, answer: LoadReport | None) -> None:
        super().__init__("http://x", None)
        self.answer = answer
        self.calls: list[str] = []

    def get(self, path: str, timeout: float = 10.0) -> object:
        if self.answer is None:
            raise MigrationFailed("unreachable")
        return self.answer

    def call(self, path: str, *_: object, **__: object) -> tuple[int, bytes]:
        self.calls.append(path)
        return 200, b"{}"


def test_no_monitor_starts_while_a_handler_is_silent() -> None:
    edge, cloud = Target("edge", "e:1"), Target("cloud", "c:1")
    o = Orchestrator([edge, cloud], PolicyConfig(tiers=("edge", "cloud")), token=None)
    idle = load(1.0, 0.0, 0, active=False)
    idle["handler"] = "cloud-1"
    silent, answering = Reports(None), Reports(idle)
    o.clients = {edge: silent, cloud: answering}  # type: ignore[dict-item]
    assert o.round() == []  # m may run on the silent edge: not started in the cloud
    silent.answer = load(1.0, 0.0, 0, active=False)
    records = o.round()
    assert [(r["monitors"], r["reason"], r["ok"]) for r in records] == [(["m"], "start", True)]
    assert answering.calls == ["/v1/monitors/m/activate"]  # its placement.tier: cloud


def test_without_starts_nothing_is_started_and_targets_follow_the_pods() -> None:
    """The operator's rounds: starting is its resources' job, and the handlers come and go."""
    edge, cloud = Target("edge", "e:1"), Target("cloud", "c:1")
    o = Orchestrator([edge], PolicyConfig(tiers=("edge", "cloud")), token=None, starts=False)
    idle = load(1.0, 0.0, 0, active=False)
    idle["handler"] = "cloud-1"
    edge_load = load(1.0, 0.0, 0, active=False)
    o.set_targets([edge, cloud])
    assert set(o.clients) == {edge, cloud}
    kept = o.clients[edge]
    o.clients = {edge: Reports(edge_load), cloud: Reports(idle)}  # type: ignore[dict-item]
    assert o.round() == []  # m runs nowhere: the orchestrator would start it, this one not
    o.set_targets([edge])
    assert list(o.clients) == [edge] and list(o.previous) == [edge] and kept is not None


def test_the_deadline_of_a_load_report_becomes_the_policys_reading() -> None:
    edge = Target("edge", "h1:1")
    report = load(10.0, 5.0, 100)
    (r,), _, _ = build_reports({edge: report}, {})
    assert r.deadline is None  # a handler without --deadline
    report["deadline"] = {
        "topic": "/cmd_vel",
        "budgetMs": 125.0,
        "windowSeconds": 2.0,
        "count": 40,
        "misses": 3,
        "p50Ms": 100.0,
        "p95Ms": 130.0,
        "maxMs": 140.0,
        "lastMs": 99.0,
        "missesTotal": 7,
        "messagesTotal": 400,
    }
    (r,), _, _ = build_reports({edge: parse_load(report)}, {})
    assert r.deadline == DeadlineReading(budget=0.125, p95=0.13, count=40, misses=3, last=0.099)
    empty = {"budgetMs": 125.0, "count": 0, "p95Ms": None}
    assert deadline_reading(empty) == DeadlineReading(0.125, None, 0)
    for odd in (None, "fast", [], {"count": 4}, {"budgetMs": "125", "count": 4}):
        assert deadline_reading(odd) is None


def orchestrate_args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_arguments(p)
    return p.parse_args(["--handlers", "edge=e:1,cloud=c:1", *argv])


def test_the_deadline_flags_set_the_policy_and_default_to_it() -> None:
    targets = parse_handlers("edge=e:1,cloud=c:1")
    config = config_from(orchestrate_args(), targets)
    default = PolicyConfig(tiers=("edge", "cloud"))
    assert (config.deadline_high, config.deadline_low) == (default.deadline_high, 0.95)
    assert (config.deadline_shed, config.deadline_wait) == (0.5, 2.0)
    config = config_from(
        orchestrate_args(
            "--deadline-high", "0.9", "--deadline-low", "0.8", "--deadline-shed", "0.25",
            "--deadline-wait", "3",
        ),
        targets,
    )  # fmt: skip
    assert (config.deadline_high, config.deadline_low) == (0.9, 0.8)
    assert (config.deadline_shed, config.deadline_wait) == (0.25, 3.0)
    with pytest.raises(InputError, match="--deadline-low: error: need 0 < deadline_low <"):
        config_from(orchestrate_args("--deadline-low", "1.2"), targets)
    with pytest.raises(InputError, match="--deadline-shed: error: need 0 < deadline_shed"):
        config_from(orchestrate_args("--deadline-shed", "2"), targets)


def test_max_moves_down_sets_the_policy_and_is_checked() -> None:
    targets = parse_handlers("edge=e:1,cloud=c:1")
    assert config_from(orchestrate_args(), targets).max_moves_down == 1
    assert config_from(orchestrate_args("--max-moves-down", "40"), targets).max_moves_down == 40
    with pytest.raises(InputError, match="--max-moves-down: error: need 1 <= max_moves_down"):
        config_from(orchestrate_args("--max-moves-down", "0"), targets)


def test_the_plan_flags_set_the_policy_and_default_to_planning() -> None:
    targets = parse_handlers("edge=e:1,cloud=c:1")
    config = config_from(orchestrate_args(), targets)
    assert (config.planner, config.planner_margin) == (True, 0.1)
    config = config_from(orchestrate_args("--no-plan", "--plan-margin", "0.3"), targets)
    assert (config.planner, config.planner_margin) == (False, 0.3)
    with pytest.raises(InputError, match="--plan-margin: error: need 0 <= planner_margin < 1"):
        config_from(orchestrate_args("--plan-margin", "1"), targets)


def test_an_unsettled_move_is_not_done_and_is_settled_before_the_monitor_moves_again(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """`edgerv migrate` ended unsettled (a handler did not answer: the edge may hold m
    released): the record says so, not ok; each later round settles m on the edge first,
    and the policy's moves of m wait until that succeeded."""
    import edgerv.control.orchestrate as orchestrate
    from edgerv.control.migrate import Moved, Unsettled
    from edgerv.control.placement import Move

    edge, cloud = Target("edge", "e:1"), Target("cloud", "c:1")
    o = Orchestrator([edge, cloud], PolicyConfig(tiers=("edge", "cloud")), token=None)
    cloud_load = load(1.0, 0.0, 0, active=False)
    cloud_load["handler"] = "cloud-1"
    edge_load = load(1.0, 0.0, 0)
    edge_load["handler"] = "edge-1"
    o.clients = {edge: Reports(edge_load), cloud: Reports(cloud_load)}  # type: ignore[dict-item]
    monkeypatch.setattr(
        orchestrate, "plan", lambda *_: [Move("m", "edge-1", "cloud-1", "pressure")]
    )
    moves: list[list[str]] = []
    settles: list[object] = [Unsettled("http://c did not answer", ["m"], ["http://c"]), {}]

    def migrate(src: object, dst: object, names: list[str], *_: object) -> Moved:
        moves.append(names)
        if len(moves) == 1:
            raise Unsettled("http://c did not say whether it adopted m", ["m"], ["http://c"])
        return Moved(0.1, 10, 5, 8, {"hold": 0.0123, "commit": 0.1})

    asked: list[tuple[object, list[str]]] = []

    def settle(client: object, names: list[str], deadline: float) -> object:
        asked.append((client, names))
        outcome = settles.pop(0)
        if isinstance(outcome, Exception):
            raise outcome
        return outcome

    monkeypatch.setattr(orchestrate, "migrate", migrate)
    monkeypatch.setattr(orchestrate, "settle", settle)
    (first,) = o.round()
    assert (first["ok"], first["unsettled"]) == (False, ["m"]) and o.unsettled == {
        "m": (edge, cloud)
    }
    (tried,) = o.round()  # the settle fails again: no move of m meanwhile
    assert (tried["settle"], tried["ok"]) == (True, False) and asked == [(o.clients[edge], ["m"])]
    assert moves == [["m"]] and "m" in o.unsettled
    settled, moved = o.round()  # settled (the edge held nothing more): then it may move
    assert (settled["settle"], settled["ok"], settled["monitors"]) == (True, True, ["m"])
    assert (moved["ok"], moves, o.unsettled) == (True, [["m"], ["m"]], {})
    assert moved["steps"] == {"hold": 12.3, "commit": 100.0}  # each step's end, in ms
