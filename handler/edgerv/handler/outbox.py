"""Verdicts on their way from the scheduler to the sinks (docs/handler.md, "Verdicts under
load").

Each sink has a *lane*: a bounded queue and a thread of its own that hands the sink what
waits, in batches. The scheduler never waits for a sink that coalesces: when a lane's
queue is full, a monitor's further verdicts are *coalesced* into a :class:`Burst` (how
many, the first and the last), one open burst per monitor, queued where the first came,
so a lane holds at most its capacity plus one burst a monitor, and each monitor's
verdicts reach the sink in their order. An *exact* lane (the verdict log) never
coalesces: the scheduler waits for room (it evaluates later, and a monitor whose buffer
fills meanwhile drops events, counted), so what it writes is every verdict reached.

:class:`VerdictQueue` is the pure part (no thread, no clock); :class:`Lane` runs one.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

from edgerv.core.pipeline import Verdict

log = logging.getLogger("edgerv.handler.outbox")

QUEUED = 20_000  # items a lane's queue holds before it coalesces (or, exact, waits)
BATCH = 2_000  # items handed to a sink at once
BEHIND_LOG_SECONDS = 10.0  # a lane that coalesces says so at most this often
ITEM_BYTES = 64  # a queued item's own cost (the verdicts are the scheduler's, shared)

T = TypeVar("T")


@dataclass
class Burst(Generic[T]):
    """A monitor's verdicts (or reactions) a lane coalesced: ``count`` of them, from
    ``first`` to ``last`` (the same one when count is 1)."""

    monitor: str
    first: T
    last: T
    count: int = 1

    @property
    def ends(self) -> list[T]:
        """What a sink gets of it one by one: the first, and the last if another."""
        return [self.first] if self.count == 1 else [self.first, self.last]

    @property
    def between(self) -> int:
        """The verdicts a sink gets only as this count: neither the first nor the last."""
        return max(0, self.count - 2)


class VerdictQueue(Generic[T]):
    """A bounded queue that coalesces per monitor once full. Not thread-safe (a
    :class:`Lane` holds its lock around it). ``key``: an item's monitor."""

    def __init__(self, key: Callable[[T], str], capacity: int = QUEUED) -> None:
        self.key = key
        self.capacity = capacity
        self._items: deque[T | Burst[T]] = deque()
        self._open: dict[str, Burst[T]] = {}  # monitor -> its burst still queued
        self.coalesced = 0  # items that joined a burst after its first

    def __len__(self) -> int:
        return len(self._items)

    @property
    def full(self) -> bool:
        return len(self._items) - len(self._open) >= self.capacity

    def put(self, items: Sequence[T]) -> int:
        """Queue ``items`` (in their order); returns how many were coalesced."""
        before = self.coalesced
        q, open_ = self._items, self._open
        for item in items:
            monitor = self.key(item)
            burst = open_.get(monitor)
            if burst is not None:  # its verdicts after a burst join it: their order kept
                burst.last = item
                burst.count += 1
                self.coalesced += 1
            elif len(q) - len(open_) < self.capacity:
                q.append(item)
            else:
                burst = open_[monitor] = Burst(monitor, item, item)
                q.append(burst)
        return self.coalesced - before

    def put_exact(self, items: Sequence[T], room: int) -> int:
        """Queue at most ``room`` of ``items`` without coalescing; returns how many."""
        taken = min(room, len(items))
        self._items.extend(items[:taken])
        return taken

    def take(self, most: int = BATCH) -> list[T | Burst[T]]:
        """The oldest ``most`` items; a burst taken is closed (its monitor's next verdict
        is queued anew)."""
        q, open_ = self._items, self._open
        out: list[T | Burst[T]] = []
        while q and len(out) < most:
            item = q.popleft()
            if isinstance(item, Burst):
                del open_[item.monitor]
            out.append(item)
        return out


