"""Cheap checks before the body (issue #38), against a real API on loopback: what a
request's head tells (the token, the call, the declared size, a handoff's step, ``adopt``'s
epoch and that a handoff receives under it) is answered before any of its body is read;
a body is read up to its call's limit and no further, chunked or not; a snapshot bundle
is refused by the size it announces after its first 8 bytes, and by what its headers say
its decoding would take before anything is decoded. Each refusal is JSON.

"Before the body": the client sends the head (and a part of the body at most) and reads
the answer without sending the rest; an API that waited for the rest would never answer.
"Before the work": the decoding is replaced by one that fails the test, and the process's
allocations (tracemalloc: the API's thread is this process's) stay far below what the
request announces.
"""

from __future__ import annotations

import gc
import json
import re
import socket
import sys
import threading
import tracemalloc
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from prometheus_client import CollectorRegistry

from edgerv.control.client import HandlerClient
from edgerv.core import handoff
from edgerv.core.handoff import bundle, encode
from edgerv.core.pipeline import MonitorRuntime
from edgerv.handler.api import MAX_BODY, MAX_EPOCH, ControlApi
from edgerv.handler.engine import Engine
from edgerv.handler.limits import Limits
from kit.documents import compiled, monitor_doc

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "fuzz"))
import fuzz_bundle  # tests/fuzz: real events, and swollen snapshots

TOKEN = "bodies-token"
BUNDLE = 8 << 20  # Limits.bundle here: a small budget
LIMITS = Limits(connections=8, read_seconds=5.0, idle_seconds=10.0, bundle=BUNDLE)
SIGNALS = {"a": "bool", "x": "float"}
EPOCH = 10**18


def serve(limits: Limits) -> ControlApi:
    engine = Engine("bodies", flush_after=1e9)
    engine.put(compiled("always (a -> x < 5)", SIGNALS), active=True)  # m: runs here
    for name in ("n", "o"):  # defined only: a receiver's side
        engine.put(compiled("always (a -> x < 5)", SIGNALS, name=name), active=False)
    served = ControlApi(engine, CollectorRegistry(), TOKEN, lambda: None, limits=limits)
    served.start("127.0.0.1", 0)
    return served


@pytest.fixture
def api() -> Iterator[ControlApi]:
    served = serve(LIMITS)
    yield served
    served.stop()


def head(method: str, path: str, length: int | None = None, chunked: bool = False) -> bytes:
    size = "Transfer-Encoding: chunked\r\n" if chunked else f"Content-Length: {length or 0}\r\n"
    return (
        f"{method} {path} HTTP/1.1\r\nHost: edge\r\nAuthorization: Bearer {TOKEN}\r\n"
        f"Connection: close\r\n{size}\r\n"
    ).encode()


def answer_to(api: ControlApi, data: bytes) -> tuple[int, Any]:
    """Send ``data`` (a head, and maybe a part of a body), never more, and read the whole
    answer: its status and its JSON body."""
    with socket.create_connection(("127.0.0.1", api.port or 0), timeout=10) as sock:
        sock.sendall(data)
        answer = b""
        while b"\r\n\r\n" not in answer or len(answer) < answer_length(answer):
            chunk = sock.recv(65536)
            assert chunk, answer
            answer += chunk
    top, _, body = answer.partition(b"\r\n\r\n")
    assert top.startswith(b"HTTP/1.1 "), answer[:300]
    assert b"Content-Type: application/json" in top, top
    return int(top[9:12]), json.loads(body)


def answer_length(answer: bytes) -> int:
    """The bytes of a whole answer whose head is in (it says its Content-Length)."""
    top, _, _ = answer.partition(b"\r\n\r\n")
    length = re.search(rb"\r\nContent-Length: (\d+)", top)
    assert length, top
    return len(top) + 4 + int(length.group(1))


def message(answer: Any) -> str:
    return str(answer["errors"][0]["message"])


