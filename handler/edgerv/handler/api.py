"""The handler's HTTP API (aiohttp), served from its own thread.

Open: ``GET /healthz``, ``GET /metrics`` (Prometheus text). Everything under
``/v1`` needs ``Authorization: Bearer <token>`` and answers 401 otherwise:

* ``GET /v1/monitors``, ``GET /v1/monitors/{name}``: placement, state, buffers
* ``GET /v1/load``: the load report the orchestrator reads (CPU seconds, ingest lag,
  the ``--deadline`` makespans, per monitor: active, events, migration wanted, placement)
* ``GET /v1/deadline?after=N&wait=S``: the ``--deadline`` makespans' reading, answered
  once more than N have missed the deadline since the handler started, or after S
  seconds (at most MAX_DEADLINE_WAIT): an orchestrator's wait between rounds, woken by
  the first miss (404 without ``--deadline``)
* ``POST /v1/monitors``: add the Monitor documents of the body (YAML or JSON); 409 if one exists
* ``PUT /v1/monitors/{name}``: add or replace that monitor
* ``DELETE /v1/monitors/{name}``: remove it
* ``POST /v1/monitors/{name}/activate`` and ``/deactivate``: run it here, or stop running it
* ``POST /v1/handoff/{step}`` with ``{"epoch": E, "monitors": [...], ...}``: one step of
  moving monitors between handlers (docs/protocol.md): ``hold``, ``release`` and
  ``commit`` on the sender, ``receive``, ``cut`` and ``adopt`` on the receiver, ``abort``
  on either

A body with bad documents changes nothing and gets 400 with every error located
in the body (``request:LINE:COL``). Every answer's body is JSON (``/metrics``: text).

What one client may take is bounded (:class:`Limits`, docs/handler.md "Limits on
input"). A connection costs a file descriptor until a request with the token comes on it
(:mod:`edgerv.handler.admission`); the open calls need no place and do not wait for the
engine's lock. Whatever can be checked before a request's body is read is checked first,
in this order: the token, a place, the call, the declared size and encoding (none is
taken), the handoff's step and (``adopt``) its epoch and that a handoff is receiving
under it. A body is read by its deadline, at most its call's limit, and within what all
bodies may hold at once (``Limits.bodies``); a snapshot bundle is checked before it is
inflated and decoded, one at a time, off the event loop
(:func:`edgerv.core.handoff.read_bundle`). The engine's lock is taken on worker threads.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
import math
import re
import resource
import ssl
import threading
import time
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from http import HTTPStatus
from typing import Any, TypeVar, cast

import msgspec
from aiohttp import web
from aiohttp.http_exceptions import HttpProcessingError
from aiohttp.web_protocol import RequestHandler, RequestPayloadError
from aiohttp.web_request import BaseRequest
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest

from edgerv.control.token import Token, current
from edgerv.control.wire import (
    AdoptAnswer,
    CutAnswer,
    HandoffRequest,
    OutcomesAnswer,
    StepAnswer,
    WaitingAnswer,
)
from edgerv.core.diagnostics import Diagnostic, InputError
from edgerv.core.documents import MonitorSpec, parse_monitors_text
from edgerv.core.handoff import (
    BundleTooLarge,
    HandoffError,
    Snapshot,
    bundle,
    bundled_size,
    encode,
    read_bundle,
)
from edgerv.core.monitor import CompiledMonitor
from edgerv.handler.admission import Connection, Pool
from edgerv.handler.engine import Engine
from edgerv.handler.handoff_state import HandoffState
from edgerv.handler.limits import Limits
from edgerv.handler.reading import Definitions, load_report, monitor_reports
from edgerv.handler.revisions import Revisions

log = logging.getLogger("edgerv.handler.api")
http_log = logging.getLogger("edgerv.handler.api.http")  # aiohttp's server logs here
Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]
T = TypeVar("T")
MAX_BODY = 1 << 20  # Monitor documents, and a call that takes no body
MAX_STEP_BODY = 8 << 20  # a handoff step's JSON (10,000 monitors' names, cuts, topics)
MAX_HANDOFF_BODY = 64 << 20  # a bundle of snapshots (deflated)
MAX_EPOCH = 2**63 - 1  # a handoff's epoch: the drivers' clock, 64-bit nanoseconds
MAX_WAIT = 5.0  # seconds a release call may wait for events past the cut
MAX_DEADLINE_WAIT = 30.0  # seconds GET /v1/deadline may wait for a missed deadline
RELEASE_POLL = 0.005  # the least time between two looks while a release waits
RELEASE_POLL_MAX = 0.01  # and the most
MAX_HEADERS = 32  # a request's header lines (our clients send 5); each at most 8,190 bytes
READ_STEP = 1 << 16  # a body is read this much at a time
OPEN = frozenset({"/healthz", "/metrics"})  # no token, no place under the cap
STEPS = ("hold", "receive", "cut", "release", "commit", "abort", "adopt")
RECEIVING = HandoffState.RECEIVING
DEADLINE = web.RequestKey("deadline", float)  # the request's body is in by then (loop time)
BODY = web.RequestKey("body", bytearray)  # read by the gate, before the call's handler
EPOCH = web.RequestKey("epoch", int)  # adopt: the epoch of its query, checked
_REPR = re.compile(r":?\s*(?:bytearray\(|b'|b\")")


class _ClientFault(logging.Filter):
    """aiohttp logs a request it cannot parse at ERROR with a traceback: a client's fault
    (garbage, too many headers, a body it cannot decode while it discards it), so one line
    at DEBUG, not a flood a client can cause."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, HttpProcessingError | RequestPayloadError):
            said = getattr(exc, "message", None) or str(exc).strip()
            record.msg, record.args = "%s: %s", (record.getMessage(), said)
            record.levelno, record.levelname = logging.DEBUG, "DEBUG"
            record.exc_info = record.exc_text = None
            return http_log.isEnabledFor(logging.DEBUG)  # the level was checked as ERROR
        return True


