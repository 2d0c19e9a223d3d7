"""The event pipeline of the paper's Fig. 2, shared by ``edgerv check`` and the live handler.

callback -> :meth:`MonitorRuntime.offer` puts ``(timestamp, values)`` in the event
buffer -> once it holds ``sortThreshold`` events it is sorted by timestamp (ties
keep arrival order) -> each event updates the signal values and the placeholders
are evaluated and bit-packed into one letter per event, without its timestamp
(the timestamps are kept beside, only to report when a verdict was decided) ->
:meth:`MonitorRuntime.evaluate` consumes the letters through the transition table.

:class:`Router` is the "one subscription per topic" part: it reads each field
once per message and hands every monitor that reads the topic its updates. A field
inside an empty optional (:data:`~edgerv.core.msgtypes.ABSENT`) is no update: its
signal holds its value, and the message is still one event.
"""

from __future__ import annotations

import math
from array import array
from bisect import bisect_left, bisect_right
from collections.abc import Callable, Collection, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from itertools import accumulate, chain, compress, islice, repeat
from operator import add, and_, is_not, itemgetter, lt, ne, sub
from typing import Any, Literal, NamedTuple

from edgerv.core.documents import QosSpec
from edgerv.core.language.past import Derived, Past
from edgerv.core.monitor import AGE_CMP, EDGES, AtomRead, CompiledMonitor, TimedAtom
from edgerv.core.msgtypes import ABSENT, ValueKind, make_getter, optional_steps, path_keys
from edgerv.core.plain_step import PlainPlan, TopicAtoms, plain_plan
from edgerv.core.snapshot import HandoffError, Snapshot, deciding_steps, runs_of

VerdictKind = Literal["violated", "satisfied"]
MonitorState = Literal["pending", "violated", "satisfied", "halted"]


def status_of(monitor: CompiledMonitor, halted: bool, step: int, state: int) -> MonitorState:
    """A runtime's state in words, from its halt, its step and its automaton's state."""
    if halted:
        return "halted"
    if step and state == monitor.table.violated:
        return "violated"
    if step and state == monitor.table.satisfied:
        return "satisfied"
    return "pending"


Update = tuple[int, Any]  # (signal index in the monitor, new value)
Event = tuple[int, int, Sequence[Update]]  # (stamp ns, arrival sequence, updates)
# evaluate: fewer letters than this, or runs of equal letters shorter than MIN_MEAN_RUN on
# average, go a letter at a time (taking runs whole costs more per run than it saves)
SHORT_EVALUATION = 64
MIN_MEAN_RUN = 6
_UNSET = object()
_UNBOUNDED = 1 << 62  # a buffer without a capacity: more than any batch makes
_STAMP = itemgetter(0)
_UPDATES = itemgetter(2)
_VALUE = itemgetter(1)
COLUMNS_FROM = 128  # batches this long are compressed column-wise (NumPy), shorter one by one


class Verdict(NamedTuple):
    """A verdict a monitor reached. (A named tuple: a check can reach one at each of
    100,000 steps, and a tuple is made in half the time of a frozen dataclass.)"""

    monitor: str
    verdict: VerdictKind
    stamp: int  # nanoseconds: the timestamp of the event whose letter decided it
    step: int  # 1-based letter index since the monitor started, never reset

    def as_dict(self) -> dict[str, Any]:
        return {"verdict": self.verdict, "stamp": self.stamp, "step": self.step}


@dataclass
class Arrivals:
    """A monitor's events in arrival order, column by column: what a check hands it a
    chunk of a trace at a time (:meth:`MonitorRuntime.offer_arrivals`), with no tuple
    made per event."""

    stamps: Sequence[int]
    # per signal index: the events (positions, ascending) that update it and the values
    # they give it, one each
    changes: list[tuple[Sequence[int], Sequence[Any]]]
    # per topic: its events (positions, ascending) and the signals each of them updates
    groups: list[tuple[Sequence[int], tuple[int, ...]]]
    # the stamps, positions and values are NumPy arrays (a bag read column-wise)
    columnar: bool = False

    def split(self, at: int) -> tuple[Arrivals, Arrivals]:
        """Arrivals in arrays cut before the ``at``-th event: its events before and after."""
        heads: list[tuple[Any, Any]] = []
        tails: list[tuple[Any, Any]] = []
        for positions, values in self.changes:
            p: Any = positions
            i = int(p.searchsorted(at)) if len(p) else 0
            heads.append((p[:i], values[:i]))
            tails.append((p[i:] - at if len(p) else p, values[i:]))
        head_groups: list[tuple[Any, tuple[int, ...]]] = []
        tail_groups: list[tuple[Any, tuple[int, ...]]] = []
        for positions, signals in self.groups:
            p = positions
            i = int(p.searchsorted(at))
            head_groups.append((p[:i], signals))
            tail_groups.append((p[i:] - at, signals))
        return (
            type(self)(self.stamps[:at], heads, head_groups, columnar=True),
            type(self)(self.stamps[at:], tails, tail_groups, columnar=True),
        )

    def as_arrays(self) -> Arrivals:
        """The same arrivals in arrays: positions and stamps of int64, values as the Python
        objects they are (compared as Python compares them)."""
        import numpy as np  # here: a check with a sort window over a long chunk

        def objects(values: Sequence[Any]) -> Any:
            out = np.empty(len(values), object)
            out[:] = values
            return out

        def ints(values: Sequence[int]) -> Any:
            return np.array(values, np.int64)

        return type(self)(
            ints(self.stamps),
            [(ints(p), objects(v)) for p, v in self.changes],
            [(ints(p), signals) for p, signals in self.groups],
            columnar=True,
        )

    def as_lists(self) -> Arrivals:
        """The same arrivals in lists of Python values."""
        return type(self)(
            _listed(self.stamps),
            [(_listed(p), _listed(v)) for p, v in self.changes],
            [(_listed(p), signals) for p, signals in self.groups],
        )

    def held(self, signal: int, k: int, before: Any) -> Any:
        """The signal's value after the ``k``-th event (``before``: its value before any)."""
        positions, values = self.changes[signal]
        i = bisect_right(positions, k) - 1
        return values[i] if i >= 0 else before

    def updates(self, k: int) -> tuple[Update, ...]:
        """The ``k``-th event's updates, as :meth:`MonitorRuntime.offer` takes them."""
        for positions, signals in self.groups:
            i = bisect_left(positions, k)
            if i < len(positions) and positions[i] == k:
                return tuple((s, self.changes[s][1][i]) for s in signals)
        raise IndexError(k)

    def every_update(self) -> list[tuple[Update, ...]]:
        """Each event's updates, in order (made a topic at a time)."""
        out: list[tuple[Update, ...]] = [()] * len(self.stamps)
        for positions, signals in self.groups:
            each = zip(*[zip(repeat(s), self.changes[s][1]) for s in signals], strict=True)
            if len(positions) == len(out):
                return list(each)
            for k, updates in zip(positions, each, strict=True):
                out[k] = updates
        return out


class HeldArrivals(Arrivals):
    """Arrivals where a signal may be updated by fewer events than its topic's: a message
    without a value for it (a field inside an empty optional) is an event of its topic
    that leaves it out of its updates, and the signal holds its value (its changes are
    the events that gave it one)."""

    def updates(self, k: int) -> tuple[Update, ...]:
        """The ``k``-th event's updates: of its topic's signals, those it gives a value."""
        for positions, signals in self.groups:
            if _holds(positions, k):
                return tuple(self._given(k, signals))
        raise IndexError(k)

    def _given(self, k: int, signals: tuple[int, ...]) -> Iterator[Update]:
        for s in signals:
            positions, values = self.changes[s]
            if _holds(positions, k):
                yield s, values[bisect_left(positions, k)]

    def every_update(self) -> list[tuple[Update, ...]]:
        """Each event's updates, in order (made an event at a time)."""
        return [self.updates(k) for k in range(len(self.stamps))]


def _without_absent(arrivals: Arrivals, held: frozenset[int]) -> Arrivals:
    """``arrivals`` where the signals ``held`` are updated only by the events that give them
    a value: ABSENT (a field inside an empty optional) taken out of their changes (a
    :class:`HeldArrivals`; ``arrivals`` itself where none was ABSENT)."""
    changes, taken = list(arrivals.changes), False
    for s in held:
        positions, values = changes[s]
        dtype = getattr(values, "dtype", None)
        if not len(positions) or (dtype is not None and not dtype.hasobject):
            continue  # (an array of numbers holds no ABSENT)
        present = list(map(is_not, values, repeat(ABSENT)))
        if all(present):
            continue
        taken = True
        if arrivals.columnar:
            import numpy as np  # (arrays: NumPy is loaded)

            mask: Any = np.array(present, bool)
            given: Any = values
            changes[s] = (np.asarray(positions)[mask], given[mask])
        else:
            changes[s] = (list(compress(positions, present)), list(compress(values, present)))
    if not taken:
        return arrivals
    return HeldArrivals(arrivals.stamps, changes, arrivals.groups, columnar=arrivals.columnar)


