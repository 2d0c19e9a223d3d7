"""The monitor handler's logic, without ROS: monitors, placement, buffers, pressure, verdicts.

Two threads drive an :class:`Engine`: the ingest thread (the ROS layer) calls
:meth:`Engine.ingest` with messages already reduced to their field values, and
the scheduler thread calls :meth:`Engine.run_scheduler`, which evaluates the
letters of active monitors and hands verdicts to the sinks. A lock guards the
monitors; sinks run outside it.

A monitor is *defined* on every handler but *active* (subscribed, buffering,
scheduled) only where it is placed (the paper's section III).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Collection, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from edgerv.core.deadline import MakespanWindow
from edgerv.core.diagnostics import Diagnostic, InputError
from edgerv.core.documents import MonitorSpec
from edgerv.core.handoff import (
    HandoffError,
    Snapshot,
    cut_point,
    export_snapshot,
    restore,
)
from edgerv.core.monitor import CompiledMonitor, compile_monitor
from edgerv.core.pipeline import MonitorRuntime, Router, TopicRoute, Verdict
from edgerv.core.placement import placement_json
from edgerv.handler.handoff_state import HandoffState, check_transition

log = logging.getLogger("edgerv.handler")

# A monitor "wants to migrate" when its buffer stays at least this full for PRESSURE_SECONDS,
# and stops wanting it once the buffer is below LOW_WATER (hysteresis).
HIGH_WATER = 0.5
LOW_WATER = 0.25
PRESSURE_SECONDS = 1.0
# The scheduler evaluates every SCHEDULE_SECONDS while letters wait (verdicts wait at most
# that long), and is woken earlier only when a monitor has WAKE_LETTERS letters waiting:
# waking it for every message would cost more than evaluating. With none waiting it sleeps
# until its next tick (an idle handler does not wake 500 times a second), and the first
# letters to come wake it.
SCHEDULE_SECONDS = 0.002
WAKE_LETTERS = 512
SENDING, RELEASED, RECEIVING = HandoffState.SENDING, HandoffState.RELEASED, HandoffState.RECEIVING
HANDOFF_EXPIRES = 120.0  # seconds a handoff may wait for its next step before it is undone
PREHOLD_SECONDS = 0.002  # a scheduler round's time for the buffers of monitors being handed off
ADOPTIONS_KEPT = 64  # per monitor: the epochs of the latest handoffs a handler adopted


class VerdictSink(Protocol):
    def write(self, handler: str, verdicts: Sequence[Verdict]) -> None: ...


@dataclass
class MonitorSlot:
    """One monitor of this handler: its definition and, when active, its runtime."""

    compiled: CompiledMonitor
    runtime: MonitorRuntime | None = None
    events: int = 0
    dropped: int = 0
    verdicts: dict[str, int] = field(default_factory=lambda: {"violated": 0, "satisfied": 0})
    pending_since: float | None = None  # when the event buffer got its oldest event
    full_since: float | None = None  # when the buffer rose above HIGH_WATER
    migration_wanted: bool = False
    capacity: int = field(init=False)
    epoch: int = 0  # the newest handoff this handler took part in, for this monitor
    handoff: HandoffState | None = None  # its handoff state here (handoff_state.py)
    released: Snapshot | None = None  # H1: the snapshot it sent, until the handoff commits
    first_stamps: dict[str, int] = field(default_factory=dict)  # H2: first stamp per topic
    # H2: per topic without a message yet, since when (wall ns) its subscription has been
    # matched with every publisher of the topic (the cut's stamp for a silent topic)
    vouched: dict[str, int] = field(default_factory=dict)
    quiet: tuple[str, ...] = ()  # H2: the topics the cut it reported vouched for
    cut_known: tuple[int, float] | None = None  # H1: the cut, and when it first heard of it
    held_at: float = 0.0  # H1: when it began to hold
    peer: str | None = None  # H1: the receiver, as the driver named it (to settle with)
    handoff_since: float = 0.0  # when it entered its handoff state
    # H2: the epochs of the handoffs it adopted (the newest ADOPTIONS_KEPT), and the newest
    # one forgotten since: a settle may ask about a handoff after a newer one (see abort)
    adopted: list[int] = field(default_factory=list)
    forgotten: int = 0
    prehold: int = 0  # H1: events buffered before the hold, not yet compressed (see hold)

    @property
    def name(self) -> str:
        return self.compiled.name

    def __post_init__(self) -> None:
        self.capacity = self.compiled.spec.buffer_capacity

    @property
    def active(self) -> bool:
        """The monitor is this handler's: it runs here, or is paused here for a handoff."""
        return self.runtime is not None and self.handoff not in (RECEIVING, RELEASED)

    @property
    def buffered(self) -> int:
        return self.runtime.buffered if self.runtime else 0

    def describe(self, handler: str) -> dict[str, Any]:
        rt = self.runtime
        spec = self.compiled.spec
        return {
            "name": self.name,
            "handler": handler,
            "active": self.active,
            "state": rt.status if rt and self.active else "inactive",
            "assertion": spec.assertion,
            "topics": spec.topics,
            "automatonState": rt.state if rt else None,
            "step": rt.step if rt else 0,
            "buffer": {
                "events": len(rt.events) if rt else 0,
                "letters": len(rt.letters) if rt else 0,
                "capacity": self.capacity,
                "fill": round(self.buffered / self.capacity, 4),
            },
            "events": self.events,
            "droppedEvents": self.dropped,
            "lateEvents": rt.late_events if rt else 0,
            "verdicts": dict(self.verdicts),
            "migrationWanted": self.migration_wanted,
            "handoff": self.handoff,
            "epoch": self.epoch,
            "peer": self.peer if self.handoff else None,
            "placement": placement_json(spec.placement),
        }