http_log.addFilter(_ClientFault())


class _Protocol(RequestHandler):
    """aiohttp's protocol, with the answers it makes itself (a request it cannot parse: a
    line too long, too many headers, not HTTP) in JSON like every other."""

    def __init__(self, server: web.Server, loop: asyncio.AbstractEventLoop) -> None:
        super().__init__(server, loop=loop, **server._kwargs)

    def handle_error(
        self,
        request: BaseRequest,
        status: int = 500,
        exc: BaseException | None = None,
        message: str | None = None,
    ) -> web.StreamResponse:
        super().handle_error(request, status, exc, message)  # logs it (at debug: _ClientFault)
        said = exc.message if isinstance(exc, HttpProcessingError) else None
        text = (said or HTTPStatus(status).phrase).splitlines()[0]
        text = _REPR.split(text)[0].rstrip(":")[:200]  # (what aiohttp quotes: a Python repr)
        what = "a request this handler cannot read" if status < 500 else "an internal error"
        answer = _message(status, f"{what}: {text}")
        answer.force_close()
        return answer


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


def _integer(value: Any, what: str, low: int = -(2**63), high: int = 2**63 - 1) -> int:
    """A whole number within ``low`` and ``high`` (by default, 64-bit nanoseconds)."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{what} must be an integer, not {_shown(value)}")
    if not low <= value <= high:
        raise ValueError(f"{what} must be from {low} to {high}, not {_shown(value)}")
    return value


def _epoch(value: Any) -> int:
    """A handoff's epoch: what the drivers take from their clock (``edgerv migrate``: the
    time in nanoseconds), so a whole number from 1 to 2^63 - 1. (An epoch of 10^29 would
    fence the monitor against every later handoff.)"""
    return _integer(value, "epoch", 1, MAX_EPOCH)


def _query_epoch(text: str | None) -> int:
    """``adopt``'s ``?epoch=``: decimal digits only (no sign, spaces or underscores)."""
    if text is None:
        raise ValueError('missing field "epoch" (?epoch= in the address)')
    if not text.isascii() or not text.isdigit() or len(text) > 19:
        raise ValueError(f"epoch must be from 1 to {MAX_EPOCH}, not {_shown(text)}")
    return _epoch(int(text))


def _query_count(text: str | None, what: str) -> int | None:
    """An optional count in the query (a whole number, 0 or more)."""
    if text is None:
        return None
    if not (text.isascii() and text.isdigit()) or len(text) > 19 or int(text) >= 2**63:
        raise ValueError(f"{what} must be a whole number, 0 or more, not {_shown(text)}")
    return int(text)


