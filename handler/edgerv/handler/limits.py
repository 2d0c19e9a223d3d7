"""What clients may take of a handler's control API (docs/handler.md, "Limits on input").

Apart from ``api`` so that ``edgerv handler --help`` shows the defaults without loading
aiohttp (the command line is built for every ``edgerv`` command).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Limits:
    """The defaults suit a small board. Without them one client could hold the API:
    aiohttp keeps an idle connection an hour and waits for a request's head or body, or
    for its answer to be read, for ever; and every monitor defined costs memory.

    Who holds a place, and who is closed to let others in: :mod:`edgerv.handler.admission`.
    """

    connections: int = 32  # admitted at once: a request with the token came on each
    pending: int = 256  # not admitted (yet) at once; one more closes one of the address with most
    read_seconds: float = 10.0  # to send a request's head and body (from its first byte)
    idle_seconds: float = 30.0  # a connection with no request under way is closed after
    monitors: int = 10_000  # defined here, active or not (~10 KiB each: bench/RESULTS.md)
    bodies: int = 128 << 20  # bytes of request bodies held at once, all requests together
    bundle: int = 256 << 20  # bytes a snapshot bundle may take, inflated and decoded

    def full(self, defined: int) -> str:
        """Why one more monitor is refused."""
        return (
            f"this handler holds {defined} monitors, its limit (--max-monitors "
            f"{self.monitors}): remove or move one, or start it with a higher --max-monitors"
        )
