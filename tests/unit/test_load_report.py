"""The load report (``GET /v1/load``) is typed on both sides: what the handler's server
sends (``reading.load_report``, a ``LoadReport``) is what the client reads back through
``parse_load``, field by field; an answer that is not one is a ``BadAnswer``, and the
orchestrator leaves that handler out of its round instead of failing on it."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from typing import Any

import pytest
from prometheus_client import CollectorRegistry

from edgerv.control.client import BadAnswer, HandlerClient
from edgerv.control.orchestrate import Orchestrator, Target
from edgerv.control.placement import PolicyConfig
from edgerv.control.wire import parse_load
from edgerv.core.deadline import MakespanWindow
from edgerv.handler.api import ControlApi
from edgerv.handler.engine import Engine
from edgerv.handler.reach import Reach
from edgerv.handler.reading import Definitions, load_report
from kit.documents import compiled

MS = 1_000_000


@pytest.fixture
def api() -> Iterator[ControlApi]:
    """A handler running m with a --deadline of 125 ms, its API on loopback."""
    window = MakespanWindow("/cmd_vel", 125 * MS)
    engine = Engine("edge-1", flush_after=1e9, deadline=window)
    engine.put(compiled("always (a -> x < 5)", {"a": "bool", "x": "float"}), active=True)
    now = time.monotonic_ns()
    for i in range(6):
        window.add(50_000 * MS + i * 50 * MS, 50_000 * MS + i * 50 * MS - 100 * MS, now)
    served = ControlApi(engine, CollectorRegistry(), "t", on_change=lambda: None)
    served.start("127.0.0.1", 0)
    yield served
    served.stop()


def test_what_the_handler_sends_reads_back_as_sent(api: ControlApi) -> None:
    sent = load_report(api.engine)
    assert parse_load(json.loads(json.dumps(sent))) == sent
    read = HandlerClient(f"127.0.0.1:{api.port}", "t").load()
    assert read["handler"] == "edge-1" and read["deadline"] is not None
    assert read["deadline"]["count"] == 6 and read["deadline"]["p95Ms"] == 100.0
    m = read["monitors"]["m"]
    assert (m["active"], m["handoff"], m["migrationWanted"], m["events"]) == (
        True,
        None,
        False,
        0,
    )
    assert m["placement"] == {"tier": None, "migrate": "auto", "maxLatencyMs": None}
    assert m["cpuSeconds"] == 0.0  # active, but nothing taken nor evaluated yet
    assert read["host"] is not None and read["host"]["cores"] >= 1  # (this is Linux)


def test_a_monitor_redefined_or_removed_shows_in_the_next_report() -> None:
    # each entry's definition part is made once per definition (reading.Definitions):
    # a new definition of the same name is read again, a removed one is gone
    engine = Engine("edge-1", flush_after=1e9)
    engine.put(compiled("always (a)", {"a": "bool"}), active=True)
    kept = Definitions()
    first = load_report(engine, kept)["monitors"]["m"]
    assert first["topics"] == ["/a"] and first["placement"]["tier"] is None
    engine.put(
        compiled("always (b)", {"b": "bool"}, placement={"tier": "cloud", "maxLatencyMs": 40}),
        active=True,
    )
    again = load_report(engine, kept)["monitors"]["m"]
    assert again["topics"] == ["/b"]
    assert again["placement"] == {"tier": "cloud", "migrate": "auto", "maxLatencyMs": 40.0}
    assert first["topics"] == ["/a"]  # (a report once sent is not changed by a later one)
    assert engine.remove("m") and load_report(engine, kept)["monitors"] == {}
    assert kept._kept == {}  # nothing kept of a monitor no longer defined


def test_what_a_handler_may_leave_out_reads_as_its_default() -> None:
    report = parse_load(
        {
            "handler": "h",
            "monotonic": 1,
            "cpuSeconds": 0.5,
            "monitors": {"m": {"active": False, "events": 3, "migrationWanted": False}},
        }
    )
    assert (report["ingestLag"], report["deadline"], report["monotonic"]) == (0.0, None, 1.0)
    assert report["reachMs"] is None
    assert report["host"] is None and report["topics"] == {}
    assert report["monitors"]["m"] == {
        "active": False,
        "handoff": None,
        "epoch": 0,
        "peer": None,
        "events": 3,
        "cpuSeconds": 0.0,
        "migrationWanted": False,
        "placement": {"tier": None, "migrate": "auto", "maxLatencyMs": None},
        "topics": [],
    }
    topic = parse_load({**GOOD, "topics": {"/imu": {"messages": 4}}})["topics"]
    assert topic == {"/imu": {"messages": 4, "cpuSeconds": 0.0}}


GOOD: dict[str, Any] = {
    "handler": "h",
    "monotonic": 1.0,
    "cpuSeconds": 0.5,
    "monitors": {"m": {"active": True, "events": 3, "migrationWanted": False}},
}


@pytest.mark.parametrize(
    ("change", "said"),
    [
        ({"handler": 7}, "handler is not a string"),
        ({"monotonic": "soon"}, "monotonic is not a number"),
        ({"cpuSeconds": None}, "cpuSeconds is not a number"),
        ({"ingestLag": True}, "ingestLag is not a number"),
        ({"reachMs": "far"}, "reachMs is not a number"),
        ({"monitors": []}, "monitors is not an object"),
        ({"topics": []}, "topics is not an object"),
        ({"topics": {"/imu": 1}}, "topics./imu is not an object"),
        ({"topics": {"/imu": {"messages": 1.5}}}, "topics./imu.messages is not a whole number"),
        ({"topics": {"/imu": {"messages": 1, "cpuSeconds": "x"}}}, "topics./imu.cpuSeconds"),
        ({"monitors": {"m": {"active": True, "events": 1, "migrationWanted": False,
                             "topics": ["/a", 2]}}}, "monitors.m.topics is not a list of strings"),
        ({"monitors": {"m": 1}}, "monitors.m is not an object"),
        ({"monitors": {"m": {"active": "yes", "events": 1}}}, "monitors.m.active is not true"),
        ({"monitors": {"m": {"active": True, "events": 1.5, "migrationWanted": False}}},
         "monitors.m.events is not a whole number"),
        ({"monitors": {"m": {"active": True, "events": 1, "cpuSeconds": "x",
                             "migrationWanted": False}}},
         "monitors.m.cpuSeconds is not a number"),
        ({"host": 2}, "host is not an object or null"),
        ({"host": {"cores": 1.5, "busySeconds": 1, "totalSeconds": 2}},
         "host.cores is not a whole number"),
        ({"host": {"cores": 1, "busySeconds": float("nan"), "totalSeconds": 2}},
         "host.busySeconds is not a number"),
        ({"deadline": "fast"}, "deadline is not an object or null"),
        ({"deadline": {"count": 4}}, "deadline.budgetMs is not a number"),
        ({"deadline": {"budgetMs": 125, "count": 4, "p95Ms": "1"}}, "deadline.p95Ms is not"),
    ],
)  # fmt: skip
def test_what_is_not_a_load_report_says_what_is_wrong(change: dict[str, Any], said: str) -> None:
    with pytest.raises(ValueError, match=said):
        parse_load({**GOOD, **change})
    with pytest.raises(ValueError, match="it is not an object"):
        parse_load([GOOD])


class Answers(HandlerClient):
    """A handler's API that answers ``GET /v1/load`` with ``answer``."""

    def __init__(self, answer: object) -> None:
        super().__init__("http://x", None)
        self.answer = answer

    def get(self, path: str, timeout: float = 10.0) -> object:
        return self.answer


