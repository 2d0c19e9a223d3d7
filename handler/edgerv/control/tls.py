"""TLS for the control API: a handler serves HTTPS with its certificate; its callers (the
operator, ``edgerv migrate``, ``edgerv orchestrate``) verify that certificate against a CA.

A handler's address is a node's IP, not a name its certificate can carry ahead of time,
so the callers may verify the certificate against one fixed **server name** instead of
the address they connect to (``ClientTls.server_name``; the chart's certificate names
``<release>-handler.<namespace>.svc``, its handlers' headless Service). Files are read
once, at start: a rotated Secret rolls the pods (the chart's checksum annotation).

The bearer token authenticates the caller; TLS authenticates the handler and keeps the
token and the handoff's bundles private on the link. Plain HTTP is served only on a
loopback address, or when asked for by name (``--plain-http``).
"""

from __future__ import annotations

import contextlib
import http.client
import ipaddress
import socket
import ssl
from dataclasses import dataclass, field

from edgerv.core.diagnostics import Diagnostic, InputError, Location


def _unreadable(path: str, what: str, exc: BaseException) -> InputError:
    reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
    return InputError([Diagnostic(Location(path), f"cannot use the {what}: {reason}")])


def server_context(cert_file: str, key_file: str) -> ssl.SSLContext:
    """The context a handler serves HTTPS with: its certificate chain and key (PEM), TLS
    1.2 or later. Raises :class:`InputError` naming the file that cannot be used."""
    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    for path, what in ((cert_file, "certificate"), (key_file, "private key")):
        try:
            with open(path, "rb"):
                pass
        except OSError as exc:
            raise _unreadable(path, what, exc) from None
    try:
        context.load_cert_chain(cert_file, key_file)
    except ssl.SSLError as exc:
        raise InputError(
            [
                Diagnostic(
                    Location(cert_file),
                    f"cannot use the certificate with the key {key_file}: {exc.reason or exc} "
                    "(both PEM; the key must be the certificate's, unencrypted)",
                )
            ]
        ) from None
    return context


@dataclass(frozen=True)
class ClientTls:
    """How a caller verifies handlers' certificates: the CA that signed them (PEM; None:
    the system's CAs) and the name they carry (None: the host of the address)."""

    ca_file: str | None = None
    server_name: str | None = None
    context: ssl.SSLContext = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        try:
            context = ssl.create_default_context(cafile=self.ca_file)
        except (OSError, ssl.SSLError) as exc:
            raise _unreadable(self.ca_file or "", "CA certificate", exc) from None
        context.minimum_version = ssl.TLSVersion.TLSv1_2
        object.__setattr__(self, "context", context)

    def connection(self, host: str, port: int | None, timeout: float) -> http.client.HTTPConnection:
        """A connection to ``host``, verified against :attr:`server_name` (or ``host``)."""
        return _VerifiedConnection(
            host, port, timeout=timeout, context=self.context, server_name=self.server_name
        )


class _VerifiedConnection(http.client.HTTPSConnection):
    """HTTPS to an address whose certificate names another host (``server_name``)."""

    def __init__(
        self,
        host: str,
        port: int | None,
        timeout: float,
        context: ssl.SSLContext,
        server_name: str | None,
    ) -> None:
        super().__init__(host, port, timeout=timeout, context=context)
        self._context = context
        self._server_name = server_name

    def connect(self) -> None:
        self.sock = socket.create_connection((self.host, self.port), self.timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.sock = self._context.wrap_socket(
            self.sock, server_hostname=self._server_name or self.host
        )


def speaks_tls(host: str, port: int, timeout: float) -> bool:
    """Does ``host:port`` answer a TLS ClientHello with a TLS handshake record (its
    ServerHello)? The handshake is left unfinished: nothing is sent but the hello, and
    the handler never counts it as a connection (a failed handshake gives its place back)."""
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    context.check_hostname = False
    context.verify_mode = ssl.CERT_NONE
    incoming, outgoing = ssl.MemoryBIO(), ssl.MemoryBIO()
    hello = context.wrap_bio(incoming, outgoing, server_hostname=host or None)
    with contextlib.suppress(ssl.SSLWantReadError):
        hello.do_handshake()  # writes the ClientHello to ``outgoing``, then wants an answer
    try:
        with socket.create_connection((host, port), timeout) as sock:
            sock.sendall(outgoing.read())
            answer = b""
            while len(answer) < 2 and (chunk := sock.recv(2 - len(answer))):
                answer += chunk
    except OSError:
        return False
    return answer == b"\x16\x03"  # a handshake record, TLS 1.x


def is_loopback(host: str) -> bool:
    """An address whose traffic never leaves the machine (127.0.0.0/8, ::1, localhost)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False
