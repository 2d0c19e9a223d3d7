"""Who may hold what of the control API's connections (docs/handler.md, "Limits on input").

A connection costs a file descriptor and nothing else until it has earned more:

* A **stranger** is a connection from its accept (over TLS its handshake too, which is
  done here: :meth:`asyncio.loop.start_tls`) until a request on it shows the token. There
  are at most ``Limits.pending`` strangers. One more closes a stranger of the peer
  address that holds the most: the one that waited longest there, first one with no
  request under way, then one still sending a request, last one being answered. The
  newcomer is always let in, and a flood of connections closes the flood's own: a
  client on another address is never closed for it, one on the flood's address only
  once the flood has opened ``pending`` connections since. Strangers are served what
  needs no token (``/healthz``, ``/metrics``, a 401, a 404) and hold no place for it.
* An **admitted** connection is one a complete request head with the token came on:
  it holds one of ``Limits.connections`` places (``--api-max-connections``) until it
  closes. One more such head takes the place of the admitted connection that has been
  idle longest, which is closed (a kept-alive connection: its client opens a new one);
  when each one has a request under way, that head is answered 503.

Every connection is closed when a request's head does not arrive within ``read_seconds``
of its first byte, or an answer waits that long to be read; aiohttp closes one idle for
``idle_seconds``. The body's deadline is kept by the API (:mod:`edgerv.handler.api`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import ssl
import time
from collections.abc import Callable

from edgerv.handler.limits import Limits

log = logging.getLogger("edgerv.handler.api")

SAY_EVERY = 10.0  # seconds between two log lines about closed strangers


class Connection(asyncio.Protocol):
    """One client's connection, around aiohttp's protocol (``inner``)."""

    def __init__(self, pool: Pool, inner: asyncio.Protocol) -> None:
        self.pool = pool
        self.inner = inner
        self.raw: asyncio.Transport | None = None  # the TCP connection
        self.peer = ""  # its peer's address
        self.told = False  # aiohttp was given the connection (over TLS: after the handshake)
        self.early: list[bytes] | None = None  # over TLS: what came before aiohttp was told
        self.early_eof = False
        self.closed = False
        self.admitted = False  # holds a place: a request with the token came on it
        self.busy = False  # a request's bytes came, its answer is not out
        self.serving = False  # its head is in: the API is at work on it
        self.deadline = 0.0  # for the request under way (the loop's clock)
        self.reading: asyncio.TimerHandle | None = None  # its head is on its way
        self.writing: asyncio.TimerHandle | None = None  # an answer waits to be read
        self.handshake: asyncio.Task[None] | None = None

    def _soon(self) -> float:
        return asyncio.get_running_loop().time() + self.pool.limits.read_seconds

    def _cut_at(self, deadline: float, why: str) -> asyncio.TimerHandle:
        return asyncio.get_running_loop().call_at(deadline, self._cut, why)

    def _cut(self, why: str) -> None:
        log.info("closed a connection: %s within %g s", why, self.pool.limits.read_seconds)
        self.abort()

    def abort(self) -> None:
        if self.raw is not None:
            self.raw.abort()

    def request_arrived(self) -> float:
        """The head is in (aiohttp parsed it): the deadline for its body. A request whose
        bytes came while the one before was answered gets the whole time for its body."""
        if self.reading is None:
            self.deadline = self._soon()
        else:
            self.reading.cancel()
            self.reading = None
        self.busy = self.serving = True
        return self.deadline

    def answered(self) -> None:
        self.busy = self.serving = False
        self.pool.answered(self)

    # -- asyncio's side ----------------------------------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.raw = transport
        peer = transport.get_extra_info("peername")
        self.peer = str(peer[0]) if isinstance(peer, tuple) and peer else ""
        self.pool.join(self)
        if self.pool.tls is None:
            self._tell(transport)
            return
        transport.pause_reading()  # the handshake's task takes it over
        self.early = []
        self.handshake = asyncio.get_running_loop().create_task(self._handshake(transport))

    async def _handshake(self, raw: asyncio.Transport) -> None:
        assert self.pool.tls is not None
        tls: asyncio.BaseTransport | None = None
        try:
            tls = await asyncio.get_running_loop().start_tls(
                raw,
                self,
                self.pool.tls,
                server_side=True,
                ssl_handshake_timeout=self.pool.limits.read_seconds,
            )
        except (OSError, ssl.SSLError, ConnectionError, TimeoutError, RuntimeError) as exc:
            # a plain-HTTP caller, a certificate refused, a handshake that timed out
            log.debug("a TLS handshake from %s failed: %s", self.peer or "?", exc)
        finally:
            if tls is None or self.closed:  # asyncio closed it (or it was closed meanwhile)
                self.closed = True
                self.pool.release(self)
        if tls is None or self.closed:
            return
        assert isinstance(tls, asyncio.Transport)
        self._tell(tls)
        early, self.early = self.early or [], None
        for data in early:
            self.data_received(data)
        if self.early_eof and not self.inner.eof_received():
            tls.close()  # what the TLS layer would have done, had aiohttp been told

    def _tell(self, transport: asyncio.Transport) -> None:
        self.told = True
        self.inner.connection_made(transport)

    def data_received(self, data: bytes) -> None:
        if self.early is not None:  # over TLS, before the handshake's task resumed
            self.early.append(data)
            return
        if not self.busy and self.reading is None:
            self.busy = True
            self.deadline = self._soon()
            self.reading = self._cut_at(self.deadline, "a request's head did not arrive")
        self.inner.data_received(data)

    def eof_received(self) -> bool | None:
        if self.early is not None:
            self.early_eof = True
            return True  # kept open until aiohttp is told
        return self.inner.eof_received()

    def pause_writing(self) -> None:  # the client does not read what it asked for
        if self.writing is None:
            self.writing = self._cut_at(self._soon(), "an answer was not read")
        if self.told:
            self.inner.pause_writing()

    def resume_writing(self) -> None:
        if self.writing is not None:
            self.writing.cancel()
            self.writing = None
        if self.told:
            self.inner.resume_writing()

    def connection_lost(self, exc: Exception | None) -> None:
        for timer in (self.reading, self.writing):
            if timer is not None:
                timer.cancel()
        self.closed = True
        self.pool.release(self)
        if self.told:
            self.inner.connection_lost(exc)


class Pool:
    """The protocol factory the API listens with: aiohttp's protocol in a
    :class:`Connection`, and who holds what (the module's rules)."""

    def __init__(
        self,
        make: Callable[[], asyncio.Protocol],
        limits: Limits,
        tls: ssl.SSLContext | None = None,
    ) -> None:
        self.make = make
        self.limits = limits
        self.tls = tls
        self.strangers: dict[Connection, None] = {}  # oldest first (by join or last answer)
        self.peers: dict[str, dict[Connection, None]] = {}  # the strangers of each address
        self.admitted: dict[Connection, None] = {}  # idle longest first
        self.closed_strangers = 0  # closed to let others in (also the metric's)
        self.closed_admitted = 0
        self.refused = 0  # authenticated heads answered 503
        self._said = float("-inf")  # when that was logged last

    @property
    def open(self) -> int:
        """Places taken under ``--api-max-connections``."""
        return len(self.admitted)

    def __call__(self) -> Connection:
        return Connection(self, self.make())

    def join(self, conn: Connection) -> None:
        """A new connection: a stranger, who may close another to come in (of the address
        holding most)."""
        if len(self.strangers) >= self.limits.pending:
            self._close(max(self.peers.values(), key=len))
        self.strangers[conn] = None
        self.peers.setdefault(conn.peer, {})[conn] = None

    def admit(self, conn: Connection) -> bool:
        """A request with the token came on ``conn``: a place for it, if one is free or
        idle (False: every place has a request under way)."""
        if conn.admitted:
            return True
        if len(self.admitted) >= self.limits.connections:
            idle = next((c for c in self.admitted if not c.busy), None)
            if idle is None:
                self.refused += 1
                return False
            self.release(idle)
            idle.abort()
            self.closed_admitted += 1
        self.release(conn)
        if conn.closed:
            return True  # gone meanwhile: its answer goes nowhere
        conn.admitted = True
        self.admitted[conn] = None
        return True

    def answered(self, conn: Connection) -> None:
        """Its answer is out: it goes to the end of its line (the last to be closed)."""
        if conn.admitted:
            self.admitted.pop(conn, None)
            self.admitted[conn] = None
        elif conn in self.strangers:
            del self.strangers[conn]
            self.strangers[conn] = None
            mine = self.peers[conn.peer]
            del mine[conn]
            mine[conn] = None

    def release(self, conn: Connection) -> None:
        """``conn`` holds nothing any more (closed, or admitted)."""
        if conn.admitted:
            conn.admitted = False
            self.admitted.pop(conn, None)
        elif conn in self.strangers:
            del self.strangers[conn]
            mine = self.peers[conn.peer]
            del mine[conn]
            if not mine:
                del self.peers[conn.peer]

    def _close(self, line: dict[Connection, None]) -> None:
        """Close the stranger of ``line`` that waited longest: one with no request under
        way, else one sending its request, else the first."""
        victim = next((c for c in line if not c.busy), None)
        if victim is None:
            victim = next((c for c in line if not c.serving), None) or next(iter(line))
        self.release(victim)
        victim.closed = True
        victim.abort()
        self.closed_strangers += 1
        self._say()

    def _say(self) -> None:
        now = time.monotonic()
        if now - self._said < SAY_EVERY:
            return
        most = max(self.peers.items(), key=lambda item: len(item[1]), default=("", {}))
        log.warning(
            "closed %d connections without the token so far to let others in (at most %d "
            "at once: --api-max-pending); %s holds %d of them",
            self.closed_strangers,
            self.limits.pending,
            most[0] or "?",
            len(most[1]),
        )
        self._said = now

    def close_all(self) -> None:
        """At shutdown."""
        for conn in [*self.strangers, *self.admitted]:
            with contextlib.suppress(Exception):
                conn.abort()
