"""The handlers' control API from the outside: one client for the operator,
``edgerv migrate`` and ``edgerv orchestrate`` (docs/handler.md lists the calls).

Every failure is an :class:`ApiError`, and its class says which failure it was, so a
caller tells a transient one (the handler is unreachable, busy or restarting: try
again) from a permanent one (the definition is invalid: fix it):

* :class:`Unreachable`: no answer (reset, timed out); :class:`Refused`: nothing listens
  there, so the handler is down and runs nothing; :class:`Unresolved`: the address's
  host name is not known (nothing was sent).
* :class:`Untrusted`: the handler's certificate is not one the caller trusts (another
  CA, another name, expired): nothing was sent; a setting to fix, not a moment to wait.
* :class:`WrongScheme`: the handler speaks HTTPS and was called over plain HTTP, or the
  reverse (each confirmed by a second connection that speaks its scheme): it acted on
  nothing; a setting to fix too.
* :class:`HttpError`: an answer with an HTTP error, ``status`` and the handler's
  reason: :class:`Invalid` (400, 413, 422: the request, e.g. a Monitor document, is
  wrong), :class:`Unauthorized` (401: the bearer token is refused, e.g. rotated),
  :class:`NotFound` (404), :class:`Conflict` (409: e.g. held by a handoff),
  :class:`ServerError` (5xx).
* :class:`BadAnswer`: an answer that is not what the API promises.
"""

from __future__ import annotations

import http.client
import json
import socket
import ssl
import urllib.parse
from collections.abc import Sequence
from typing import Any, Literal, cast

from edgerv.control.tls import ClientTls, is_loopback, speaks_tls
from edgerv.control.token import Token, current
from edgerv.control.wire import (
    ErrorBody,
    HandoffRequest,
    LoadReport,
    MonitorListing,
    MonitorLoadReport,
    MonitorReport,
    parse_deadline,
    parse_load,
)
from edgerv.core.deadline import DeadlineLoad


class ApiError(Exception):
    """A call to a handler's control API failed."""


class Unreachable(ApiError):
    """The handler did not answer (reset, timed out)."""


class Refused(Unreachable):
    """Nothing listens at the handler's address: it is down, and runs no monitor."""


class Unresolved(Unreachable):
    """The host name of the handler's address is not known (DNS): nothing was sent.
    ``detail``: that, in words (``its host NAME is not known (REASON)``)."""

    def __init__(self, message: str, detail: str) -> None:
        super().__init__(message)
        self.detail = detail


class Untrusted(ApiError):
    """The handler's certificate failed verification: the request was not sent.
    ``reason``: OpenSSL's (``unable to get local issuer certificate``, ``Hostname
    mismatch, ...``)."""

    def __init__(self, message: str, reason: str = "") -> None:
        super().__init__(message)
        self.reason = reason


class WrongScheme(ApiError):
    """The handler speaks another scheme than the one it was called with: ``speaks`` is
    ``https`` (called over plain HTTP: its TLS took the request for a bad handshake) or
    ``http`` (called over HTTPS: it answered the handshake in plain HTTP). It acted on
    nothing."""

    def __init__(self, message: str, speaks: Literal["http", "https"]) -> None:
        super().__init__(message)
        self.speaks = speaks


class HttpError(ApiError):
    """The handler answered with an HTTP error; ``errors`` are the items of its body."""

    def __init__(self, message: str, status: int, errors: Sequence[Any] = ()) -> None:
        super().__init__(message)
        self.status = status
        self.errors = list(errors)


class Invalid(HttpError):
    """400/413/422: the request is wrong (a Monitor document's problems are in ``errors``)."""


class Unauthorized(HttpError):
    """401: the handler refuses the bearer token; it acted on nothing."""


class NotFound(HttpError):
    """404: no such monitor (or path) on that handler."""


class Conflict(HttpError):
    """409: the monitor exists already, or a handoff holds it."""


class ServerError(HttpError):
    """5xx: the handler failed."""


class BadAnswer(ApiError):
    """The answer is not what the API promises (not JSON, or the wrong shape)."""


_BY_STATUS: dict[int, type[HttpError]] = {
    400: Invalid,
    413: Invalid,
    422: Invalid,
    401: Unauthorized,
    404: NotFound,
    409: Conflict,
}


def http_error(where: str, status: int, answer: bytes) -> HttpError:
    """The error class of an HTTP error answer, with the handler's reason."""
    items: list[Any] = []
    try:
        body = cast(ErrorBody, json.loads(answer))
        items = list(body["errors"])
        reason = "; ".join(
            f"{e['location']}: {e['message']}" if e.get("location") else str(e["message"])
            for e in items
        )
    except (ValueError, KeyError, IndexError, TypeError, RecursionError):
        reason = answer[:200].decode(errors="replace")
    kind = _BY_STATUS.get(status, ServerError if status >= 500 else HttpError)
    return kind(f"{where}: {reason} (HTTP {status})", status, items)


