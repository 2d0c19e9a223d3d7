"""The handler's HTTP API (aiohttp), served from its own thread.

Open: ``GET /healthz``, ``GET /metrics`` (Prometheus text). Everything under
``/v1`` needs ``Authorization: Bearer <token>`` and answers 401 otherwise:

* ``GET /v1/monitors``, ``GET /v1/monitors/{name}``: placement, state, buffers
* ``GET /v1/load``: the load report the orchestrator reads (CPU seconds, ingest lag,
  the ``--deadline`` makespans, per monitor: active, events, migration wanted, placement)
* ``POST /v1/monitors``: add the Monitor documents of the body (YAML or JSON); 409 if one exists
* ``PUT /v1/monitors/{name}``: add or replace that monitor
* ``DELETE /v1/monitors/{name}``: remove it
* ``POST /v1/monitors/{name}/activate`` and ``/deactivate``: run it here, or stop running it
* ``POST /v1/handoff/{step}`` with ``{"epoch": E, "monitors": [...], ...}``: one step of
  moving monitors between handlers (docs/protocol.md): ``hold``, ``release`` and
  ``commit`` on the sender, ``receive``, ``cut`` and ``adopt`` on the receiver, ``abort``
  on either

A body with bad documents changes nothing and gets 400 with every error located
in the body (``request:LINE:COL``).

What one client may take is bounded (:class:`Limits`, docs/handler.md "Limits on
input"): connections open at once (one more gets 503), the time to send a request
(head and body) and to read its answer, idle kept-alive connections, monitors defined.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
import ssl
import threading
import time
from collections.abc import Awaitable, Callable
from typing import Any, cast

from aiohttp import web
from aiohttp.http_exceptions import HttpProcessingError
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest

from edgerv.core.diagnostics import Diagnostic, InputError
from edgerv.core.documents import MonitorSpec, parse_monitors_text
from edgerv.core.handoff import HandoffError, bundle, decode_frames, encode, unbundle
from edgerv.core.monitor import CompiledMonitor
from edgerv.handler.engine import Engine
from edgerv.handler.limits import Limits
from edgerv.handler.payloads import (
    AdoptAnswer,
    CutAnswer,
    HandoffRequest,
    OutcomesAnswer,
    StepAnswer,
    WaitingAnswer,
)
from edgerv.handler.token import Token, current

log = logging.getLogger("edgerv.handler.api")
http_log = logging.getLogger("edgerv.handler.api.http")  # aiohttp's server logs here
Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]
MAX_BODY = 1 << 20  # Monitor documents
MAX_HANDOFF_BODY = 64 << 20  # a bundle of snapshots (deflated)
MAX_WAIT = 5.0  # seconds a release call may wait for events past the cut
RELEASE_POLL = 0.002  # how often it looks again meanwhile
MAX_HEADERS = 32  # a request's header lines (our clients send 5); each at most 8,190 bytes
REFUSED_LINGER = 1.0  # seconds a connection beyond the cap stays open to read its answer
DEADLINE = web.RequestKey("deadline", float)  # the request's body is in by then (loop time)


class _ClientFault(logging.Filter):
    """aiohttp logs a request it cannot parse at ERROR with a traceback: a client's fault
    (garbage, too many headers), so one line at DEBUG, not a flood a client can cause."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, HttpProcessingError):
            record.msg, record.args = "%s: %s", (record.getMessage(), exc.message)
            record.levelno, record.levelname = logging.DEBUG, "DEBUG"
            record.exc_info = record.exc_text = None
            return http_log.isEnabledFor(logging.DEBUG)  # the level was checked as ERROR
        return True


http_log.addFilter(_ClientFault())


