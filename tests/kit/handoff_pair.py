"""Two handlers' engines (:func:`edge_and_cloud`) behind their real HTTP APIs, the
receiver behind a TCP gate that can cut the link (:class:`Gate`): the :class:`Pair` that
``edgerv migrate``'s tests move a monitor across (the fixture ``pair`` of
tests/unit/conftest.py builds one)."""

from __future__ import annotations

import contextlib
import socket
import threading
from dataclasses import dataclass

from edgerv.control.client import HandlerClient
from edgerv.handler.api import ControlApi
from edgerv.handler.engine import Engine
from kit.documents import compiled

TOKEN = "test-token"


def edge_and_cloud() -> tuple[Engine, Engine]:
    """The engines of two handlers, edge and cloud, that hold the monitor ``m`` (always
    (a -> x < 5), over /a and /x): active on the edge, inactive on the cloud."""
    edge, cloud = Engine("edge", flush_after=1e9), Engine("cloud", flush_after=1e9)
    monitor = compiled("always (a -> x < 5)", {"a": "bool", "x": "float"})
    edge.put(monitor, active=True)
    cloud.put(monitor, active=False)
    return edge, cloud


class Gate:
    """A TCP forwarder to ``port`` on loopback. ``mode``: ``pass``; ``mute`` (requests
    go through, answers are dropped: the receiver acts, the driver never hears);
    ``black`` (nothing goes through)."""

    def __init__(self, port: int) -> None:
        self.target = port
        self.mode = "pass"
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.sockets: list[socket.socket] = []
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.server.accept()
            except OSError:
                return
            upstream = socket.create_connection(("127.0.0.1", self.target))
            self.sockets += [client, upstream]
            threading.Thread(
                target=self._pump, args=(client, upstream, "request"), daemon=True
            ).start()
            threading.Thread(
                target=self._pump, args=(upstream, client, "answer"), daemon=True
            ).start()

    def _pump(self, src: socket.socket, dst: socket.socket, what: str) -> None:
        with contextlib.suppress(OSError):
            while data := src.recv(65536):
                if self.mode == "pass" or (self.mode == "mute" and what == "request"):
                    dst.sendall(data)

    def close(self) -> None:
        self.server.close()
        for s in self.sockets:
            with contextlib.suppress(OSError):
                s.close()


@dataclass
class Pair:
    edge: Engine
    cloud: Engine
    apis: list[ControlApi]
    gate: Gate

    def source(self) -> HandlerClient:
        return HandlerClient(f"127.0.0.1:{self.apis[0].port}", TOKEN)

    def destination(self) -> HandlerClient:  # through the gate
        return HandlerClient(f"127.0.0.1:{self.gate.port}", TOKEN)

    def active(self) -> list[str]:
        return [e.name for e in (self.edge, self.cloud) if e.slots["m"].active]