class HandlerClient:
    """One handler's control API, over one kept-alive connection (a round trip per call).

    ``address``: ``HOST:PORT`` or a URL. Without a scheme it is reached over HTTPS,
    except on a loopback address without ``tls`` (plain HTTP, which never leaves the
    machine); ``http://`` asks for plain HTTP by name. ``tls``: how to verify the
    handler's certificate (None: against the system's CAs, by the address's host).

    Not thread-safe: one client per thread (they are cheap)."""

    def __init__(self, address: str, token: Token, tls: ClientTls | None = None) -> None:
        if "://" in address:
            self.base = address
        else:
            host = urllib.parse.urlsplit(f"//{address}").hostname or ""
            scheme = "http" if tls is None and is_loopback(host) else "https"
            self.base = f"{scheme}://{address}"
        self.token = token
        self.tls = tls
        parts = urllib.parse.urlsplit(self.base)
        self._https = parts.scheme == "https"
        self._host, self._port = parts.hostname or "", parts.port
        self._netloc = parts.netloc
        self._conn: http.client.HTTPConnection | None = None
        # what the last listing and load report said, by name, and the cursor to ask
        # for only what changed since (docs/protocol.md, "Reading only what changed")
        self._kept: dict[str, tuple[str, dict[str, Any]]] = {}

    def __repr__(self) -> str:
        return f"HandlerClient({self.base!r})"

    def _connection(self, timeout: float) -> http.client.HTTPConnection:
        if self._conn is None:
            if self._https:
                self._conn = (self.tls or ClientTls()).connection(self._host, self._port, timeout)
            else:
                self._conn = http.client.HTTPConnection(self._netloc, timeout=timeout)
        self._conn.timeout = timeout
        if self._conn.sock is not None:
            self._conn.sock.settimeout(timeout)
        return self._conn

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def call(
        self,
        path: str,
        body: Any = None,
        raw: bytes | None = None,
        timeout: float = 10.0,
        check: bool = False,
        method: str = "POST",
        content_type: str | None = None,
    ) -> tuple[int, bytes]:
        """One request; with ``check``, a 4xx/5xx answer raises its :class:`HttpError`.

        Every call of the API is idempotent, so a call on a kept-alive connection that
        the handler had closed is sent once more on a new one.
        """
        data = raw if raw is not None else json.dumps(body or {}).encode()
        headers = {
            "Content-Type": content_type
            or ("application/octet-stream" if raw is not None else "application/json")
        }
        if token := current(self.token):
            headers["Authorization"] = f"Bearer {token}"
        for attempt in (1, 2):
            reused = self._conn is not None and self._conn.sock is not None
            conn = self._connection(timeout)
            try:
                conn.request(
                    method, path, body=data if method in ("POST", "PUT") else None, headers=headers
                )
                resp = conn.getresponse()
                status, answer = resp.status, resp.read()
                break
            except ssl.SSLCertVerificationError as exc:
                self.close()
                raise Untrusted(
                    f"{self.base}: its certificate is not trusted ({exc.verify_message}): "
                    "give the CA that signed it (and the name it carries), or check that "
                    "this address is the handler's",
                    str(exc.verify_message),
                ) from None
            except (http.client.HTTPException, OSError) as exc:
                self.close()
                if attempt == 1 and reused and not isinstance(exc, TimeoutError):
                    continue  # the kept-alive connection had been closed: once more
                self._wrong_scheme(exc, timeout)
                if isinstance(exc, socket.gaierror):
                    detail = f"its host {self._host} is not known ({exc.strerror or exc})"
                    raise Unresolved(f"{self.base} is unreachable: {detail}", detail) from None
                kind = Refused if isinstance(exc, ConnectionRefusedError) else Unreachable
                raise kind(f"{self.base} is unreachable: {exc}") from None
        if check and status >= 400:
            raise http_error(f"{self.base}{path}", status, answer)
        return status, answer

    def _wrong_scheme(self, exc: BaseException, timeout: float) -> None:
        """Raise :class:`WrongScheme` when the failure ``exc`` of a call is the handler
        speaking the other scheme: HTTPS that took our plain request for a bad handshake
        (it closed the connection), or plain HTTP that answered our handshake. Each is
        confirmed by a second connection in the scheme it seems to speak (a TLS hello
        that gets a TLS answer, or ``GET /healthz``, which needs no token, that gets an
        HTTP one): a handler that only went away is unreachable, as before."""
        port = self._port or (443 if self._https else 80)
        probe = min(timeout, 5.0)
        if self._https:
            if isinstance(exc, ssl.SSLError) and _speaks_plain_http(
                self._host, port, self._netloc, probe
            ):
                raise WrongScheme(
                    f"{self.base}: the handler speaks plain HTTP, not HTTPS: nothing was sent",
                    "http",
                )
        elif isinstance(exc, http.client.BadStatusLine | ConnectionResetError) and speaks_tls(
            self._host, port, probe
        ):
            raise WrongScheme(
                f"{self.base}: the handler speaks HTTPS, not plain HTTP: it took the request "
                "for a bad handshake and acted on nothing",
                "https",
            )

    def json(self, what: str, raw: bytes) -> Any:
        """An answer as JSON, or :class:`BadAnswer` naming the handler and the call."""
        try:
            return json.loads(raw)
        except (ValueError, RecursionError):
            raise BadAnswer(f"{self.base} answered {what} with something not JSON") from None

    def get(self, path: str, timeout: float = 10.0) -> Any:
        """GET a JSON document."""
        return self.json(path, self.call(path, timeout=timeout, check=True, method="GET")[1])

    def handoff(
        self,
        step: str,
        epoch: int,
        monitors: Sequence[str],
        timeout: float,
        check: bool = True,
        peer: str | None = None,
        cuts: dict[str, int] | None = None,
        quiet: dict[str, list[str]] | None = None,
        grace: float | None = None,
        wait: float | None = None,
    ) -> tuple[int, bytes]:
        """One step of a handoff (docs/protocol.md) for ``monitors`` under ``epoch``."""
        request: HandoffRequest = {"epoch": epoch, "monitors": list(monitors)}
        if peer is not None:
            request["peer"] = peer
        if cuts is not None:
            request["cuts"] = cuts
        if quiet is not None:
            request["quiet"] = quiet
        if grace is not None:
            request["grace"] = grace
        if wait is not None:
            request["wait"] = wait
        return self.call(f"/v1/handoff/{step}", request, check=check, timeout=timeout)

    def _since(self, path: str, timeout: float) -> tuple[Any, dict[str, Any] | None]:
        """GET ``path``, asking only for what changed since the last answer kept (the
        client's own); the answer, and the entries kept to merge it with (None: the
        answer is whole)."""
        kept = self._kept.get(path)
        query = f"?since={urllib.parse.quote(kept[0], safe='')}" if kept else ""
        answer = self.get(f"{path}{query}", timeout=timeout)
        honoured = kept is not None and isinstance(answer, dict) and answer.get("since") == kept[0]
        return answer, kept[1] if kept is not None and honoured else None

    def _keep(
        self,
        path: str,
        answer: dict[str, Any],
        entries: dict[str, Any] | None,
        changed: dict[str, Any],
    ) -> dict[str, Any]:
        """The whole listing: ``changed`` merged into ``entries`` (less what the answer
        says was removed), kept with the answer's cursor for the next call."""
        if entries is None:
            whole = changed
        else:
            removed = answer.get("removed")
            if not isinstance(removed, list) or not all(isinstance(n, str) for n in removed):
                self._kept.pop(path, None)
                raise BadAnswer(f"{self.base} answered {path} with no list of names removed")
            whole = dict(entries)
            for name in removed:
                whole.pop(name, None)
            whole.update(changed)
        cursor = answer.get("cursor")
        if isinstance(cursor, str):
            self._kept[path] = (cursor, whole)
        else:  # (a handler that keeps no cursors: every answer is whole)
            self._kept.pop(path, None)
        return dict(whole)  # (the caller's to change: the kept one stays as answered)

    def load(self, timeout: float = 10.0) -> LoadReport:
        """``GET /v1/load``: its load report (:class:`BadAnswer` when it is not one).
        Only the monitors' entries that changed since this client's last call are sent
        and parsed; the others are the last call's."""
        answer, entries = self._since("/v1/load", timeout)
        try:
            report = parse_load(answer)
        except ValueError as exc:
            self._kept.pop("/v1/load", None)
            raise BadAnswer(f"{self.base} answered /v1/load with no load report: {exc}") from None
        report["monitors"] = cast(
            dict[str, MonitorLoadReport],
            self._keep("/v1/load", answer, entries, dict(report["monitors"])),
        )
        return report

    def deadline(self, after: int | None = None, wait: float = 0.0) -> DeadlineLoad:
        """``GET /v1/deadline``: the reading of the handler's deadline; given ``after``,
        once more than ``after`` makespans missed it since the handler started, or after
        ``wait`` seconds (:class:`NotFound`: it measures none)."""
        query = "" if after is None else f"?after={after}&wait={wait:g}"
        try:
            return parse_deadline(self.get(f"/v1/deadline{query}", timeout=wait + 10.0))
        except ValueError as exc:
            raise BadAnswer(f"{self.base} answered /v1/deadline with no reading: {exc}") from None

    # -- monitors -------------------------------------------------------------------------

    def monitors(self, timeout: float = 10.0) -> list[MonitorReport]:
        """``GET /v1/monitors``: every monitor it defines, each with its name (only the
        reports changed since this client's last call are sent; the others are the last
        call's, the same objects: read them, do not change them)."""
        listing, entries = self._since("/v1/monitors", timeout)
        monitors = listing.get("monitors") if isinstance(listing, dict) else None
        if not isinstance(monitors, list) or not all(
            isinstance(m, dict) and isinstance(m.get("name"), str) for m in monitors
        ):
            self._kept.pop("/v1/monitors", None)
            raise BadAnswer(f"{self.base} answered /v1/monitors with no list of monitors")
        changed = {m["name"]: m for m in cast(MonitorListing, listing)["monitors"]}
        return list(self._keep("/v1/monitors", listing, entries, changed).values())

    def monitor(self, name: str, timeout: float = 10.0) -> MonitorReport | None:
        """``GET /v1/monitors/{name}``; None when it does not define that monitor."""
        try:
            report = self.get(f"/v1/monitors/{_quoted(name)}", timeout=timeout)
        except NotFound:
            return None
        if not isinstance(report, dict) or report.get("name") != name:
            raise BadAnswer(f"{self.base} answered /v1/monitors/{name} with no such monitor")
        return cast(MonitorReport, report)

    def define(self, name: str, document: str, active: bool, timeout: float = 30.0) -> bool:
        """``PUT /v1/monitors/{name}``: define it (True) or redefine it (False), running
        here or idle (``active``). :class:`Invalid` names the document's problems."""
        path = f"/v1/monitors/{_quoted(name)}?active={'true' if active else 'false'}"
        _, answer = self.call(
            path,
            raw=document.encode(),
            content_type="application/yaml",
            timeout=timeout,
            check=True,
            method="PUT",
        )
        return bool(self.json(path, answer).get("created"))

    def activate(self, name: str, timeout: float = 30.0) -> None:
        """Run it here (:class:`Conflict` while a handoff holds it)."""
        self.call(f"/v1/monitors/{_quoted(name)}/activate", timeout=timeout, check=True)

    def deactivate(self, name: str, timeout: float = 30.0) -> None:
        """Stop running it here, keeping its definition."""
        self.call(f"/v1/monitors/{_quoted(name)}/deactivate", timeout=timeout, check=True)

    def delete(self, name: str, timeout: float = 10.0) -> None:
        """Remove it (:class:`NotFound` when it was not there)."""
        self.call(f"/v1/monitors/{_quoted(name)}", timeout=timeout, check=True, method="DELETE")


