"""A live handler's engine driven by a test: its clock (:class:`ManualClock`) and the
robot's two topics heard from a thread (:func:`robot_feed`)."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator, Sequence
from typing import Any


class ManualClock:
    """An engine's clock (handler.engine.Clock) that moves only when told, or, with
    ``running``, as the real one does plus what it was told."""

    def __init__(self, running: bool = False) -> None:
        self.running = running
        self.offset = 0.0 if running else 1000.0

    def monotonic(self) -> float:
        return self.offset + (time.monotonic() if self.running else 0.0)

    def wall_ns(self) -> int:
        return int(self.offset * 1e9) + (time.time_ns() if self.running else 1_700_000_000 * 10**9)

    def advance(self, seconds: float) -> None:
        self.offset += seconds


class Feed:
    """The robot's feed running (:func:`robot_feed`): how many pairs every engine heard."""

    def __init__(self) -> None:
        self.rounds = 0
        self.heard = threading.Condition()

    def wait_round(self, timeout: float = 30.0) -> None:
        """Until every engine has heard one more pair from now, however busy the machine."""
        with self.heard:
            target = self.rounds + 1
            if not self.heard.wait_for(lambda: self.rounds >= target, timeout):
                raise TimeoutError(f"the robot's feed thread heard nothing in {timeout:g} s")


@contextlib.contextmanager
def robot_feed(engines: Sequence[Any]) -> Iterator[Feed]:
    """Every engine hears the robot's two topics while the block runs: /a (true) and /x
    (0 to 6) half a millisecond of stamps apart, a pair every 2 ms, from a thread. The
    block starts once every engine has heard the first pair, however busy the machine;
    :meth:`Feed.wait_round` waits for one more."""
    stop, feed = threading.Event(), Feed()

    def publish() -> None:
        stamp = 0
        while not stop.is_set():
            stamp += 1_000_000
            batch = [(stamp, "/a", [True]), (stamp + 500_000, "/x", [float(stamp % 7)])]
            for e in engines:
                e.ingest(batch)
            with feed.heard:
                feed.rounds += 1
                feed.heard.notify_all()
            time.sleep(0.002)

    feeder = threading.Thread(target=publish, daemon=True)
    feeder.start()
    try:
        with feed.heard:
            if not feed.heard.wait_for(lambda: feed.rounds > 0, 30.0):
                raise TimeoutError("the robot's feed thread did not run in 30 s")
        yield feed
    finally:
        stop.set()
        feeder.join()