def test_a_handler_that_answers_no_load_report_is_left_out_of_the_round() -> None:
    with pytest.raises(BadAnswer, match=r"http://x answered /v1/load with no load report: "):
        Answers({**GOOD, "monotonic": "soon"}).load()
    edge, cloud = Target("edge", "e:1"), Target("cloud", "c:1")
    o = Orchestrator([edge, cloud], PolicyConfig(tiers=("edge", "cloud")), token=None)
    o.clients = {edge: Answers(GOOD), cloud: Answers({"handler": "c"})}
    assert list(o.poll()) == [edge]
    assert o.round() == [] and list(o.seen) == [edge]


def test_how_long_messages_take_to_reach_the_handler() -> None:
    """The load report's reachMs: the 95th percentile (nearest rank) of the newest
    REACH_SAMPLES readings the take loop notes (the longest a topic's messages took in a
    round, from publication to reception); a clock behind reads 0; none yet: null."""
    engine = Engine("edge-1")
    assert load_report(engine)["reachMs"] is None
    for ms in range(1, 101):  # 1..100 ms: the 95th of 100 is 95
        engine.reach.note(ms * 1_000_000)
    assert load_report(engine)["reachMs"] == 95.0
    reach = Reach(size=4)
    for ns in (-5, 10, 20, 30, 40, 50):  # the newest four: 20, 30, 40, 50
        reach.note(ns)
    assert reach.p95_ms() == 50 / 1e6 and reach.count == 6
    fresh = Reach(size=4)
    fresh.note(-5)  # a publisher's clock ahead of this one's
    assert fresh.p95_ms() == 0.0
    assert parse_load({**GOOD, "reachMs": 12.5})["reachMs"] == 12.5
