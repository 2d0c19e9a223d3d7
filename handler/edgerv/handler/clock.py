"""The time a handler's engine reads, injected (tests move it instead of waiting).

Two clocks: the system clock (:class:`SystemClock`), and with ``--use-sim-time`` the
ROS time a simulator or ``edgerv replay`` publishes on ``/clock``
(``rosgraph_msgs/msg/Clock``), as ROS nodes take it with ``use_sim_time``
(:class:`SimClock`; docs/handler.md, "Sim time").
"""

from __future__ import annotations

import contextlib
import logging
import math
import struct
import threading
import time
from bisect import bisect_right
from collections.abc import Callable
from typing import Any, Protocol

log = logging.getLogger("edgerv.handler.clock")

CLOCK_TOPIC = "/clock"
CLOCK_TYPE = "rosgraph_msgs/msg/Clock"
# a raw subscription's next message, as rclpy takes it: (bytes, info) or None
Take = Callable[[], tuple[bytes, dict[str, Any]] | None]
SYSTEM_CLOCK_HINT = (
    f"{CLOCK_TOPIC} has a publisher (a simulation, `edgerv replay`), but this handler's "
    "clock is the system clock: its timed monitors measure time by that; give "
    "--use-sim-time to follow /clock"
)
# ROS time the engine reads before the first /clock: before every stamp, so no monitor
# takes a clock step until a clock comes (a ROS node's clock reads 0 then)
NO_TIME = -(2**62)
KEEP_SECONDS = 10.0  # /clock samples are kept this long (a message taken late is mapped)
CLOCK_DEPTH = 1000  # /clock samples the subscription holds between two takes
SILENCE_SECONDS = 5.0  # no /clock this long after the start: said once


class Clock(Protocol):
    """The time an engine reads: seconds on a monotonic clock (buffers, pressure,
    handoff expiry) and ROS time in nanoseconds (``wall_ns``: clock steps, silent
    topics; the system clock's, or under ``--use-sim-time`` what :class:`SimClock`
    makes of /clock). Injected, so that tests move time instead of waiting for it."""

    def monotonic(self) -> float: ...

    def wall_ns(self) -> int: ...


class SystemClock:
    def monotonic(self) -> float:
        return time.monotonic()

    def wall_ns(self) -> int:
        return time.time_ns()


class ClockSamples:
    """The /clock samples a handler took, each with the instant it was published (its
    DDS source timestamp) and the instant it reached the handler (the system clock's):
    the ROS time at a publication, and at a moment of the handler's. Pure: no ROS.

    ROS time is a step function: what the last /clock published (or received) said.
    Samples older than ``keep`` (seconds, by reception) than the newest are forgotten;
    an instant before the oldest kept is read as the oldest."""

    def __init__(self, keep: float = KEEP_SECONDS) -> None:
        self.keep_ns = int(keep * 1e9)
        self.sources: list[int] = []  # sorted
        self.by_source: list[int] = []  # the ROS time of each, in that order
        self.received: list[int] = []  # sorted
        self.by_received: list[int] = []
        self.newest: int | None = None  # the ROS time of the sample taken last
        self.count = 0
        self.forgotten = False  # samples were dropped: an instant before them is approximate

    def add(self, source: int, received: int, ros: int) -> int | None:
        """Note a sample; returns the ROS time before it when time went back (a simulation
        reset, a replay started again), else None."""
        back = self.newest if self.newest is not None and ros < self.newest else None
        self.newest = ros
        self.count += 1
        for keys, values, key in (
            (self.sources, self.by_source, source),
            (self.received, self.by_received, received),
        ):
            if not keys or key >= keys[-1]:
                keys.append(key)
                values.append(ros)
            else:  # (another publisher's, a little behind)
                at = bisect_right(keys, key)
                keys.insert(at, key)
                values.insert(at, ros)
        oldest = self.received[-1] - self.keep_ns
        if self.received[0] < oldest and len(self.received) > 64:
            cut = bisect_right(self.received, oldest)
            del self.received[:cut], self.by_received[:cut]
            cut = bisect_right(self.sources, self.sources[-1] - self.keep_ns)
            del self.sources[:cut], self.by_source[:cut]
            self.forgotten = True
        return back

    @staticmethod
    def _at(keys: list[int], values: list[int], instant: int, forgotten: bool) -> int | None:
        i = bisect_right(keys, instant) - 1
        if i >= 0:
            return values[i]
        return values[0] if forgotten and values else None

    def at_source(self, instant: int) -> int | None:
        """The ROS time at ``instant`` (system clock ns) as publishers saw it: what the
        /clock published last at or before it said; None before the first."""
        return self._at(self.sources, self.by_source, instant, self.forgotten)

    def at_received(self, instant: int) -> int | None:
        """The ROS time at ``instant`` as this handler saw it: what the /clock received
        last at or before it said; None before the first."""
        return self._at(self.received, self.by_received, instant, self.forgotten)