def split(items: Sequence[T | Burst[T]]) -> tuple[list[T], list[Burst[T]]]:
    """A batch as its single items and its bursts. Each monitor's order is kept by handing
    a sink the singles first: a burst is its monitor's last item in a batch (what came
    after it while it was queued joined it)."""
    singles: list[T] = []
    bursts: list[Burst[T]] = []
    for item in items:
        if isinstance(item, Burst):
            bursts.append(item)
        else:
            singles.append(item)
    return singles, bursts


class Lane(Generic[T]):
    """One sink's queue and thread. ``exact``: never coalesce, the producer waits for room.
    Thread-safe."""

    def __init__(
        self,
        name: str,
        write: Callable[[Sequence[T], Sequence[Burst[T]]], None],
        key: Callable[[T], str],
        exact: bool = False,
        capacity: int = QUEUED,
        batch: int = BATCH,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.name = name
        self.write = write
        self.exact = exact
        self.batch = batch
        self.clock = clock
        self.queue: VerdictQueue[T] = VerdictQueue(key, capacity)
        self._cond = threading.Condition()
        self._closing = False
        self._busy = False  # the thread is writing a batch it took
        self.written = 0  # items handed to the sink one by one (a burst's ends included)
        self.failed = 0  # batches the sink raised on
        self.unwritten = 0  # items still queued when the lane was closed (not written)
        self._said = -BEHIND_LOG_SECONDS  # when it last said it coalesces
        self._said_count = 0
        self._thread = threading.Thread(target=self._run, name=f"edgerv-sink-{name}", daemon=True)
        self._thread.start()

    @property
    def coalesced(self) -> int:
        return self.queue.coalesced

    def queued(self) -> int:
        with self._cond:
            return len(self.queue)

    def put(self, items: Sequence[T], until: float | None = None) -> None:
        """Queue ``items``. An exact lane waits for room (at most until ``until``,
        monotonic, and not once the lane closes: what does not fit then is counted
        unwritten)."""
        if not items:
            return
        with self._cond:
            if self._closing:
                self.unwritten += len(items)
                return
            if not self.exact:
                n = self.queue.put(items)
                self._cond.notify()
                if n:
                    self._behind()
                return
            done = 0
            while done < len(items):
                room = self.queue.capacity - len(self.queue)
                if room > 0:
                    done += self.queue.put_exact(items[done:], room)
                    self._cond.notify()
                    continue
                if self._closing or (until is not None and self.clock() >= until):
                    self.unwritten += len(items) - done
                    return
                self._cond.wait(0.1)

    def _behind(self) -> None:
        """Say that this lane coalesces, at most every BEHIND_LOG_SECONDS (lock held)."""
        now = self.clock()
        if now - self._said < BEHIND_LOG_SECONDS:
            return
        n = self.queue.coalesced
        log.warning(
            "verdict sink %s falls behind: %d verdicts coalesced since %s, %d in all "
            "(edgerv_verdicts_coalesced_total): each monitor's count, first and last "
            "verdict still go out; the handler keeps taking messages",
            self.name,
            n - self._said_count,
            "its last line" if self._said_count else "it started",
            n,
        )
        self._said, self._said_count = now, n

    def _run(self) -> None:
        while True:
            with self._cond:
                while not len(self.queue) and not self._closing:
                    self._cond.wait()
                if not len(self.queue) and self._closing:
                    return
                items = self.queue.take(self.batch)
                self._busy = True
                self._cond.notify_all()  # an exact producer waits for room
            try:
                singles, bursts = split(items)
                self.write(singles, bursts)
                self.written += len(singles) + sum(len(b.ends) for b in bursts)
            except Exception:  # a failing sink must not stop its lane (or the others)
                self.failed += 1
                if self.failed in (1, 10, 100) or self.failed % 1000 == 0:
                    log.exception("verdict sink %s failed (%d times)", self.name, self.failed)
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()

    def flush(self, until: float) -> bool:
        """Wait until everything queued is written, at most until ``until`` (monotonic)."""
        with self._cond:
            while len(self.queue) or self._busy:
                left = until - self.clock()
                if left <= 0:
                    return False
                self._cond.wait(min(left, 0.1))
            return True

    def close(self, until: float) -> int:
        """Write what is queued until ``until`` (monotonic), then stop; returns the items
        left unwritten (counted in :attr:`unwritten`)."""
        self.flush(until)
        with self._cond:
            self._closing = True
            left = self.queue.take(len(self.queue) or 1) if len(self.queue) else []
            n = sum(b.count if isinstance(b, Burst) else 1 for b in left)
            self.unwritten += n
            self._cond.notify_all()
        self._thread.join(timeout=max(0.0, until - self.clock()) + 1.0)
        return n


# -- the engine's side -------------------------------------------------------------------


class VerdictSink(Protocol):
    def write(self, handler: str, verdicts: Sequence[Verdict]) -> None: ...


def hand_to(
    sink: VerdictSink, handler: str
) -> Callable[[Sequence[Verdict], Sequence[Burst[Verdict]]], None]:
    """A lane's writer for ``sink``: its singles, then its bursts, through the sink's
    ``write_bursts`` when it has one, else as each burst's first and last verdicts."""
    own = getattr(sink, "write_bursts", None)

    def write(singles: Sequence[Verdict], bursts: Sequence[Burst[Verdict]]) -> None:
        if singles:
            sink.write(handler, singles)
        if bursts:
            if own is not None:
                own(handler, bursts)
            else:
                sink.write(handler, [v for b in bursts for v in b.ends])

    return write


def _monitor(v: Verdict) -> str:
    return v.monitor


class Outbox:
    """The engine's one verdict sink: each batch goes to every lane (one per sink) and
    the scheduler goes on. :meth:`close` gives what is queued a deadline."""

    def __init__(self, handler: str, capacity: int = QUEUED) -> None:
        self.handler = handler
        self.capacity = capacity
        self.lanes: list[Lane[Verdict]] = []
        self.until: float | None = None  # set at stop: an exact lane waits no longer

    def add(self, name: str, sink: VerdictSink, exact: bool = False) -> Lane[Verdict]:
        lane = Lane(name, hand_to(sink, self.handler), _monitor, exact, self.capacity)
        self.lanes.append(lane)
        return lane

    def write(self, handler: str, verdicts: Sequence[Verdict]) -> None:
        for lane in self.lanes:
            lane.put(verdicts, self.until)

    def counts(self) -> dict[str, tuple[int, int, int]]:
        """Per lane: verdicts coalesced, items queued now, verdicts left unwritten."""
        return {lane.name: (lane.coalesced, lane.queued(), lane.unwritten) for lane in self.lanes}

    def coalesced(self) -> dict[str, int]:
        return {lane.name: lane.coalesced for lane in self.lanes}

    def close(self, until: float) -> None:
        """Write what is queued until ``until`` (monotonic), every lane at once; say what
        was left unwritten."""
        self.until = until
        for lane in self.lanes:
            lane.flush(until)
        for lane in self.lanes:
            if lane.close(until) or lane.unwritten:
                log.error(
                    "verdict sink %s: %d verdicts not written: the handler's stop time ran "
                    "out with them queued",
                    lane.name,
                    lane.unwritten,
                )


class ReactionLane:
    """The engine's reactor, through a lane: a violation's reactions are done on the
    lane's thread, and a monitor whose violations come faster than they are done reacts
    to the first and last of each burst (the count is in the lane's coalesced)."""

    def __init__(self, reactor: Any, handler: str, capacity: int = QUEUED) -> None:
        self.reactor = reactor
        self.handler = handler

        def write(singles: Sequence[Any], bursts: Sequence[Burst[Any]]) -> None:
            reactor.react(handler, [*singles, *(d for b in bursts for d in b.ends)])

        self.lane: Lane[Any] = Lane("reactions", write, lambda d: d[0].monitor, False, capacity)

    def prepare(self, reaction: Any) -> None:
        self.reactor.prepare(reaction)

    def react(self, handler: str, due: Sequence[Any]) -> None:
        self.lane.put(due)

    def close(self, until: float) -> None:
        self.lane.close(until)