def _holds(positions: Sequence[int], k: int) -> bool:
    i = bisect_left(positions, k)
    return i < len(positions) and positions[i] == k


def _listed(values: Any) -> list[Any]:
    return values.tolist() if hasattr(values, "tolist") else list(values)


def letter_typecode(bits: int) -> str:
    """The narrowest array type holding ``bits`` placeholder bits per letter (a wide
    letter's, up to 63 bits: a signed 64-bit integer, NumPy's int64)."""
    return "B" if bits <= 8 else "H" if bits <= 16 else "q"


@dataclass
class Clock:
    """The time of a monitor with timed atoms (``age(x) < 200ms``), in stamp nanoseconds.

    ``now`` is the time of its last step, ``last[s]`` the time of the last message on
    signal s's topic (None: none yet, an infinite age), and ``deadline`` the next
    instant after ``now`` at which a timed atom changes its truth without any message:
    there the monitor takes a clock step (docs/semantics.md, "Time").
    """

    atoms: tuple[TimedAtom, ...]
    last: list[int | None]
    past: Past | None = None  # its timed past operators change with time too
    now: int | None = None
    deadline: int | None = None
    mask: int = field(init=False)  # the timed atoms' placeholder bits

    def __post_init__(self) -> None:
        self.mask = sum(1 << a.bit for a in self.atoms)

    def bits(self) -> int:
        """The timed atoms' placeholder bits at ``now``."""
        out, now = 0, self.now
        for a in self.atoms:
            last = self.last[a.signal]  # when set, now is too; unset: an infinite age
            if (
                a.op in (">", ">=") if last is None else AGE_CMP[a.op](now - last, a.duration)  # type: ignore[operator]
            ):
                out |= 1 << a.bit
        return out

    def next_deadline(self) -> int | None:
        best = None
        now = self.now
        for a in self.atoms:
            last = self.last[a.signal]
            if last is None or now is None:  # an infinite age stays infinite
                continue
            for edge in EDGES[a.op]:
                at = last + a.duration + edge
                if at > now:
                    if best is None or at < best:
                        best = at
                    break
        if self.past is not None and now is not None:
            later = self.past.next_change(now)
            if later is not None and (best is None or later < best):
                best = later
        return best

    def snapshot(self) -> tuple[int | None, tuple[int | None, ...]]:
        return self.now, tuple(self.last)

    def restore(self, now: int | None, last: Sequence[int | None]) -> None:
        self.now, self.last = now, list(last)
        self.deadline = self.next_deadline()


