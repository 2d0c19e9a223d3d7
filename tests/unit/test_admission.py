"""Admission before work (issue #38): a real API on loopback with small limits, and
strangers that never show the token: connections that send nothing, send a byte now and
then, or send requests without the token, reopened as they are closed, from one address
and from many (127.0.0.0/8 is all loopback). Meanwhile an operator's calls and
``/healthz`` are answered, many in a row, each before a generous timeout: a connection
holds a place only once a request with the token came on it; a place is never held by
a stranger (docs/handler.md, "Limits on input").
"""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from prometheus_client import CollectorRegistry

from edgerv.control.client import HandlerClient
from edgerv.control.tls import ClientTls, server_context
from edgerv.handler.admission import Pool
from edgerv.handler.api import ControlApi
from edgerv.handler.engine import Engine
from edgerv.handler.limits import Limits
from kit.documents import compiled
from kit.pki import make_pki

TOKEN = "admission-token"
LIMITS = Limits(connections=4, pending=24, read_seconds=3.0, idle_seconds=6.0, monitors=10)
ANSWER_WITHIN = 5.0  # seconds: generous (a loaded machine), a stalled API takes longer
MONITOR = ("always (a -> x < 5)", {"a": "bool", "x": "float"})


def serve(limits: Limits = LIMITS) -> ControlApi:
    engine = Engine("admission", flush_after=1e9)
    engine.put(compiled(*MONITOR), active=True)
    api = ControlApi(engine, CollectorRegistry(), TOKEN, lambda: None, limits=limits)
    api.start("127.0.0.1", 0)
    return api


@pytest.fixture
def api() -> Iterator[ControlApi]:
    served = serve()
    yield served
    served.stop()


def on_loop(api: ControlApi, read: object) -> object:
    """``read()`` on the API's loop thread (its pool is that thread's)."""
    assert api._loop is not None and callable(read)
    got: list[object] = []
    done = threading.Event()

    def run() -> None:
        got.append(read())
        done.set()

    api._loop.call_soon_threadsafe(run)
    assert done.wait(ANSWER_WITHIN)
    return got[0]


def until(api: ControlApi, read: Callable[[Pool], object], want: object) -> None:
    """Wait until ``read(pool) == want`` (read on the API's loop), at most ANSWER_WITHIN."""
    deadline = time.monotonic() + ANSWER_WITHIN
    while (got := on_loop(api, lambda: read(api.connections))) != want:  # type: ignore[arg-type]
        assert time.monotonic() < deadline, (got, want)
        time.sleep(0.01)


def connect(port: int, source: str = "127.0.0.1") -> socket.socket:
    sock = socket.socket()
    sock.settimeout(ANSWER_WITHIN)
    sock.bind((source, 0))
    sock.connect(("127.0.0.1", port))
    return sock


def was_closed(sock: socket.socket, wait: float = ANSWER_WITHIN) -> bool:
    """The server closed it (a FIN, or a reset: it had bytes left unread) within ``wait``."""
    sock.settimeout(wait)
    try:
        return sock.recv(1) == b""
    except ConnectionResetError:
        return True
    except TimeoutError:
        return False


def exchange(sock: socket.socket, data: bytes) -> bytes:
    """Send a request, read its whole answer (Connection: close)."""
    sock.sendall(data)
    answer = b""
    while chunk := sock.recv(65536):
        answer += chunk
    return answer


def request(
    method: str, path: str, body: bytes = b"", token: bool = True, length: int | None = None
) -> bytes:
    auth = f"Authorization: Bearer {TOKEN}\r\n" if token else ""
    size = len(body) if length is None else length
    return (
        f"{method} {path} HTTP/1.1\r\nHost: edge\r\n{auth}Connection: close\r\n"
        f"Content-Length: {size}\r\n\r\n"
    ).encode() + body


def status_of(answer: bytes) -> int:
    assert answer.startswith(b"HTTP/1.1 "), answer[:200]
    return int(answer[9:12])


def json_of(answer: bytes) -> object:
    head, _, body = answer.partition(b"\r\n\r\n")
    assert b"application/json" in head, head
    return json.loads(body)