def _whereabouts(slot: MonitorSlot) -> str:
    """What a monitor is doing here, for a refused ``hold`` or ``receive``: "already runs
    here" only when it does; a monitor held for a handoff is evaluated nowhere here."""
    epoch, peer = slot.epoch, slot.peer or "another handler"
    if slot.handoff == SENDING:
        return f"is held here for a handoff to {peer} (epoch {epoch}), not evaluated"
    if slot.handoff == RELEASED:
        return (
            f"is held here, released to {peer} in a handoff not yet settled (epoch {epoch}), "
            "not evaluated here: that handoff's edgerv migrate, run again, settles it"
        )
    if slot.handoff == RECEIVING:
        return f"is being received here in another handoff (epoch {epoch}), not yet adopted"
    return "already runs here" if slot.runtime is not None else "does not run here"


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


class Engine:
    """All monitors of one handler. Thread-safe."""

    def __init__(
        self,
        name: str,
        sinks: Iterable[VerdictSink] = (),
        flush_after: float = 0.5,
        type_check: Callable[[str], str | None] | None = None,
        reorder_window: float = 0.02,
        matched: Callable[[str], bool] | None = None,
        deadline: MakespanWindow | None = None,
        clock: Clock | None = None,
    ) -> None:
        self.name = name
        self.clock: Clock = clock or SystemClock()
        self.sinks = list(sinks)
        self.flush_after = flush_after
        self.type_check = type_check  # message type -> error text if it cannot be subscribed
        # The delivery skew the handler allows between topics (its reorder window): how
        # long a silent topic's subscription must have been matched before H2 vouches for
        # it, and how far past a cut H1's stream must run before it lets go a topic H2
        # vouched for (docs/protocol.md, "Silent topics").
        self.settle_ns = int(max(reorder_window, 0.01) * 1e9)
        # topic -> its subscription here is matched with every publisher the ROS graph
        # shows (the ROS layer's; None: no ROS, a silent topic never vouched for)
        self.matched = matched
        # wall ns at which the ROS layer last found every subscription empty and nothing in
        # its reorder window: nothing had reached this handler that it had not taken
        self.drained_at: int | None = None
        self.lock = threading.RLock()
        self.ready = threading.Condition(self.lock)
        self.dozing = False  # the scheduler sleeps until its tick: the next letters wake it
        self.slots: dict[str, MonitorSlot] = {}
        self.router = Router()
        self.routes_version = 0  # bumped whenever topics or their fields change
        self.messages: dict[str, int] = {}  # topic -> messages ingested
        # per topic: the newest stamp and when a message last came (a sender's release)
        self.newest: dict[str, int] = {}
        self.heard: dict[str, float] = {}
        self.ingest_lag = 0.0  # seconds between publication and ingestion, last batch
        self.waiting: dict[str, MonitorRuntime] = {}  # monitors with letters to evaluate
        self.in_handoff: dict[str, MonitorSlot] = {}  # so ingest need not scan every slot
        # --deadline: the makespans of the robot's real-time task (the ROS layer measures)
        self.deadline = deadline

    # -- monitors --------------------------------------------------------------------------

    def compile(self, spec: MonitorSpec) -> CompiledMonitor:
        """Compile a monitor and check that its message types can be subscribed to."""
        compiled = compile_monitor(spec)
        if self.type_check is not None:
            errors = []
            for sig in spec.signals.values():
                problem = self.type_check(sig.msg_type)
                if problem:
                    errors.append(
                        Diagnostic(sig.location, f"spec.signals.{sig.name}.type: {problem}")
                    )
            if errors:
                raise InputError(errors)
        return compiled

    def put(self, compiled: CompiledMonitor, active: bool) -> bool:
        """Define (or redefine) a monitor; returns True when it is new.

        Redefining a monitor restarts it: its buffers and automaton state start afresh.
        """
        with self.lock:
            old = self.slots.get(compiled.name)
            if old is not None and old.runtime is not None:
                self.router.remove(old.name)
            slot = MonitorSlot(compiled)
            self.slots[compiled.name] = slot
            self.in_handoff.pop(compiled.name, None)
            if active:
                self._activate(slot)
            self.routes_version += 1
            return old is None

    def remove(self, name: str) -> bool:
        with self.lock:
            slot = self.slots.pop(name, None)
            if slot is None:
                return False
            self.in_handoff.pop(name, None)
            if slot.runtime is not None:
                self.router.remove(name)
            self.routes_version += 1
            return True

    def set_active(self, name: str, active: bool) -> None:
        with self.lock:
            slot = self.slots[name]
            if slot.handoff is not None:
                raise HandoffError(
                    f"monitor '{name}' is in a handoff ({slot.handoff}); abort it first"
                )
            if active and slot.runtime is None:
                self._activate(slot)
            elif not active and slot.runtime is not None:
                self.router.remove(name)
                slot.runtime = None
            self.routes_version += 1

    def _activate(self, slot: MonitorSlot) -> None:
        slot.runtime = MonitorRuntime(slot.compiled)
        self.router.add(slot.runtime)

    def routes(self) -> dict[str, TopicRoute]:
        """A snapshot of the topics to subscribe to (with their fields and QoS)."""
        with self.lock:
            return dict(self.router.routes)

    # -- the data path ---------------------------------------------------------------------

    def ingest(
        self,
        batch: Sequence[tuple[int, str, Sequence[Any]]],
        now: float | None = None,
        routes_version: int | None = None,
    ) -> bool:
        """Offer messages, in this order, as ``(stamp ns, topic, field values)``.

        ``routes_version``: the :attr:`routes_version` the values were read for (each
        topic's fields, in its route's order). If the routes changed since (a monitor
        added or removed meanwhile), nothing is offered and False is returned: the
        caller reads the messages again for the new fields and retries."""
        if not batch:
            return True
        now = self.clock.monotonic() if now is None else now
        woke = False
        with self.lock:
            if routes_version is not None and routes_version != self.routes_version:
                return False
            routes, slots = self.router.routes, self.slots

            def admit(runtime: MonitorRuntime) -> bool:
                slot = slots[runtime.name]
                if len(runtime.events) + len(runtime.letters) >= slot.capacity:
                    slot.dropped += 1
                    if slot.dropped in (1, 10, 100, 1000) or slot.dropped % 10000 == 0:
                        log.warning(
                            "monitor %s: buffer full (%d events), %d events dropped",
                            slot.name,
                            slot.capacity,
                            slot.dropped,
                        )
                    return False
                slot.events += 1
                if slot.pending_since is None:
                    slot.pending_since = now
                return True

            messages, newest, heard = self.messages, self.newest, self.heard
            if self.in_handoff:
                self._note_firsts(batch)
            for stamp, topic, values in batch:
                route = routes.get(topic)
                if route is None:
                    continue
                messages[topic] = messages.get(topic, 0) + 1
                heard[topic] = now
                if stamp > newest.get(topic, stamp - 1):
                    newest[topic] = stamp
                for runtime in self.router.offer_values(route, stamp, values, admit):
                    slots[runtime.name].pending_since = now if runtime.events else None
                    self.waiting[runtime.name] = runtime
                    woke = woke or len(runtime.letters) >= WAKE_LETTERS
            if woke or (self.dozing and self.waiting):
                self.dozing = False
                self.ready.notify()
        return True

    def taken(self, batch: Sequence[tuple[Any, ...]]) -> None:
        """Messages taken from their subscriptions, before they are merged in stamp order
        (the ROS layer's reorder window): a receiver notes its first stamp on each topic
        from them, a window earlier. Each is ingested after, in the same topic order."""
        if batch and self.in_handoff:
            with self.lock:
                self._note_firsts(batch)

    def _note_firsts(self, batch: Sequence[tuple[Any, ...]]) -> None:
        """H2 notes its first stamp on each topic of a receiving monitor (for the cut)."""
        for slot in self.in_handoff.values():
            firsts, topics = slot.first_stamps, slot.compiled.spec.topics
            if slot.handoff == RECEIVING and len(firsts) < len(topics):
                for item in batch:
                    topic = item[1]
                    if topic not in firsts and topic in topics:
                        firsts[topic] = item[0]

    def _evaluate(self) -> list[Verdict]:
        """Evaluate the letters of the monitors that have some (not all monitors: cheap)."""
        verdicts: list[Verdict] = []
        waiting, self.waiting = self.waiting, {}
        for name, rt in waiting.items():
            slot = self.slots.get(name)
            if slot is None or slot.runtime is not rt:
                continue  # removed or redefined since
            for v in rt.evaluate():
                slot.verdicts[v.verdict] += 1
                verdicts.append(v)
        return verdicts

    def advance_clocks(self, wall_ns: int) -> None:
        """Time passes for the monitors with timed atoms: each takes its clock steps up to
        ``wall_ns - flush_after`` (this handler's clock; stamps are ROS time), the moment
        before which it takes every event as in (docs/semantics.md, "Time")."""
        until = wall_ns - int(self.flush_after * 1e9)
        with self.lock:
            for slot in self.slots.values():
                rt = slot.runtime
                if rt is not None and rt.clock is not None and slot.active and rt.advance(until):
                    self.waiting[rt.name] = rt
                    if not rt.events:
                        slot.pending_since = None

    def tick(self, now: float | None = None) -> list[Verdict]:
        """Release event buffers that waited longer than ``flush_after``; update pressure."""
        now = self.clock.monotonic() if now is None else now
        with self.lock:
            self._precompress()
            self._expire_handoffs(now)
            self.advance_clocks(self.clock.wall_ns())
            for slot in self.slots.values():
                rt = slot.runtime
                if rt is None:
                    continue
                if (
                    slot.pending_since is not None
                    and not rt.holding
                    and now - slot.pending_since >= self.flush_after
                ):
                    if rt.flush():
                        self.waiting[rt.name] = rt
                    slot.pending_since = None
                if (
                    not rt.events
                    and not rt.letters
                    and slot.full_since is None
                    and not slot.migration_wanted
                ):
                    continue  # an idle monitor: nothing to update
                fill = rt.buffered / slot.capacity
                if fill >= HIGH_WATER:
                    slot.full_since = slot.full_since if slot.full_since is not None else now
                    if now - slot.full_since >= PRESSURE_SECONDS and not slot.migration_wanted:
                        slot.migration_wanted = True
                        log.warning(
                            "monitor %s: buffer %.0f%% full for %.1f s: migration wanted",
                            slot.name,
                            fill * 100,
                            now - slot.full_since,
                        )
                else:
                    slot.full_since = None
                    if fill < LOW_WATER:
                        slot.migration_wanted = False
            return self._evaluate()

    def emit(self, verdicts: Sequence[Verdict]) -> None:
        if verdicts:
            for sink in self.sinks:
                try:
                    sink.write(self.name, verdicts)
                except Exception:  # a failing sink must not stop the others or the scheduler
                    log.exception("verdict sink %s failed", type(sink).__name__)

    def run_scheduler(self, stop: threading.Event, period: float = 0.05) -> None:
        """The scheduler thread: evaluate every SCHEDULE_SECONDS, tick every ``period``."""
        next_tick = time.monotonic()
        while not stop.is_set():
            with self.lock:
                self.dozing = not self.waiting and not self.in_handoff
                doze = max(0.0, next_tick - time.monotonic())
                self.ready.wait(timeout=doze if self.dozing else SCHEDULE_SECONDS)
                self.dozing = False
                verdicts = self._evaluate()
                if self.in_handoff:
                    self._precompress()
            if time.monotonic() >= next_tick:
                verdicts += self.tick()
                next_tick = time.monotonic() + period
            self.emit(verdicts)

    def drain(self) -> None:
        """At shutdown: release every buffer and evaluate it, so no accepted event is lost."""
        with self.lock:
            for slot in self.slots.values():
                if slot.runtime is not None and slot.active:  # not what is held for the other side
                    slot.runtime.flush()
                    self.waiting[slot.name] = slot.runtime
                    slot.pending_since = None
            verdicts = self._evaluate()
        self.emit(verdicts)

    # -- handoff (docs/protocol.md): each step is a call; epochs fence stale ones -----------

    def _slot(self, name: str) -> MonitorSlot:
        slot = self.slots.get(name)
        if slot is None:
            raise HandoffError(f"no monitor '{name}' here")
        return slot

    def hold(
        self, name: str, epoch: int, now: float | None = None, peer: str | None = None
    ) -> None:
        """H1, step 2a: stop scheduling the monitor, keep buffering its events.

        ``peer`` names the receiver: whoever settles an interrupted handoff asks it."""
        now = self.clock.monotonic() if now is None else now
        with self.lock:
            slot = self._slot(name)
            if epoch <= slot.epoch:
                raise HandoffError(f"epoch {epoch} is not newer than {slot.epoch}")
            if slot.runtime is None or slot.handoff is not None:
                raise HandoffError(f"monitor '{name}' {_whereabouts(slot)}")
            slot.epoch = epoch
            self._set_handoff(slot, SENDING)
            slot.cut_known, slot.held_at, slot.peer = None, now, peer
            slot.runtime.holding = True
            # What the sort buffer holds now is all at or before any cut H2 can report
            # (H2 subscribes after this, and each topic is delivered in order): the
            # scheduler compresses it while the handoff goes on (a partial batch, as
            # flushAfter releases one), so that the release has only the rest to do.
            slot.prehold = len(slot.runtime.events)
            self.waiting.pop(name, None)

    def receive(self, name: str, epoch: int) -> None:
        """H2, step 3: subscribe and hold the monitor's events, without scheduling it."""
        with self.lock:
            slot = self._slot(name)
            if epoch <= slot.epoch:
                raise HandoffError(f"epoch {epoch} is not newer than {slot.epoch}")
            if slot.runtime is not None:
                raise HandoffError(f"monitor '{name}' {_whereabouts(slot)}")
            slot.epoch, slot.first_stamps, slot.vouched = epoch, {}, {}
            self._set_handoff(slot, RECEIVING)
            self._activate(slot)
            assert slot.runtime is not None
            # H2 holds its events raw: they are compressed after H1's, from H1's state
            slot.runtime.holding, slot.runtime.speculate = True, False
            self.routes_version += 1

    def cut(self, name: str, epoch: int, wall: int | None = None) -> int | None:
        """H2, step 4: the cut once every topic delivered an event or is vouched for,
        else None.

        A topic that brought nothing yet is vouched for from ``settle`` after the moment
        its subscription was seen matched with every publisher of the topic (none at
        all: from its subscription): from then on every message published on it
        reaches H2, so that moment plus ``settle`` stands for its first stamp."""
        wall = self.clock.wall_ns() if wall is None else wall
        with self.lock:
            slot = self._handoff_slot(name, epoch, RECEIVING)
            topics, firsts = slot.compiled.spec.topics, dict(slot.first_stamps)
            quiet = []
            for topic in topics:
                if topic in firsts or self.matched is None:
                    continue
                if not self.matched(topic):  # a new publisher, or not subscribed yet
                    slot.vouched.pop(topic, None)
                    continue
                since = slot.vouched.setdefault(topic, wall) + self.settle_ns
                if wall >= since:
                    firsts[topic] = since
                    quiet.append(topic)
            cut = cut_point(firsts, topics)
            slot.quiet = tuple(quiet) if cut is not None else ()
            return cut

    def release(
        self,
        name: str,
        epoch: int,
        cut: int,
        grace: float,
        now: float | None = None,
        quiet: Collection[str] = (),
    ) -> Snapshot | None:
        """H1, step 5: the snapshot, else None while events up to the cut may still come.
        (The API encodes it, outside the lock: the ingest goes on meanwhile.)

        Each topic is its own channel: an event stamped at or before the cut can reach
        H1 after a later one on another topic. So H1 waits until every topic of the
        monitor brought an event past the cut. A quiet topic is let go when another
        one has run ``grace`` seconds of stamps past the cut, or when nothing at all
        came for ``grace`` seconds since H1 learned the cut: stream time, not H1's
        clock, so that a lagging H1 does not give up on events still in its queues.
        A ``quiet`` topic (one H2 vouched for: it brought H2 nothing) is let go sooner,
        once H1's stream (the newest stamp it took on any topic) ran ``settle`` past
        the cut, or its ROS layer found nothing left to take that long after the cut
        (a parked robot): with the topics' skew within the reorder window, nothing at
        or before the cut is still on its way (docs/protocol.md, "Silent topics").

        Then the monitor stops running here, but H1 keeps the snapshot and goes on
        holding the events after the cut until the handoff commits (H2 adopted) or is
        aborted (H1 resumes from both: nothing lost).
        A repeated release (its answer was lost) gets the same snapshot again.
        """
        now = self.clock.monotonic() if now is None else now
        with self.lock:
            slot = self._slot(name)
            if slot.handoff == RELEASED and slot.epoch == epoch and slot.released:
                return slot.released
            slot = self._handoff_slot(name, epoch, SENDING)
            rt = slot.runtime
            assert rt is not None
            # Never below what H1 compressed: what it released into the pipeline before it
            # held, and what its sort buffer held at the hold (compressed now, if the
            # scheduler has not yet): the snapshot carries the raised cut, so H2 filters
            # with the very same one.
            self._compress_prehold(slot)
            if rt.last_released is not None:
                cut = max(cut, rt.last_released)
            if slot.cut_known is None or slot.cut_known[0] != cut:
                slot.cut_known = (cut, now)
            # (A topic is delivered in order: once an event past the cut came, every event
            # at or before it did, also those that came before the hold.)
            topics = slot.compiled.spec.topics
            newest = [self.newest.get(t, cut) for t in topics]
            quiet_since = max([slot.held_at] + [self.heard.get(t, 0.0) for t in topics])
            settled = self._settled(cut + self.settle_ns)
            if not (
                all(
                    n > cut or (t in quiet and settled) for t, n in zip(topics, newest, strict=True)
                )
                or max(newest) - cut >= grace * 1e9  # the others ran grace past it: quiet
                or now - max(slot.cut_known[1], quiet_since) >= grace  # nothing comes
            ):
                return None
            snap = export_snapshot(rt, cut, epoch)  # rt keeps the events after it
            rt.letters, rt.stamps = rt.letters[:0], rt.stamps[:0]
            slot.released = snap
            self._set_handoff(slot, RELEASED)
            return snap

    def _settled(self, stamp: int) -> bool:
        """Nothing stamped up to ``stamp`` is still on its way to this handler: its stream
        (the newest stamp it took, on any topic) is past it, or its ROS layer found
        nothing left to take after that instant. (Stalled, a handler has neither.)"""
        if self.newest and max(self.newest.values()) >= stamp:
            return True
        return self.drained_at is not None and self.drained_at >= stamp

    def commit(self, name: str, epoch: int) -> str:
        """H1, after H2 adopted: let go of the snapshot and the held events."""
        with self.lock:
            slot = self._slot(name)
            if slot.epoch != epoch:
                raise HandoffError(f"no handoff of '{name}' with epoch {epoch} here")
            if slot.handoff is None and slot.runtime is None:
                return "committed"  # a repeated commit
            if slot.handoff != RELEASED:
                raise HandoffError(f"the handoff of '{name}' is {slot.handoff or 'over'}")
            self._let_go(slot)
            return "committed"

    def adopt(self, name: str, epoch: int, snap: Snapshot) -> None:
        """H2, step 6: take the snapshot, merge the held events after the cut, schedule."""
        if snap.monitor != name:
            raise HandoffError(f"{name}: the snapshot is of '{snap.monitor}'")
        self.adopt_many(epoch, [snap])

    def adopt_many(self, epoch: int, snaps: Sequence[Snapshot]) -> list[str]:
        """:meth:`adopt` for a batch, all or nothing: every snapshot is checked and
        restored before any monitor is scheduled. Repeating an adoption is a no-op.
        Returns the monitors' names. (The API decodes them, outside the lock.)"""
        with self.lock:
            restored = []
            for snap in snaps:
                name = snap.monitor
                slot = self._slot(name)
                if slot.handoff is None and slot.epoch == epoch and slot.runtime is not None:
                    continue  # a repeated adoption (its answer was lost): already running
                slot = self._handoff_slot(name, epoch, RECEIVING)
                held = slot.runtime
                assert held is not None  # a receiving slot holds what it received
                try:
                    if snap.epoch != epoch:
                        raise HandoffError("the snapshot belongs to another handoff")
                    restored.append((slot, restore(slot.compiled, snap, held.events)))
                except HandoffError as exc:
                    raise HandoffError(f"{name}: {exc}") from None
            self._resume(restored)
            for slot, _ in restored:
                slot.adopted.append(epoch)
                if len(slot.adopted) > ADOPTIONS_KEPT:
                    slot.forgotten = slot.adopted.pop(0)
        return [snap.monitor for snap in snaps]

    def abort(self, name: str, epoch: int) -> str:
        """Undo a handoff on this side; what it did, as one word.

        ``resumed``: H1 runs the monitor again (from its kept snapshot after a
        release); ``dropped``: H2 let go of what it held, and will refuse an adoption
        with this epoch; ``active``: too late, the monitor runs here (H2 adopted);
        ``gone``: H1 let go already (committed); ``nothing to undo`` otherwise.

        Asked about an older handoff than its newest one (a settle that comes after the
        monitor moved on, or back): ``active`` if it adopted that one and runs the monitor
        now, ``adopted`` if it adopted it and is in a newer handoff or let go since; else
        ``nothing to undo`` (its epoch is past that one: it never will adopt it), or
        ``unknown`` past its record of adoptions. (``nothing to undo`` there would make
        the sender resume a monitor that runs here or moved on from here: two copies.)
        An abort of a handoff newer than any it saw here fences that epoch.
        """
        with self.lock:
            slot = self._slot(name)
            if slot.epoch != epoch:
                if epoch in slot.adopted:
                    running = slot.handoff is None and slot.runtime is not None
                    return "active" if running else "adopted"
                if epoch > slot.epoch and slot.handoff is None:
                    # it overtook that handoff's hold or receive: fence them, so that a
                    # late one does not hold the monitor for HANDOFF_EXPIRES
                    slot.epoch = epoch
                return "unknown" if epoch <= slot.forgotten else "nothing to undo"
            if slot.handoff is None:
                return "active" if slot.runtime is not None else "gone"
            rt = slot.runtime
            assert rt is not None
            if slot.handoff == SENDING:
                rt.holding = False
                if len(rt.events) >= rt.threshold and rt.flush():
                    self.waiting[name] = rt
                    self.ready.notify()
                self._set_handoff(slot, None)
                return "resumed"
            if slot.handoff == RELEASED:
                assert slot.released is not None
                self._resume([(slot, restore(slot.compiled, slot.released, rt.events))])
                return "resumed"
            self._let_go(slot)
            return "dropped"

    def _resume(self, restored: Sequence[tuple[MonitorSlot, MonitorRuntime]]) -> None:
        """Run restored runtimes in place of what their slots held."""
        self.router.remove_many(slot.name for slot, _ in restored)
        for slot, rt in restored:
            slot.runtime, slot.released = rt, None
            self._set_handoff(slot, None)
            self.router.add(rt)
            self.waiting[slot.name] = rt
        self.routes_version += 1
        self.ready.notify()

    def _let_go(self, slot: MonitorSlot) -> None:
        self.router.remove(slot.name)
        slot.runtime, slot.released = None, None
        self._set_handoff(slot, None)
        self.routes_version += 1

    def _expire_handoffs(self, now: float) -> None:
        """Undo handoffs no driver finished: a sender that released nothing resumes, a
        receiver that adopted nothing lets go (both safe: a late step is fenced). A
        released one waits to be settled: the receiver may have adopted it."""
        for slot in list(self.in_handoff.values()):
            if slot.handoff in (SENDING, RECEIVING) and now - slot.handoff_since > (
                HANDOFF_EXPIRES
            ):
                log.warning(
                    "monitor %s: handoff %d %s for %.0f s with no next step: %s",
                    slot.name,
                    slot.epoch,
                    slot.handoff,
                    now - slot.handoff_since,
                    self.abort(slot.name, slot.epoch),
                )

    def _precompress(self) -> None:
        """Compress, a few ms at a time, what senders buffered before their hold."""
        until = time.perf_counter() + PREHOLD_SECONDS
        for slot in self.in_handoff.values():
            if slot.prehold:
                self._compress_prehold(slot)
                if time.perf_counter() > until:
                    break

    @staticmethod
    def _compress_prehold(slot: MonitorSlot) -> None:
        rt = slot.runtime
        if slot.prehold and slot.handoff == SENDING and rt is not None:
            rt.flush_prefix(slot.prehold)
        slot.prehold = 0

    def _set_handoff(self, slot: MonitorSlot, role: HandoffState | None) -> None:
        check_transition(slot.handoff, role)
        slot.handoff, slot.handoff_since = role, self.clock.monotonic()
        if role is None:
            self.in_handoff.pop(slot.name, None)
        else:
            self.in_handoff[slot.name] = slot

    def _handoff_slot(self, name: str, epoch: int, role: HandoffState) -> MonitorSlot:
        slot = self._slot(name)
        if slot.handoff != role or slot.epoch != epoch:
            raise HandoffError(f"no {role} handoff of '{name}' with epoch {epoch} here")
        return slot

    def load(self) -> dict[str, Any]:
        """The load report the orchestrator reads (``GET /v1/load``): counters, not rates;
        ``deadline`` is the makespan window's reading (null without ``--deadline``)."""
        now_ns = int(self.clock.monotonic() * 1e9)
        deadline = self.deadline.report(now_ns) if self.deadline else None
        with self.lock:
            return {
                "handler": self.name,
                "monotonic": self.clock.monotonic(),
                "cpuSeconds": time.process_time(),
                "ingestLag": self.ingest_lag,
                "deadline": deadline,
                "monitors": {
                    slot.name: {
                        "active": slot.active,
                        "handoff": slot.handoff,
                        "epoch": slot.epoch,
                        "peer": slot.peer if slot.handoff else None,
                        "events": slot.events,
                        "migrationWanted": slot.migration_wanted,
                        "placement": placement_json(slot.compiled.spec.placement),
                    }
                    for slot in self.slots.values()
                },
            }

    def snapshot(self) -> list[dict[str, Any]]:
        with self.lock:
            return [slot.describe(self.name) for slot in self.slots.values()]

    def wake(self) -> None:
        with self.lock:
            self.ready.notify_all()