@dataclass
class MonitorRuntime:
    """One monitor's buffers and state. Not thread-safe: one thread drives it."""

    monitor: CompiledMonitor
    name: str = field(init=False)
    threshold: int = field(init=False)  # sortThreshold
    events: list[Event] = field(default_factory=list)  # the sort buffer, kept in order
    letters: array = field(init=False)  # type: ignore[type-arg]
    stamps: array = field(init=False)  # type: ignore[type-arg]
    values: list[Any] = field(init=False)
    missing: int = field(init=False)  # signals without a value yet
    valuation: int = 0  # the placeholder bits after the last compressed event
    state: int = 0  # the automaton state: the one integer a migration moves
    step: int = 0  # letters evaluated so far
    halted: bool = False
    holding: bool = False  # during a handoff: buffer events, never release them by count
    floor: int = -(2**63)  # events stamped at or below it were evaluated elsewhere: ignore
    late_events: int = 0  # events released after a newer one (beyond the sort window)
    last_released: int | None = None
    # Compressing ahead: each event of the sort buffer is compressed on arrival, into
    # ahead_letters, so that the release at sortThreshold has nothing left to do. The
    # buffer is kept in stamp order (an insertion, equal stamps in arrival order: what a
    # stable sort gives); ``ahead`` events (its first) are compressed so, from ``base``,
    # the signal state from before the first of them. An event arriving out of order
    # cuts the compressed part back to where it goes; the rest is compressed again.
    ahead: int = 0
    speculate: bool = True  # off only to test that it changes nothing (and on receivers)
    redone: int = 0  # events compressed again since the last release
    disordered: bool = False  # redone more than the buffer held: not worth it until empty
    ahead_letters: array = field(init=False)  # type: ignore[type-arg]
    ahead_stamps: array = field(init=False)  # type: ignore[type-arg]
    base: tuple[list[Any], int, int] = field(init=False)
    # A monitor whose placeholders time alone changes (timed atoms, timed past operators)
    # steps by the clock too (clock steps); None without any.
    clock: Clock | None = field(init=False)
    past: Past | None = field(init=False)  # its past operators' placeholders and state
    # the valuation is a letter its past operators made (a step, not a valuation of the
    # atoms alone): a later letter with the same atoms may take it again (_compress_one)
    past_stepped: bool = field(default=False, init=False)
    # (a monitor with either compresses its events one by one, never ahead nor with NumPy;
    # a check's chunks and the live handler's long batches, a run of equal letters at a
    # time: :meth:`offer_arrivals`, :meth:`take_arrivals`)
    # The signals read through an optional: a message whose optional is empty gives them
    # ABSENT, no update (the signal holds its value). A monitor with one takes ABSENT out
    # of the updates it is offered (the router's events come without: Router._offer_held).
    held: frozenset[int] = field(init=False)
    # a wide letter's derived placeholders (what the automaton reads), None for any other
    derived: Derived | None = field(init=False)
    # none of these (nor a signal read through an optional): Router.offer_values takes
    # its events as they come in one inlined step (what _compress_one does for it)
    plain: bool = field(default=False, init=False)
    atom_funcs: Any = field(default=None, init=False)  # (the monitor's, for that step)
    atoms_of_signal: Any = field(default=None, init=False)
    # its table's rows, letter width and first verdict state, for that step: a letter
    # with none before it waiting is walked at once when it reaches no verdict
    rows: Any = field(default=None, init=False)
    table_bits: int = field(default=0, init=False)
    live: int = field(default=0, init=False)
    # events that step taken since it was made (its host counts the others as it admits
    # them: MonitorSlot.events adds these; not in a snapshot)
    taken: int = field(default=0, init=False, compare=False)
    # the CPU (ns) its host measured spending on it since it was made: taking its events
    # and evaluating them (a handler's estimate from sampled timings; not in a snapshot)
    cost_ns: float = field(default=0.0, init=False, compare=False, repr=False)

    def __post_init__(self) -> None:
        spec = self.monitor.spec
        self.name = spec.name
        m = self.monitor
        self.past = Past(m.past) if m.past else None
        self.derived = m.derived
        self.clock = Clock(m.timed, [None] * len(m.signal_names), self.past) if m.clocked else None
        if m.stateful:
            self.speculate = False
        self.threshold = spec.sort_threshold
        self.letters = array(letter_typecode(m.letter_bits))
        self.stamps = array("q")
        self.ahead_letters = array(self.letters.typecode)
        self.ahead_stamps = array("q")
        self.base = ([], 0, 0)
        self.values = [
            _UNSET if spec.signals[n].initial is None else spec.signals[n].initial
            for n in self.monitor.signal_names
        ]
        self.missing = sum(v is _UNSET for v in self.values)
        if not self.missing:
            self.valuation = self._full_valuation()
        self.held = frozenset(
            i
            for i, n in enumerate(m.signal_names)
            if optional_steps(spec.signals[n].msg_type, spec.signals[n].field)
        )
        if self.held:  # (so, not a test per message for the others)
            self.offer = self._offer_held  # type: ignore[method-assign]
        self.plain = (
            self.clock is None and self.past is None and self.derived is None and not self.held
        )
        self.atom_funcs, self.atoms_of_signal = m.atom_funcs, m.atoms_of_signal
        self.rows, self.table_bits, self.live = m.table.table, m.table.bits, m.table.live

    @property
    def buffered(self) -> int:
        """Events held in the event buffer plus letters not yet evaluated."""
        return len(self.events) + len(self.letters)

    @property
    def walks(self) -> bool:
        """It walks its letters as they are made, up to one that reaches a verdict (which
        waits to be evaluated, and the letters after it): a plain monitor taking its
        events as they come, running (Router.offer_values; after a long batch,
        :meth:`walk_quiet`)."""
        return self.plain and self.threshold == 1 and not self.holding and not self.halted

    def walk_quiet(self) -> None:
        """Walk the letters that wait, from the first, up to the first that reaches a
        verdict (what :meth:`evaluate` does with them; they report nothing): what a
        monitor that :attr:`walks` gives, offered the same events one by one."""
        letters = self.letters
        rows, bits, live, state = self.rows, self.table_bits, self.live, self.state
        i, n = 0, len(letters)
        while i < n:
            letter = letters[i]
            new = rows[(state << bits) | letter]
            if new >= live:
                break
            i += 1
            if new == state:  # it stays: so does the rest of the run of this letter
                while i < n and letters[i] == letter:
                    i += 1
            state = new
        if i:
            self.state = state
            self.step += i
            del letters[:i]
            del self.stamps[:i]

    @property
    def status(self) -> MonitorState:
        return status_of(self.monitor, self.halted, self.step, self.state)

    def offer(self, stamp: int, seq: int, updates: Sequence[Update]) -> bool:
        """Buffer one event; sort and compress the buffer once it holds sortThreshold events.

        Returns True when letters were produced and :meth:`evaluate` has work.
        """
        if self.threshold == 1 and not self.holding and not self.halted and stamp > self.floor:
            # nothing to sort: straight to letters (offer_event's first case, no tuple made)
            last = self.last_released
            if last is not None and stamp < last:
                self.late_events += 1
            self.last_released = stamp
            self._compress_one(stamp, updates, self.letters, self.stamps)
            return self._walked() if self.plain else not self.missing
        return self.offer_event((stamp, seq, updates))

    def _walked(self) -> bool:
        """(A plain monitor's letter just made: walked, with those before it, unless it
        reaches a verdict; whether letters wait to be evaluated.)"""
        self.walk_quiet()
        return bool(self.letters)

    def _offer_held(self, stamp: int, seq: int, updates: Sequence[Update]) -> bool:
        """:meth:`offer` of a monitor with a signal read through an optional: an update
        without a value (ABSENT) is none."""
        return self.offer_event((stamp, seq, tuple(u for u in updates if u[1] is not ABSENT)))

    def offer_event(self, event: Event) -> bool:
        """:meth:`offer` for an event tuple ``(stamp, seq, updates)``, kept as it is: the
        router hands one tuple to every monitor with the same bindings (less to allocate
        on arrival, and to free once the event is compressed)."""
        stamp, _, updates = event
        if self.halted or stamp <= self.floor:
            return False
        if self.threshold == 1 and not self.holding:  # nothing to sort: straight to letters
            if self.last_released is not None and stamp < self.last_released:
                self.late_events += 1
            self.last_released = stamp
            self._compress_one(stamp, updates, self.letters, self.stamps)
            return self._walked() if self.plain else not self.missing
        events = self.events
        if not events or stamp >= events[-1][0]:
            events.append(event)
            if self.speculate and not self.disordered:
                ahead = self.ahead
                if ahead and ahead == len(events) - 1:  # the usual: only the new one to do
                    self._compress_one(stamp, updates, self.ahead_letters, self.ahead_stamps)
                    self.ahead = ahead + 1
                else:
                    self._compress_ahead()
        else:  # out of order: where a stable sort puts it; compressed with the next in order
            at = bisect_right(events, stamp, key=_STAMP)
            events.insert(at, event)
            if at < self.ahead:
                self._cut_ahead(at)
        if len(events) >= self.threshold and not self.holding:
            return self.flush()
        return False

    def offer_arrivals(self, arrivals: Arrivals) -> bool:
        """:meth:`offer` each of these events in turn; the same letters, stamps and state,
        made a run of equal letters at a time where the monitor takes its events as they
        come (``sortThreshold`` 1, no handoff holding them).

        Returns True when letters were produced and :meth:`evaluate` has work.
        """
        if not len(arrivals.stamps) or self.halted:
            return False
        self.take_arrivals(arrivals)
        return len(self.letters) > 0

    def take_walking(self, arrivals: Arrivals, capacity: int) -> tuple[int, bool]:
        """:meth:`take_arrivals` for a monitor that :attr:`walks`, as offering the events
        one at a time does: its letters walked as they are made, up to one that reaches
        a verdict. While no letter waits it takes every event its buffer has room for (a
        walked letter leaves none): the events a chunk at a time, as many a chunk as the
        buffer has room for with no letter, each chunk's letters walked; from a letter
        that reaches a verdict on, the buffer fills as take_arrivals fills it. Returns
        the events taken, and whether letters wait to be evaluated."""
        if self.letters:
            self.walk_quiet()  # (what one at a time does before the first event)
        taken, rest = 0, arrivals
        while self.walks and not self.letters:
            room = capacity - len(self.events)
            if room <= 0 or len(rest.stamps) <= room:
                break
            head, rest = (rest if rest.columnar else rest.as_arrays()).split(room)
            taken += self.take_arrivals(head, capacity)[0]
            self.walk_quiet()
        taken += self.take_arrivals(rest, capacity)[0]
        self.walk_quiet()
        return taken, bool(self.letters)

    def take_arrivals(self, arrivals: Arrivals, capacity: int | None = None) -> tuple[int, bool]:
        """:meth:`offer_arrivals` into a buffer that holds at most ``capacity`` events
        plus letters (``bufferCapacity``; None: no bound), as the live handler admits
        its events one at a time: an event is taken while the buffer holds fewer than
        ``capacity``, and dropped otherwise, with nothing changed. So exactly the events
        that offering each in turn after that test takes are taken, with the same
        letters (clock steps included), stamps and state.

        Returns how many events were taken, and whether offering one of them would have
        returned True (letters were produced: :meth:`evaluate` has work).
        """
        stamps = arrivals.stamps
        n = len(stamps)
        if capacity is not None and self.buffered >= capacity:
            return 0, False  # full: nothing is taken, so it stays full
        if not n or self.halted:
            return n, False
        if self.held:
            arrivals = _without_absent(arrivals, self.held)
        if arrivals.columnar:
            if self._offer_columns(arrivals, capacity):
                return n, True  # (every signal valued: each event, or window, made letters)
            arrivals = arrivals.as_lists()
            stamps = arrivals.stamps
        elif (  # a sort window over a long chunk: else offered one by one
            self.threshold != 1
            and n >= COLUMNS_FROM
            and self.past is None
            and self._offer_columns(arrivals.as_arrays(), capacity)
        ):
            return n, True
        if self.threshold != 1 or self.holding or min(stamps) <= self.floor:
            # one by one; with a sort window a release can leave fewer events plus
            # letters than it took (no letter while a signal has no value): each tested
            taken, ready = 0, False
            for stamp, updates in zip(stamps, arrivals.every_update(), strict=True):
                if capacity is None or self.buffered < capacity:
                    ready = self.offer(stamp, 0, updates) or ready
                    taken += 1
            return taken, ready
        late = sum(map(lt, islice(stamps, 1, None), stamps))  # each older than the one before
        taken = self._compress_arrivals(arrivals, not late, capacity)
        if taken < n:  # the rest dropped: only the events taken count
            late = sum(map(lt, islice(stamps, 1, taken), stamps))
        last = self.last_released
        if last is not None and stamps[0] < last:
            late += 1
        self.late_events += late
        self.last_released = stamps[taken - 1]
        return taken, not self.missing  # (what offer returns for each: the last tells)

    def _offer_columns(self, arrivals: Arrivals, capacity: int | None = None) -> bool:
        """:meth:`offer_arrivals` for arrivals in arrays, a column at a time
        (:func:`edgerv.core.columns.compress`) where that gives the same letters: False
        where it does not, having changed nothing; also where the buffer (``capacity``:
        events plus letters) might not take every event (:meth:`take_arrivals`).

        With ``sortThreshold`` k > 1, events in stamp order arriving at an empty sort
        buffer are released k at a time in the order they came: the chunk's whole windows
        are compressed as with k = 1, and the events after the last whole window wait in
        the buffer, offered one by one."""
        if self.holding or self.missing or self.past is not None:
            return False
        from edgerv.core import columns  # here: NumPy, for a check's bag alone

        stamps: Any = arrivals.stamps  # an int64 array
        clock, n, last = self.clock, len(stamps), self.last_released
        if int(stamps.min()) <= self.floor:
            return False
        whole = n
        if self.threshold != 1:
            in_order = not bool((stamps[1:] < stamps[:-1]).any())
            if self.events or not in_order or (last is not None and int(stamps[0]) < last):
                return False
            whole = n - n % self.threshold
            if not whole:
                return False
        head, tail = arrivals.split(whole) if whole < n else (arrivals, None)
        got = columns.compress(
            self.monitor,
            head.stamps,  # type: ignore[arg-type]
            head.changes,  # type: ignore[arg-type]
            self.values,
            self.valuation,
            None if clock is None else clock.now,
            [] if clock is None else clock.last,
        )
        if got is None:
            return False
        if capacity is not None and self.buffered + len(got.letters) + n - whole > capacity:
            # (else all are taken: one by one, each event finds the buffer holding less
            # than this, without its own letter or place and those of the events after it)
            return False
        released = stamps[:whole]
        late = int((released[1:] < released[:-1]).sum())
        if last is not None and int(released[0]) < last:
            late += 1
        self.late_events += late
        self.last_released = int(released[-1])
        self.values[:] = got.values
        self.valuation = int(got.letters[-1])
        self.letters.frombytes(got.letters.astype(self.letters.typecode).tobytes())
        self.stamps.frombytes(got.stamps.tobytes())
        if clock is not None:
            clock.last = got.last
            clock.now = int(released[-1])
            clock.deadline = clock.next_deadline()
        if tail is not None:  # the start of a window: into the sort buffer
            rest = tail.as_lists()
            for stamp, updates in zip(rest.stamps, rest.every_update(), strict=True):
                self.offer(stamp, 0, updates)
        return True

    def _compress_arrivals(
        self, arrivals: Arrivals, in_order: bool, capacity: int | None = None
    ) -> int:
        """What :meth:`_compress_one` does event by event, a run of equal letters at once.

        An event changes the letter only if it changes an atom's truth (a timed atom's
        too: its age starts again at each message on its topic and grows with time),
        if time alone changes a timed atom before it (a clock step), or, in a monitor
        with past operators, if the last step left a ``prev`` unsettled or a timed
        operator may change with time before it (:meth:`Past.settled`,
        :meth:`Past.next_change`). Only those events are compressed one by one, with
        the state they would have; each event between two of them makes the letter of
        the last one again, with its own stamp (docs/semantics.md, section 3: how, not
        what).

        With a ``capacity`` (events plus letters, :meth:`take_arrivals`) the events are
        taken while the buffer holds fewer: an event compressed one by one is tested
        before its clock steps and letter, and a run of equal letters, one letter each,
        is cut where it fills the buffer; the events from there on are not taken (with
        one letter per event, letters only grow: once full, full). Returns how many
        events were taken: what this gives for those alone, the same.
        """
        stamps, n = arrivals.stamps, len(arrivals.stamps)
        before = list(self.values)
        clock, past = self.clock, self.past
        nows = self._nows(stamps, in_order) if clock is not None else stamps
        last = [] if clock is None else list(clock.last)
        # no letter is made while a signal has no value, clock steps included: the events
        # until then all fit if the first does (take_arrivals tested it)
        k = self._compress_while_missing(arrivals) if self.missing else 0
        if k == n:
            return n
        letters, out_stamps = self.letters, self.stamps
        # the letters at which the buffer is full (the sort buffer stays as it is)
        full = _UNBOUNDED if capacity is None else capacity - len(self.events)
        changes = self._atom_changes(arrivals, k, before)
        if self.monitor.timed:
            changes = sorted({*changes, *self._timed_changes(arrivals, k, nows, last)})
        pending = iter(changes)
        change = next(pending, n)
        synced = k - 1  # the events up to it have the state a step leaves
        while k < n:
            if len(letters) >= full:  # the k-th event and every later one are dropped
                break
            if synced < k - 1:  # the run before it left the values and the time behind
                self._sync(arrivals, k - 1, before, nows)
            self._compress_one(stamps[k], arrivals.updates(k), letters, out_stamps)
            synced = k
            while change <= k:
                change = next(pending, n)
            end = change
            if past is not None and not (past.always_settled or past.settled(self.valuation)):
                end = k + 1
            elif (later := self._past_change()) is not None:
                end = bisect_left(nows, later, k + 1, end)
            end = min(end, k + 1 + max(0, full - len(letters)))  # those the buffer takes
            if end > k + 1:  # the same letter again, up to the next event that may change it
                letters.extend(array(letters.typecode, [self.valuation]) * (end - k - 1))
                out_stamps.extend(stamps[k + 1 : end])
            k = end
        if synced < k - 1:
            self._sync(arrivals, k - 1, before, nows)
            if past is not None:
                past.prune(nows[k - 1])
        return k

    def _past_change(self) -> int | None:
        """The first instant after now at which a timed past operator may change."""
        clock, past = self.clock, self.past
        if clock is None or past is None:
            return None
        if not self.monitor.timed:  # the clock's deadline is the past operators' alone
            return clock.deadline
        return past.next_change(clock.now) if clock.now is not None else None

    def _compress_while_missing(self, arrivals: Arrivals) -> int:
        """Compress events one by one while a signal has no value yet; return how many were."""
        stamps, k = arrivals.stamps, 0
        while k < len(stamps) and self.missing:
            self._compress_one(stamps[k], arrivals.updates(k), self.letters, self.stamps)
            k += 1
        return k

    def _timed_changes(
        self, arrivals: Arrivals, k: int, nows: Sequence[int], last: list[int | None]
    ) -> list[int]:
        """The events after the ``k``-th before which a timed atom changes: by a message
        (the age starts again) or by time (a clock step comes before the event).

        Each computed for every event, a column at a time: the time of the signal's
        last message (``last``: before these events; none is an infinite age, -inf
        here), the age, the atom's truth, and whether one of the instants its truth
        changes at (``EDGES``) falls after the event's time and before the next
        event's stamp.
        """
        n, stamps = len(nows), arrivals.stamps
        out: set[int] = set()
        for atom in self.monitor.timed:
            held = last[atom.signal]
            marks: list[float] = [-math.inf if held is None else held] * n
            for p in arrivals.changes[atom.signal][0]:
                marks[p] = nows[p]
            lasts = list(accumulate(marks, max))  # times only grow: the latest is the last
            truths = list(map(AGE_CMP[atom.op], map(sub, nows, lasts), repeat(atom.duration)))
            changed = map(ne, islice(truths, k + 1, None), islice(truths, k, None))
            out.update(compress(range(k + 1, n), changed))
            for edge in EDGES[atom.op]:
                at = list(map(add, islice(lasts, k, n - 1), repeat(atom.duration + edge)))
                after = map(lt, islice(nows, k, n - 1), at)
                before_next = map(lt, at, islice(stamps, k + 1, None))
                out.update(compress(range(k + 1, n), map(and_, after, before_next)))
        return sorted(out)

    def _nows(self, stamps: Sequence[int], in_order: bool) -> Sequence[int]:
        """The monitor's time after each event: the latest stamp so far (a late event
        counts at the time of the step before it)."""
        now = self.clock.now if self.clock is not None else None
        if in_order and (now is None or stamps[0] >= now):
            return stamps
        if now is None:
            return list(accumulate(stamps, max))
        return list(accumulate(stamps, max, initial=now))[1:]

    def _atom_changes(self, arrivals: Arrivals, k: int, before: list[Any]) -> list[int]:
        """The events after the ``k``-th that may change an atom's truth, in order: the
        first update of its signals after it, then each update that changes its truth."""
        out: set[int] = set()
        for read in self.monitor.reads:
            if read.right is None:
                positions, values = arrivals.changes[read.left]
                truths = list(map(read.compare, values, repeat(read.const)))
            else:
                positions, truths = self._pair_truths(arrivals, read, k, before)
            start = bisect_right(positions, k)
            if start < len(positions):
                out.add(positions[start])
                changed = map(ne, islice(truths, start + 1, None), islice(truths, start, None))
                out.update(compress(islice(positions, start + 1, None), changed))
        return sorted(out)

    @staticmethod
    def _pair_truths(
        arrivals: Arrivals, read: AtomRead, k: int, before: list[Any]
    ) -> tuple[list[int], list[bool]]:
        """An atom comparing two signals, at each update of either after the ``k``-th event
        (from which on both have a value)."""
        assert read.right is not None
        left, right = arrivals.changes[read.left][0], arrivals.changes[read.right][0]
        after = {*islice(left, bisect_right(left, k), None)}
        positions = sorted(after.union(islice(right, bisect_right(right, k), None)))
        truths = [
            read.compare(
                arrivals.held(read.left, p, before[read.left]),
                arrivals.held(read.right, p, before[read.right]),
            )
            for p in positions
        ]
        return positions, truths

    def _sync(self, arrivals: Arrivals, k: int, before: list[Any], nows: Sequence[int]) -> None:
        """The state after the ``k``-th event, which a run of equal letters took whole:
        its values, its time, the time of each signal's last message, and the clock's
        deadline, which the ages' messages move. (The letter and the past operators are
        those the run began with.)"""
        values, clock = self.values, self.clock
        for s, (positions, given) in enumerate(arrivals.changes):
            i = bisect_right(positions, k) - 1
            if i < 0:  # no message on it up to the k-th event
                values[s] = before[s]
                continue
            values[s] = given[i]
            if clock is not None:
                clock.last[s] = nows[positions[i]]
        if clock is not None:
            clock.now = nows[k]
            if self.monitor.timed:  # the ages' deadlines moved with the messages
                clock.deadline = clock.next_deadline()

    def _compress_ahead(self) -> None:
        """Compress the buffered events not compressed ahead yet: the new one, and those
        from where an event out of order cut the compressed part back."""
        events, ahead = self.events, self.ahead
        self.redone += len(events) - ahead - 1
        if self.redone > len(events):  # too disordered to be worth it (at most twice the work)
            self.unspeculate()
            self.disordered = True
            return
        if not ahead:
            self.base = (list(self.values), self.valuation, self.missing)
        letters, stamps = self.ahead_letters, self.ahead_stamps
        for stamp, _, updates in events[ahead:]:
            self._compress_one(stamp, updates, letters, stamps)
        self.ahead = len(events)

    def _cut_ahead(self, keep: int) -> None:
        """Forget what was compressed ahead from the ``keep``-th buffered event on."""
        made, (values, self.valuation, self.missing) = self._state_after(self.events[:keep])
        self.values[:] = values
        del self.ahead_letters[made:]
        del self.ahead_stamps[made:]
        self.ahead = keep

    def _state_after(self, prefix: Sequence[Event]) -> tuple[int, tuple[list[Any], int, int]]:
        """How many letters the first compressed-ahead events made, and the signal state
        (values, valuation, missing) after them.

        Once every signal has a value, each event makes one letter: the first
        ``ahead - len(ahead_letters)`` events made none. The values after the prefix
        are each signal's last update in it.
        """
        made = max(0, len(prefix) - (self.ahead - len(self.ahead_letters)))
        values, valuation, _ = self.base
        values, seen = list(values), set()
        for _, _, updates in reversed(prefix):
            for sig, value in reversed(updates):
                if sig not in seen:
                    seen.add(sig)
                    values[sig] = value
            if len(seen) == len(values):
                break
        missing = sum(v is _UNSET for v in values)
        return made, (values, self.ahead_letters[made - 1] if made else valuation, missing)

    def hold(self) -> None:
        """A handoff's hold (a sender's from its hold, a receiver's from its receive):
        its events are buffered raw, nothing compressed ahead as they come (what a sender
        takes then is mostly past the cut, never to be compressed here; a receiver's are
        compressed after the sender's state, once adopted)."""
        self.holding, self.speculate = True, False

    def resume(self) -> None:
        """A sender's hold undone: its events compressed ahead again as they come, as a
        monitor's are when made (none of a stateful one's)."""
        self.holding, self.speculate = False, not self.monitor.stateful

    def unspeculate(self) -> None:
        """Forget what was compressed ahead: back to the state before the sort buffer."""
        if self.ahead:
            values, self.valuation, self.missing = self.base
            self.values[:] = values
            self.ahead = 0
            del self.ahead_letters[:]
            del self.ahead_stamps[:]

    def flush(self) -> bool:
        """Sort and compress whatever the event buffer holds now."""
        return self.flush_prefix(len(self.events))

    def flush_prefix(self, count: int) -> bool:
        """Compress the ``count`` oldest events (by stamp) of the sort buffer."""
        if not self.events or count <= 0:
            return False
        count = min(count, len(self.events))
        if count == len(self.events):
            batch, self.events = self.events, []
            self.disordered = False
        else:
            batch, self.events = self.events[:count], self.events[count:]
        self.redone = 0
        ahead = self.ahead
        if count <= ahead:  # compressed already
            self._commit_ahead(batch)
        else:
            if ahead:
                self._commit_ahead(batch[:ahead])
            self._compress(batch[ahead:])
        last = self.last_released
        if last is not None and batch[0][0] < last:  # rare: count what came too late
            self.late_events += bisect_left(batch, last, key=_STAMP)
        self.last_released = batch[-1][0]
        return len(self.letters) > 0

    def _commit_ahead(self, batch: Sequence[Event]) -> None:
        """Move the letters of ``batch`` (the first events compressed ahead) to the letters;
        what stays ahead starts from the signal state after the batch."""
        pending, stamps = self.ahead_letters, self.ahead_stamps
        if len(batch) == self.ahead:
            made = len(pending)
        else:
            made, self.base = self._state_after(batch)
        self.letters.extend(pending[:made] if made < len(pending) else pending)
        self.stamps.extend(stamps[:made] if made < len(stamps) else stamps)
        del pending[:made]
        del stamps[:made]
        self.ahead -= len(batch)

    def cover(self, cut: int) -> None:
        """Compress the buffered events stamped at or before ``cut``; keep the later ones
        in the buffer, with nothing compressed ahead (a handoff's release)."""
        self.flush_prefix(bisect_right(self.events, cut, key=_STAMP))
        self.unspeculate()
        if self.clock is not None:  # and the clock steps up to it: the cut splits time too
            self._clock_steps(cut, self.letters, self.stamps)

    def advance(self, now: int) -> bool:
        """Time has reached ``now``: no event stamped at or before it is still to come
        (one that comes is late). Release the buffered events up to it and take the
        clock steps up to it. Only a monitor with timed atoms has anything to do.

        Returns True when letters were produced and :meth:`evaluate` has work.
        """
        clock = self.clock
        if clock is None or self.halted or self.holding:
            return False
        if self.events and self.events[0][0] <= now:
            self.flush_prefix(bisect_right(self.events, now, key=_STAMP))
        if clock.deadline is not None and clock.deadline <= now:
            self._clock_steps(now, self.letters, self.stamps)
        return len(self.letters) > 0

    def _clock_steps(
        self,
        until: int,
        letters: array,  # type: ignore[type-arg]
        stamps: array,  # type: ignore[type-arg]
    ) -> None:
        """The clock steps up to ``until``: a letter at each instant at which time alone
        changes a timed placeholder (an age atom, a timed past operator, its operands
        held), once every signal has a value."""
        clock, past = self.clock, self.past
        assert clock is not None
        keep = ~clock.mask
        while clock.deadline is not None and clock.deadline <= until:
            clock.now = now = clock.deadline
            if self.missing:  # no letter before every signal has a value
                clock.deadline = clock.next_deadline()
                continue
            aged = clock.bits()
            if aged != self.valuation & clock.mask or (
                past is not None and past.time_changes(now, self.valuation)
            ):  # time alone changed a timed placeholder here: a step, all evaluated anew
                bits = (self.valuation & keep) | aged
                if past is not None:
                    bits = past.step(now, bits)
                    self.past_stepped = True
                if self.derived is not None:
                    bits = self.derived(bits)
                self.valuation = bits
                letters.append(bits)
                stamps.append(now)
            clock.deadline = clock.next_deadline()

    def _full_valuation(self) -> int:
        bits = 0
        clock = self.clock
        for i, fn in enumerate(self.monitor.atom_funcs):
            if clock is not None and (clock.mask >> i) & 1:
                continue
            if fn(self.values):
                bits |= 1 << i
        return bits if clock is None else bits | clock.bits()

    def _compress(self, batch: Sequence[Event]) -> None:
        if len(batch) >= COLUMNS_FROM and not self.monitor.stateful:
            self._compress_columns(batch)
            return
        letters, stamps = self.letters, self.stamps
        for stamp, _seq, updates in batch:
            self._compress_one(stamp, updates, letters, stamps)

    def _compress_columns(self, batch: Sequence[Event]) -> None:
        """What :meth:`_compress_one` does event by event, for a whole sorted batch at once.

        Each signal's value after each event becomes a column (forward-filled from
        its updates); each placeholder is its comparison over the columns; a letter
        is their bits, from the event at which every signal has a value. The
        columns are object arrays: each element is compared as the Python value it
        holds, so the letters are those of the scalar path (tested side by side).
        """
        import numpy as np  # here: a check that never compresses a long batch does without it

        n = len(batch)
        values = self.values
        stamps = np.fromiter(map(_STAMP, batch), np.int64, n)
        per_event = list(map(_UPDATES, batch))
        flat = list(chain.from_iterable(per_event))  # every (signal, value), in order
        event_of = np.repeat(np.arange(n), np.fromiter(map(len, per_event), np.int64, n))
        signal_of = np.fromiter(map(_STAMP, flat), np.int64, len(flat))
        new_values = np.empty(len(flat), dtype=object)
        new_values[:] = list(map(_VALUE, flat))
        first = 0  # the first event after which every signal has a value
        columns = []
        for sig in range(len(values)):
            before = values[sig]
            mine = signal_of == sig
            pos = event_of[mine]
            if len(pos):
                new = new_values[mine]
                values[sig] = new[-1]
                if before is _UNSET:
                    first = max(first, int(pos[0]))
            elif before is _UNSET:
                first = n  # still without a value: no letter in this batch
            if first >= n:
                continue
            source = np.empty(len(pos) + 1, dtype=object)
            source[: len(pos)] = new if len(pos) else []
            source[len(pos)] = before  # index -1: the value from before the batch
            index = np.full(n, -1, dtype=np.int64)
            index[pos] = np.arange(len(pos))
            np.maximum.accumulate(index, out=index)
            columns.append(source[index])
        self.missing = sum(v is _UNSET for v in values)
        if first >= n:
            return
        columns = [c[first:] for c in columns]
        letters = np.zeros(n - first, dtype=np.int64)
        with np.errstate(all="ignore"):  # NaN compares false, as in Python
            for atom, compare in enumerate(self.monitor.atom_columns):
                letters |= np.asarray(compare(columns), dtype=bool).astype(np.int64) << atom
        if self.monitor.derived is not None:  # what the automaton reads of a wide letter
            letters = self.monitor.derived.columns(letters)
        self.valuation = int(letters[-1])
        self.letters.frombytes(letters.astype(self.letters.typecode).tobytes())
        self.stamps.frombytes(stamps[first:].tobytes())

    def _compress_one(
        self,
        stamp: int,
        updates: Sequence[Update],
        letters: array,  # type: ignore[type-arg]
        stamps: array,  # type: ignore[type-arg]
    ) -> None:
        """Apply one event to the signal values; append its letter once all have a value."""
        values = self.values
        clock = self.clock
        now, deadline = stamp, None
        if clock is not None:  # time passed up to the event: the clock steps before it
            deadline = clock.deadline
            if deadline is not None and deadline < stamp:
                self._clock_steps(stamp - 1, letters, stamps)
                deadline = clock.deadline
            # a late event counts at the time of the step before it: time never goes back
            if clock.now is not None and stamp <= clock.now:
                now = clock.now
            clock.now = now
            last = clock.last
            for sig, _ in updates:
                last[sig] = now
        if self.missing:
            for sig, value in updates:
                if values[sig] is _UNSET:
                    self.missing -= 1
                values[sig] = value
            if self.missing:  # no letter until every signal has a value
                if clock is not None:
                    clock.deadline = clock.next_deadline()
                return
            bits = self._full_valuation()
        else:  # only the placeholders that read the updated signals change
            monitor = self.monitor
            funcs, readers = monitor.atom_funcs, monitor.atoms_of_signal
            bits = self.valuation
            for sig, value in updates:
                values[sig] = value
                for atom in readers[sig]:
                    if funcs[atom](values):
                        bits |= 1 << atom
                    else:
                        bits &= ~(1 << atom)
            if clock is not None and clock.atoms:
                bits = (bits & ~clock.mask) | clock.bits()
        past = self.past
        if past is None:
            if clock is not None:
                clock.deadline = clock.next_deadline()
        elif (
            bits == self.valuation
            and self.past_stepped
            and (deadline is None or now < deadline)
            and (past.always_settled or past.settled(bits))
        ):
            # The atoms of the last letter again, before any timed past operator may change
            # with time, and no prev that a step changes: the step would give the same
            # letter and leave the state as it is (Past.settled), so it is not taken. The
            # clock's deadline stays (the past operators' next change is the same) unless
            # ages started again.
            if clock is not None and clock.atoms:
                clock.deadline = clock.next_deadline()
        else:
            bits = past.step(now, bits)
            self.past_stepped = True
            if clock is not None:
                clock.deadline = clock.next_deadline()
        if self.derived is not None:  # what the automaton reads of a wide letter
            bits = self.derived(bits)
        self.valuation = bits
        letters.append(bits)
        stamps.append(stamp)

    def evaluate(self) -> list[Verdict]:
        """Consume every compressed letter; return the verdicts they decided.

        A run of equal letters is taken whole once the automaton stays in one state on
        it (:meth:`_walk_runs`). Where the runs are short (a few letters, as a handler's
        scheduler rounds and lively signals give) a letter at a time costs less
        (:meth:`_walk_each`).
        """
        letters = self.letters
        if not letters or self.halted:
            return []
        if len(letters) == 1 and self.derived is None:  # (a live handler's usual round)
            table = self.monitor.table
            state = table.table[(self.state << table.bits) | letters[0]]
            if state < table.live:  # no verdict: one step, nothing else
                self.state = state
                self.step += 1
                del letters[0]
                del self.stamps[0]
                return []
        if self.monitor.derived is not None:  # a wide letter: the automaton reads its top
            letters = _projected(letters, self.monitor)
        ends = _long_run_ends(letters) if len(letters) >= SHORT_EVALUATION else None
        state, consumed, verdicts = (
            self._walk_each(letters) if ends is None else self._walk_runs(ends, letters)
        )
        self.state = state
        self.step += consumed
        del self.letters[:]
        del self.stamps[:]
        if self.halted:
            self.unspeculate()
            self.events.clear()
        return verdicts

    def _walk_runs(
        self,
        ends: list[int],
        letters: array,  # type: ignore[type-arg]
    ) -> tuple[int, int, list[Verdict]]:
        """The automaton over the letters, run by run (``ends``: one past each run): once
        a step stays in the state it left, every step left in the run ends there, a
        verdict each if it is one. Returns the state, the letters consumed (fewer if it
        halted) and the verdicts."""
        table = self.monitor.table
        rows, bits, live = table.table, table.bits, table.live
        halt = self.monitor.spec.on_verdict == "halt"
        verdicts: list[Verdict] = []
        state, start = self.state, 0
        for end in ends:
            letter, i = letters[start], start
            while i < end:
                new = rows[(state << bits) | letter]
                stays = new == state
                state = new
                if state >= live:
                    last = end if stays and not halt else i + 1
                    verdicts += self._verdicts(state == live, i, last)
                    if halt:
                        self.halted = True
                        return state, i + 1, verdicts
                i = end if stays else i + 1
            start = end
        return state, len(letters), verdicts

    def _walk_each(self, letters: array) -> tuple[int, int, list[Verdict]]:  # type: ignore[type-arg]
        """:meth:`_walk_runs`, a letter at a time."""
        table = self.monitor.table
        rows, bits, live = table.table, table.bits, table.live
        halt = self.monitor.spec.on_verdict == "halt"
        verdicts: list[Verdict] = []
        state, step = self.state, self.step + 1
        for i, letter in enumerate(letters):
            state = rows[(state << bits) | letter]
            if state >= live:
                kind: VerdictKind = "violated" if state == live else "satisfied"
                verdicts.append(Verdict(self.name, kind, self.stamps[i], step + i))
                if halt:
                    self.halted = True
                    return state, i + 1, verdicts
        return state, len(self.letters), verdicts

    def _verdicts(self, violated: bool, first: int, end: int) -> list[Verdict]:
        """The verdicts of the letters ``first`` to ``end`` (excluded) of this evaluation."""
        step = self.step + 1
        return list(
            map(
                Verdict,
                repeat(self.name),
                repeat("violated" if violated else "satisfied"),
                self.stamps[first:end],
                range(step + first, step + end),
            )
        )

    # -- the handoff's snapshot (docs/protocol.md): taken at the cut, restored from it --

    def snapshot(self, cut: int, epoch: int) -> Snapshot:
        """H1's side: compress the held events up to the cut, take the state.

        Afterwards it holds only the events after the cut, raw; it must not run
        any more: the monitor belongs to H2 (H1 keeps those events in case it resumes).
        """
        self.cover(cut)
        m = self.monitor
        # what is left to evaluate: the letters as the automaton reads them (a wide
        # letter's top; the values, the valuation and the past's state give the rest)
        letters = self.letters if m.derived is None else _projected(self.letters, m)
        stamps, runs = self.stamps, runs_of(letters)
        return Snapshot(
            monitor=self.name,
            epoch=epoch,
            cut=cut,
            state=self.state,
            step=self.step,
            halted=self.halted,
            values=tuple(None if v is _UNSET else v for v in self.values),
            valuation=self.valuation,
            last_released=self.last_released,
            late_events=self.late_events,
            bits=m.table.bits,
            letters=letters[:] if m.derived is None else letters,
            stamps={i: stamps[i] for i in deciding_steps(self.monitor, self.state, runs)},
            clock=None if self.clock is None else self.clock.snapshot(),
            past=None if self.past is None else self.past.save(),
            runs=runs,
            wide=m.letter_bits if m.derived is not None else 0,
        )

    @classmethod
    def restored(
        cls, monitor: CompiledMonitor, snap: Snapshot, held: list[Event]
    ) -> MonitorRuntime:
        """H2's side: the monitor as H1 left it, then H2's own held events after the cut
        (``held``: a sort buffer, in stamp order)."""
        if snap.monitor != monitor.name:
            raise HandoffError(f"snapshot of '{snap.monitor}' given for '{monitor.name}'")
        table = monitor.table
        wide = monitor.letter_bits if monitor.derived is not None else 0
        if (
            snap.bits != table.bits
            or snap.wide != wide
            or len(snap.values) != len(monitor.signal_names)
        ):
            raise HandoffError(
                f"snapshot of '{snap.monitor}' does not fit this definition "
                "(placeholders or signals differ): the handlers disagree on it"
            )
        if not 0 <= snap.state < table.states:
            raise HandoffError(f"automaton state {snap.state} out of range")
        for name, value in zip(monitor.signal_names, snap.values, strict=True):
            kind = monitor.spec.signals[name].kind
            if value is not None and not _checker(kind)(value):
                raise HandoffError(
                    f"signal '{name}' is {value!r} in the snapshot, not a {kind} value"
                )
        clock_fits = (
            not monitor.clocked
            if snap.clock is None
            else monitor.clocked and len(snap.clock[1]) == len(monitor.signal_names)
        )
        if not clock_fits or (snap.past is None) != (not monitor.past):
            raise HandoffError(
                f"snapshot of '{snap.monitor}' does not fit this definition (timed atoms or "
                "past operators differ): the handlers disagree on it"
            )
        rt = cls(monitor)
        if rt.past is not None:
            try:
                rt.past.load(snap.past)
            except (ValueError, TypeError, KeyError, OverflowError) as exc:  # Overflow: int(inf)
                raise HandoffError(f"snapshot of '{snap.monitor}': {exc}") from None
        if rt.clock is not None and snap.clock is not None:
            rt.clock.restore(*snap.clock)
        rt.state, rt.step, rt.halted = snap.state, snap.step, snap.halted
        rt.values = [_UNSET if v is None else v for v in snap.values]
        rt.missing = sum(v is None for v in snap.values)
        rt.valuation = snap.valuation
        rt.last_released, rt.late_events = snap.last_released, snap.late_events
        if monitor.derived is None:
            rt.letters.extend(snap.letters)
        else:  # the automaton's letters at the top of wide ones (all that is read of them)
            import numpy as np

            top = np.frombuffer(snap.letters, snap.letters.typecode).astype(np.int64)
            rt.letters.frombytes((top << monitor.shift).tobytes())
        base = len(rt.stamps)
        rt.stamps.frombytes(bytes(8 * len(snap.letters)))  # unreported steps need none
        for i, stamp in snap.stamps.items():
            rt.stamps[base + i] = stamp
        # Events up to the cut are H1's, also those H2 has not taken yet (still in its queues)
        rt.floor = snap.cut
        rt.events = held[bisect_right(held, snap.cut, key=_STAMP) :]  # held is in stamp order
        if len(rt.events) >= rt.threshold:
            rt.flush()
        return rt