def _quoted(name: str) -> str:
    return urllib.parse.quote(name, safe="")


def _speaks_plain_http(host: str, port: int, netloc: str, timeout: float) -> bool:
    """Does ``host:port`` answer a plain ``GET /healthz`` with an HTTP status line?"""
    request = f"GET /healthz HTTP/1.1\r\nHost: {netloc}\r\nConnection: close\r\n\r\n"
    try:
        with socket.create_connection((host, port), timeout) as sock:
            sock.sendall(request.encode())
            answer = b""
            while len(answer) < 5 and (chunk := sock.recv(5 - len(answer))):
                answer += chunk
    except OSError:
        return False
    return answer == b"HTTP/"


def address_problem(address: str) -> str | None:
    """What is wrong with a handler's address as :class:`HandlerClient` reads it
    (``HOST:PORT``, ``http://HOST[:PORT]`` or ``https://HOST[:PORT]``); None if nothing."""
    if not address.strip() or address != address.strip():
        return f"'{address}' is not HOST:PORT" if address.strip() else "an empty address"
    scheme, sep, _ = address.partition("://")
    if sep and scheme not in ("http", "https"):
        return f"'{address}': the scheme must be http:// or https://, not {scheme}://"
    parts = urllib.parse.urlsplit(address if sep else f"//{address}")
    if parts.path not in ("", "/") or parts.query or parts.fragment or parts.username:
        return f"'{address}' is not HOST:PORT: a handler's address has no path, query or user"
    try:
        port = parts.port
    except ValueError:
        return f"'{address}': the port must be a number from 1 to 65535"
    if not parts.hostname:
        return f"'{address}' names no host"
    if port is None and not sep:
        return f"'{address}' is not HOST:PORT: give the port, e.g. {address}:8470"
    if port == 0:
        return f"'{address}': the port must be a number from 1 to 65535"
    return None
