"""The wait between the orchestrator's rounds ends at a missed deadline
(docs/protocol.md, "Deadline pressure"): ``GET /v1/deadline?after=N&wait=S`` answers once
the handler has measured more than N misses, or after S seconds; ``Orchestrator.wait``
asks it of each handler measuring a deadline after a round that found every deadline met,
so the round that moves monitors starts at the miss, not up to an interval later. A real
handler's API on loopback, a real client; the misses are added to its window as the ROS
layer adds them."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import pytest
from hypothesis import given
from hypothesis import strategies as st
from prometheus_client import CollectorRegistry

from edgerv.control.client import HandlerClient, Invalid, NotFound
from edgerv.control.orchestrate import Orchestrator, Target
from edgerv.control.placement import PolicyConfig
from edgerv.core.deadline import MakespanWindow
from edgerv.handler.api import MAX_DEADLINE_WAIT, ControlApi, _query_count, _query_seconds
from edgerv.handler.engine import Engine
from kit.documents import compiled

MS = 1_000_000
BUDGET = 125 * MS
WAIT = 20.0  # what a waiting call is given: answered long before it, or the wait failed


def _serve(window: MakespanWindow | None) -> ControlApi:
    engine = Engine("edge-1", flush_after=1e9, deadline=window)
    engine.put(compiled("always (a -> x < 5)", {"a": "bool", "x": "float"}), active=True)
    served = ControlApi(engine, CollectorRegistry(), "t", on_change=lambda: None)
    served.start("127.0.0.1", 0)
    return served


def _makespan(window: MakespanWindow, i: int, span_ms: float) -> None:
    published = 50_000 * MS + i * 125 * MS
    window.add(published, published - int(span_ms * MS), time.monotonic_ns())


@pytest.fixture
def window() -> MakespanWindow:
    w = MakespanWindow("/cmd_vel", BUDGET)
    for i in range(6):
        _makespan(w, i, 100)  # met: 100 ms of 125
    return w


@pytest.fixture
def api(window: MakespanWindow) -> Iterator[ControlApi]:
    served = _serve(window)
    yield served
    served.stop()


def _late(window: MakespanWindow, after: float = 0.3) -> threading.Timer:
    """A makespan of 200 ms added ``after`` seconds from now (on another thread)."""
    timer = threading.Timer(after, _makespan, (window, 6, 200))
    timer.start()
    return timer


def test_the_call_waits_for_the_next_miss(api: ControlApi, window: MakespanWindow) -> None:
    client = HandlerClient(f"127.0.0.1:{api.port}", "t")
    assert client.deadline()["missesTotal"] == 0  # no after: answered at once
    timer = _late(window)
    started = time.monotonic()
    reading = client.deadline(after=0, wait=WAIT)
    timer.join()
    # answered with the miss in it (had it not waited, it would read 0), before its wait
    assert reading["missesTotal"] == 1 and reading["lastMs"] == 200.0
    assert time.monotonic() - started < WAIT
    # more misses than `after` already: answered at once, as is
    assert client.deadline(after=0, wait=WAIT)["missesTotal"] == 1
    # none comes: answered when the wait ends, with the reading then
    assert client.deadline(after=1, wait=0.2)["missesTotal"] == 1


def test_what_the_call_refuses(api: ControlApi) -> None:
    client = HandlerClient(f"127.0.0.1:{api.port}", "t")
    for query, said in [
        ("after=-1&wait=1", 'after must be a whole number, 0 or more, not "-1"'),
        ("after=x&wait=1", "after must be a whole number"),
        ("after=1&wait=31", 'wait must be seconds from 0 to 30, not "31"'),
        ("after=1&wait=nan", "wait must be seconds from 0 to 30"),
        ("after=1&wait=-1", "wait must be seconds from 0 to 30"),
    ]:
        with pytest.raises(Invalid, match=said):
            client.get(f"/v1/deadline?{query}")
    without = _serve(None)
    try:
        with pytest.raises(NotFound, match="started without --deadline TOPIC=DURATION"):
            HandlerClient(f"127.0.0.1:{without.port}", "t").deadline(after=0, wait=1)
    finally:
        without.stop()


@given(
    st.one_of(
        st.text(),
        st.sampled_from(["²", "٣", "1" * 20, "9" * 19, str(2**63 - 1)]),
        st.from_regex(r"-?[0-9]{0,25}(\.[0-9]*)?(e-?[0-9]+)?"),
    )
)
def test_any_query_reads_as_a_value_in_range_or_says_what_is_wrong(text: str) -> None:
    for read, what in ((_query_count, "after"), (lambda t, w: _query_seconds(t, w, 30.0), "wait")):
        try:
            value = read(text, what)
        except ValueError as exc:
            assert str(exc).startswith(f"{what} must be ")
        else:
            assert value is not None and 0 <= value <= (2**63 - 1 if what == "after" else 30)
    assert MAX_DEADLINE_WAIT == 30.0


def test_the_orchestrators_wait_ends_at_a_miss_only_when_every_deadline_was_met(
    api: ControlApi, window: MakespanWindow
) -> None:
    edge = Target("edge", f"127.0.0.1:{api.port}")
    o = Orchestrator([edge], PolicyConfig(tiers=("edge", "cloud")), token="t")
    stop = threading.Event()
    assert o.round() == [] and o.idle is not None and o.idle.kind == "deadline met"
    timer = _late(window)
    assert o.wait(WAIT, stop) == "missed"
    timer.join()
    # the next round reads the miss: the p95 is over the deadline, and the edge has
    # nowhere to move its monitor; a round under pressure waits its whole interval
    o.round()
    assert o.idle is not None and o.idle.kind == "no room"
    _late(window, 0.0).join()
    assert o.wait(0.3, stop) == "waited"
    stop.set()
    assert o.wait(WAIT, stop) == "stopped"