def _projected(letters: array, monitor: CompiledMonitor) -> array:  # type: ignore[type-arg]
    """Wide letters as the automaton reads them: their placeholders from ``shift`` on
    (edgerv.core.language.past.Derived), in the table's letter type."""
    import numpy as np  # here: only a monitor with wide letters needs it

    wide = np.frombuffer(letters, dtype=letters.typecode) if len(letters) else np.zeros(0, "q")
    out = array(letter_typecode(monitor.table.bits))
    out.frombytes((wide >> monitor.shift).astype(out.typecode).tobytes())
    return out


def _long_run_ends(letters: array) -> list[int] | None:  # type: ignore[type-arg]
    """Where each run of equal letters ends (one past it), if the runs are at least
    MIN_MEAN_RUN long on average; else None."""
    import numpy as np  # here: only long evaluations (a check's) need it

    codes = np.frombuffer(letters, dtype=letters.typecode)  # a view: let go on return
    changes = np.flatnonzero(codes[1:] != codes[:-1])
    if (len(changes) + 1) * MIN_MEAN_RUN > len(codes):
        return None
    return [*(changes + 1).tolist(), len(codes)]


class ValueTypeError(Exception):
    """A message field whose value does not fit the signal's declared kind."""


def _checker(kind: ValueKind) -> Callable[[Any], bool]:
    if kind == "bool":
        return lambda v: isinstance(v, bool)
    if kind == "string":
        return lambda v: isinstance(v, str)
    if kind == "int":
        return lambda v: isinstance(v, int) and not isinstance(v, bool)
    return lambda v: isinstance(v, int | float) and not isinstance(v, bool)


