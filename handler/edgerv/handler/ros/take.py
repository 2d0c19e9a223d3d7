"""The take loop: how messages reach the engine.

Instead of the stock executor (a Python callback per message, about 6,000 messages/s on
a small machine), one thread waits on a wait set and *takes* every ready message as the
bytes the publisher sent, reads just the needed fields from the CDR
(:mod:`edgerv.core.cdr`), orders what it took by timestamp and hands the batch to the
engine.

The timestamp of a message is its ``header.stamp`` when it has a header, else the DDS
source timestamp: the instant the robot published it (with ``--use-sim-time``, the ROS
time then: :meth:`edgerv.handler.clock.SimClock.published`).
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from operator import itemgetter, lt
from typing import Any

from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

from edgerv.handler.clock import SimClock
from edgerv.handler.engine import Engine
from edgerv.handler.reorder import ReorderWindow
from edgerv.handler.ros.deadline import DeadlineTopic
from edgerv.handler.ros.subscriptions import TAKE_PER_WAKE, Subscription, Subscriptions

log = logging.getLogger("edgerv.handler.ros")

COALESCE_SECONDS = 0.0005  # at most this much latency for much less work per message
# How long the loop waits for a message before it says again how far everything is
# taken (engine.drained_at), and looks at what changed: IDLE_WAIT_SECONDS when idle (an
# idle handler's wake-ups cost CPU: issue 35), waking at once when the routes change,
# a subscription is to be made, the handler stops or the scheduler finds it said so
# longer than engine.STALE_DRAINED_SECONDS ago when a clock is to step (engine.wake_ingest);
# BUSY_WAIT_SECONDS while a handoff is under way or under --use-sim-time
IDLE_WAIT_SECONDS = 1.0
BUSY_WAIT_SECONDS = 0.1
_FIRST = itemgetter(0)
LOST_LOG_SECONDS = 10.0  # a topic's lost messages are logged at most this often
# (stamp ns, topic, field values, the message's bytes, the routes version they were read for)
Taken = tuple[int, str, list[Any], bytes, int]


class TakeLoop:
    """The ingest thread (``edgerv-ingest``, :meth:`start`): waits on ``subscriptions``
    (and --deadline's topic, and the guard condition ``wakeup``), takes what came, passes
    it through the reorder window (``reorder_window`` seconds; 0: none) to the engine,
    and says how far everything that reached the handler is taken (engine.drained_at);
    until ``stop`` is set. It makes and changes the subscriptions, in its own thread."""

    def __init__(
        self,
        node: Any,
        engine: Engine,
        subscriptions: Subscriptions,
        deadline: DeadlineTopic | None,
        wakeup: Any,
        stop: threading.Event,
        reorder_window: float = 0.02,
        sim: SimClock | None = None,
    ) -> None:
        self.node = node
        self.engine = engine
        self.subscriptions = subscriptions
        self.deadline = deadline
        self.wakeup = wakeup
        self._stop = stop
        self.reorder_window = reorder_window
        self.sim = sim  # --use-sim-time: stamps of unstamped messages, drained_at in ROS time
        self._lost_logged: dict[str, float] = {}  # topic -> when its losses were last logged
        self.ready = threading.Event()  # set once the loop waits on its subscriptions
        self.failed = False
        self._thread: threading.Thread | None = None

    def take_all(self, subs: list[Subscription]) -> tuple[list[Taken], int]:
        """One round over ``subs``: up to TAKE_PER_WAKE messages from each, in timestamp
        order across topics; and the instant (wall ns) before which everything that had
        reached these subscriptions is now taken: the round's start, or earlier where a
        subscription still holds messages (the source timestamp of the last one taken)."""
        batch: list[Taken] = []
        through = time.time_ns()
        version = self.subscriptions.version
        append = batch.append
        oldest_source: int | None = None
        delivered = 0  # subscriptions that had messages
        lags, lag_cap = self.engine.stamp_lag, int(self.engine.flush_after * 1e9)
        published = None if self.sim is None else self.sim.published  # ROS time of a source
        taking = self.engine.taking_ns
        note_reach = self.engine.reach.note
        # CPU (this thread's) since the last topic that delivered: a topic's share is what
        # its takes and reads cost, with the empty takes before it (one reading a round
        # and one a topic that delivers, where each topic's took two: ~0.75 us a reading)
        clock = time.thread_time_ns
        mark = clock()
        for sub in subs:
            topic = sub.route.topic
            handle, reader, cls = sub.subscription.handle, sub.reader, sub.subscription.msg_type
            take = handle.take_message
            got = take(cls, True)
            if got is None:
                continue
            delivered += 1
            first = got[1]["source_timestamp"]  # a subscription's first message is its oldest
            oldest_source = first if oldest_source is None else min(oldest_source, first)
            lag = 0  # the most a message here reached this handler after its stamp
            way = 0  # and after its publication (reach.py)
            left = TAKE_PER_WAKE
            seqs: list[int] = []
            while got is not None:
                raw, info = got
                source = info["source_timestamp"]
                seqs.append(info["publication_sequence_number"])
                try:
                    values, stamp = reader(raw)
                except Exception:  # a malformed message is counted and skipped
                    self.subscriptions.bad_message(topic, sub.route.msg_type)
                else:
                    at = source if published is None else published(source)
                    # published after its stamp (a header stamp), then on its way here
                    # (0: the middleware did not say when it came; taken now, at latest)
                    received = info["received_timestamp"] or time.time_ns()
                    travel = received - source
                    if travel > way:
                        way = travel
                    reach = (at - stamp if stamp else 0) + travel
                    if reach > lag:
                        lag = reach
                    # unstamped: 0; the bytes and the routes' version: read again if they change
                    append((stamp or at, topic, values, raw, version))
                left -= 1
                if not left:  # messages may be left: taken up to this one's publication
                    through = min(through, source)
                    break
                got = take(cls, True)
            if lag > lags.get(topic, -1):  # (a topic that reached it at all has one)
                lags[topic] = min(lag, lag_cap)
            note_reach(way)
            self._count_lost(sub, seqs)
            now = clock()
            taking[topic] = taking.get(topic, 0) + now - mark
            mark = now
        # how old the oldest message waiting here was: nothing waited, none (a lag read
        # once would otherwise stay after the last monitor left, and keep the handler
        # from reading as calm: the policy would never bring monitors home)
        self.engine.ingest_lag = (
            0.0 if oldest_source is None else max(0.0, (time.time_ns() - oldest_source) / 1e9)
        )
        if delivered > 1:
            batch.sort(key=_FIRST)  # one order across topics: by timestamp
        return batch, through

    def _count_lost(self, sub: Subscription, seqs: list[int]) -> None:
        """Messages the middleware lost before this handler took them (a subscription's
        queue that overflowed, best-effort delivery): the gaps in the publication sequence
        numbers of what a round took, counted while the topic has one publisher (the graph
        thread's count, a second old at most; rclpy does not say which publisher sent a
        message: with several, their numbers interleave). A number that goes back (a new
        or restarted publisher) starts over."""
        last = sub.last_seq
        if sub.publishers != 1 or not all(map(lt, seqs, seqs[1:])):
            sub.last_seq = None  # several publishers, or one that started again
            return
        if last is not None and seqs[0] > last:
            lost = seqs[-1] - last - len(seqs)  # increasing: the gaps, summed
            if lost:
                topic = sub.route.topic
                n = self.engine.lost[topic] = self.engine.lost.get(topic, 0) + lost
                now = time.monotonic()
                if now - self._lost_logged.get(topic, -LOST_LOG_SECONDS) >= LOST_LOG_SECONDS:
                    self._lost_logged[topic] = now
                    log.warning(
                        "%s: %d message(s) lost before this handler took them, %d in all "
                        "(edgerv_messages_lost_total): its monitors' verdicts may differ "
                        "from a recording's; a larger qos.depth, or a handler less loaded",
                        topic,
                        lost,
                        n,
                    )
        sub.last_seq = seqs[-1] if last is None or seqs[0] > last else None

    def _ingest(self, items: list[Taken]) -> None:
        """Hand taken messages to the engine, read for the fields its routes have now.

        Messages wait in the reorder window while monitors come and go (a handoff adds
        some mid-stream), and the API changes the engine's routes from another thread:
        a message read for an older set of fields is read again from its bytes, and the
        engine refuses a batch read for routes it no longer has (then this retries)."""
        subscriptions = self.subscriptions
        while items:
            if self.engine.routes_version != subscriptions.version:
                subscriptions.reconfigure()  # the loop rebuilds its wait set on its next turn
            version = subscriptions.version
            batch = []
            for stamp, topic, values, raw, read_for in items:
                if read_for != version:
                    sub = subscriptions.subs.get(topic)
                    if sub is None:
                        continue  # no monitor reads the topic any more
                    try:
                        values = sub.reader(raw)[0]
                    except Exception:  # a malformed message is counted and skipped
                        subscriptions.bad_message(topic, sub.route.msg_type)
                        continue
                batch.append((stamp, topic, values))
            if self.engine.ingest(batch, routes_version=version):
                return
            items = [(s, t, v, r, -1) for s, t, v, r, _ in items]  # all read again

    def drained(self, through: int, reorder: ReorderWindow[Taken] | None) -> None:
        """Everything that reached this handler before ``through`` (wall ns) is taken:
        it is in the engine once no older stamp waits in the reorder window. The
        monitors' clocks and a handoff's cut wait for this instant (engine.drained_at)."""
        self.engine.drained_said = time.monotonic()
        if self.sim is not None:  # in ROS time, as the stamps
            through = self.sim.ros_ns(through)
        if reorder is not None and reorder.pending:
            through = min(through, reorder.pending[0][0])
        drained = self.engine.drained_at
        if drained is None or through > drained:
            self.engine.drained_at = through

    def _loop(self) -> None:
        stack = contextlib.ExitStack()
        wait_set: Any = None
        handles: list[Any] = []
        version = None
        # The window outlives reconfigurations: draining it early would reorder.
        reorder: ReorderWindow[Taken] | None = (
            ReorderWindow(self.reorder_window) if self.reorder_window > 0 else None
        )
        several = False  # one topic is delivered in order: only several need the window
        ingest, taken = self._ingest, self.engine.taken
        subscriptions, deadline = self.subscriptions, self.deadline
        timed: DeadlineTopic | None = None  # --deadline once subscribed: waited on too
        waited: list[Any] = []
        burst = True  # the last round took several messages: more may be gathering
        try:
            while not self._stop.is_set():
                if subscriptions.resubscribing and subscriptions.resubscribe():
                    version = None  # a subscription was re-created: rebuild the wait set
                if deadline is not None and deadline.moving:
                    deadline.move()  # (its subscription goes: the wait set is rebuilt)
                    version = None
                if deadline is not None and deadline.pending:
                    deadline.subscribe()
                    version = None
                if version != self.engine.routes_version:
                    stack.close()  # the wait set is rebuilt for the new subscriptions
                    subscriptions.reconfigure()
                    version = subscriptions.version
                    stack = contextlib.ExitStack()
                    handles = [s.subscription.handle for s in subscriptions.subs.values()]
                    subscribed = deadline is not None and deadline.subscription is not None
                    timed = deadline if subscribed else None
                    waited = [*handles, timed.subscription.handle] if timed else handles
                    for h in (*waited, self.wakeup.handle, self.node.context.handle):
                        stack.enter_context(h)  # keeps each alive while the wait set holds it
                    wait_set = _rclpy.WaitSet(len(waited), 1, 0, 0, 0, 0, self.node.context.handle)
                    several = len(handles) > 1
                    self.ready.set()
                wait_set.clear_entities()
                for h in waited:
                    wait_set.add_subscription(h)
                wait_set.add_guard_condition(self.wakeup.handle)
                if reorder is not None and reorder.pending:
                    timeout = self.reorder_window
                elif self.sim is not None or self.engine.in_handoff:
                    timeout = BUSY_WAIT_SECONDS
                else:
                    timeout = IDLE_WAIT_SECONDS
                wait_set.wait(int(timeout * 1e9))
                waited_at = time.time_ns()
                if reorder is not None:
                    ingest(reorder.due(time.monotonic()))
                ready = set(wait_set.get_ready_entities("subscription"))
                if timed is not None and timed.subscription.handle.pointer in ready:
                    ready.discard(timed.subscription.handle.pointer)  # not a monitor's topic
                    timed.take()
                if not ready:  # (the monitors' topics: the deadline's does not count)
                    self.engine.ingest_lag = 0.0  # nothing waits
                    self.drained(waited_at, reorder)  # everything here was taken
                    continue
                if burst:  # let a burst gather: fewer, larger batches
                    time.sleep(COALESCE_SECONDS)
                # Every round takes from every subscription, not only from those ready at
                # the wait: a topic that was quiet then is not left behind while the
                # others keep coming (it would reach the monitors later than the reorder
                # window allows), and a round over all of them says how far this
                # handler has taken everything (the monitors' clocks wait for that).
                subs, taking = list(subscriptions.subs.values()), subscriptions.version
                batch, through = self.take_all(subs)
                while batch and not self._stop.is_set():  # while messages keep coming
                    # A round that took one message is no burst: back to the wait, which
                    # returns at once if more came meanwhile (at a robot's rates, a round
                    # again over every subscription would take nothing).
                    burst = len(batch) > 1
                    if reorder is not None and (several or reorder.pending):
                        taken(batch)  # a monitor being received learns its cut sooner
                        ingest(reorder.add(batch, time.monotonic()))
                    else:
                        ingest(batch)
                    self.drained(through, reorder)
                    if timed is not None:  # an overloaded handler measures on, too
                        timed.take()
                    if subscriptions.version != taking:  # _ingest subscribed anew (a monitor came)
                        subs, taking = list(subscriptions.subs.values()), subscriptions.version
                    if not burst:
                        break
                    batch, through = self.take_all(subs)
                self.drained(through, reorder)
        finally:
            if reorder is not None:
                ingest(reorder.drain())  # nothing taken is lost at shutdown
            stack.close()

    def start(self, on_failure: Callable[[], None]) -> None:
        """Run the loop in a thread; ``on_failure`` is called if it dies."""
        self._thread = threading.Thread(
            target=self._run, args=(on_failure,), name="edgerv-ingest", daemon=True
        )
        self._thread.start()

    def _run(self, on_failure: Callable[[], None]) -> None:
        try:
            self._loop()
        except Exception:
            log.exception("the ingest loop failed: stopping the handler")
            self.failed = True
            self.ready.set()
            on_failure()

    def join(self, timeout: float) -> None:
        if self._thread is not None:
            self._thread.join(timeout=timeout)
