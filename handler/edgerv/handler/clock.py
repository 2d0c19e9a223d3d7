"""The time a handler's engine reads, injected (tests move it instead of waiting)."""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    """The time an engine reads: seconds on a monotonic clock (buffers, pressure,
    handoff expiry) and wall nanoseconds (ROS time: clock steps, silent topics).
    Injected, so that tests move time instead of waiting for it."""

    def monotonic(self) -> float: ...

    def wall_ns(self) -> int: ...


class SystemClock:
    def monotonic(self) -> float:
        return time.monotonic()

    def wall_ns(self) -> int:
        return time.time_ns()