class _Connection(asyncio.Protocol):
    """One client's connection, around aiohttp's protocol: it counts toward the cap and
    is closed when a request's head does not arrive within ``read_seconds`` of its first
    byte, or an answer waits that long for the client to read it. (The body's deadline is
    kept by ``ControlApi._limit``; aiohttp keeps the idle one.)"""

    def __init__(self, pool: _Connections, inner: asyncio.Protocol, counted: bool = False) -> None:
        self.pool = pool
        self.inner = inner
        self.transport: asyncio.Transport | None = None
        self.busy = False  # a request is under way: its bytes came, its answer is not out
        self.deadline = 0.0  # for the request under way (the loop's clock)
        self.reading: asyncio.TimerHandle | None = None  # its head is on its way
        self.writing: asyncio.TimerHandle | None = None  # an answer waits to be read
        self.counted = counted  # toward the cap: from the accept, or over TLS from the handshake
        self.refused = False  # over TLS: the cap was reached during its handshake

    def _soon(self) -> float:
        return asyncio.get_running_loop().time() + self.pool.limits.read_seconds

    def _cut_at(self, deadline: float, why: str) -> asyncio.TimerHandle:
        return asyncio.get_running_loop().call_at(deadline, self._cut, why)

    def _cut(self, why: str) -> None:
        log.info("closed a connection: %s within %g s", why, self.pool.limits.read_seconds)
        if self.transport is not None:
            self.transport.abort()

    def request_arrived(self) -> float:
        """The head is in (aiohttp parsed it): the deadline for its body. A request whose
        bytes came while the one before was answered gets the whole time for its body."""
        if self.reading is None:
            self.deadline = self._soon()
        else:
            self.reading.cancel()
            self.reading = None
        self.busy = True
        return self.deadline

    def answered(self) -> None:
        self.busy = False

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        if not self.counted:  # over TLS: the handshake is done
            if self.pool.open >= self.pool.limits.connections:
                self.refused = True
                _Refused(self.pool.refusal).connection_made(transport)
                return
            self.pool.open += 1
            self.counted = True
        self.inner.connection_made(transport)

    def data_received(self, data: bytes) -> None:
        if self.refused:
            return
        if not self.busy and self.reading is None:
            self.busy = True
            self.deadline = self._soon()
            self.reading = self._cut_at(self.deadline, "a request's head did not arrive")
        self.inner.data_received(data)

    def eof_received(self) -> bool | None:
        return None if self.refused else self.inner.eof_received()

    def pause_writing(self) -> None:  # the client does not read what it asked for
        if self.refused:
            return
        if self.writing is None:
            self.writing = self._cut_at(self._soon(), "an answer was not read")
        self.inner.pause_writing()

    def resume_writing(self) -> None:
        if self.refused:
            return
        if self.writing is not None:
            self.writing.cancel()
            self.writing = None
        self.inner.resume_writing()

    def connection_lost(self, exc: Exception | None) -> None:
        for timer in (self.reading, self.writing):
            if timer is not None:
                timer.cancel()
        self.transport = None
        self.pool.release(self)
        if not self.refused:
            self.inner.connection_lost(exc)


class _Refused(asyncio.Protocol):
    """A connection beyond the cap: answered 503 at once, closed once the client is done
    (or after ``REFUSED_LINGER``; closing before its request was read could reset the
    connection under the answer)."""

    def __init__(self, answer: bytes) -> None:
        self.answer = answer
        self.timer: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        transport.write(self.answer)
        try:
            transport.write_eof()
        except OSError:  # the client is gone already
            transport.abort()
            return
        self.timer = asyncio.get_running_loop().call_later(REFUSED_LINGER, transport.abort)

    def data_received(self, data: bytes) -> None:
        pass  # the request: it is not served

    def connection_lost(self, exc: Exception | None) -> None:
        if self.timer is not None:
            self.timer.cancel()


class _Connections:
    """The protocol factory the API listens with: aiohttp's, counted and capped."""

    def __init__(self, make: Callable[[], asyncio.Protocol], limits: Limits, tls: bool) -> None:
        self.make = make
        self.limits = limits
        # Over TLS a connection counts from the end of its handshake: asyncio never tells
        # the protocol of a handshake that failed (a plain-HTTP caller, a certificate the
        # caller refused, a handshake that timed out), so one counted at the accept would
        # never be given back. Handshakes under way are bounded by their timeout.
        self.tls = tls
        self.open = 0
        text = (
            f"this handler serves at most {limits.connections} connections at once "
            "(--api-max-connections): try again in a moment"
        )
        body = json.dumps({"errors": [{"message": text}]}).encode()
        self.refusal = (
            "HTTP/1.1 503 Service Unavailable\r\nContent-Type: application/json\r\n"
            f"Content-Length: {len(body)}\r\nRetry-After: 1\r\nConnection: close\r\n\r\n"
        ).encode() + body

    def __call__(self) -> asyncio.Protocol:
        if self.open >= self.limits.connections:  # counted here: accepts come in bursts
            return _Refused(self.refusal)
        if self.tls:  # counted once its handshake is done (see _Connection.connection_made)
            return _Connection(self, self.make())
        self.open += 1
        return _Connection(self, self.make(), counted=True)

    def release(self, connection: _Connection) -> None:
        if connection.counted:
            connection.counted = False
            self.open -= 1


