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
"""

from __future__ import annotations

import asyncio
import hmac
import logging
import threading
import time
from collections.abc import Awaitable, Callable
from typing import Any

from aiohttp import web
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest

from edgerv.core.diagnostics import Diagnostic, InputError
from edgerv.core.documents import MonitorSpec, parse_monitors_text
from edgerv.core.handoff import HandoffError, bundle, decode_frames, encode, unbundle
from edgerv.core.monitor import CompiledMonitor
from edgerv.handler.engine import Engine

log = logging.getLogger("edgerv.handler.api")
Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]
MAX_BODY = 1 << 20  # Monitor documents
MAX_HANDOFF_BODY = 64 << 20  # a bundle of snapshots (deflated)
MAX_WAIT = 5.0  # seconds a release call may wait for events past the cut
RELEASE_POLL = 0.002  # how often it looks again meanwhile


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


def _integer(value: Any, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{what} must be an integer, not {value!r}"[:200])
    return value


def _seconds(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not value >= 0:
        raise ValueError(f"{what} must be a number of seconds, not {value!r}"[:200])
    return min(float(value), 1e9)  # inf: never


def _handoff_body(body: Any) -> tuple[dict[str, Any], int, list[str]]:
    """A handoff step's JSON body, checked: an object with an integer ``epoch`` and a list
    of monitor names (raises ValueError naming what is wrong: the answer is 400)."""
    if not isinstance(body, dict):
        raise ValueError("the body must be a JSON object")
    names = body["monitors"]
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise ValueError("monitors must be a list of monitor names")
    return body, _integer(body["epoch"], "epoch"), names


def _release_body(
    body: dict[str, Any], names: list[str]
) -> tuple[dict[str, int], dict[str, list[str]], float, float]:
    """The release step's fields: a cut for every monitor, the topics H2 vouched for,
    the grace and how long to wait (seconds)."""
    cuts, quiet = body["cuts"], body.get("quiet") or {}
    if not isinstance(cuts, dict):
        raise ValueError("cuts must map each monitor to its cut")
    checked = {n: _integer(cuts[n], f"the cut of {n}") for n in names}
    if not isinstance(quiet, dict) or not all(
        isinstance(q, list) and all(isinstance(t, str) for t in q) for q in quiet.values()
    ):
        raise ValueError("quiet must map monitors to lists of topics")
    grace = _seconds(body.get("grace", 1.0), "grace")
    return checked, quiet, grace, _seconds(body.get("wait", 0), "wait")


class ControlApi:
    def __init__(
        self,
        engine: Engine,
        registry: CollectorRegistry,
        token: str | None,
        on_change: Callable[[], None],
        on_routes: Callable[[], None] | None = None,
    ) -> None:
        self.engine = engine
        self.registry = registry
        self.token = token
        self.on_change = on_change  # monitors defined or removed
        self.on_routes = on_routes or on_change  # only the topics to read changed
        self._loop: asyncio.AbstractEventLoop | None = None
        self._runner: web.AppRunner | None = None
        self._thread: threading.Thread | None = None
        self.port: int | None = None

    # -- authentication --------------------------------------------------------------------

    @web.middleware
    async def _auth(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        if request.path.startswith("/v1"):
            given = request.headers.get("Authorization", "")
            scheme, _, credential = given.partition(" ")
            ok = self.token is None or (
                scheme.lower() == "bearer"
                and hmac.compare_digest(credential.strip().encode(), self.token.encode())
            )
            if not ok:
                return web.json_response(
                    {"errors": [{"message": "missing or wrong bearer token"}]},
                    status=401,
                    headers={"WWW-Authenticate": 'Bearer realm="edgerv"'},
                )
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
        too_big = _message(413, f"body larger than {MAX_BODY} bytes")
        if (request.content_length or 0) > MAX_BODY:
            return [], too_big
        raw = await request.read()  # chunked: bounded by the app's client_max_size
        if len(raw) > MAX_BODY:
            return [], too_big
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
        existing = {m["name"] for m in self.engine.snapshot()}
        clash = [c.name for c in compiled if c.name in existing]
        if clash:
            return _message(
                409, f"monitor '{clash[0]}' exists; PUT /v1/monitors/{clash[0]} replaces it"
            )
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
        created = self.engine.put(compiled[0], active=_active(request))
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
                return web.json_response({"active": names})
            body, epoch, names = _handoff_body(await request.json())
            if step in ("hold", "receive"):
                done: list[str] = []
                peer = body.get("peer")
                if peer is not None and not isinstance(peer, str):
                    raise ValueError("peer must be a handler's address")
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
                return web.json_response({"monitors": done})
            if step == "cut":
                with e.lock:
                    cuts = {n: e.cut(n, epoch) for n in names}
                    quiet = {n: list(e.slots[n].quiet) for n in names if cuts[n] is not None}
                return web.json_response({"cuts": cuts, "quiet": quiet})
            if step == "release":
                at, quiet, grace, wait = _release_body(body, names)
                # up to ``wait`` seconds for events past the cut here: no round trip a try
                until = time.monotonic() + min(MAX_WAIT, wait)
                while True:
                    with e.lock:
                        released = {
                            n: e.release(n, epoch, at[n], grace, quiet=quiet.get(n, ()))
                            for n in names
                        }
                    waiting = [n for n, data in released.items() if data is None]
                    if not waiting or time.monotonic() >= until:
                        break
                    await asyncio.sleep(RELEASE_POLL)
                if waiting:
                    return web.json_response({"waiting": waiting}, status=202)
                frames = (encode(snap) for snap in released.values() if snap is not None)
                return web.Response(body=bundle(frames), content_type="application/octet-stream")
            if step in ("commit", "abort"):
                act = e.commit if step == "commit" else e.abort
                with e.lock:
                    outcomes = {n: act(n, epoch) for n in names}
                self.on_routes()
                return web.json_response({"outcomes": outcomes})
        except HandoffError as exc:
            return _message(409, str(exc))
        except (KeyError, ValueError, TypeError) as exc:
            return _message(400, f"bad handoff request: {exc!r}")
        except RecursionError:
            return _message(400, "bad handoff request: nested too deep")
        return _message(404, f"no handoff step '{step}'")

    async def activate(self, request: web.Request) -> web.Response:
        return await self._set_active(request, True)

    async def deactivate(self, request: web.Request) -> web.Response:
        return await self._set_active(request, False)

    # -- serving ---------------------------------------------------------------------------

    def app(self) -> web.Application:
        app = web.Application(middlewares=[self._auth], client_max_size=MAX_HANDOFF_BODY)
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

    def start(self, host: str, port: int) -> None:
        """Serve in a thread; returns once listening (``self.port`` is the bound port)."""
        started = threading.Event()
        failure: list[BaseException] = []

        def serve() -> None:
            loop = asyncio.new_event_loop()
            self._loop = loop
            try:
                self._runner = web.AppRunner(self.app(), access_log=None)
                loop.run_until_complete(self._runner.setup())
                site = web.TCPSite(self._runner, host, port)
                loop.run_until_complete(site.start())
                server: Any = site._server  # the bound port, when 0 was asked for
                self.port = server.sockets[0].getsockname()[1] if server else port
            except BaseException as exc:
                failure.append(exc)
                started.set()
                return
            started.set()
            loop.run_forever()
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
