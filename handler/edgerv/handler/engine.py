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

import dataclasses
import logging
import math
import random
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any, Protocol

import numpy as np

from edgerv.core import arrivals as batches
from edgerv.core.deadline import MakespanWindow
from edgerv.core.diagnostics import Diagnostic, InputError
from edgerv.core.documents import MonitorSpec
from edgerv.core.handoff import HandoffError
from edgerv.core.monitor import CompiledMonitor, compile_monitor
from edgerv.core.pipeline import MonitorRuntime, Router, TopicRoute, Verdict
from edgerv.core.reactions import Reaction
from edgerv.core.robots import ros_namespace
from edgerv.handler.budget import MemoryBudget, monitor_cost
from edgerv.handler.clock import Clock, SystemClock
from edgerv.handler.handoff_steps import HandoffSteps
from edgerv.handler.reach import Reach
from edgerv.handler.slot import MonitorSlot

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
# An idle scheduler (no message since its last tick, nothing buffered) sleeps until the
# next instant a tick has work, at most this long.
IDLE_TICK_SECONDS = 5.0
# A take loop with nothing to take says how far everything is taken (drained_at) every
# IDLE_WAIT_SECONDS (ros.take); a tick that finds it said so longer ago than this wakes it
STALE_DRAINED_SECONDS = 0.05
# Batches of at least this many messages are ingested a column at a time (each monitor's
# messages of the batch at once: in NumPy arrays where it has this many and no past
# operator, else in lists), shorter ones a message at a time: below it, building the
# columns costs more than it saves.
COLUMNS_FROM = 32
# A short batch offered while the scheduler dozes, giving letters to at most this many
# monitors, is evaluated by the ingest thread itself (Engine.ingest): at a robot's rates,
# waking the scheduler for every message cost more than evaluating.
INLINE_MONITORS = 512
# A scheduler round evaluates monitors until it has this many verdicts, then lets go of
# the lock and hands them on: the ingest thread takes messages between rounds, and what
# is in flight stays bounded, however many monitors violate at once (the verdict storm).
EVALUATE_CHUNK = 4096
# What each monitor costs here (its runtime's ``cost_ns``, the load report's
# ``cpuSeconds`` per monitor) is estimated from the CPU time (the thread's clock, not the
# wall's: on a core shared with the robot's real-time task a preempted step would count
# the task's time too) of one message in COST_SAMPLE and one evaluation round in
# COST_SAMPLE, chosen at random (unbiased, whatever the topics' rhythm), each scaled by
# COST_SAMPLE: timing every one would cost more than the edge's budget allows (a read of
# the thread's clock is ~0.5 us, a monitor's step ~1 us).
COST_SAMPLE = 16


class VerdictSink(Protocol):
    def write(self, handler: str, verdicts: Sequence[Verdict]) -> None: ...


class Reactor(Protocol):
    """Does monitors' reactions (``spec.onViolation``): the ROS layer's."""

    def prepare(self, reaction: Reaction) -> None: ...

    def react(self, handler: str, due: Sequence[tuple[Verdict, Reaction]]) -> None: ...


