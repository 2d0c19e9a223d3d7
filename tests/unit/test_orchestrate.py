"""The orchestrator's pure parts: its flags, and load reports turned into the policy's inputs."""

from __future__ import annotations

import pytest

from edgerv.core.diagnostics import InputError
from edgerv.core.placement import Placement
from edgerv.handler.orchestrate import Counters, Target, build_reports, parse_handlers, parse_pairs


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


def load(t: float, cpu: float, events: int, **extra: object) -> dict[str, object]:
    monitor = {
        "active": True,
        "handoff": None,
        "events": events,
        "migrationWanted": False,
        "placement": {"tier": "cloud", "migrate": "pinned", "maxLatencyMs": 20},
    }
    monitor.update(extra)
    return {
        "handler": "h1",
        "monotonic": t,
        "cpuSeconds": cpu,
        "ingestLag": 0.2,
        "monitors": {"m": monitor},
    }


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