class Flood:
    """``n`` strangers from ``source``, each doing ``how`` ("idle": nothing; "slow": a
    request's head a byte every 0.5 s; "no token": requests without the token, one of
    them announcing a 16 MiB body it never sends), each reopened as soon as it is found
    closed, until :meth:`stop`."""

    def __init__(self, port: int, source: str, n: int, how: str) -> None:
        self.port, self.source, self.n, self.how = port, source, n, how
        self.opened = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _open(self) -> tuple[socket.socket, int]:
        self.opened += 1
        sock = connect(self.port, self.source)
        sock.setblocking(False)
        if self.how == "no token":
            sock.send(request("GET", "/v1/monitors", token=False).replace(b"close", b"keep-alive"))
            sock.send(request("POST", "/v1/handoff/hold", token=False, length=16 << 20))
        return sock, 0

    def _run(self) -> None:
        head = b"GET /v1/monitors HTTP/1.1\r\nHost: edge\r\nX-Slow: " + b"s" * 10_000
        socks = [self._open() for _ in range(self.n)]
        while not self._stop.wait(0.02):
            for i, (sock, sent) in enumerate(socks):
                try:
                    if sock.recv(65536) == b"":
                        raise ConnectionResetError
                except BlockingIOError:
                    pass
                except OSError:
                    sock.close()
                    try:
                        socks[i] = self._open()
                    except OSError:
                        socks[i] = (socket.socket(), 0)  # refused: tried again next round
                    continue
                if self.how == "slow" and time.monotonic() * 2 % 1 < 0.05:
                    try:
                        sock.send(head[sent : sent + 1])
                        socks[i] = (sock, sent + 1)
                    except OSError:
                        pass
        for sock, _ in socks:
            sock.close()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(10)


def operator_calls(api: ControlApi, rounds: int) -> list[tuple[str, int]]:
    """What an operator and a kubelet do meanwhile: each round a new connection for
    ``/healthz`` and ``/metrics`` (no token), and the operator's calls on its kept-alive
    one; each answer must come before ``ANSWER_WITHIN`` (the client's timeout)."""
    operator = HandlerClient(f"127.0.0.1:{api.port}", TOKEN)
    got = []
    for _ in range(rounds):
        probe = HandlerClient(f"127.0.0.1:{api.port}", None)
        got.append(("healthz", probe.call("/healthz", method="GET", timeout=ANSWER_WITHIN)[0]))
        got.append(("metrics", probe.call("/metrics", method="GET", timeout=ANSWER_WITHIN)[0]))
        probe.close()
        got.append(
            ("monitors", operator.call("/v1/monitors", method="GET", timeout=ANSWER_WITHIN)[0])
        )
        got.append(("load", operator.call("/v1/load", method="GET", timeout=ANSWER_WITHIN)[0]))
        time.sleep(0.02)
    operator.close()
    return got


@pytest.mark.parametrize("how", ["idle", "slow", "no token"])
def test_strangers_from_one_address_reopened_as_closed_take_no_answer_away(
    api: ControlApi, how: str
) -> None:
    """The issue's probe: 32 sockets that send nothing (or a byte every so often, or
    requests without the token), reopened as they are closed, from one address. They hold
    no place: they are closed among themselves, and every call is answered."""
    flood = Flood(api.port or 0, "127.0.0.2", 32, how)
    try:
        time.sleep(0.3)  # all open
        got = operator_calls(api, 25)
    finally:
        flood.stop()
    assert got == [(call, 200) for call, _ in got], [g for g in got if g[1] != 200]
    assert len(got) == 100
    assert flood.opened > 32  # some were closed to let the others in, and came back
    pool = api.connections
    assert pool is not None and pool.closed_strangers > 0


def test_strangers_from_many_addresses_fill_the_pending_line_and_close_their_own(
    api: ControlApi,
) -> None:
    """Three times more strangers than ``pending``, from 24 addresses: the line is full,
    each newcomer closes one of the address holding most; the operator and the probes
    (their own address) are answered."""
    floods = [
        Flood(api.port or 0, f"127.0.0.{10 + i}", 3, ["idle", "slow"][i % 2]) for i in range(24)
    ]
    try:
        time.sleep(0.5)
        got = operator_calls(api, 15)
        strangers = on_loop(api, lambda: len(api.connections.strangers))  # type: ignore[union-attr]
    finally:
        for flood in floods:
            flood.stop()
    assert got == [(call, 200) for call, _ in got], [g for g in got if g[1] != 200]
    assert strangers == LIMITS.pending
    assert sum(flood.opened for flood in floods) > 72


def test_the_liveness_probe_is_answered_while_the_engine_holds_its_lock(
    api: ControlApi,
) -> None:
    """``/healthz`` reads no more than the monitors' places: an engine busy under its lock
    (a long batch) does not stall it, nor the API's other connections."""
    release = threading.Event()
    taken = threading.Event()

    def busy_engine() -> None:
        with api.engine.lock:
            taken.set()
            release.wait(30)

    holder = threading.Thread(target=busy_engine)
    holder.start()
    try:
        assert taken.wait(5)
        probe = HandlerClient(f"127.0.0.1:{api.port}", None)
        for _ in range(20):
            status, body = probe.call("/healthz", method="GET", timeout=ANSWER_WITHIN)
            assert status == 200 and json.loads(body)["activeMonitors"] == 1
        # an operator's call waits for the lock on a worker thread, not on the event loop
        waiting = threading.Thread(
            target=lambda: HandlerClient(f"127.0.0.1:{api.port}", TOKEN).monitors()
        )
        waiting.start()
        time.sleep(0.1)
        assert probe.call("/healthz", method="GET", timeout=ANSWER_WITHIN)[0] == 200
    finally:
        release.set()
        holder.join()
    waiting.join(10)
    assert not waiting.is_alive()


