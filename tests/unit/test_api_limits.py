"""The control API's limits (docs/handler.md, "Limits on input") against a real API served on
loopback with small limits: slow clients are cut off while others get answers, idle
connections hold no place and are closed, monitors beyond --max-monitors are refused
over POST, PUT and at start. (Who holds a place: tests/unit/test_admission.py.)
"""

from __future__ import annotations

import argparse
import json
import socket
import threading
import time
from collections.abc import Iterator

import pytest
from prometheus_client import CollectorRegistry

from edgerv.control.client import HandlerClient
from edgerv.handler.api import ControlApi
from edgerv.handler.engine import Engine
from edgerv.handler.limits import Limits
from edgerv.handler.main import add_arguments, load
from kit.documents import monitor_doc, spec_of
from kit.sockets import closed_after

TOKEN = "limits-token"
# idle longer than read: an idle connection is closed when no request came for that long
LIMITS = Limits(connections=4, read_seconds=0.5, idle_seconds=0.8, monitors=2)


@pytest.fixture
def api() -> Iterator[ControlApi]:
    served = ControlApi(
        Engine("limits", flush_after=1e9), CollectorRegistry(), TOKEN, lambda: None, limits=LIMITS
    )
    served.start("127.0.0.1", 0)
    yield served
    served.stop()


def client(api: ControlApi) -> HandlerClient:
    return HandlerClient(f"127.0.0.1:{api.port}", TOKEN)


def connect(api: ControlApi) -> socket.socket:
    return socket.create_connection(("127.0.0.1", api.port or 0), timeout=10)


def answers_meanwhile(api: ControlApi, stop: threading.Event, statuses: list[int]) -> None:
    """A normal client: /healthz every 50 ms until ``stop``."""
    handler = client(api)
    while not stop.wait(0.05):
        statuses.append(handler.call("/healthz", method="GET", timeout=5)[0])
    handler.close()


def monitor(name: str) -> bytes:
    return json.dumps(
        monitor_doc(name, "always (a -> x < 5)", {"a": "bool", "x": "float"})
    ).encode()


SLOW = {
    "head": b"GET /healthz HTTP/1.1\r\nHost: edge\r\n\r\n",
    "body": (
        f"PUT /v1/monitors/m HTTP/1.1\r\nHost: edge\r\nAuthorization: Bearer {TOKEN}\r\n"
        "Content-Type: application/json\r\nContent-Length: 400\r\n\r\n"
    ).encode()
    + monitor("m").ljust(400),
}


@pytest.mark.parametrize("part", SLOW)
def test_a_client_sending_a_byte_at_a_time_is_cut_off_while_others_get_answers(
    api: ControlApi, part: str
) -> None:
    data = SLOW[part]
    sock = connect(api)
    head = data.index(b"\r\n\r\n") + 4 if part == "body" else 0  # sent at once
    stop, statuses = threading.Event(), list[int]()
    normal = threading.Thread(target=answers_meanwhile, args=(api, stop, statuses))
    normal.start()
    took, answer = closed_after(sock, data, every=0.2, at_once=head)
    stop.set()
    normal.join()
    sock.close()
    assert LIMITS.read_seconds <= took < LIMITS.read_seconds + 0.5, took
    if part == "body":  # the handler answers why, then closes
        assert answer.startswith(b"HTTP/1.1 408"), answer
        assert b"--api-read-timeout" in answer
    else:
        assert answer == b""  # a head never seen: the connection is closed
    assert len(statuses) >= 5 and set(statuses) == {200}, statuses
    assert "m" not in api.engine.slots


def test_idle_connections_hold_no_place_and_the_api_answers_while_they_stay(
    api: ControlApi,
) -> None:
    """Connections that said nothing hold no place (issue #38: they held the cap and every
    answer was 503): the API answers while they are open, and closes them after
    --api-idle-timeout. Places are taken by requests with the token
    (tests/unit/test_admission.py)."""
    held = [connect(api) for _ in range(3 * LIMITS.connections)]
    time.sleep(0.1)  # accepted
    handler = client(api)
    assert handler.call("/healthz", method="GET")[0] == 200
    assert handler.call("/v1/monitors", method="GET")[0] == 200
    handler.close()
    # they said nothing: closed after --api-idle-timeout
    time.sleep(LIMITS.idle_seconds + 0.3)
    for sock in held:
        assert sock.recv(1) == b""
        sock.close()
    others = [client(api) for _ in range(LIMITS.connections)]
    assert [h.call("/v1/monitors", method="GET")[0] for h in others] == [200] * 4
    for h in others:
        h.close()