@dataclass
class TopicRoute:
    """Everything that reads one topic: its distinct fields and the monitors' bindings.

    ``qos`` is that of the first signal that named the topic (one subscription per topic).
    """

    topic: str
    msg_type: str
    qos: QosSpec = field(default_factory=QosSpec)
    fields: list[str] = field(default_factory=list)
    kinds: list[ValueKind] = field(default_factory=list)
    getters: list[Callable[[Any], Any]] = field(default_factory=list)
    checks: list[Callable[[Any], bool]] = field(default_factory=list)
    plain: list[Callable[[Any], Any]] = field(default_factory=list)  # for parsed JSON only
    # the fields read through an optional (ABSENT where it is empty): their indexes
    held: set[int] = field(default_factory=set)
    # the distinct bindings, each ((signal index, field index), ...): the monitors that
    # share one get one event tuple per message
    bindings: list[tuple[tuple[int, int], ...]] = field(default_factory=list)
    readers: list[tuple[MonitorRuntime, int]] = field(default_factory=list)  # (rt, binding)
    # each reader's plan when it is plain and takes its events as they come (else None),
    # over the topic's distinct atoms: Router.offer_values's step of such a monitor
    plans: list[PlainPlan | None] = field(default_factory=list)
    atoms: TopicAtoms = field(default_factory=TopicAtoms)

    def add_reader(self, runtime: MonitorRuntime, binding: int) -> None:
        self.readers.append((runtime, binding))
        plain = runtime.plain and runtime.threshold == 1
        pairs = self.bindings[binding]
        self.plans.append(plain_plan(self.atoms, runtime.monitor, pairs) if plain else None)

    def keep_readers(self, keep: Callable[[MonitorRuntime], bool]) -> None:
        """Only the readers ``keep`` keeps, their atoms made anew (none of the others')."""
        readers, self.readers, self.plans = self.readers, [], []
        self.atoms = TopicAtoms()
        for runtime, binding in readers:
            if keep(runtime):
                self.add_reader(runtime, binding)

    def field_index(self, path: str, kind: ValueKind) -> int:
        if path not in self.fields:
            optional = optional_steps(self.msg_type, path)
            check = _checker(kind)
            if optional:
                self.held.add(len(self.fields))
                check = _or_absent(check)
            self.fields.append(path)
            self.kinds.append(kind)
            self.getters.append(make_getter(path, optional))
            self.checks.append(check)
            self.plain.append(_plain_getter(path, optional))
        return self.fields.index(path)

    def extract_all(self, msgs: Sequence[Any], parsed_json: bool) -> list[list[Any]] | None:
        """Each field's values in these messages (one list per field), or None if one of
        them lacks a field or holds a value of another kind: :meth:`extract` then says
        which, message by message. ``parsed_json``: the messages are what json.loads
        gives (dicts, lists, strings, numbers), read with plain indexing."""
        out = []
        getters = self.plain if parsed_json else self.getters
        for get, ok in zip(getters, self.checks, strict=True):
            try:
                values = list(map(get, msgs))
            except Exception:  # extract raises it again, at its message
                return None
            for kind in set(map(type, values)):  # ok depends on the type alone
                if not ok(next(v for v in values if type(v) is kind)):
                    return None
            out.append(values)
        return out

    def extract(self, msg: Any) -> list[Any]:
        """The value of each field; raises LookupError/AttributeError/ValueTypeError."""
        out = []
        for path, get, ok, kind in zip(
            self.fields, self.getters, self.checks, self.kinds, strict=True
        ):
            value = get(msg)
            if not ok(value):
                raise ValueTypeError(f"field '{path}' is {value!r}, not a {kind} value")
            out.append(value)
        return out