def clock_ns(raw: bytes) -> int:
    """The ROS time of a serialized ``rosgraph_msgs/msg/Clock`` (CDR: the encapsulation,
    then ``builtin_interfaces/Time``: int32 sec, uint32 nanosec)."""
    if len(raw) < 12 or raw[0] != 0 or raw[1] not in (0, 1):
        raise ValueError("not a CDR rosgraph_msgs/msg/Clock")
    sec, nanosec = struct.unpack_from("<iI" if raw[1] else ">iI", raw, 4)
    return int(sec) * 1_000_000_000 + int(nanosec)


class SimClock:
    """``--use-sim-time``: ROS time is what ``/clock`` says, as for a ROS node with
    ``use_sim_time`` (the node's own clock follows it too: /diagnostics' and
    /edgerv/last_verdicts' stamps).

    * :meth:`published`: the ROS time at which a message without a header stamp was
      published: what the /clock published last before it said (by DDS source
      timestamps, so a publisher that sends /clock and then its message, as ``edgerv
      replay`` does, gets its stamp exactly);
    * :meth:`wall_ns`, what the engine reads as "now": the ROS time this handler had
      received ``lag`` (its ``--flush-after``) ago, plus ``lag``. The engine steps its
      monitors' clocks up to that minus ``lag``: the ROS time of ``lag`` ago in real
      time, so ``--flush-after`` stays real time for delivery whatever the pace of
      /clock, and once /clock stops (a paused simulation, the end of a replay) the
      monitors reach its last time ``lag`` later;
    * :meth:`ros_ns` maps the ROS layer's "everything that reached this handler before
      this instant is taken" (system clock ns) the same way.

    Before the first /clock, ROS time is :data:`NO_TIME` for the engine (no clock step)
    and 0 for an unstamped message (what a ROS node's clock reads)."""

    def __init__(self, lag: float, samples: ClockSamples | None = None) -> None:
        self.lag_ns = int(max(lag, 0.0) * 1e9)
        self.samples = samples or ClockSamples(KEEP_SECONDS + max(lag, 0.0))
        self._lock = threading.Lock()
        self._subscription: Take | None = None
        self._follow: Callable[[int], None] | None = None
        self.failures = 0
        self.unclocked = 0  # unstamped messages published before the first /clock
        self._back_logged = -1e9  # when time going back was last logged (monotonic s)
        self._overridden: int | None = None  # the time the node's clock was last given
        self._waiting_since: float | None = None  # the first read of time without a /clock

    # -- ROS -------------------------------------------------------------------------------

    def attach(self, take: Take, follow: Callable[[int], None] | None = None) -> None:
        """Take /clock's samples with ``take`` (the ROS layer's: a raw subscription's
        next ``(bytes, info)``, None when none waits), where time is read (no thread of
        its own: the scheduler's tick, the take loop); ``follow`` is given each newer
        time (the node's own clock follows it)."""
        with self._lock:
            self._subscription = take
            self._follow = follow
        log.info("sim time: the handler's clock is %s (rosgraph_msgs/msg/Clock)", CLOCK_TOPIC)

    def detach(self) -> None:
        with self._lock:
            self._subscription = None

    def catch_up(self) -> None:
        """Take the /clock samples that came."""
        with self._lock:
            self._take()

    def _take(self) -> None:
        """:meth:`catch_up`, the lock held."""
        take = self._subscription
        if take is None:
            return
        try:
            while (got := take()) is not None:
                raw, info = got
                received = info.get("received_timestamp") or time.time_ns()
                back = self.samples.add(info["source_timestamp"], received, clock_ns(raw))
                if back is not None:
                    self._went_back(back)
        except Exception as exc:  # a bad sample, a handle gone at shutdown
            self.failures += 1
            if self.failures in (1, 10, 100) or self.failures % 1000 == 0:
                log.warning(
                    "%s: a sample could not be taken (%s), %d so far",
                    CLOCK_TOPIC,
                    exc,
                    self.failures,
                )
        newest = self.samples.newest
        if newest is not None and newest != self._overridden and self._follow is not None:
            self._overridden = newest
            with contextlib.suppress(Exception):  # (a time the node's clock refuses)
                self._follow(newest)

    def _went_back(self, before: int) -> None:
        now = time.monotonic()
        if now - self._back_logged >= 10.0:
            self._back_logged = now
            log.warning(
                "%s went back from %s to %s (a simulation reset, a replay started again?): "
                "a monitor's time never goes back; events stamped before what it passed "
                "are late",
                CLOCK_TOPIC,
                seconds(before),
                seconds(self.samples.newest or 0),
            )

    # -- the engine's and the ROS layer's time ---------------------------------------------

    def monotonic(self) -> float:
        return time.monotonic()

    def wall_ns(self) -> int:
        return self.ros_ns(time.time_ns())

    def now_ns(self) -> int:
        """ROS time now: what the /clock received last said (0 before the first)."""
        with self._lock:
            self._take()
            return self.samples.newest or 0

    def ros_ns(self, wall: int) -> int:
        """The engine's ROS time for ``wall`` (system clock ns): the /clock time received
        ``lag`` before it, plus ``lag``; :data:`NO_TIME` before the first."""
        with self._lock:
            self._take()
            ros = self.samples.at_received(wall - self.lag_ns)
            if self.samples.newest is None:
                self._no_clock_yet()
        return NO_TIME if ros is None else ros + self.lag_ns

    def _no_clock_yet(self) -> None:
        now = time.monotonic()
        if self._waiting_since is None:
            self._waiting_since = now
        elif now - self._waiting_since >= SILENCE_SECONDS and self._subscription is not None:
            self._waiting_since = math.inf  # said once
            log.warning(
                "--use-sim-time: no %s for %g s: ROS time stands still, and timed monitors "
                "take no clock step (is the simulation, or `edgerv replay`, running in this "
                "ROS_DOMAIN_ID?)",
                CLOCK_TOPIC,
                SILENCE_SECONDS,
            )

    def published(self, source: int) -> int:
        """The ROS time of a message published at ``source`` (its DDS source timestamp):
        what the /clock published last at or before it said; 0 before the first."""
        samples = self.samples
        with self._lock:
            if not samples.sources or source > samples.sources[-1]:
                self._take()  # a /clock published just before it may be waiting
            ros = samples.at_source(source)
        if ros is None:
            self.unclocked += 1
            if self.unclocked == 1:
                log.warning(
                    "a message without a header stamp was published before the first %s "
                    "reached this handler: stamped 0, as a ROS node's clock reads then",
                    CLOCK_TOPIC,
                )
            return 0
        return ros


def seconds(ns: int) -> str:
    """A ROS time as seconds.nanoseconds."""
    sec, nanosec = divmod(ns, 1_000_000_000)
    return f"{sec}.{nanosec:09d}"