def _active(request: web.Request) -> bool:
    """``?active=false``: define a monitor without running it here (it runs elsewhere)."""
    return request.query.get("active", "true").lower() not in ("false", "0", "no")


def _errors(diagnostics: list[Diagnostic], status: int = 400) -> web.Response:
    body = {
        "errors": [
            {
                "location": str(d.location),
                "message": d.message,
                "hint": d.hint,
                "severity": d.severity,
            }
            for d in diagnostics
        ]
    }
    return web.json_response(body, status=status)


def _message(status: int, text: str) -> web.Response:
    return web.json_response({"errors": [{"message": text}]}, status=status)


def _shown(value: Any) -> str:
    """A request's value as JSON writes it, shortened: never a Python repr."""
    try:
        text = json.dumps(value)
    except (TypeError, ValueError, RecursionError):
        text = f"a {type(value).__name__}"
    return text if len(text) <= 60 else text[:57] + "..."


def _why(exc: Exception) -> str:
    """What is wrong with a request, in the request's terms (never a Python repr)."""
    if isinstance(exc, KeyError):
        return f"missing field {_shown(exc.args[0] if exc.args else '?')}"
    return str(exc)[:200] or type(exc).__name__


def _integer(value: Any, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{what} must be an integer, not {_shown(value)}")
    return value


def _seconds(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not value >= 0:
        raise ValueError(f"{what} must be a number of seconds, not {_shown(value)}")
    return min(float(value), 1e9)  # inf: never


def _record(epoch: int, what: str, names: list[str]) -> None:
    """The handler's record of a handoff, one log line a step that changes who runs a
    monitor (hold, adopt, commit, abort): who moved what, and when, read back from logs."""
    log.info("handoff %d %s: %s", epoch, what, ", ".join(names))


def _handoff_body(body: Any) -> HandoffRequest:
    """A handoff step's JSON body, checked: an object with an integer ``epoch`` and a list
    of monitor names, a ``peer`` address if any (raises ValueError naming what is wrong:
    the answer is 400). The release's own fields are checked by :func:`_release_body`."""
    if not isinstance(body, dict):
        raise ValueError("the body must be a JSON object")
    names = body["monitors"]
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise ValueError("monitors must be a list of monitor names")
    _integer(body["epoch"], "epoch")
    if body.get("peer") is not None and not isinstance(body["peer"], str):
        raise ValueError("peer must be a handler's address")
    return cast(HandoffRequest, body)


def _release_body(
    request: HandoffRequest,
) -> tuple[dict[str, int], dict[str, list[str]], float, float]:
    """The release step's fields: a cut for every monitor, the topics H2 vouched for,
    the grace and how long to wait (seconds)."""
    cuts, quiet = request["cuts"], request.get("quiet") or {}
    if not isinstance(cuts, dict):
        raise ValueError("cuts must map each monitor to its cut")
    checked = {n: _integer(cuts[n], f"the cut of {n}") for n in request["monitors"]}
    if not isinstance(quiet, dict) or not all(
        isinstance(q, list) and all(isinstance(t, str) for t in q) for q in quiet.values()
    ):
        raise ValueError("quiet must map monitors to lists of topics")
    grace = _seconds(request.get("grace", 1.0), "grace")
    return checked, quiet, grace, _seconds(request.get("wait", 0), "wait")


class ControlApi:
    def __init__(
        self,
        engine: Engine,
        registry: CollectorRegistry,
        token: Token,
        on_change: Callable[[], None],
        on_routes: Callable[[], None] | None = None,
        limits: Limits | None = None,
    ) -> None:
        self.engine = engine
        self.limits = limits or Limits()
        self.registry = registry
        self.token = token
        self.on_change = on_change  # monitors defined or removed
        self.on_routes = on_routes or on_change  # only the topics to read changed
        self._loop: asyncio.AbstractEventLoop | None = None
        self._runner: web.AppRunner | None = None
        self.connections: _Connections | None = None  # counted toward the cap (its loop's)
        self._server: asyncio.Server | None = None
        self._thread: threading.Thread | None = None
        self.port: int | None = None

    # -- authentication --------------------------------------------------------------------

    @web.middleware
    async def _auth(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        if request.path.startswith("/v1"):
            given = request.headers.get("Authorization", "")
            scheme, _, credential = given.partition(" ")
            token = current(self.token)
            ok = token is None or (
                scheme.lower() == "bearer"
                and hmac.compare_digest(credential.strip().encode(), token.encode())
            )
            if not ok:
                return web.json_response(
                    {"errors": [{"message": "missing or wrong bearer token"}]},
                    status=401,
                    headers={"WWW-Authenticate": 'Bearer realm="edgerv"'},
                )
        return await handler(request)

    # -- limits ----------------------------------------------------------------------------

    @web.middleware
    async def _limit(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        """Outermost: the request's head is in; its body must be by the deadline."""
        transport = request.transport
        conn = transport.get_protocol() if transport is not None else None
        if not isinstance(conn, _Connection):  # served some other way (aiohttp's test client)
            return await handler(request)
        request[DEADLINE] = conn.request_arrived()
        try:
            return await handler(request)
        finally:
            conn.answered()

    @web.middleware
    async def _body(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        """After the token is checked: read the body of a call that takes one, by its
        deadline and within its size (the handlers then read it from memory)."""
        if not request.body_exists or request.match_info.http_exception is not None:
            return await handler(request)  # nothing to read, or a 404/405: left unread
        limit = MAX_HANDOFF_BODY if request.path.startswith("/v1/handoff/") else MAX_BODY
        if (request.content_length or 0) > limit:
            answer = _message(413, f"body larger than {limit} bytes")
            answer.force_close()  # not read: the connection cannot carry another request
            return answer
        try:
            async with asyncio.timeout_at(request.get(DEADLINE)):
                await request.read()  # chunked: bounded by the app's client_max_size
        except TimeoutError:
            answer = _message(
                408,
                f"the request's body did not arrive within {self.limits.read_seconds:g} s "
                "(--api-read-timeout); the connection is closed",
            )
            with contextlib.suppress(ConnectionError):  # said now, not after aiohttp has
                await answer.prepare(request)  # waited as long again for the rest
                await answer.write_eof()
            if request.transport is not None:
                request.transport.close()
            return answer
        return await handler(request)

    # -- routes ----------------------------------------------------------------------------

    async def healthz(self, request: web.Request) -> web.Response:
        active = sum(1 for m in self.engine.snapshot() if m["active"])
        return web.json_response(
            {"status": "ok", "handler": self.engine.name, "activeMonitors": active}
        )

    async def metrics(self, request: web.Request) -> web.Response:
        return web.Response(
            body=generate_latest(self.registry), headers={"Content-Type": CONTENT_TYPE_LATEST}
        )

    async def load(self, request: web.Request) -> web.Response:
        return web.json_response(self.engine.load())

    async def list_monitors(self, request: web.Request) -> web.Response:
        return web.json_response({"handler": self.engine.name, "monitors": self.engine.snapshot()})

    async def get_monitor(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        for m in self.engine.snapshot():
            if m["name"] == name:
                return web.json_response(m)
        return _message(404, f"no monitor '{name}'")

    async def _read_specs(
        self, request: web.Request
    ) -> tuple[list[CompiledMonitor], web.Response | None]:
        raw = await request.read()  # read by ``_body``, within the app's client_max_size
        if len(raw) > MAX_BODY:
            return [], _message(413, f"body larger than {MAX_BODY} bytes")
        try:
            text = raw.decode()
        except UnicodeDecodeError:
            return [], _message(400, "the body is not UTF-8 text")
        specs, diagnostics = parse_monitors_text("request", text)
        if diagnostics:
            return [], _errors(diagnostics)
        loop = asyncio.get_running_loop()
        compiled, errors = await loop.run_in_executor(None, self._compile_all, specs)
        if errors:
            return [], _errors(errors)
        return compiled, None

    def _compile_all(
        self, specs: list[MonitorSpec]
    ) -> tuple[list[CompiledMonitor], list[Diagnostic]]:
        compiled, errors = [], []
        for spec in specs:
            try:
                compiled.append(self.engine.compile(spec))
            except InputError as exc:
                errors += exc.errors
        return compiled, errors

    async def post_monitors(self, request: web.Request) -> web.Response:
        compiled, problem = await self._read_specs(request)
        if problem is not None:
            return problem
        existing = self.engine.slots.keys()
        clash = [c.name for c in compiled if c.name in existing]
        if clash:
            return _message(
                409, f"monitor '{clash[0]}' exists; PUT /v1/monitors/{clash[0]} replaces it"
            )
        if len(existing) + len(compiled) > self.limits.monitors:
            return _message(403, self.limits.full(len(existing)))
        active = _active(request)
        for c in compiled:
            self.engine.put(c, active=active)
        self.on_change()
        log.info("added %s%s", ", ".join(c.name for c in compiled), "" if active else " (idle)")
        return web.json_response({"created": [c.name for c in compiled]}, status=201)

    async def put_monitor(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        compiled, problem = await self._read_specs(request)
        if problem is not None:
            return problem
        if [c.name for c in compiled] != [name]:
            return _message(400, f"the body must hold exactly one Monitor named '{name}'")
        defined = len(self.engine.slots)
        if name not in self.engine.slots and defined >= self.limits.monitors:
            return _message(403, self.limits.full(defined))
        try:
            created = self.engine.put(compiled[0], active=_active(request))
        except HandoffError as exc:
            return _message(409, str(exc))
        self.on_change()
        log.info("%s %s", "added" if created else "replaced", name)
        return web.json_response({"name": name, "created": created}, status=201 if created else 200)

    async def delete_monitor(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        if not self.engine.remove(name):
            return _message(404, f"no monitor '{name}'")
        self.on_change()
        log.info("removed %s", name)
        return web.json_response({"deleted": name})

    async def _set_active(self, request: web.Request, active: bool) -> web.Response:
        name = request.match_info["name"]
        try:
            self.engine.set_active(name, active)
        except KeyError:
            return _message(404, f"no monitor '{name}'")
        except HandoffError as exc:
            return _message(409, str(exc))
        self.on_change()
        return web.json_response({"name": name, "active": active})

    async def handoff(self, request: web.Request) -> web.StreamResponse:
        """One step of a handoff, for a batch of monitors under one epoch (docs/protocol.md).

        All or nothing: when a step fails for one monitor, ``hold`` and ``receive``
        undo it for the others and the answer is 409 naming the monitor.
        """
        step = request.match_info["step"]
        e = self.engine
        try:
            if step == "adopt":
                epoch = int(request.query["epoch"])
                snaps = decode_frames(unbundle(await request.read()))  # outside the engine's lock
                names = e.adopt_many(epoch, snaps)  # all or nothing
                self.on_routes()
                _record(epoch, "adopted", names)
                return web.json_response(AdoptAnswer(active=names))
            body = _handoff_body(await request.json())
            epoch, names = body["epoch"], body["monitors"]
            if step in ("hold", "receive"):
                done: list[str] = []
                peer = body.get("peer")
                with e.lock:
                    try:
                        for name in names:
                            if step == "hold":
                                e.hold(name, epoch, peer=peer)
                            else:
                                e.receive(name, epoch)
                            done.append(name)
                    except HandoffError as exc:
                        for name in done:
                            e.abort(name, epoch)
                        raise HandoffError(f"{name}: {exc}") from None
                self.on_routes()
                if step == "hold":
                    _record(epoch, f"held for {peer or 'a receiver'}", done)
                return web.json_response(StepAnswer(monitors=done))
            if step == "cut":
                with e.lock:
                    cuts = {n: e.cut(n, epoch) for n in names}
                    quiet = {n: list(e.slots[n].quiet) for n in names if cuts[n] is not None}
                return web.json_response(CutAnswer(cuts=cuts, quiet=quiet))
            if step == "release":
                at, vouched, grace, wait = _release_body(body)
                # up to ``wait`` seconds for events past the cut here: no round trip a try
                until = time.monotonic() + min(MAX_WAIT, wait)
                while True:
                    with e.lock:
                        released = {
                            n: e.release(n, epoch, at[n], grace, quiet=vouched.get(n, ()))
                            for n in names
                        }
                    waiting = [n for n, data in released.items() if data is None]
                    if not waiting or time.monotonic() >= until:
                        break
                    await asyncio.sleep(RELEASE_POLL)
                if waiting:
                    return web.json_response(WaitingAnswer(waiting=waiting), status=202)
                frames = (encode(snap) for snap in released.values() if snap is not None)
                return web.Response(body=bundle(frames), content_type="application/octet-stream")
            if step in ("commit", "abort"):
                act = e.commit if step == "commit" else e.abort
                with e.lock:
                    outcomes = {n: act(n, epoch) for n in names}
                self.on_routes()
                for outcome in sorted(set(outcomes.values())):
                    said = outcome if step == "commit" else f"aborted ({outcome})"
                    _record(epoch, said, [n for n in names if outcomes[n] == outcome])
                return web.json_response(OutcomesAnswer(outcomes=outcomes))
        except HandoffError as exc:
            return _message(409, str(exc))
        except (KeyError, ValueError, TypeError) as exc:
            return _message(400, f"bad handoff request: {_why(exc)}")
        except RecursionError:
            return _message(400, "bad handoff request: nested too deep")
        return _message(404, f"no handoff step '{step}'")

    async def activate(self, request: web.Request) -> web.Response:
        return await self._set_active(request, True)

    async def deactivate(self, request: web.Request) -> web.Response:
        return await self._set_active(request, False)

    # -- serving ---------------------------------------------------------------------------

    def app(self) -> web.Application:
        app = web.Application(
            middlewares=[self._limit, self._auth, self._body], client_max_size=MAX_HANDOFF_BODY
        )
        app.add_routes(
            [
                web.get("/healthz", self.healthz),
                web.get("/metrics", self.metrics),
                web.get("/v1/load", self.load),
                web.get("/v1/monitors", self.list_monitors),
                web.post("/v1/monitors", self.post_monitors),
                web.get("/v1/monitors/{name}", self.get_monitor),
                web.put("/v1/monitors/{name}", self.put_monitor),
                web.delete("/v1/monitors/{name}", self.delete_monitor),
                web.post("/v1/monitors/{name}/activate", self.activate),
                web.post("/v1/monitors/{name}/deactivate", self.deactivate),
                web.post("/v1/handoff/{step}", self.handoff),
            ]
        )
        return app

    def start(self, host: str, port: int, tls: ssl.SSLContext | None = None) -> None:
        """Serve in a thread, HTTPS with ``tls`` (:func:`edgerv.handler.tls.server_context`);
        returns once listening (``self.port`` is the bound port)."""
        started = threading.Event()
        failure: list[BaseException] = []

        def serve() -> None:
            loop = asyncio.new_event_loop()
            self._loop = loop
            try:
                self._runner = web.AppRunner(
                    self.app(),
                    access_log=None,
                    keepalive_timeout=self.limits.idle_seconds,
                    lingering_time=self.limits.read_seconds,  # reading an unwanted body
                    max_headers=MAX_HEADERS,
                    logger=http_log,
                )
                loop.run_until_complete(self._runner.setup())
                assert self._runner.server is not None
                connections = _Connections(self._runner.server, self.limits, tls is not None)
                self.connections = connections
                self._server = loop.run_until_complete(
                    loop.create_server(  # in place of a TCPSite
                        connections,
                        host,
                        port,
                        ssl=tls,
                        # a caller that connects and never completes the handshake
                        ssl_handshake_timeout=self.limits.read_seconds if tls else None,
                    )
                )
                self.port = self._server.sockets[0].getsockname()[1]  # when 0 was asked for
            except BaseException as exc:
                failure.append(exc)
                started.set()
                return
            started.set()
            loop.run_forever()
            self._server.close()
            loop.run_until_complete(self._runner.cleanup())
            loop.close()

        self._thread = threading.Thread(target=serve, name="edgerv-api", daemon=True)
        self._thread.start()
        started.wait()
        if failure:
            raise failure[0]

    def stop(self) -> None:
        """Stop serving (once; later calls do nothing)."""
        loop, self._loop = self._loop, None
        if loop is not None:
            loop.call_soon_threadsafe(loop.stop)
        if self._thread is not None:
            self._thread.join(timeout=10)