class Router:
    """Routes each message to the monitors that read its topic (one extraction per field)."""

    def __init__(self, runtimes: Iterable[MonitorRuntime] = ()) -> None:
        self.routes: dict[str, TopicRoute] = {}
        self.runtimes: dict[str, MonitorRuntime] = {}
        self.seq = 0
        # inside :meth:`removing`: the runtimes removed, their routes not yet rebuilt
        self._removed: list[MonitorRuntime] | None = None
        for rt in runtimes:
            self.add(rt)

    def add(self, runtime: MonitorRuntime) -> None:
        spec = runtime.monitor.spec
        self.runtimes[spec.name] = runtime
        bindings: dict[str, list[tuple[int, int]]] = {}
        for i, name in enumerate(runtime.monitor.signal_names):
            sig = spec.signals[name]
            route = self.routes.setdefault(sig.topic, TopicRoute(sig.topic, sig.msg_type, sig.qos))
            bindings.setdefault(sig.topic, []).append((i, route.field_index(sig.field, sig.kind)))
        for topic, pairs in bindings.items():
            route, key = self.routes[topic], tuple(pairs)
            if key not in route.bindings:
                route.bindings.append(key)
            route.add_reader(runtime, route.bindings.index(key))

    def remove(self, name: str) -> MonitorRuntime | None:
        return self.remove_many([name]).get(name)

    def remove_many(self, names: Iterable[str]) -> dict[str, MonitorRuntime]:
        """Stop routing to these monitors (one pass over each of their topics; inside
        :meth:`removing`, one pass when it ends)."""
        gone = {n: rt for n in names if (rt := self.runtimes.pop(n, None)) is not None}
        if self._removed is not None:
            self._removed += gone.values()
        else:
            self._unroute(gone.values())
        return gone

    @contextmanager
    def removing(self) -> Iterator[None]:
        """Removals inside are routed away from at once when it ends: a topic's readers
        and atoms are made anew once, not once a monitor (a handoff's commit of 450
        monitors took 308 ms one at a time, 1.3 ms at once). Until then a removed
        runtime still gets its topics' messages: use it under the lock that keeps
        messages out (the engine's)."""
        if self._removed is not None:  # nested: the outer one does it
            yield
            return
        self._removed = []
        try:
            yield
        finally:
            removed, self._removed = self._removed, None
            self._unroute(removed)

    def _unroute(self, removed: Collection[MonitorRuntime]) -> None:
        ids = {id(rt) for rt in removed}
        if not ids:
            return
        topics = {t for rt in removed for t in rt.monitor.spec.topics}
        for topic in topics & self.routes.keys():
            route = self.routes[topic]
            route.keep_readers(lambda rt: id(rt) not in ids)
            if not route.readers:
                del self.routes[topic]

    def dispatch(self, topic: str, stamp: int, msg: Any) -> list[MonitorRuntime]:
        """Offer one message to its monitors; return those with letters to evaluate."""
        route = self.routes.get(topic)
        if route is None:
            return []
        return self.offer_values(route, stamp, route.extract(msg))

    def offer_values(
        self,
        route: TopicRoute,
        stamp: int,
        values: Sequence[Any],
        admit: Callable[[MonitorRuntime], bool] | None = None,
        buffered: list[MonitorRuntime] | None = None,
    ) -> list[MonitorRuntime]:
        """Offer a message's field values (in ``route.fields`` order) to the route's monitors
        (those ``admit`` accepts); return the monitors with letters to evaluate. A field the
        message has no value for (ABSENT: inside an empty optional) is left out of the
        event's updates.

        A plain monitor (:attr:`MonitorRuntime.plain`) taking its events as they come,
        with nothing buffered, takes the event without ``admit`` (its buffer is empty;
        counted in :attr:`MonitorRuntime.taken`), its letter made from the topic's atoms
        computed once (:mod:`edgerv.core.plain_step`), and walks it at once when it
        reaches no verdict (what :meth:`MonitorRuntime.evaluate` would do, one step): it
        is then not returned. The monitors that took the event into a buffer without a
        letter to evaluate (a sort buffer, a signal without a value yet) are appended to
        ``buffered``."""
        self.seq += 1
        seq, bindings, held = self.seq, route.bindings, route.held
        events: list[Event | None] = [None] * len(bindings)  # built on first use
        ready = []
        truths: list[Any] | None = None  # the topic's atoms on this message, on first use
        for (runtime, b), plan in zip(route.readers, route.plans, strict=True):
            if plan is not None and not runtime.holding and not runtime.halted:  # it walks
                if runtime.letters:
                    runtime.walk_quiet()  # (a verdict's letter waits first: it stops at once)
                if (
                    not runtime.letters
                    and not runtime.events
                    and not runtime.missing
                    and stamp > runtime.floor
                ):
                    # The common step, inlined (what offer_event, _compress_one and
                    # evaluate do for a plain monitor taking its events as they come,
                    # every signal valued, nothing waiting): its letter from the topic's
                    # atoms computed once and its own, walked at once unless it reaches a
                    # verdict. Its buffer is empty: the event is taken (counted here, as
                    # the handler's admission would).
                    runtime.taken += 1
                    last = runtime.last_released
                    if last is not None and stamp < last:
                        runtime.late_events += 1
                    runtime.last_released = stamp
                    values_ = runtime.values
                    for sig, f in plan.updates:
                        values_[sig] = values[f]
                    bits = runtime.valuation & plan.keep
                    if plan.shared:
                        if truths is None:
                            truths = route.atoms.truths(values)
                        for k, bit in plan.shared:
                            if truths[k]:
                                bits |= bit
                    if plan.own:
                        funcs = runtime.atom_funcs
                        for atom in plan.own:
                            if funcs[atom](values_):
                                bits |= 1 << atom
                    runtime.valuation = bits
                    state = runtime.rows[(runtime.state << runtime.table_bits) | bits]
                    if state < runtime.live:
                        runtime.state = state
                        runtime.step += 1
                    else:  # a verdict: evaluated with the others
                        runtime.letters.append(bits)
                        runtime.stamps.append(stamp)
                        ready.append(runtime)
                    continue
            if admit is not None and not admit(runtime):
                continue
            event = events[b]
            if event is None:
                updates = [(s, values[f]) for s, f in bindings[b]]
                if held:
                    updates = [u for u in updates if u[1] is not ABSENT]
                event = events[b] = (stamp, seq, tuple(updates))
            if runtime.offer_event(event):  # (a plain one's letters walked: what is left)
                ready.append(runtime)
            elif buffered is not None:
                buffered.append(runtime)
        return ready