def test_a_client_that_does_not_read_its_answers_is_cut_off(api: ControlApi) -> None:
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # fills soon
    sock.connect(("127.0.0.1", api.port or 0))
    request = f"GET /v1/monitors HTTP/1.1\r\nHost: e\r\nAuthorization: Bearer {TOKEN}\r\n\r\n"
    sock.settimeout(0.5)
    start, sent = time.monotonic(), 0
    with pytest.raises(OSError):  # reset once the handler gave up on it
        while time.monotonic() - start < 10:
            try:
                sock.sendall(request.encode() * 100)
                sent += 100
            except TimeoutError:
                continue  # it reads no more requests while answers wait: wait with it
    took = time.monotonic() - start
    sock.close()
    # cut off before the 10 s the loop gives it (how soon is a timing, and a loaded machine
    # took 2.7 s for the 0.5 s read deadline: not a pass/fail matter)
    assert sent > 100, (sent, took)
    assert client(api).call("/healthz", method="GET")[0] == 200


def test_monitors_beyond_the_limit_are_refused_over_post_and_put(api: ControlApi) -> None:
    h = client(api)
    assert h.call("/v1/monitors", raw=monitor("a"))[0] == 201
    status, body = h.call("/v1/monitors", raw=monitor("b") + b"\n---\n" + monitor("c"))
    assert status == 403  # two more would make three: neither is added
    assert json.loads(body)["errors"][0]["message"] == (
        "this handler holds 1 monitors, its limit (--max-monitors 2): remove or move one, "
        "or start it with a higher --max-monitors"
    )
    assert h.call("/v1/monitors/b", raw=monitor("b"), method="PUT")[0] == 201
    status, body = h.call("/v1/monitors/c", raw=monitor("c"), method="PUT")
    assert status == 403 and b"--max-monitors 2" in body
    assert h.call("/v1/monitors", raw=monitor("c"))[0] == 403
    assert h.call("/v1/monitors/b", raw=monitor("b"), method="PUT")[0] == 200  # replaced
    assert sorted(api.engine.slots) == ["a", "b"]
    assert h.call("/v1/monitors/a", method="DELETE")[0] == 200
    assert h.call("/v1/monitors/c", raw=monitor("c"), method="PUT")[0] == 201
    h.close()


def test_monitors_beyond_the_limit_are_refused_at_start_at_their_place() -> None:
    engine = Engine("start")
    specs = [spec_of("always (a -> x < 5)", {"a": "bool", "x": "float"}, n) for n in "pqrs"]
    problems = load(engine, specs, {"p", "r"}, most=2)
    assert sorted(engine.slots) == ["p", "q"]
    assert engine.slots["p"].active and not engine.slots["q"].active
    [refused] = problems
    assert refused.location == specs[2].location
    assert refused.severity == "error"
    assert refused.message == (
        "monitor 'r' and the 1 after it not loaded: this handler holds at most 2 "
        "(--max-monitors): raise it, or run the others on another handler"
    )


@pytest.mark.parametrize(
    ("flag", "value"),
    [
        ("--max-monitors", "0"),
        ("--api-max-connections", "-1"),
        ("--api-max-connections", "²"),
        ("--api-read-timeout", "0"),
        ("--api-idle-timeout", "inf"),
        ("--api-idle-timeout", "soon"),
    ],
)
def test_a_limit_that_is_not_one_is_refused_on_the_command_line(
    flag: str, value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    parser = argparse.ArgumentParser(prog="edgerv handler")
    add_arguments(parser)
    with pytest.raises(SystemExit) as exited:
        parser.parse_args(["--name", "h", flag, value])
    assert exited.value.code == 2
    assert f"argument {flag}: '{value}' is not a" in capsys.readouterr().err