def _query_seconds(text: str | None, what: str, most: float) -> float:
    """Optional seconds in the query: 0 to ``most`` (0 when absent)."""
    if text is None:
        return 0.0
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0 <= value <= most:  # (NaN too)
        raise ValueError(f"{what} must be seconds from 0 to {most:g}, not {_shown(text)}")
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
    _epoch(body["epoch"])
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
        self.connections: Pool | None = None  # who holds what (its loop's)
        self._server: asyncio.Server | None = None
        self._thread: threading.Thread | None = None
        self.port: int | None = None
        # the engine's lock is taken here, off the event loop: the open calls are answered
        # while the engine holds it; /metrics has a thread of its own
        self._work = ThreadPoolExecutor(2, thread_name_prefix="edgerv-api")
        self._scraper = ThreadPoolExecutor(1, thread_name_prefix="edgerv-metrics")
        self._scrape: asyncio.Future[bytes] | None = None  # shared by concurrent scrapes
        self._bodies = 0  # bytes of request bodies held now (Limits.bodies)
        self._decoding: asyncio.Lock | None = None  # one bundle decoded at a time
        self._missed: asyncio.Event | None = None  # set by the deadline's next miss
        # what each listing sent, for readers that ask only what changed (?since=)
        self._listed = Revisions()
        self._loaded = Revisions()
        self._definitions = Definitions()  # the load report's parts made once a definition

    async def _locked(self, call: Callable[..., T], *args: Any) -> T:
        """``call(*args)`` on a worker thread (it takes the engine's lock)."""
        return await asyncio.get_running_loop().run_in_executor(self._work, call, *args)

    # -- admission: the token, a place, the call, its body ----------------------------------

    def _authorized(self, request: web.Request) -> bool:
        given = request.headers.get("Authorization", "")
        scheme, _, credential = given.partition(" ")
        token = current(self.token)
        return token is None or (
            scheme.lower() == "bearer"
            # (a header's bytes that are not UTF-8 come as surrogates: compared as sent)
            and hmac.compare_digest(
                credential.strip().encode("utf-8", "surrogateescape"), token.encode()
            )
        )

    @web.middleware
    async def _gate(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        """The only middleware: what needs no token is served at once; the rest shows the
        token, takes a place, is checked as far as its head allows, then has its body
        read (``request[BODY]``) before its handler runs."""
        transport = request.transport
        conn = transport.get_protocol() if transport is not None else None
        if not isinstance(conn, Connection):  # served some other way (aiohttp's test client)
            conn = None
        else:
            request[DEADLINE] = conn.request_arrived()
        held = [0]  # bytes of the bodies' budget this request holds
        try:
            if request.path in OPEN or not request.path.startswith("/v1"):
                return await self._answer(request, handler)  # no token, no place, no body
            if not self._authorized(request):
                return web.json_response(
                    {"errors": [{"message": "missing or wrong bearer token"}]},
                    status=401,
                    headers={"WWW-Authenticate": 'Bearer realm="edgerv"'},
                )
            if conn is not None and self.connections and not self.connections.admit(conn):
                answer = _message(
                    503,
                    f"this handler serves at most {self.limits.connections} clients' "
                    "connections at once, each busy now (--api-max-connections): try again "
                    "in a moment",
                )
                answer.headers["Retry-After"] = "1"
                answer.force_close()
                return answer
            if request.match_info.http_exception is not None:
                return await self._answer(request, handler)  # 404, 405: its body left unread
            refused = self._before_body(request)
            if refused is None and request.body_exists:
                refused = await self._read_body(request, held)
            if refused is not None:
                return refused
            return await self._answer(request, handler)
        finally:
            self._bodies -= held[0]
            if conn is not None:
                conn.answered()

    @staticmethod
    async def _answer(request: web.Request, handler: Handler) -> web.StreamResponse:
        """The handler's answer; aiohttp's own 4xx (no such call, a method not allowed) as
        JSON like every other."""
        try:
            return await handler(request)
        except web.HTTPException as exc:
            if exc.status < 400:
                raise
            answer = _message(exc.status, exc.reason)
            for name in ("Allow", "Retry-After"):
                if name in exc.headers:
                    answer.headers[name] = exc.headers[name]
            return answer

    def _body_limit(self, request: web.Request) -> int:
        """The most a call's body may be: its own limit, within what all may hold at once."""
        if request.path == "/v1/handoff/adopt":
            limit = MAX_HANDOFF_BODY
        else:
            limit = MAX_STEP_BODY if request.path.startswith("/v1/handoff/") else MAX_BODY
        return min(limit, self.limits.bodies)

    def _before_body(self, request: web.Request) -> web.Response | None:
        """What the head alone tells: the declared size against the call's limit, a
        handoff's step, and for ``adopt`` its epoch and that a handoff receives under it."""
        limit = self._body_limit(request)
        if (request.content_length or 0) > limit:
            return _too_large(f"body larger than {limit} bytes")
        if request.headers.get("Content-Encoding", "identity").lower() not in ("identity", ""):
            answer = _message(415, "a body is taken as it is sent: no Content-Encoding")
            answer.force_close()
            return answer
        if not request.path.startswith("/v1/handoff/"):
            return None
        step = request.match_info.get("step", "")
        if step not in STEPS:
            return _message(404, f"no handoff step {_shown(step)}; the steps: {', '.join(STEPS)}")
        if step != "adopt":
            return None
        try:
            epoch = request[EPOCH] = _query_epoch(request.query.get("epoch"))
        except ValueError as exc:
            return _message(400, f"bad handoff request: {exc}")
        if not self._adopts(epoch):
            return _message(
                409,
                f"no monitor is being received here under epoch {epoch} (nor was adopted "
                "under it): a bundle is taken after its receive step",
            )
        return None

    def _adopts(self, epoch: int) -> bool:
        """Some monitor here takes a bundle of ``epoch``: it is being received under it, or
        it was adopted under it (a repeated adoption: its answer was lost). Read without
        the engine's lock (a glance: the adoption itself checks under it)."""
        for slot in list(self.engine.slots.values()):
            if slot.epoch == epoch and (
                slot.handoff == RECEIVING or (slot.handoff is None and slot.runtime is not None)
            ):
                return True
        return False

    async def _read_body(self, request: web.Request, held: list[int]) -> web.Response | None:
        """Read the body into ``request[BODY]``: by the request's deadline, at most its
        call's limit (chunked or not: never a byte past it), within what all bodies may
        hold at once. An answer when it is refused."""
        limit = self._body_limit(request)
        declared = request.content_length
        if not self._hold(held, declared or 0):
            return self._busy()
        body = bytearray()
        first = request.path == "/v1/handoff/adopt"  # a bundle: its size, in its first bytes
        try:
            async with asyncio.timeout_at(request.get(DEADLINE)):
                while len(body) <= limit:
                    chunk = await request.content.read(min(READ_STEP, limit + 1 - len(body)))
                    if not chunk:
                        break
                    if declared is None and not self._hold(held, len(body) + len(chunk)):
                        return self._busy()
                    body += chunk
                    if first and len(body) >= 8:
                        first = False
                        if refused := self._bundle_head(body):
                            return refused
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
        except ConnectionError:  # the client is gone: the answer goes nowhere
            answer = _message(400, "the connection was lost before the body came")
            answer.force_close()
            return answer
        except (HttpProcessingError, RequestPayloadError, ValueError) as exc:  # a bad chunk
            answer = _message(400, f"the request's body cannot be read: {_why(exc)}")
            answer.force_close()
            return answer
        if len(body) > limit:
            return _too_large(f"body larger than {limit} bytes")
        request[BODY] = body
        return None

    def _hold(self, held: list[int], size: int) -> bool:
        """Hold ``size`` bytes of the bodies' budget for this request (it held ``held[0]``)."""
        more = size - held[0]
        if more > 0 and self._bodies + more > self.limits.bodies:
            return False
        if more > 0:
            self._bodies += more
            held[0] = size
        return True

    def _busy(self) -> web.Response:
        answer = _message(
            503,
            f"this handler holds {self._bodies} bytes of request bodies now, and no more "
            f"than {self.limits.bodies} at once: try again in a moment",
        )
        answer.headers["Retry-After"] = "1"
        answer.force_close()
        return answer

    def _bundle_head(self, body: bytearray) -> web.Response | None:
        """A bundle's first bytes: that it is one, and the size it announces inflated."""
        try:
            size = bundled_size(body)
        except HandoffError as exc:
            answer = _message(409, str(exc))
            answer.force_close()  # the rest is not read
            return answer
        if size > self.limits.bundle:
            return _too_large(
                f"a bundle of {size} bytes inflated is over the limit of {self.limits.bundle}"
            )
        return None

    # -- routes ----------------------------------------------------------------------------

    async def healthz(self, request: web.Request) -> web.Response:
        # without the engine's lock: the liveness probe is answered whatever the engine does
        active = sum(1 for slot in list(self.engine.slots.values()) if slot.active)
        return web.json_response(
            {"status": "ok", "handler": self.engine.name, "activeMonitors": active}
        )

    async def metrics(self, request: web.Request) -> web.Response:
        """One collection at a time, on its own thread, shared by the scrapes that come
        while it runs."""
        scrape = self._scrape
        if scrape is None or scrape.done():
            loop = asyncio.get_running_loop()
            scrape = self._scrape = loop.run_in_executor(
                self._scraper, generate_latest, self.registry
            )
        body = await asyncio.shield(scrape)
        return web.Response(body=body, headers={"Content-Type": CONTENT_TYPE_LATEST})

    async def load(self, request: web.Request) -> web.Response:
        # made and encoded off the event loop: it is polled twice a second, for every
        # monitor defined here (msgspec's encoder: 0.12 ms for 450 monitors, json.dumps 1.1)
        since = request.query.get("since")
        body = await self._locked(lambda: msgspec.json.encode(self._load(since)))
        return web.Response(body=body, content_type="application/json")

    def _load(self, since: str | None) -> dict[str, Any]:
        """The load report; given a cursor, its monitors only those whose entry changed
        since, and those removed (docs/protocol.md, "Reading only what changed")."""
        report = cast(dict[str, Any], load_report(self.engine, self._definitions))
        monitors, removed, cursor = self._loaded.read(report["monitors"], since)
        report["monitors"], report["cursor"] = monitors, cursor
        if removed is not None:
            report["since"], report["removed"] = since, removed
        return report

    async def deadline(self, request: web.Request) -> web.Response:
        window = self.engine.deadline
        if window is None:
            return _message(
                404,
                "this handler measures no deadline: it was started without "
                "--deadline TOPIC=DURATION",
            )
        try:
            after = _query_count(request.query.get("after"), "after")
            wait = _query_seconds(request.query.get("wait"), "wait", MAX_DEADLINE_WAIT)
        except ValueError as exc:
            return _message(400, str(exc))
        if after is not None and wait > 0 and self._missed is not None:
            missed = self._missed  # (set by the next miss: read before the count)
            if window.misses_total <= after:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(missed.wait(), wait)
        return web.json_response(window.report(int(self.engine.clock.monotonic() * 1e9)))

    def _miss(self) -> None:
        """On the event loop, after a makespan missed the deadline: wake who waits."""
        if self._missed is not None:
            self._missed.set()
        self._missed = asyncio.Event()

    async def list_monitors(self, request: web.Request) -> web.Response:
        since = request.query.get("since")
        body = await self._locked(lambda: msgspec.json.encode(self._listing(since)))
        return web.Response(body=body, content_type="application/json")

    def _listing(self, since: str | None) -> dict[str, Any]:
        """Every monitor's report; given a cursor, only those whose report changed since,
        and the names of those removed (docs/protocol.md, "Reading only what changed")."""
        reports = {m["name"]: m for m in monitor_reports(self.engine)}
        monitors, removed, cursor = self._listed.read(reports, since)
        listing: dict[str, Any] = {
            "handler": self.engine.name,
            "monitors": list(monitors.values()),
            "cursor": cursor,
        }
        if removed is not None:
            listing["since"], listing["removed"] = since, removed
        return listing

    async def get_monitor(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        for m in await self._locked(monitor_reports, self.engine):
            if m["name"] == name:
                return web.json_response(m)
        return _message(404, f"no monitor '{name}'")

    async def _read_specs(
        self, request: web.Request
    ) -> tuple[list[CompiledMonitor], web.Response | None]:
        raw = request.get(BODY, bytearray())  # read by the gate, within MAX_BODY
        try:
            text = raw.decode()
        except UnicodeDecodeError:
            return [], _message(400, "the body is not UTF-8 text")
        del raw
        loop = asyncio.get_running_loop()  # parsed and compiled off the event loop
        compiled, errors = await loop.run_in_executor(None, self._compile_all, text)
        if errors:
            return [], _errors(errors)
        return compiled, None

    def _compile_all(self, text: str) -> tuple[list[CompiledMonitor], list[Diagnostic]]:
        specs: list[MonitorSpec]
        specs, diagnostics = parse_monitors_text("request", text)
        if diagnostics:
            return [], diagnostics
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
        active = _active(request)
        e = self.engine

        def define() -> web.Response | None:  # checked and done at once, under the lock
            with e.lock:
                existing = e.slots.keys()
                clash = [c.name for c in compiled if c.name in existing]
                if clash:
                    return _message(
                        409, f"monitor '{clash[0]}' exists; PUT /v1/monitors/{clash[0]} replaces it"
                    )
                if len(existing) + len(compiled) > self.limits.monitors:
                    return _message(403, self.limits.full(len(existing)))
                try:
                    e.refuse_over_budget(compiled)  # all or nothing
                    for c in compiled:
                        e.put(c, active=active)
                except InputError as exc:
                    return _errors(exc.errors, 403)
            return None

        if refused := await self._locked(define):
            return refused
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
        active = _active(request)
        e = self.engine

        def define() -> bool | web.Response:  # checked and done at once, under the lock
            with e.lock:
                defined = len(e.slots)
                if name not in e.slots and defined >= self.limits.monitors:
                    return _message(403, self.limits.full(defined))
                try:
                    return e.put(compiled[0], active=active)
                except InputError as exc:  # over the memory budget
                    return _errors(exc.errors, 403)

        try:
            created = await self._locked(define)
        except HandoffError as exc:
            return _message(409, str(exc))
        if isinstance(created, web.Response):
            return created
        self.on_change()
        log.info("%s %s", "added" if created else "replaced", name)
        return web.json_response({"name": name, "created": created}, status=201 if created else 200)

    async def delete_monitor(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        if not await self._locked(self.engine.remove, name):
            return _message(404, f"no monitor '{name}'")
        self.on_change()
        log.info("removed %s", name)
        return web.json_response({"deleted": name})

    async def _set_active(self, request: web.Request, active: bool) -> web.Response:
        name = request.match_info["name"]
        try:
            await self._locked(self.engine.set_active, name, active)
        except KeyError:
            return _message(404, f"no monitor '{name}'")
        except HandoffError as exc:
            return _message(409, str(exc))
        self.on_change()
        return web.json_response({"name": name, "active": active})

    async def handoff(self, request: web.Request) -> web.StreamResponse:
        """One step of a handoff, for a batch of monitors under one epoch (docs/protocol.md).

        All or nothing: when a step fails for one monitor, ``hold`` and ``receive``
        undo it for the others and the answer is 409 naming the monitor. (The gate
        checked the step, and ``adopt``'s epoch and that something receives under it.)
        """
        step = request.match_info["step"]
        try:
            if step == "adopt":
                return await self._adopt(request)
            body = _handoff_body(json.loads(request.get(BODY) or b"null"))
            epoch, names = body["epoch"], body["monitors"]
            if step in ("hold", "receive"):
                peer = body.get("peer")
                done = await self._locked(self._take, step, epoch, names, peer)
                self.on_routes()
                if step == "hold":
                    _record(epoch, f"held for {peer or 'a receiver'}", done)
                return web.json_response(StepAnswer(monitors=done))
            if step == "cut":
                cuts, quiet = await self._locked(self._cut, epoch, names)
                return web.json_response(CutAnswer(cuts=cuts, quiet=quiet))
            if step == "release":
                return await self._release(body)
            settle = "commit" if step == "commit" else "abort"
            outcomes = await self._locked(self.engine.handoffs.settle, settle, epoch, names)
            self.on_routes()
            for outcome in sorted(set(outcomes.values())):
                said = outcome if step == "commit" else f"aborted ({outcome})"
                _record(epoch, said, [n for n in names if outcomes[n] == outcome])
            return web.json_response(OutcomesAnswer(outcomes=outcomes))
        except BundleTooLarge as exc:
            return _too_large(str(exc))
        except HandoffError as exc:
            return _message(409, str(exc))
        except (KeyError, ValueError, TypeError) as exc:
            return _message(400, f"bad handoff request: {_why(exc)}")
        except RecursionError:
            return _message(400, "bad handoff request: nested too deep")

    def _take(self, step: str, epoch: int, names: list[str], peer: str | None) -> list[str]:
        """``hold`` or ``receive``, all or nothing."""
        e, done = self.engine, list[str]()
        with e.lock:
            try:
                for name in names:
                    if step == "hold":
                        e.handoffs.hold(name, epoch, peer=peer)
                    else:
                        e.handoffs.receive(name, epoch)
                    done.append(name)
            except HandoffError as exc:
                for name in done:
                    e.handoffs.abort(name, epoch)
                raise HandoffError(f"{name}: {exc}") from None
        return done

    def _cut(
        self, epoch: int, names: list[str]
    ) -> tuple[dict[str, int | None], dict[str, list[str]]]:
        e = self.engine
        with e.lock:
            cuts = {n: e.handoffs.cut(n, epoch) for n in names}
            quiet = {n: list(e.slots[n].quiet) for n in names if cuts[n] is not None}
        return cuts, quiet

    async def _release(self, body: HandoffRequest) -> web.Response:
        epoch, names = body["epoch"], body["monitors"]
        at, vouched, grace, wait = _release_body(body)
        e = self.engine

        def release(among: list[str]) -> dict[str, Snapshot | None]:
            with e.lock:
                return {
                    n: e.handoffs.release(n, epoch, at[n], grace, quiet=vouched.get(n, ()))
                    for n in among
                }

        # up to ``wait`` seconds for events past the cut here: no round trip a try. Each
        # look again asks only the monitors still waiting, and waits three times what
        # the last look took (at least RELEASE_POLL, at most RELEASE_POLL_MAX): looking
        # takes the engine's lock and CPU, on an edge whose core the robot's real-time
        # task and this handler's ingest need (200 monitors waiting: about 0.6 ms a look;
        # looking every 2 ms, as before, took 28 to 30% of a core, now 15 to 19%)
        until = time.monotonic() + min(MAX_WAIT, wait)
        waiting = list(names)
        while True:
            looked = time.perf_counter()
            found = await self._locked(release, waiting)
            waiting = [n for n, data in found.items() if data is None]
            if not waiting or time.monotonic() >= until:
                break
            took = time.perf_counter() - looked
            await asyncio.sleep(min(RELEASE_POLL_MAX, max(RELEASE_POLL, 3 * took)))
        released = await self._locked(release, names)  # the answer: all, as they are now
        waiting = [n for n, data in released.items() if data is None]
        if waiting:
            return web.json_response(WaitingAnswer(waiting=waiting), status=202)

        def wire() -> bytes:
            return bundle(encode(snap) for snap in released.values() if snap is not None)

        return web.Response(body=await self._locked(wire), content_type="application/octet-stream")

    async def _adopt(self, request: web.Request) -> web.Response:
        """Read the bundle off the event loop, one at a time, each snapshot's header
        checked against what this handler receives before any is decoded; then adopt."""
        epoch = request[EPOCH]
        body = request.get(BODY) or bytearray()
        seen: set[str] = set()

        def admit(name: str, snap_epoch: int) -> None:
            slot = self.engine.slots.get(name)
            if slot is None:
                raise HandoffError(f"no monitor {_shown(name)} here")
            if name in seen:
                raise HandoffError(f"monitor {_shown(name)} comes twice")
            seen.add(name)
            if snap_epoch != epoch:
                raise HandoffError(f"{name}: the snapshot belongs to another handoff")
            if slot.epoch != epoch or slot.handoff not in (RECEIVING, None):
                raise HandoffError(f"no receiving handoff of '{name}' with epoch {epoch} here")

        if self._decoding is None:
            self._decoding = asyncio.Lock()
        async with self._decoding:
            snaps = await self._locked(read_bundle, body, self.limits.bundle, admit)
        del body
        request[BODY] = bytearray()
        names = await self._locked(self.engine.handoffs.adopt_many, epoch, snaps)  # all or nothing
        self.on_routes()
        _record(epoch, "adopted", names)
        return web.json_response(AdoptAnswer(active=names))

    async def activate(self, request: web.Request) -> web.Response:
        return await self._set_active(request, True)

    async def deactivate(self, request: web.Request) -> web.Response:
        return await self._set_active(request, False)

    # -- serving ---------------------------------------------------------------------------

    def app(self) -> web.Application:
        app = web.Application(middlewares=[self._gate], client_max_size=MAX_HANDOFF_BODY)
        app.add_routes(
            [
                web.get("/healthz", self.healthz),
                web.get("/metrics", self.metrics),
                web.get("/v1/load", self.load),
                web.get("/v1/deadline", self.deadline),
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

    async def prepare(self, tls: ssl.SSLContext | None = None) -> Pool:
        """The app and its runner on the running loop, and the protocol factory to serve
        it with (:meth:`start` listens with it; the fuzz target, tests/fuzz/fuzz_api.py,
        feeds its connections bytes)."""
        self._runner = web.AppRunner(
            self.app(),
            access_log=None,
            keepalive_timeout=self.limits.idle_seconds,
            lingering_time=self.limits.read_seconds,  # reading an unwanted body
            max_headers=MAX_HEADERS,
            logger=http_log,
        )
        await self._runner.setup()
        server = self._runner.server
        assert server is not None
        loop = asyncio.get_running_loop()
        self.connections = Pool(lambda: _Protocol(server, loop=loop), self.limits, tls)
        self._missed = asyncio.Event()
        if self.engine.deadline is not None:

            def missed() -> None:  # (on the ROS layer's thread)
                with contextlib.suppress(RuntimeError):  # the loop closed: stopping
                    loop.call_soon_threadsafe(self._miss)

            self.engine.deadline.on_miss = missed
        return self.connections

    def start(self, host: str, port: int, tls: ssl.SSLContext | None = None) -> None:
        """Serve in a thread, HTTPS with ``tls`` (:func:`edgerv.control.tls.server_context`);
        returns once listening (``self.port`` is the bound port)."""
        _room_for(self.limits)
        started = threading.Event()
        failure: list[BaseException] = []

        def serve() -> None:
            loop = asyncio.new_event_loop()
            self._loop = loop
            try:
                connections = loop.run_until_complete(self.prepare(tls))
                self._server = loop.run_until_complete(
                    # in place of a TCPSite; TLS is started by each connection (admission)
                    loop.create_server(connections, host, port)
                )
                self.port = self._server.sockets[0].getsockname()[1]  # when 0 was asked for
            except BaseException as exc:
                failure.append(exc)
                started.set()
                return
            started.set()
            loop.run_forever()
            self._server.close()
            connections.close_all()
            assert self._runner is not None
            loop.run_until_complete(self._runner.cleanup())
            left = asyncio.all_tasks(loop)  # handshakes, bodies being discarded
            for task in left:
                task.cancel()
            if left:
                loop.run_until_complete(_settled(left))
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
        for pool in (self._work, self._scraper):
            pool.shutdown(wait=False, cancel_futures=True)


async def _settled(tasks: set[asyncio.Task[Any]]) -> None:
    await asyncio.gather(*tasks, return_exceptions=True)


def _too_large(text: str) -> web.Response:
    answer = _message(413, text)
    answer.force_close()  # not read: the connection cannot carry another request
    return answer


def _room_for(limits: Limits) -> None:
    """Open files enough for every connection the limits allow, and as many again for the
    rest of the handler (DDS, files): the soft limit raised toward the hard one if need be."""
    want = 2 * (limits.connections + limits.pending) + 64
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != resource.RLIM_INFINITY and soft < want:
        raised = want if hard == resource.RLIM_INFINITY else min(want, hard)
        with contextlib.suppress(ValueError, OSError):
            resource.setrlimit(resource.RLIMIT_NOFILE, (raised, hard))
        if raised < want:
            log.warning(
                "open files are limited to %d: fewer than the %d the API's limits may take "
                "(--api-max-connections %d, --api-max-pending %d)",
                raised,
                want,
                limits.connections,
                limits.pending,
            )