def snapshot_of(engine: Engine, name: str, epoch: int) -> bytes:
    """A real frame of ``name``'s snapshot for ``epoch``: what its sender releases."""
    rt = MonitorRuntime(engine.slots[name].compiled)
    rt.holding = True
    for stamp, seq, updates in fuzz_bundle.events(3, 40, 100):
        rt.offer(stamp, seq, updates)
    return encode(rt.snapshot(cut=150, epoch=epoch))


def swollen(frame: bytes) -> bytes:
    """The frame's snapshot with as many letters as one may carry (16 Mi), in long runs."""
    letters = handoff.frame_sizes(frame)[1]
    return fuzz_bundle.swollen(frame, handoff.MAX_LETTERS // letters)


@pytest.fixture
def no_decoding(monkeypatch: pytest.MonkeyPatch) -> None:
    def decoded(*args: Any) -> Any:
        raise AssertionError("a snapshot was decoded")

    monkeypatch.setattr(handoff, "_decode", decoded)


# -- what the head tells ---------------------------------------------------------------------


@pytest.mark.parametrize(
    ("path", "length", "status", "said"),
    [
        ("/v1/monitors", MAX_BODY + 1, 413, "body larger than 1048576 bytes"),
        ("/v1/handoff/hold", (8 << 20) + 1, 413, "body larger than 8388608 bytes"),
        ("/v1/handoff/adopt?epoch=5", (64 << 20) + 1, 413, "body larger than 67108864 bytes"),
        ("/v1/handoff/hand-over", 1 << 20, 404, 'no handoff step "hand-over"'),
        ("/v1/handoff/adopt", 1 << 20, 400, 'missing field "epoch"'),
        ("/v1/handoff/adopt?epoch=-5", 1 << 20, 400, "epoch must be from 1 to"),
        (f"/v1/handoff/adopt?epoch={10**29}", 1 << 20, 400, f'not "{10**29}"'),
        (f"/v1/handoff/adopt?epoch={MAX_EPOCH + 1}", 1 << 20, 400, "epoch must be from 1"),
        ("/v1/handoff/adopt?epoch=12", 1 << 20, 409, "no monitor is being received here"),
        ("/v1/nosuch", 1 << 20, 404, "Not Found"),
    ],
)
def test_what_the_head_tells_is_answered_before_the_body_comes(
    api: ControlApi, path: str, length: int, status: int, said: str
) -> None:
    got, answer = answer_to(api, head("POST", path, length))  # the body is never sent
    assert got == status, answer
    assert said in message(answer), answer


def test_a_method_not_allowed_and_no_token_are_json_too(api: ControlApi) -> None:
    got, answer = answer_to(api, head("DELETE", "/v1/load"))
    assert got == 405 and message(answer) == "Method Not Allowed"
    data = head("POST", "/v1/handoff/hold", 1 << 20).replace(f"Bearer {TOKEN}".encode(), b"x")
    got, answer = answer_to(api, data)
    assert got == 401 and message(answer) == "missing or wrong bearer token"


@pytest.mark.parametrize("epoch", [10**29, MAX_EPOCH + 1, 0, -1, 2.5, "7"])
@pytest.mark.parametrize("step", ["hold", "receive", "abort", "commit", "cut"])
def test_an_epoch_beyond_the_drivers_clock_is_refused_and_fences_nothing(
    api: ControlApi, step: str, epoch: Any
) -> None:
    """An epoch of 10^29 was taken before, and fenced the monitor against every later
    move: now 400, and a move with a real epoch goes on."""
    client = HandlerClient(f"127.0.0.1:{api.port}", TOKEN)
    status, body = client.call(f"/v1/handoff/{step}", {"epoch": epoch, "monitors": ["m"]})
    assert status == 400, body
    assert "epoch must be" in message(json.loads(body))
    assert api.engine.slots["m"].epoch == 0 and api.engine.slots["m"].handoff is None
    assert client.handoff("hold", EPOCH, ["m"], 5.0)[0] == 200
    assert client.handoff("abort", EPOCH, ["m"], 5.0)[0] == 200
    assert client.handoff("hold", MAX_EPOCH, ["m"], 5.0)[0] == 200  # the last one there is
    client.close()


# -- bodies: at most the limit, chunked or not --------------------------------------------------


def test_a_chunked_body_is_read_up_to_its_limit_and_no_further(api: ControlApi) -> None:
    """1 MiB and a bit more of chunked Monitor documents, and the body goes on: the 413
    (JSON) comes without the rest, which is never sent."""
    part = b"#" * (64 << 10)
    chunks = b"".join(b"%x\r\n%s\r\n" % (len(part), part) for _ in range(17))  # 1 MiB + 64 KiB
    got, answer = answer_to(api, head("POST", "/v1/monitors", chunked=True) + chunks)
    assert got == 413 and message(answer) == f"body larger than {MAX_BODY} bytes"


def test_oversized_chunked_bodies_leave_nothing_behind(api: ControlApi) -> None:
    """The memory of refused bodies does not stay (1.3 GB after 17 requests before)."""
    part = b"#" * (256 << 10)
    chunks = b"".join(b"%x\r\n%s\r\n" % (len(part), part) for _ in range(6))
    answer_to(api, head("POST", "/v1/monitors", chunked=True) + chunks)  # warm up
    gc.collect()
    tracemalloc.start()
    try:
        for _ in range(17):
            assert answer_to(api, head("POST", "/v1/monitors", chunked=True) + chunks)[0] == 413
        current, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 12 << 20, peak  # a body (1 MiB) and its chunks at a time, not 17 of them
    assert current < 4 << 20, current


def test_bodies_held_at_once_are_bounded_by_their_budget() -> None:
    """Two uploads whose bodies together pass ``Limits.bodies`` (4 MiB here): the second
    is answered 503 at once, the first goes on; one larger than all may hold gets 413."""
    api = serve(Limits(bodies=4 << 20))
    first = socket.create_connection(("127.0.0.1", api.port or 0), timeout=10)
    try:
        receiving(api, "n", 5)
        first.sendall(head("POST", "/v1/handoff/adopt?epoch=5", 3 << 20) + b"ERVB")
        threading.Event().wait(0.2)  # its head is in, its body begins
        got, answer = answer_to(api, head("POST", "/v1/handoff/adopt?epoch=5", 2 << 20))
        assert got == 503 and "no more than 4194304 at once" in message(answer)
        got, answer = answer_to(api, head("POST", "/v1/handoff/adopt?epoch=5", 5 << 20))
        assert got == 413 and message(answer) == "body larger than 4194304 bytes"
    finally:
        first.close()
        api.stop()


def receiving(api: ControlApi, name: str, epoch: int) -> None:
    api.engine.handoffs.receive(name, epoch)


# -- snapshot bundles: checked before they are inflated and decoded ----------------------------


def test_a_bundle_announcing_more_than_its_budget_is_refused_after_8_bytes(
    api: ControlApi, no_decoding: None
) -> None:
    receiving(api, "n", EPOCH)
    announced = b"ERVB" + (BUNDLE + 1).to_bytes(4, "big")
    data = head("POST", f"/v1/handoff/adopt?epoch={EPOCH}", 3 << 20) + announced
    got, answer = answer_to(api, data)  # the other 3 MiB never come
    assert got == 413, answer
    assert (
        message(answer) == f"a bundle of {BUNDLE + 1} bytes inflated is over the limit of {BUNDLE}"
    )
    assert api.engine.slots["n"].handoff == "receiving"  # nothing adopted, still receiving


def test_not_a_bundle_is_refused_after_its_first_bytes(api: ControlApi) -> None:
    receiving(api, "n", EPOCH)
    data = head("POST", f"/v1/handoff/adopt?epoch={EPOCH}", 1 << 20) + b"GIF89a\x00\x00"
    got, answer = answer_to(api, data)
    assert got == 409 and message(answer).startswith("not an edgerv snapshot bundle")


def test_a_deflate_bomb_stops_at_its_announced_size(api: ControlApi, no_decoding: None) -> None:
    """1 MiB of deflate that inflates to 1 GiB, announcing the budget: inflated a step at a
    time, refused one step past what it announced; the memory taken stays about that."""
    receiving(api, "n", EPOCH)
    stream = fuzz_bundle.deflate_bomb(1 << 30)
    wire = b"ERVB" + BUNDLE.to_bytes(4, "big") + stream
    gc.collect()
    tracemalloc.start()
    try:
        got, answer = answer_to(
            api, head("POST", f"/v1/handoff/adopt?epoch={EPOCH}", len(wire)) + wire
        )
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert got == 409 and "does not inflate to its announced size" in message(answer)
    assert peak < 3 * BUNDLE, peak  # the body, the budget and a step: not 1 GiB


def test_a_valid_bundle_that_would_decode_past_its_budget_is_refused_undecoded(
    api: ControlApi, no_decoding: None
) -> None:
    """A few KiB of valid snapshots whose letters come in long runs: 16 Mi letters each,
    for the two monitors received, 6 bytes a run on the wire (a 32 KiB body took 2.5 GiB
    before). The headers say what decoding would take: refused before any is decoded."""
    for name in ("n", "o"):
        receiving(api, name, EPOCH)
    frames = [swollen(snapshot_of(api.engine, name, EPOCH)) for name in ("n", "o")]
    wire = bundle(frames)
    assert len(wire) < 4096
    gc.collect()
    tracemalloc.start()
    try:
        got, answer = answer_to(
            api, head("POST", f"/v1/handoff/adopt?epoch={EPOCH}", len(wire)) + wire
        )
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert got == 413, answer
    assert "snapshots would take" in message(answer) and f"limit of {BUNDLE}" in message(answer)
    assert peak < 4 << 20, peak
    assert all(api.engine.slots[n].handoff == "receiving" for n in ("n", "o"))


@pytest.mark.parametrize(
    ("what", "said"),
    [
        ("not received", "snapshot 2 of 2: no receiving handoff of 'm' with epoch"),
        ("unknown", 'snapshot 2 of 2: no monitor "z" here'),
        ("twice", 'snapshot 2 of 2: monitor "n" comes twice'),
        ("other epoch", "snapshot 2 of 2: o: the snapshot belongs to another handoff"),
    ],
)
def test_a_snapshot_the_handler_does_not_receive_is_refused_before_any_is_decoded(
    api: ControlApi, no_decoding: None, what: str, said: str
) -> None:
    receiving(api, "n", EPOCH)
    receiving(api, "o", EPOCH)
    good = snapshot_of(api.engine, "n", EPOCH)
    bad = {
        "not received": snapshot_of(api.engine, "m", EPOCH),
        "unknown": good.replace(b'"monitor":"n"', b'"monitor":"z"'),
        "twice": good,
        "other epoch": snapshot_of(api.engine, "o", EPOCH + 1),
    }[what]
    wire = bundle([good, bad])
    got, answer = answer_to(api, head("POST", f"/v1/handoff/adopt?epoch={EPOCH}", len(wire)) + wire)
    assert got == 409 and message(answer).startswith(said), answer
    assert api.engine.slots["n"].handoff == "receiving"


def test_a_bundle_the_handler_receives_is_adopted_and_a_repeat_is_answered_alike(
    api: ControlApi,
) -> None:
    receiving(api, "n", EPOCH)
    wire = bundle([snapshot_of(api.engine, "n", EPOCH)])
    client = HandlerClient(f"127.0.0.1:{api.port}", TOKEN)
    for _ in range(2):  # the second: its answer was lost, the driver asks again
        status, body = client.call(f"/v1/handoff/adopt?epoch={EPOCH}", raw=wire)
        assert (status, json.loads(body)) == (200, {"active": ["n"]})
    assert api.engine.slots["n"].active
    client.close()


def test_documents_are_parsed_off_the_event_loop_and_answered(api: ControlApi) -> None:
    doc = monitor_doc("p", "always (a -> x < 5)", SIGNALS)
    client = HandlerClient(f"127.0.0.1:{api.port}", TOKEN)
    status, body = client.call("/v1/monitors", raw=json.dumps(doc).encode())
    assert (status, json.loads(body)) == (201, {"created": ["p"]})
    status, body = client.call("/v1/monitors", raw=b"\xff\xfe")
    assert (status, message(json.loads(body))) == (400, "the body is not UTF-8 text")
    client.close()
