"""A call that may hang fails instead (:func:`bounded`, :class:`Hang`)."""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Iterator
from types import FrameType


class Hang(BaseException):
    """A call ran past its time (:func:`bounded`): a BaseException, so that no ``except
    Exception`` in the code under test eats it."""


@contextlib.contextmanager
def bounded(seconds: float) -> Iterator[None]:
    """Fail with :class:`Hang` instead of hanging (main thread only: SIGALRM)."""

    def expire(signum: int, frame: FrameType | None) -> None:
        raise Hang(f"no answer within {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