class Engine:
    """All monitors of one handler. Thread-safe. The handoff's steps are its
    :attr:`handoffs` (:mod:`edgerv.handler.handoff_steps`)."""

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
        # wall ns before which everything that reached this handler's subscriptions is in
        # the engine (taken, and out of the reorder window): the ROS layer's, advanced by
        # each round over every subscription (None: no ROS layer, the wall clock says)
        self.drained_at: int | None = None
        self.lock = threading.RLock()
        self.ready = threading.Condition(self.lock)
        self.dozing = False  # the scheduler sleeps until its tick: the next letters wake it
        self.doze_until: float | None = None  # (time.monotonic) the dozing scheduler's tick
        self.ingested = False  # messages came since the scheduler planned its next tick
        self.replan = False  # the scheduler plans its next tick anew when it wakes
        self.tick_period = 0.05  # the scheduler's (run_scheduler)
        # the fingerprint when the scheduler last planned an idle handler's tick, one that
        # would change nothing while it stays (no monitor buffers anything, none has a
        # clock: next_tick_due); None: the plan was not one
        self.idle_plan: tuple[object, ...] | None = None
        # bumped by what may change a status's level other than a verdict, a message or a
        # route, or time: a dropped event, a buffer past or back under HIGH_WATER, a
        # migration wanted or no longer, a reaction's outcome (health.alarm_counts)
        self.alarms = 0
        # bumped by whatever changes a monitor's state but a message or a route: an
        # evaluation, a flush or a change of pressure, a handoff's step, a reaction's
        # outcome (the diagnostics skip their check while it and those stay: Health.settled)
        self.changes = 0
        # wakes the ROS layer's take loop (its wakeup guard condition; a no-op without
        # one): it then says how far everything is taken (drained_at) at once, which an
        # idle take loop says only every IDLE_WAIT_SECONDS otherwise
        self.wake_ingest: Callable[[], None] = lambda: None
        self.drained_said = 0.0  # (time.monotonic) when the take loop last said how far
        self.reached: list[Verdict] = []  # evaluated by ingest, for the scheduler to emit
        self.slots: dict[str, MonitorSlot] = {}
        self.router = Router()
        self.routes_version = 0  # bumped whenever topics or their fields change
        self._robots: tuple[int, frozenset[str]] | None = None  # (routes_version, robots)
        self.messages: dict[str, int] = {}  # topic -> messages ingested
        self.lost: dict[str, int] = {}  # topic -> messages the middleware lost (ROS layer's)
        # topic -> CPU ns the ROS layer spent taking and decoding its messages (the load
        # report's topics: what each topic's ingestion costs, whatever monitors read it)
        self.taking_ns: dict[str, int] = {}
        # per topic: the newest stamp and when a message last came (a sender's release)
        self.newest: dict[str, int] = {}
        self.heard: dict[str, float] = {}
        # per topic: the most a message reached this handler after its stamp (ns: header
        # stamps taken before processing lag their publication, and the way here takes
        # time), at most flush_after (the ROS layer's; a handoff's release waits for it)
        self.stamp_lag: dict[str, int] = {}
        self.ingest_lag = 0.0  # seconds between publication and ingestion, last batch
        self.reach = Reach()  # how long messages take from publication to here (ROS layer's)
        self.waiting: dict[str, MonitorRuntime] = {}  # monitors with letters to evaluate
        self.in_handoff: dict[str, MonitorSlot] = {}  # so ingest need not scan every slot
        # The slots a tick looks at, so that it need not scan every slot (10,000 idle ones
        # took it 11 ms, under the lock, every period while messages come): those that took
        # events or letters from a message, a clock step or a handoff's step since, until a
        # tick finds them idle (nothing buffered, no flush due, no pressure followed); and
        # each activated one once (its slot's flush or pressure from before settles).
        self.watched: dict[str, MonitorSlot] = {}
        self.clocked: dict[str, MonitorSlot] = {}  # the slots whose monitor has a clock
        # --deadline: the makespans of the robot's real-time task (the ROS layer measures)
        self.deadline = deadline
        # violations whose monitor reacts, evaluated here and not yet handed to the reactor:
        # a violation is evaluated once, on one handler, so it is reacted to once
        self.reactions_due: list[tuple[Verdict, Reaction]] = []
        self.reactor: Reactor | None = None
        self.behind = False  # the last round stopped at EVALUATE_CHUNK verdicts: more wait
        self.budget: MemoryBudget | None = None  # --memory-budget: monitors' buffers count
        # 1 in cost_every messages and rounds, at random, timed for the monitors' costs
        # (1: every one): how many more messages, and rounds, until the next timed one
        self.random = random.Random()
        self.sample_costs(COST_SAMPLE)
        self.handoffs = HandoffSteps(self)  # hold, receive, cut, release, adopt, settle

    def sample_costs(self, every: int) -> None:
        """Time 1 in ``every`` messages and rounds, at random, for the monitors' costs."""
        self.cost_every = every
        self.untimed_messages = self.untimed_rounds = self.cost_gap()

    def cost_gap(self) -> int:
        """How many messages (or rounds) until the next timed one, counting it: the gaps
        of a Bernoulli process of probability 1/cost_every (each one timed independently
        of the others, so no rhythm of the topics biases the estimate), drawn once per
        timed one rather than a draw per message."""
        if self.cost_every <= 1:
            return 1
        u = 1.0 - self.random.random()  # (0, 1]
        return int(math.log(u) / math.log(1.0 - 1.0 / self.cost_every)) + 1

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
            reaction = spec.on_violation
            used = [] if reaction is None else reaction.types()
            for part, msg_type in used:
                problem = self.type_check(msg_type)
                if problem:
                    where = f"spec.onViolation.{part}.type"
                    errors.append(Diagnostic(spec.location, f"{where}: {problem}"))
            if errors:
                raise InputError(errors)
        return compiled

    def put(self, compiled: CompiledMonitor, active: bool) -> bool:
        """Define (or redefine) a monitor; returns True when it is new.

        Redefining a monitor restarts it (the same definition again too): its buffers
        and automaton state start afresh; except a definition that differs only in its
        placement, given with the activity the monitor has here: that updates the
        placement, and the monitor runs on (or stays idle) with its state and counts
        (the operator's tier edits). A monitor in a handoff is not redefined (HandoffError:
        that would restart it and lose the move): settle or abort the handoff first.

        A monitor that reacts has its publisher and client made now, active or not: a
        publisher made at the violation would publish before any subscriber matched it.
        """
        if self.reactor is not None and compiled.spec.on_violation is not None:
            self.reactor.prepare(compiled.spec.on_violation)
        with self.lock:
            self.refuse_over_budget([compiled])
            old = self.slots.get(compiled.name)
            if old is not None and old.handoff is not None:
                raise HandoffError(
                    f"monitor '{compiled.name}' is in a handoff ({old.handoff}): settle or "
                    "abort it first (edgerv migrate settles it)"
                )
            if (
                old is not None
                and old.active == active
                and compiled.spec.placement != old.compiled.spec.placement
                and dataclasses.replace(compiled.spec, placement=old.compiled.spec.placement)
                == old.compiled.spec
            ):
                old.compiled = compiled  # the runtime keeps its own: the same monitor
                self.changes += 1  # (its status shows the tier)
                return False
            if old is not None and old.runtime is not None:
                self.router.remove(old.name)
            slot = MonitorSlot(compiled)
            self.slots[compiled.name] = slot
            self.watched.pop(compiled.name, None)  # (the old slot's; an active one is again)
            self.clocked.pop(compiled.name, None)
            if compiled.clocked:
                self.clocked[compiled.name] = slot
            if self.budget is not None:
                self.budget.commit(compiled.name, monitor_cost(compiled.spec))
            if active:
                self.activate(slot)
            self.routes_version += 1
            return old is None

    def robot_namespace(self) -> str | None:
        """The ROS namespace of the one robot whose monitors this handler runs (their
        documents' robot label, as the operator writes it: a fleet's edge handler runs
        its own robot's); None when it runs no robot's, or several robots' (a shared
        handler). A relative ``--deadline`` topic is resolved in it."""
        with self.lock:
            if self._robots is None or self._robots[0] != self.routes_version:
                robots = frozenset(
                    r
                    for s in self.slots.values()
                    if (r := s.compiled.spec.placement.robot) is not None
                )
                self._robots = (self.routes_version, robots)
            robots = self._robots[1]
        return ros_namespace(next(iter(robots))) if len(robots) == 1 else None

    def remove(self, name: str) -> bool:
        with self.lock:
            slot = self.slots.pop(name, None)
            if slot is None:
                return False
            self.in_handoff.pop(name, None)
            self.watched.pop(name, None)
            self.clocked.pop(name, None)
            if slot.runtime is not None:
                self.router.remove(name)
            if self.budget is not None:
                self.budget.forget(name)
            self.routes_version += 1
            return True

    def refuse_over_budget(self, monitors: Sequence[CompiledMonitor]) -> None:
        """Raise InputError, at the first monitor's definition, when these monitors (new,
        or replacing those of their names) would pass the memory budget together."""
        if self.budget is None or not monitors:
            return
        costs = {c.name: monitor_cost(c.spec) for c in monitors}
        problem = self.budget.problem(costs)
        if problem is None:
            return
        self.budget.refused += len(monitors)
        first = monitors[0].spec
        names = ", ".join(f"'{c.name}'" for c in monitors)
        what = f"monitor {names}" if len(monitors) == 1 else f"monitors {names} together"
        raise InputError(
            [
                Diagnostic(
                    first.location,
                    f"spec.bufferCapacity: {what} would pass this handler's memory budget: "
                    f"{problem}",
                )
            ]
        )

    def set_active(self, name: str, active: bool) -> None:
        with self.lock:
            slot = self.slots[name]
            if slot.handoff is not None:
                raise HandoffError(
                    f"monitor '{name}' is in a handoff ({slot.handoff}); abort it first"
                )
            if active and slot.runtime is None:
                self.activate(slot)
            elif not active and slot.runtime is not None:
                self.router.remove(name)
                slot.runtime = None
            self.routes_version += 1

    def activate(self, slot: MonitorSlot) -> None:
        slot.runtime = MonitorRuntime(slot.compiled)
        self.router.add(slot.runtime)
        self.watched[slot.name] = slot  # (a flush or pressure left from before: settled)

    def fingerprint(self) -> tuple[object, ...]:
        """A few counters that change whenever anything a monitor's reading shows may
        have (health.read_engine; Health.settled): the messages offered, the routes, the
        changes (evaluations, clock steps, flushes, pressure, handoffs, reactions, a tier
        edit) and the messages lost."""
        return (self.router.seq, self.routes_version, self.changes, tuple(self.lost.items()))

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
        with self.lock:
            if routes_version is not None and routes_version != self.routes_version:
                return False
            admit = self._admit
            if self.in_handoff:
                self.handoffs.note_firsts(batch)
            if len(batch) >= COLUMNS_FROM:
                woke = self._ingest_columns(batch, now, admit)
            else:
                woke = self._ingest_each(batch, now, admit)
            self.ingested = True
            if (
                self.dozing
                and self.doze_until is not None
                and self.doze_until > time.monotonic() + self.tick_period
            ):  # an idle scheduler's long doze: it ticks every period again
                self.replan = woke = True
                self.doze_until = None
            if (
                not woke
                and self.dozing
                and self.waiting
                and len(batch) < COLUMNS_FROM
                and len(self.waiting) <= INLINE_MONITORS
            ):
                # A few messages while the scheduler dozes (a robot's rates): their letters
                # are evaluated here, under the lock this thread holds, rather than by
                # waking the scheduler for each message; it is woken only to hand the
                # verdicts on (the sinks, the reactions: always its thread).
                reached = self._evaluate(EVALUATE_CHUNK)
                if reached or self.behind or self.reactions_due:
                    self.reached += reached
                    woke = True
            if woke or (self.dozing and self.waiting):
                self.dozing = False
                self.ready.notify()
        return True

    def _take_reached(self) -> list[Verdict]:
        """The verdicts :meth:`ingest` reached since the scheduler last handed them on."""
        reached, self.reached = self.reached, []
        return reached

    def _admit(self, runtime: MonitorRuntime) -> bool:
        """Whether ``runtime``'s buffer takes one more event (counted); else it is dropped.
        (Its ``pending_since`` is set by :meth:`_ingest_each`, for what it then holds.)"""
        slot = self.slots[runtime.name]
        if len(runtime.events) + len(runtime.letters) >= slot.capacity:
            self._dropped(slot, 1)
            return False
        slot.admitted += 1
        return True

    def _dropped(self, slot: MonitorSlot, count: int) -> None:
        """Count ``count`` events that found ``slot``'s buffer full, and log the 1st, 10th,
        100th, 1000th and every 10,000th (as each would be, one at a time)."""
        self.alarms += 1
        before = slot.dropped
        slot.dropped = after = before + count
        marks = [m for m in (1, 10, 100, 1000) if before < m <= after]
        marks += range((before // 10000 + 1) * 10000, after + 1, 10000)
        for dropped in marks:
            log.warning(
                "monitor %s: buffer full (%d events), %d events dropped",
                slot.name,
                slot.capacity,
                dropped,
            )

    def _ingest_each(
        self,
        batch: Sequence[tuple[int, str, Sequence[Any]]],
        now: float,
        admit: Callable[[MonitorRuntime], bool],
    ) -> bool:
        """:meth:`ingest` a message at a time; True when a monitor has WAKE_LETTERS waiting."""
        routes, slots, watched, woke = self.router.routes, self.slots, self.watched, False
        messages, newest, heard = self.messages, self.newest, self.heard
        offer, untimed = self.router.offer_values, self.untimed_messages
        buffered: list[MonitorRuntime] = []  # took an event into a buffer, no letter yet
        for stamp, topic, values in batch:
            route = routes.get(topic)
            if route is None:
                continue
            messages[topic] = messages.get(topic, 0) + 1
            heard[topic] = now
            if stamp > newest.get(topic, stamp - 1):
                newest[topic] = stamp
            untimed -= 1
            if untimed:
                ready = offer(route, stamp, values, admit, buffered)
            else:  # a timed message: its cost shared by its readers
                start = time.thread_time_ns()
                ready = offer(route, stamp, values, admit, buffered)
                share = (time.thread_time_ns() - start) * self.cost_every / len(route.readers)
                for reader, _ in route.readers:
                    reader.cost_ns += share
                untimed = self.cost_gap()
            for runtime in ready:
                slot = watched[runtime.name] = slots[runtime.name]
                slot.pending_since = now if runtime.events else None
                self.waiting[runtime.name] = runtime
                woke = woke or len(runtime.letters) >= WAKE_LETTERS
            if buffered:
                for runtime in buffered:
                    slot = watched[runtime.name] = slots[runtime.name]
                    if runtime.events and slot.pending_since is None:
                        slot.pending_since = now
                buffered.clear()
        self.untimed_messages = untimed
        return woke

    def _ingest_columns(
        self,
        batch: Sequence[tuple[int, str, Sequence[Any]]],
        now: float,
        admit: Callable[[MonitorRuntime], bool],
    ) -> bool:
        """:meth:`ingest` a long batch a column at a time: each topic's field values
        gathered once, each monitor handed its messages of the batch as
        :class:`~edgerv.core.pipeline.Arrivals`, which give the letters of offering them
        one by one (runs of equal letters at once), clock steps included. Its buffer's
        capacity is tested where the letters are made
        (:meth:`~edgerv.core.pipeline.MonitorRuntime.take_arrivals`): it takes and drops
        exactly what :meth:`_ingest_each` would. A batch with fewer than COLUMNS_FROM
        messages on every topic goes to :meth:`_ingest_each` whole."""
        began = time.thread_time_ns()  # every such batch timed: 0.5 us is nothing here
        routes, slots = self.router.routes, self.slots
        stamps_, topics, rows = (list(c) for c in zip(*batch, strict=True))
        by_topic = batches.positions_by_topic(topics, routes)
        if max(map(len, by_topic.values()), default=0) < COLUMNS_FROM:
            # spread over many topics: no monitor has enough of them for NumPy to pay
            return self._ingest_each(batch, now, admit)
        reads: dict[str, list[tuple[str, batches.Binding]]] = {}
        runtimes: dict[str, MonitorRuntime] = {}
        lists: dict[str, batches.Column] = {}  # each topic's column, Python values
        for topic, at in by_topic.items():
            route = routes[topic]
            lists[topic] = batches.rows_column(at, rows)
            self.messages[topic] = self.messages.get(topic, 0) + len(at)
            self.heard[topic] = now
            for runtime, b in route.readers:
                reads.setdefault(runtime.name, []).append((topic, route.bindings[b]))
                runtimes[runtime.name] = runtime
        self.router.seq += len(batch)
        woke = False
        arrays: dict[str, batches.Column] = {}  # in NumPy arrays, made on first use
        stamps: Any = None
        own = 0  # ns spent on one monitor at a time; the rest is shared by all of them
        for name, mine in reads.items():
            start = time.thread_time_ns()
            runtime, slot = runtimes[name], slots[name]
            self.watched[name] = slot
            if runtime.past is None:  # columns.compress may make its letters: arrays
                if stamps is None:
                    stamps = np.array(stamps_, np.int64)
                for topic, _ in mine:
                    if topic not in arrays:
                        arrays[topic] = batches.as_arrays(lists[topic])
                columns = [(arrays[topic], binding) for topic, binding in mine]
                arrived = batches.column_arrivals(stamps, columns, len(runtime.values))
                if len(arrived.stamps) < COLUMNS_FROM:  # too few for NumPy to pay
                    arrived = arrived.as_lists()
            else:  # past operators are stepped in Python: a run of equal letters at a time
                columns = [(lists[topic], binding) for topic, binding in mine]
                arrived = batches.arrivals(stamps_, columns, len(runtime.values))
            n = len(arrived.stamps)
            # the events its buffer takes, as _admit would one at a time; the rest dropped
            if runtime.walks:  # its letters walked as they come, up to its first verdict
                taken, ready = runtime.take_walking(arrived, slot.capacity)
            else:
                taken, ready = runtime.take_arrivals(arrived, slot.capacity)
            slot.admitted += taken
            if taken < n:
                self._dropped(slot, n - taken)
            if runtime.events and slot.pending_since is None:
                slot.pending_since = now
            if ready:
                slot.pending_since = now if runtime.events else None
                self.waiting[name] = runtime
                woke = woke or len(runtime.letters) >= WAKE_LETTERS
            spent = time.thread_time_ns() - start
            runtime.cost_ns += spent
            own += spent
        for topic, at in by_topic.items():
            if topic in arrays:  # (NumPy's max, where the arrays were made)
                top = int(stamps[arrays[topic][0]].max())
            else:
                top = max(map(stamps_.__getitem__, at))
            if top > self.newest.get(topic, top - 1):
                self.newest[topic] = top
        if runtimes:
            share = (time.thread_time_ns() - began - own) / len(runtimes)
            for runtime in runtimes.values():
                runtime.cost_ns += share
        return woke

    def taken(self, batch: Sequence[tuple[Any, ...]]) -> None:
        """Messages taken from their subscriptions, before they are merged in stamp order
        (the ROS layer's reorder window): a receiver notes its first stamp on each topic
        from them, a window earlier. Each is ingested after, in the same topic order."""
        if batch and self.in_handoff:
            with self.lock:
                self.handoffs.note_firsts(batch)

    def note_reaction(self, monitor: str, problem: str | None) -> None:
        """The reactor's outcome of one reaction of ``monitor``: done (None) or why not."""
        with self.lock:
            slot = self.slots.get(monitor)
            if slot is None:
                return  # removed since
            self.changes += 1
            self.alarms += 1
            if problem is None:
                slot.reactions += 1
            else:
                slot.reaction_failures += 1
            slot.reaction_problem = problem

    def evaluate(self) -> list[Verdict]:
        """A scheduler round: evaluate the letters that wait (the verdicts, to emit)."""
        with self.lock:
            return self._take_reached() + self._evaluate()

    def _evaluate(self, most: int | None = None) -> list[Verdict]:
        """Evaluate the letters of the monitors that have some (not all monitors: cheap);
        given ``most``, stop after the monitor that brings the verdicts to it: the others
        wait first in line for the next round (:attr:`behind` is then True)."""
        verdicts: list[Verdict] = []
        waiting, self.waiting = self.waiting, {}
        if waiting:
            self.changes += 1
        items = iter(waiting.items())
        self.untimed_rounds -= 1
        timed = not self.untimed_rounds  # a timed round: each monitor's evaluation
        if timed:
            self.untimed_rounds = self.cost_gap()
        for name, rt in items:
            slot = self.slots.get(name)
            if slot is None or slot.runtime is not rt:
                continue  # removed or redefined since
            if timed:
                start = time.thread_time_ns()
                reached = rt.evaluate()
                rt.cost_ns += (time.thread_time_ns() - start) * self.cost_every
            else:
                reached = rt.evaluate()
            for v in reached:
                slot.verdicts[v.verdict] += 1
                slot.last_verdict = v
                verdicts.append(v)
                reaction = slot.compiled.spec.on_violation
                if reaction is not None and v.verdict == "violated":
                    self.reactions_due.append((v, reaction))
            if most is not None and len(verdicts) >= most:
                break
        rest = dict(items)
        self.behind = bool(rest)
        if rest:
            rest.update(self.waiting)  # (those that came meanwhile: after them)
            self.waiting = rest
        return verdicts

    def advance_clocks(self, wall_ns: int) -> None:
        """Time passes for the monitors with timed atoms: each takes its clock steps up to
        ``min(wall_ns, drained_at) - flush_after`` (this handler's clock; stamps are ROS
        time), the moment before which it takes every event as in (docs/semantics.md,
        "Time"): a handler that fell behind (starved of CPU, a burst to take) holds its
        clocks until it has taken what came, so it never steps past an event it has not
        seen yet."""
        drained = self.drained_at
        until = (wall_ns if drained is None else min(wall_ns, drained)) - int(
            self.flush_after * 1e9
        )
        if time.monotonic() - self.drained_said > STALE_DRAINED_SECONDS:
            self.wake_ingest()  # (an idle take loop: its next round says how far, at once)
        with self.lock:
            for slot in self.clocked.values():
                rt = slot.runtime
                if rt is not None and slot.active and rt.advance(until):
                    self.waiting[rt.name] = rt
                    self.watched[rt.name] = slot
                    if not rt.events:
                        slot.pending_since = None

    def tick(self, now: float | None = None) -> list[Verdict]:
        """Release event buffers that waited longer than ``flush_after``; update pressure."""
        now = self.clock.monotonic() if now is None else now
        with self.lock:
            self.handoffs.precompress()
            self.handoffs.expire(now)
            self.advance_clocks(self.clock.wall_ns())
            watched = self.watched
            for slot in [*watched.values()]:
                rt = slot.runtime
                if rt is None:
                    del watched[slot.name]
                    continue
                if (
                    slot.pending_since is not None
                    and not rt.holding
                    and now - slot.pending_since >= self.flush_after
                ):
                    if rt.flush():
                        self.waiting[rt.name] = rt
                    slot.pending_since = None
                    self.changes += 1
                if (
                    not rt.events
                    and not rt.letters
                    and slot.full_since is None
                    and not slot.migration_wanted
                ):
                    if slot.pending_since is None:
                        del watched[slot.name]  # until it takes something again
                    continue  # an idle monitor: nothing to update
                self.changes += 1
                fill = rt.buffered / slot.capacity
                if fill >= HIGH_WATER:
                    if slot.full_since is None:
                        slot.full_since = now
                        self.alarms += 1
                    if now - slot.full_since >= PRESSURE_SECONDS and not slot.migration_wanted:
                        slot.migration_wanted = True
                        self.alarms += 1
                        log.warning(
                            "monitor %s: buffer %.0f%% full for %.1f s: migration wanted",
                            slot.name,
                            fill * 100,
                            now - slot.full_since,
                        )
                else:
                    if slot.full_since is not None:
                        slot.full_since = None
                        self.alarms += 1
                    if fill < LOW_WATER and slot.migration_wanted:
                        slot.migration_wanted = False
                        self.alarms += 1
            return self._evaluate(EVALUATE_CHUNK)

    def emit(self, verdicts: Sequence[Verdict]) -> None:
        """Hand verdicts to the sinks, and the violations due a reaction to the reactor
        (first: the reaction is the one that cannot wait)."""
        if self.reactions_due:
            with self.lock:
                due, self.reactions_due = self.reactions_due, []
            if due and self.reactor is not None:
                try:
                    self.reactor.react(self.name, due)
                except Exception:  # it must not stop the scheduler: logged, counted there
                    log.exception("the reactor failed")
        if verdicts:
            for sink in self.sinks:
                try:
                    sink.write(self.name, verdicts)
                except Exception:  # a failing sink must not stop the others or the scheduler
                    log.exception("verdict sink %s failed", type(sink).__name__)

    def run_scheduler(self, stop: threading.Event, period: float = 0.05) -> None:
        """The scheduler thread: evaluate every SCHEDULE_SECONDS while letters wait, and
        :meth:`tick` when one has work: every ``period`` while messages come, a buffer
        holds events or letters, or a handoff is under way; else it sleeps until the
        next instant a tick can change anything (:meth:`next_tick_due`: a sort buffer's
        flush, a clock step), and the first message wakes it."""
        self.tick_period = period
        next_tick = time.monotonic()
        while not stop.is_set():
            with self.lock:
                if not self.behind:  # (else more wait from the last round: at once)
                    self.dozing = not self.waiting and not self.in_handoff
                    doze = max(0.0, next_tick - time.monotonic())
                    self.doze_until = next_tick if self.dozing else None
                    self.ready.wait(timeout=doze if self.dozing else SCHEDULE_SECONDS)
                    self.dozing = False
                    self.doze_until = None
                verdicts = self._take_reached() + self._evaluate(EVALUATE_CHUNK)
                if self.in_handoff:
                    self.handoffs.precompress()
                replan, self.replan = self.replan, False
            now = time.monotonic()
            if now >= next_tick:
                with self.lock:  # idle since an idle plan: that tick would change nothing
                    idle = self.idle_plan is not None and self.idle_plan == self.fingerprint()
                if idle:
                    next_tick = now + IDLE_TICK_SECONDS
                else:
                    verdicts += self.tick()
                    replan = True
            if replan:
                now = time.monotonic()
                with self.lock:
                    next_tick = self.next_tick_due(now, period)
            self.emit(verdicts)

    def next_tick_due(self, now: float, period: float) -> float:
        """When :meth:`tick` next has work (time.monotonic; lock held): ``now + period``
        while messages came since the last tick, a monitor holds events or letters or
        its pressure is being followed, or a handoff is under way (and always under a
        clock other than the system's); else the earliest sort-buffer flush
        (``flush_after`` after its first event) and clock step (a monitor's clock
        deadline, ``flush_after`` late as :meth:`advance_clocks` takes it), at most
        IDLE_TICK_SECONDS away. Reset: :attr:`ingested`. A plan of IDLE_TICK_SECONDS for
        monitors without a clock notes :attr:`idle_plan`: the scheduler skips that tick if
        nothing changed meanwhile (it would change nothing)."""
        soon = now + period
        self.idle_plan = None
        if self.ingested or self.in_handoff or not isinstance(self.clock, SystemClock):
            self.ingested = False
            return soon
        due = now + IDLE_TICK_SECONDS
        flush_ns = int(self.flush_after * 1e9)
        wall = self.clock.wall_ns()
        for slot in self.watched.values():  # (any other is idle)
            rt = slot.runtime
            if rt is None:
                continue
            if rt.letters or rt.events or slot.full_since is not None or slot.migration_wanted:
                return soon
            if slot.pending_since is not None:
                due = min(due, slot.pending_since + self.flush_after)
        for slot in self.clocked.values():
            clock = slot.runtime.clock if slot.runtime is not None else None
            if clock is not None and clock.deadline is not None and slot.active:
                due = min(due, now + (clock.deadline + flush_ns - wall) / 1e9)
        timed = any(slot.runtime is not None for slot in self.clocked.values())
        if not timed and due == now + IDLE_TICK_SECONDS:
            self.idle_plan = self.fingerprint()  # (a tick then changes nothing: skipped)
        # a step not taken when due (everything was not drained up to it yet): once a period
        return max(due, soon) if due <= now else due

    def handoff_changed(self, slot: MonitorSlot) -> None:
        """A handoff's step changed ``slot``'s state: the scheduler ticks every period
        while one is under way, and plans anew when one ends (a restored monitor may have
        a clock step due)."""
        self.watched[slot.name] = slot  # (it may hold events or letters restored)
        self.changes += 1
        self.wake_ingest()  # (it waits IDLE_WAIT_SECONDS no more while one is under way)
        self.replan = True
        if self.dozing:
            self.ready.notify()

    def drain(self, until: float | None = None) -> int:
        """At shutdown: release every buffer and evaluate it, so no accepted event is
        lost; a round at a time, until ``until`` (monotonic) at most. Returns the letters
        left unevaluated when the time ran out (logged: their verdicts are not reached)."""
        with self.lock:
            for slot in self.slots.values():
                if slot.runtime is not None and slot.active:  # not what is held for the other side
                    slot.runtime.flush()
                    self.waiting[slot.name] = slot.runtime
                    slot.pending_since = None
        while True:
            with self.lock:
                verdicts = self._take_reached() + self._evaluate(EVALUATE_CHUNK)
                more = self.behind
            self.emit(verdicts)
            if not more:
                return 0
            if until is not None and time.monotonic() >= until:
                with self.lock:
                    waiting, self.waiting = self.waiting, {}
                    left = sum(len(rt.letters) for rt in waiting.values())
                log.error(
                    "stopping: %d letters of %d monitors not evaluated within the stop time "
                    "(their verdicts are in no sink; each monitor's verdicts before them are)",
                    left,
                    len(waiting),
                )
                return left

    def wake(self) -> None:
        with self.lock:
            self.ready.notify_all()
