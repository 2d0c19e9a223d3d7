"""Reading only what changed (docs/protocol.md, "Reading only what changed"): ``GET
/v1/monitors`` and ``GET /v1/load`` with ``?since=CURSOR`` send only the entries whose
report changed since the cursor, and the names removed; a client merging those answers
holds exactly the whole listing, whatever happened between its calls, and a cursor the
handler cannot answer from (another boot, forgotten removals, a made-up one) gets the
whole listing."""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from prometheus_client import CollectorRegistry

from edgerv.control.client import BadAnswer, HandlerClient
from edgerv.handler.api import ControlApi
from edgerv.handler.engine import Engine
from edgerv.handler.reading import monitor_reports
from edgerv.handler.revisions import Revisions
from kit.documents import compiled

NAMES = st.sampled_from([f"m{i}" for i in range(8)])
LISTINGS = st.lists(st.dictionaries(NAMES, st.integers(0, 3)), min_size=1, max_size=12)


def merged(
    kept: dict[str, Any] | None, answer: tuple[dict[str, Any], list[str] | None, str]
) -> dict[str, Any]:
    changed, removed, _ = answer
    if removed is None:
        return dict(changed)
    assert kept is not None
    whole = {n: v for n, v in kept.items() if n not in removed}
    whole.update(changed)
    return whole


@settings(max_examples=300, deadline=None)
@given(LISTINGS, st.lists(st.booleans(), min_size=12, max_size=12), st.integers(1, 6))
def test_a_reader_merging_what_changed_holds_the_whole_listing(
    listings: list[dict[str, int]], reads: list[bool], remembered: int
) -> None:
    """Two readers, each reading at some of the listings (the other's reads in between
    count too), one of them lagging; with few removals remembered, a reader too far
    behind gets the whole listing, never a wrong one."""
    revisions = Revisions(remembered=remembered)
    kept: list[tuple[str | None, dict[str, Any] | None]] = [(None, None), (None, None)]
    for step, listing in enumerate(listings):
        reader = 0 if reads[step] else 1
        cursor, entries = kept[reader]
        answer = revisions.read(listing, cursor)
        if answer[1] is not None:  # a delta: only what changed
            assert set(answer[0]) <= set(listing)
            assert all(listing[n] == v for n, v in answer[0].items())
        whole = merged(entries, answer)
        assert whole == listing
        kept[reader] = (answer[2], whole)


def test_only_the_changed_entries_and_the_removed_names_are_sent() -> None:
    r = Revisions()
    changed, removed, first = r.read({"a": 1, "b": 2}, None)
    assert (changed, removed) == ({"a": 1, "b": 2}, None)  # no cursor: the whole listing
    assert r.read({"a": 1, "b": 2}, first)[:2] == ({}, [])  # nothing changed: nothing sent
    changed, removed, second = r.read({"a": 1, "b": 3, "c": 4}, first)
    assert (changed, removed) == ({"b": 3, "c": 4}, [])
    assert r.read({"b": 3, "c": 4}, second)[:2] == ({}, ["a"])
    # the first reader, further behind, gets everything since its own cursor
    assert r.read({"b": 3, "c": 4}, first)[:2] == ({"b": 3, "c": 4}, ["a"])
    # back again: sent as changed, and no longer as removed
    changed, removed, _ = r.read({"a": 1, "b": 3, "c": 4}, second)
    assert (changed, removed) == ({"a": 1}, [])


@pytest.mark.parametrize(
    "cursor",
    ["", "x", "nope.1", "{boot}.", "{boot}.99", "{boot}.-1", "{boot}.²", "{boot}.1.2", "{boot}"],
)
def test_a_cursor_it_cannot_answer_from_gets_the_whole_listing(cursor: str) -> None:
    r = Revisions()
    r.read({"a": 1}, None)
    changed, removed, _ = r.read({"a": 1, "b": 2}, cursor.format(boot=r.boot))
    assert (changed, removed) == ({"a": 1, "b": 2}, None)


def test_a_reader_behind_the_removals_remembered_gets_the_whole_listing() -> None:
    r = Revisions(remembered=2)
    _, _, cursor = r.read({"a": 1, "b": 1, "c": 1, "d": 1}, None)
    for gone in ({"b": 1, "c": 1, "d": 1}, {"c": 1, "d": 1}):
        r.read(gone, None)
    assert r.read({"c": 1, "d": 1}, cursor)[1] == ["a", "b"]  # two remembered: a delta
    r.read({"d": 1}, None)  # a third removal: a's is forgotten
    assert r.read({"d": 1}, cursor)[:2] == ({"d": 1}, None)


@pytest.fixture
def api() -> Iterator[ControlApi]:
    """A handler defining three monitors (m0 active), its API on loopback."""
    engine = Engine("cloud-1", flush_after=1e9)
    for i in range(3):
        engine.put(compiled("always (a)", {"a": "bool"}, name=f"m{i}"), active=i == 0)
    served = ControlApi(engine, CollectorRegistry(), "t", on_change=lambda: None)
    served.start("127.0.0.1", 0)
    yield served
    served.stop()