def _or_absent(check: Callable[[Any], bool]) -> Callable[[Any], bool]:
    return lambda v: v is ABSENT or check(v)


def _plain_getter(path: str, optional: frozenset[int] = frozenset()) -> Callable[[Any], Any]:
    """``path`` read with plain indexing: what the message's getter does on parsed JSON,
    where every message is a dict and no value has ``item`` (a NumPy scalar's); on
    anything else it raises, and the getter itself reads it. ABSENT where an index of
    ``optional`` goes into an empty list."""
    keys = path_keys(path)
    if optional:
        held: Callable[[Any], Any] = make_getter(path, optional)
        return held
    if len(keys) == 1:
        return itemgetter(keys[0])

    def get(msg: Any) -> Any:
        for key in keys:
            msg = msg[key]
        return msg

    return get


def header_stamp(msg: Any) -> int | None:
    """``header.stamp`` in nanoseconds when the message has a header that was stamped.

    None without a header, and for a zero stamp: ROS publishers leave a header they do
    not stamp at zero, and then the publication time is the better timestamp.
    """
    try:
        header = msg["header"] if isinstance(msg, dict) else msg.header
        stamp = header["stamp"] if isinstance(header, dict) else header.stamp
        if isinstance(stamp, dict):
            ns = int(stamp["sec"]) * 1_000_000_000 + int(stamp["nanosec"])
        else:
            ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
        return ns or None
    except (KeyError, AttributeError, TypeError, ValueError, OverflowError):  # inf: Overflow
        return None
