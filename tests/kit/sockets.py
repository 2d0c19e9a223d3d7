"""A client that sends a request a byte at a time (a slow client, as an attack or a bad
link makes one) and sees when the server cuts it off."""

from __future__ import annotations

import socket
import time


def closed_after(
    sock: socket.socket, data: bytes, every: float, at_once: int = 0
) -> tuple[float, bytes]:
    """Send ``data`` (its first ``at_once`` bytes at once) a byte at a time, ``every``
    seconds apart, until the server answers or closes the connection: the seconds from the
    first byte until then, and its answer."""
    start, answer = time.monotonic(), b""
    sock.sendall(data[:at_once])
    sock.settimeout(every)
    for i in range(at_once, len(data)):
        try:
            sock.sendall(data[i : i + 1])
            answer = sock.recv(4096)  # waits a pace's time: an answer, or b"" at the end
        except TimeoutError:
            continue
        except OSError:
            pass  # reset
        break
    took = time.monotonic() - start
    sock.settimeout(5)
    while answer and (more := sock.recv(4096)):
        answer += more
    return took, answer