def test_places_are_held_by_connections_the_token_came_on(api: ControlApi) -> None:
    """Four connections each with a request with the token under way (a body on its way)
    hold the four places: a fifth such request gets 503 (JSON, Retry-After), while
    ``/healthz`` and requests without the token are answered. An idle admitted
    connection gives its place to a newcomer; and once the four are done, all is served."""
    port = api.port or 0
    busy = [connect(port) for _ in range(LIMITS.connections)]
    for sock in busy:  # a PUT whose body is still on its way: a request under way
        sock.sendall(request("PUT", "/v1/monitors/m", length=100))
    until(api, lambda pool: pool.open, 4)
    answer = exchange(connect(port), request("GET", "/v1/monitors"))
    assert status_of(answer) == 503 and b"Retry-After: 1" in answer
    assert "--api-max-connections" in json_of(answer)["errors"][0]["message"]  # type: ignore[index]
    assert status_of(exchange(connect(port), request("GET", "/healthz", token=False))) == 200
    assert status_of(exchange(connect(port), request("GET", "/v1/load", token=False))) == 401
    for sock in busy:
        sock.close()
    until(api, lambda pool: pool.open, 0)
    # kept-alive admitted connections, idle: a newcomer with the token takes one's place
    idle = [HandlerClient(f"127.0.0.1:{port}", TOKEN) for _ in range(LIMITS.connections)]
    for client in idle:
        assert client.monitors()[0]["name"] == "m"
    assert on_loop(api, lambda: api.connections.open) == 4  # type: ignore[union-attr]
    assert status_of(exchange(connect(port), request("GET", "/v1/monitors"))) == 200
    for client in idle:  # the one closed for it opens a new connection by itself
        assert client.monitors()[0]["name"] == "m"
        client.close()
    assert api.connections is not None and api.connections.closed_admitted >= 1


def test_a_full_line_closes_the_oldest_idle_stranger_of_the_address_holding_most(
    api: ControlApi,
) -> None:
    """The line full: an address with many strangers (one sending its head first), one
    with one. Each newcomer (from an address of its own) closes a stranger of the first
    address, those with no request under way oldest first; the one sending its head and
    the other address's are not closed."""
    port = api.port or 0
    slow = connect(port, "127.0.0.3")
    slow.sendall(b"GET /healthz HTTP/1.1\r\n")  # sending its head: closed after the idle ones
    idle = [connect(port, "127.0.0.3") for _ in range(LIMITS.pending - 2)]
    other = connect(port, "127.0.0.4")
    until(api, lambda pool: len(pool.strangers), LIMITS.pending)
    until(api, lambda pool: sum(c.busy for c in pool.strangers), 1)
    newcomers = [connect(port, f"127.0.0.{10 + i}") for i in range(LIMITS.pending - 2)]
    for sock in idle:  # each newcomer closed one of these, oldest first
        assert was_closed(sock)
    slow.sendall(b"Host: e\r\nConnection: close\r\n\r\n")
    assert status_of(exchange(slow, b"")) == 200
    assert status_of(exchange(other, request("GET", "/healthz", token=False))) == 200
    for sock in [*idle, *newcomers]:
        sock.close()


def test_over_tls_handshakes_are_strangers_too(tmp_path: Path) -> None:
    """Over TLS a connection is a stranger from its accept: callers that never finish (or
    never start) their handshake are closed to let others in, and a caller with the
    token is served over TLS meanwhile; when they are gone the pool holds nothing."""
    pki = make_pki(tmp_path)
    engine = Engine("edge", flush_after=1e9)
    api = ControlApi(engine, CollectorRegistry(), TOKEN, lambda: None, limits=LIMITS)
    api.start("127.0.0.1", 0, tls=server_context(str(pki.crt), str(pki.key)))
    port = api.port or 0
    silent = [connect(port, "127.0.0.5") for _ in range(LIMITS.pending)]
    half = [connect(port, "127.0.0.6") for _ in range(LIMITS.pending)]
    for sock in half:
        sock.sendall(b"\x16\x03\x01\x02\x00\x01")  # a ClientHello's first bytes, no more
    try:
        caller = HandlerClient(f"127.0.0.1:{port}", TOKEN, ClientTls(str(pki.ca)))
        for _ in range(10):
            assert caller.monitors() == []
        caller.close()
        assert api.connections is not None and api.connections.closed_strangers >= LIMITS.pending
        assert sum(was_closed(sock, 0.1) for sock in silent) >= LIMITS.pending // 2
    finally:
        for sock in [*silent, *half]:
            sock.close()
    until(api, lambda pool: (len(pool.strangers), pool.open), (0, 0))
    api.stop()