def test_the_client_is_sent_only_what_changed_and_holds_the_whole_listing(
    api: ControlApi,
) -> None:
    client = HandlerClient(f"127.0.0.1:{api.port}", "t")
    fresh = lambda: HandlerClient(f"127.0.0.1:{api.port}", "t")  # noqa: E731 (no cursor)
    assert client.monitors() == fresh().monitors() and len(client.monitors()) == 3
    assert client.load()["monitors"] == fresh().load()["monitors"]
    cursor = client._kept["/v1/monitors"][0]
    idle = client.get(f"/v1/monitors?since={cursor}")  # what an idle handler sends
    assert (idle["monitors"], idle["removed"], idle["since"]) == ([], [], cursor)
    api.engine.set_active("m1", True)
    api.engine.remove("m2")
    api.engine.put(compiled("always (b)", {"b": "bool"}, name="m3"), active=False)
    for whole, alone in ((client.monitors(), fresh().monitors()),
                         (client.load()["monitors"], fresh().load()["monitors"])):  # fmt: skip
        assert whole == alone
    assert sorted(m["name"] for m in client.monitors()) == ["m0", "m1", "m3"]
    assert client.load()["monitors"]["m1"]["active"] is True
    sent = client.get(f"/v1/load?since={client._kept['/v1/load'][0]}")
    assert sent["monitors"] == {} and sent["removed"] == []


def test_a_restarted_handler_sends_its_whole_listing_and_nothing_stale_stays(
    api: ControlApi,
) -> None:
    client = HandlerClient(f"127.0.0.1:{api.port}", "t")
    assert len(client.monitors()) == 3 and len(client.load()["monitors"]) == 3
    api.engine.remove("m2")
    api._listed, api._loaded = Revisions(), Revisions()  # another boot: it knows no cursor
    assert sorted(m["name"] for m in client.monitors()) == ["m0", "m1"]
    assert sorted(client.load()["monitors"]) == ["m0", "m1"]


def test_an_answer_with_no_list_of_removals_is_a_bad_answer_and_nothing_is_kept(
    api: ControlApi,
) -> None:
    client = HandlerClient(f"127.0.0.1:{api.port}", "t")
    client.monitors()
    original = api._listing
    api._listing = lambda since: {**original(since), "removed": "m1"}  # type: ignore[method-assign]
    with pytest.raises(BadAnswer, match="no list of names removed"):
        client.monitors()
    assert "/v1/monitors" not in client._kept  # the next call asks for everything
    api._listing = original  # type: ignore[method-assign]
    assert len(client.monitors()) == 3


def test_a_handler_that_keeps_no_cursor_is_read_whole_each_time() -> None:
    """An older handler (no ``cursor`` in its answers): every answer is the listing."""
    engine = Engine("old", flush_after=1e9)
    engine.put(compiled("always (a)", {"a": "bool"}), active=True)
    served = ControlApi(engine, CollectorRegistry(), "t", on_change=lambda: None)
    served._listing = lambda since: {  # type: ignore[method-assign]
        "handler": "old",
        "monitors": json.loads(json.dumps(monitor_reports(engine))),
    }
    served.start("127.0.0.1", 0)
    try:
        client = HandlerClient(f"127.0.0.1:{served.port}", "t")
        assert [m["name"] for m in client.monitors()] == ["m"]
        assert "/v1/monitors" not in client._kept
        engine.remove("m")
        assert client.monitors() == []
    finally:
        served.stop()


OPERATIONS = st.lists(
    st.tuples(
        st.sampled_from(["put", "put-idle", "remove", "on", "off", "read"]), st.integers(0, 4)
    ),
    min_size=1,
    max_size=15,
)


@settings(max_examples=40, deadline=None)
@given(OPERATIONS)
def test_two_clients_of_a_real_handler_each_hold_its_whole_listing(
    operations: list[tuple[str, int]],
) -> None:
    """Monitors defined, redefined, removed, started and stopped on a real handler's API
    between the reads of two clients (one reads after every change, the other only at
    some): each client's merged listing and load report equal what a client without a
    cursor reads."""
    engine = Engine("h", flush_after=1e9)
    served = ControlApi(engine, CollectorRegistry(), "t", on_change=lambda: None)
    served.start("127.0.0.1", 0)
    try:
        address = f"127.0.0.1:{served.port}"
        eager, lazy = HandlerClient(address, "t"), HandlerClient(address, "t")
        for kind, i in operations:
            name = f"m{i}"
            if kind in ("put", "put-idle"):
                signal = "a" if i % 2 else "b"
                engine.put(
                    compiled(f"always ({signal})", {signal: "bool"}, name=name),
                    active=kind == "put",
                )
            elif kind == "remove":
                engine.remove(name)
            elif name in engine.slots:
                engine.set_active(name, kind == "on")
            readers = [eager, lazy] if kind == "read" else [eager]
            for client in readers:
                fresh = HandlerClient(address, "t")
                key = lambda m: m["name"]  # noqa: E731
                assert sorted(client.monitors(), key=key) == sorted(fresh.monitors(), key=key)
                assert client.load()["monitors"] == fresh.load()["monitors"]
    finally:
        served.stop()
