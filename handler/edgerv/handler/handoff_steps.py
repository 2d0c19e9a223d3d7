"""The handoff's steps on one handler (docs/protocol.md): hold, receive, cut, release,
adopt, commit, abort, and the handler's own undoing of a handoff no driver finishes.

Each step is one call with the handoff's epoch, under the engine's lock; the state it
changes is the monitor's :class:`~edgerv.handler.handoff_state.HandoffState` and the
handoff fields of its :class:`~edgerv.handler.slot.MonitorSlot`. The engine holds them
(``Engine.handoffs``), and they share its lock, slots, router and scheduler queue
(:class:`HandoffHost`). The HTTP API
parses and encodes (snapshots travel as objects here), the wire form is
:mod:`edgerv.core.handoff`'s.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Collection, Iterable, Sequence
from typing import Any, Literal, Protocol

from edgerv.control.wire import HANDOFF_EXPIRES
from edgerv.core.handoff import HandoffError, Snapshot, cut_point
from edgerv.core.pipeline import MonitorRuntime, Router
from edgerv.handler.clock import Clock
from edgerv.handler.handoff_state import HandoffState, check_transition
from edgerv.handler.slot import MonitorSlot

log = logging.getLogger("edgerv.handler")

SENDING, RELEASED, RECEIVING = HandoffState.SENDING, HandoffState.RELEASED, HandoffState.RECEIVING
PREHOLD_SECONDS = 0.002  # a scheduler round's time for the buffers of monitors being handed off
ADOPTIONS_KEPT = 64  # per monitor: the epochs of the latest handoffs a handler adopted


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


class HandoffHost(Protocol):
    """What the steps share with the engine that holds them: its lock and scheduler's
    condition, its clock, slots, router and queues, and what its ROS layer says of each
    topic (the engine's attributes of these names)."""

    lock: threading.RLock
    ready: threading.Condition
    clock: Clock
    slots: dict[str, MonitorSlot]
    router: Router
    routes_version: int
    waiting: dict[str, MonitorRuntime]
    in_handoff: dict[str, MonitorSlot]
    newest: dict[str, int]
    heard: dict[str, float]
    settle_ns: int
    flush_after: float
    stamp_lag: dict[str, int]
    matched: Callable[[str], bool] | None
    drained_at: int | None

    def activate(self, slot: MonitorSlot) -> None:
        """A runtime for ``slot``, routed."""

    def handoff_changed(self, slot: MonitorSlot) -> None:
        """``slot``'s handoff state changed (a step, or one undone)."""


class HandoffSteps:
    """The steps on one engine (``Engine.handoffs``): each takes its lock."""

    def __init__(self, engine: HandoffHost) -> None:
        self.engine = engine

    def note_firsts(self, batch: Sequence[tuple[Any, ...]]) -> None:
        """H2 notes its first stamp on each topic of a receiving monitor (for the cut)."""
        for slot in self.engine.in_handoff.values():
            firsts, topics = slot.first_stamps, slot.compiled.spec.topics
            if slot.handoff == RECEIVING and len(firsts) < len(topics):
                for item in batch:
                    topic = item[1]
                    if topic not in firsts and topic in topics:
                        firsts[topic] = item[0]

    # -- handoff (docs/protocol.md): each step is a call; epochs fence stale ones -----------

    def _slot(self, name: str) -> MonitorSlot:
        slot = self.engine.slots.get(name)
        if slot is None:
            raise HandoffError(f"no monitor '{name}' here")
        return slot

    def hold(
        self, name: str, epoch: int, now: float | None = None, peer: str | None = None
    ) -> None:
        """H1, step 2a: stop scheduling the monitor, keep buffering its events.

        ``peer`` names the receiver: whoever settles an interrupted handoff asks it."""
        now = self.engine.clock.monotonic() if now is None else now
        with self.engine.lock:
            slot = self._slot(name)
            if epoch <= slot.epoch:
                raise HandoffError(f"epoch {epoch} is not newer than {slot.epoch}")
            if slot.runtime is None or slot.handoff is not None:
                raise HandoffError(f"monitor '{name}' {_whereabouts(slot)}")
            slot.epoch = epoch
            self._set_handoff(slot, SENDING)
            slot.cut_known, slot.held_at, slot.peer = None, now, peer
            # Nothing compressed ahead as it comes while it holds: most of what it takes
            # now is past the cut, never to be compressed here, and the release compresses
            # what is not (make demo's 450 held: 14.0% of a core compressing ahead, 6.3%
            # not, where running them takes 5.2 to 5.7%; bench/RESULTS.md)
            slot.runtime.hold()
            # What the sort buffer holds now is all at or before any cut H2 can report
            # (H2 subscribes after this, and each topic is delivered in order): the
            # scheduler compresses it while the handoff goes on (a partial batch, as
            # flushAfter releases one), so that the release has only the rest to do.
            slot.prehold = len(slot.runtime.events)
            self.engine.waiting.pop(name, None)

    def receive(self, name: str, epoch: int) -> None:
        """H2, step 3: subscribe and hold the monitor's events, without scheduling it."""
        with self.engine.lock:
            slot = self._slot(name)
            if epoch <= slot.epoch:
                raise HandoffError(f"epoch {epoch} is not newer than {slot.epoch}")
            if slot.runtime is not None:
                raise HandoffError(f"monitor '{name}' {_whereabouts(slot)}")
            slot.epoch, slot.first_stamps, slot.vouched = epoch, {}, {}
            self._set_handoff(slot, RECEIVING)
            self.engine.activate(slot)
            assert slot.runtime is not None
            # H2 holds its events raw: they are compressed after H1's, from H1's state
            slot.runtime.hold()
            self.engine.routes_version += 1

    def cut(self, name: str, epoch: int, wall: int | None = None) -> int | None:
        """H2, step 4: the cut once every topic delivered an event or is vouched for,
        else None.

        A topic that brought nothing yet is vouched for from ``settle`` after the moment
        its subscription was seen matched with every publisher of the topic (none at
        all: from its subscription): from then on every message published on it
        reaches H2, so that moment plus ``settle`` stands for its first stamp."""
        wall = self.engine.clock.wall_ns() if wall is None else wall
        with self.engine.lock:
            slot = self._handoff_slot(name, epoch, RECEIVING)
            topics, firsts = slot.compiled.spec.topics, dict(slot.first_stamps)
            quiet = []
            for topic in topics:
                if topic in firsts or self.engine.matched is None:
                    continue
                if not self.engine.matched(topic):  # a new publisher, or not subscribed yet
                    slot.vouched.pop(topic, None)
                    continue
                since = slot.vouched.setdefault(topic, wall) + self.engine.settle_ns
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
        H1 after a later one on another topic. So H1 waits until each topic of the
        monitor brought an event past the cut, or until nothing of it stamped at or
        before the cut can still come: its ROS layer took everything that reached H1
        up to ``settle`` past the cut, plus the most that topic's messages reached H1
        after their stamps (:attr:`stamp_lag`: a command stamped with its camera
        frame's time is published a makespan later, and every message takes its way
        here). A ``quiet`` topic (one H2 vouched for: it brought H2 nothing) is also
        let go once H1's stream (the newest stamp it took on any topic) ran that far
        (docs/protocol.md, "Silent topics"). Failing those (no ROS layer, a stalled
        one), a topic is let go when another one has run ``grace`` seconds of stamps
        past the cut, or when nothing at all came for ``grace`` seconds since H1
        learned the cut: stream time, not H1's clock, so that a lagging H1 does not give
        up on events still in its queues.

        Then the monitor stops running here, but H1 keeps the snapshot and goes on
        holding the events after the cut until the handoff commits (H2 adopted) or is
        aborted (H1 resumes from both: nothing lost).
        A repeated release (its answer was lost) gets the same snapshot again.
        """
        now = self.engine.clock.monotonic() if now is None else now
        with self.engine.lock:
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
                slot.cut_known, slot.waiting_on = (cut, now), ()
            # (A topic is delivered in order: once an event past the cut came, every event
            # at or before it did, also those that came before the hold.)
            topics = slot.compiled.spec.topics
            newest = [self.engine.newest.get(t, cut) for t in topics]
            quiet_since = max([slot.held_at] + [self.engine.heard.get(t, 0.0) for t in topics])
            waiting = [
                t
                for t, n in zip(topics, newest, strict=True)
                if not (n > cut or self._all_in(cut, t, t in quiet))
            ]
            if waiting and not (
                max(newest) - cut >= grace * 1e9  # the others ran grace past it: quiet
                or now - max(slot.cut_known[1], quiet_since) >= grace  # nothing comes
            ):
                slot.waiting_on = tuple(waiting)
                return None
            snap = rt.snapshot(cut, epoch)  # rt keeps the events after it
            log.info(
                "%s: released at cut %d (epoch %d) %s: step %d, %d letters carried, %d "
                "events and letters after the cut kept",
                name,
                cut,
                epoch,
                self._waited(slot, now, waiting),
                snap.step,
                len(snap.letters),
                rt.buffered,
            )
            rt.letters, rt.stamps = rt.letters[:0], rt.stamps[:0]
            slot.released = snap
            self._set_handoff(slot, RELEASED)
            return snap

    def _waited(self, slot: MonitorSlot, now: float, waiting: list[str]) -> str:
        """What a release waited for, for its log line: how long since H1 learned the
        cut, and the topics it last waited for, each with its reach (the most its
        messages reached H1 after their stamps), or that ``grace`` let them go."""
        assert slot.cut_known is not None
        waited = (now - slot.cut_known[1]) * 1e3
        if not slot.waiting_on and not waiting:
            return "at once"
        topics = ", ".join(
            f"{t} (reach {self.engine.stamp_lag[t] / 1e6:.0f} ms)"
            if t in self.engine.stamp_lag
            else t
            for t in slot.waiting_on or waiting
        )
        given_up = f"; grace let go of {', '.join(waiting)}" if waiting else ""
        return f"after {waited:.0f} ms waiting for {topics}{given_up}"

    def _all_in(self, cut: int, topic: str, vouched: bool) -> bool:
        """Nothing of ``topic`` stamped up to ``cut`` is still on its way to this handler:
        its ROS layer has taken everything that reached it until a reorder window plus
        ``flushAfter`` past the cut (wall time; stalled, it has not), or, for a topic the
        receiver ``vouched`` for (it brought nothing there), the handler's stream (the
        newest stamp it took, on any topic) ran that far. ``flushAfter`` is how late an
        event may come and still be taken in time here (every clock steps only up to
        ``flushAfter`` before what was taken): the most the topic's messages reached it
        after their stamps so far (:attr:`stamp_lag`, at most ``flushAfter``) is not a
        bound, since the load that moves monitors grows a makespan (in `make demo` a
        command came 284 ms after its stamp where the most before was 209 ms: let go at
        that reach, it was neither side's). A topic that never brought this handler a
        message waits a reorder window (docs/protocol.md, "Silent topics"). Stream time
        alone does not let go of a topic that brings messages: a round takes at most
        TAKE_PER_WAKE of each, so a busy topic's backlog can lag a slow one's stamps; the
        drained instant accounts for that. A topic that brought H2 a message and never
        one here waits for it."""
        reach = self.engine.stamp_lag.get(topic)
        if reach is None and not vouched:
            return False
        horizon = 0 if reach is None else max(reach, int(self.engine.flush_after * 1e9))
        stamp = cut + self.engine.settle_ns + horizon
        if self.engine.drained_at is not None and self.engine.drained_at >= stamp:
            return True
        return vouched and bool(self.engine.newest) and max(self.engine.newest.values()) >= stamp

    def settle(
        self, step: Literal["commit", "abort"], epoch: int, names: Iterable[str]
    ) -> dict[str, str]:
        """:meth:`commit` or :meth:`abort` each of these monitors' handoff, their routes
        made anew once for all of them (Router.removing); each one's answer."""
        act = self.commit if step == "commit" else self.abort
        with self.engine.lock, self.engine.router.removing():
            return {n: act(n, epoch) for n in names}

    def commit(self, name: str, epoch: int) -> str:
        """H1, after H2 adopted: let go of the snapshot and the held events."""
        with self.engine.lock:
            slot = self._slot(name)
            if slot.epoch != epoch:
                raise HandoffError(f"no handoff of '{name}' with epoch {epoch} here")
            if slot.handoff is None and slot.runtime is None:
                return "committed"  # a repeated commit
            if slot.handoff != RELEASED:
                raise HandoffError(f"the handoff of '{name}' is {slot.handoff or 'over'}")
            self._let_go(slot)
            slot.moved_out += 1
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
        with self.engine.lock:
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
                    restored.append(
                        (slot, MonitorRuntime.restored(slot.compiled, snap, held.events))
                    )
                    log.info(
                        "%s: adopted at cut %d (epoch %d): step %d, %d letters carried, "
                        "%d events and letters after the cut held here",
                        name,
                        snap.cut,
                        epoch,
                        snap.step,
                        len(snap.letters),
                        held.buffered,
                    )
                except HandoffError as exc:
                    raise HandoffError(f"{name}: {exc}") from None
            self._resume(restored)
            for slot, _ in restored:
                slot.moved_in += 1
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
        with self.engine.lock:
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
                rt.resume()
                if len(rt.events) >= rt.threshold and rt.flush():
                    self.engine.waiting[name] = rt
                    self.engine.ready.notify()
                self._set_handoff(slot, None)
                return "resumed"
            if slot.handoff == RELEASED:
                assert slot.released is not None
                self._resume(
                    [(slot, MonitorRuntime.restored(slot.compiled, slot.released, rt.events))]
                )
                return "resumed"
            self._let_go(slot)
            return "dropped"

    def _resume(self, restored: Sequence[tuple[MonitorSlot, MonitorRuntime]]) -> None:
        """Run restored runtimes in place of what their slots held."""
        self.engine.router.remove_many(slot.name for slot, _ in restored)
        for slot, rt in restored:
            slot.runtime, slot.released = rt, None
            self._set_handoff(slot, None)
            self.engine.router.add(rt)
            self.engine.waiting[slot.name] = rt
        self.engine.routes_version += 1
        self.engine.ready.notify()

    def _let_go(self, slot: MonitorSlot) -> None:
        self.engine.router.remove(slot.name)
        slot.runtime, slot.released = None, None
        self._set_handoff(slot, None)
        self.engine.routes_version += 1

    def expire(self, now: float) -> None:
        """Undo handoffs no driver finished: a sender that released nothing resumes, a
        receiver that adopted nothing lets go (both safe: a late step is fenced). A
        released one waits to be settled: the receiver may have adopted it."""
        expired = [
            slot
            for slot in self.engine.in_handoff.values()
            if slot.handoff in (SENDING, RECEIVING) and now - slot.handoff_since > HANDOFF_EXPIRES
        ]
        with self.engine.router.removing():
            for slot in expired:
                log.warning(
                    "monitor %s: handoff %d %s for %.0f s with no next step: %s",
                    slot.name,
                    slot.epoch,
                    slot.handoff,
                    now - slot.handoff_since,
                    self.abort(slot.name, slot.epoch),
                )

    def precompress(self) -> None:
        """Compress, a few ms at a time, what senders buffered before their hold."""
        until = time.perf_counter() + PREHOLD_SECONDS
        for slot in self.engine.in_handoff.values():
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
        slot.handoff, slot.handoff_since = role, self.engine.clock.monotonic()
        if role is None:
            self.engine.in_handoff.pop(slot.name, None)
        else:
            self.engine.in_handoff[slot.name] = slot
        self.engine.handoff_changed(slot)

    def _handoff_slot(self, name: str, epoch: int, role: HandoffState) -> MonitorSlot:
        slot = self._slot(name)
        if slot.handoff != role or slot.epoch != epoch:
            raise HandoffError(f"no {role} handoff of '{name}' with epoch {epoch} here")
        return slot
