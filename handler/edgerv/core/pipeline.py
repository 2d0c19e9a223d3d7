"""The event pipeline of the paper's Fig. 2, shared by ``edgerv check`` and the live handler.

callback -> :meth:`MonitorRuntime.offer` puts ``(timestamp, values)`` in the event
buffer -> once it holds ``sortThreshold`` events it is sorted by timestamp (ties
keep arrival order) -> each event updates the signal values and the placeholders
are evaluated and bit-packed into one letter per event, without its timestamp
(the timestamps are kept beside, only to report when a verdict was decided) ->
:meth:`MonitorRuntime.evaluate` consumes the letters through the transition table.

:class:`Router` is the "one subscription per topic" part: it reads each field
once per message and hands every monitor that reads the topic its updates.
"""

from __future__ import annotations

from array import array
from bisect import bisect_left
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from itertools import chain
from operator import itemgetter
from typing import Any, Literal

import numpy as np

from edgerv.core.documents import QosSpec
from edgerv.core.monitor import CompiledMonitor
from edgerv.core.msgtypes import ValueKind, make_getter

VerdictKind = Literal["violated", "satisfied"]
MonitorState = Literal["pending", "violated", "satisfied", "halted"]
Update = tuple[int, Any]  # (signal index in the monitor, new value)
_UNSET = object()
_STAMP = itemgetter(0)
_UPDATES = itemgetter(2)
_VALUE = itemgetter(1)
_LETTER_DTYPE: dict[str, Any] = {"B": np.uint8, "H": np.uint16, "L": np.dtype("L")}  # typecode
COLUMNS_FROM = 48  # batches this long are compressed column-wise (NumPy), shorter one by one


@dataclass(frozen=True)
class Verdict:
    monitor: str
    verdict: VerdictKind
    stamp: int  # nanoseconds: the timestamp of the event whose letter decided it
    step: int  # 1-based letter index since the monitor started, never reset

    def as_dict(self) -> dict[str, Any]:
        return {"verdict": self.verdict, "stamp": self.stamp, "step": self.step}


def letter_typecode(bits: int) -> str:
    """The narrowest array type holding ``bits`` placeholder bits per letter."""
    return "B" if bits <= 8 else "H" if bits <= 16 else "L"


@dataclass
class MonitorRuntime:
    """One monitor's buffers and state. Not thread-safe: one thread drives it."""

    monitor: CompiledMonitor
    name: str = field(init=False)
    threshold: int = field(init=False)  # sortThreshold
    events: list[tuple[int, int, Sequence[Update]]] = field(default_factory=list)
    letters: array = field(init=False)  # type: ignore[type-arg]
    stamps: array = field(init=False)  # type: ignore[type-arg]
    values: list[Any] = field(init=False)
    missing: int = field(init=False)  # signals without a value yet
    valuation: int = 0  # the placeholder bits after the last compressed event
    state: int = 0  # the automaton state: the one integer a migration moves
    step: int = 0  # letters evaluated so far
    halted: bool = False
    holding: bool = False  # during a handoff: buffer raw events, neither sort nor compress
    floor: int = -(2**63)  # events stamped at or below it were evaluated elsewhere: ignore
    late_events: int = 0  # events released after a newer one (beyond the sort window)
    last_released: int | None = None
    # Compressing ahead: while the events of the sort buffer arrive in stamp order (the
    # common case), each is compressed on arrival into ahead_letters, so that the sort
    # at sortThreshold has nothing left to do. ``ahead`` events (the first of ``events``)
    # are compressed so; ``base`` is the signal state from before the first of them, to
    # start again from when one arrives out of order.
    ahead: int = 0
    speculate: bool = True  # off only to test that it changes nothing
    ahead_letters: array = field(init=False)  # type: ignore[type-arg]
    ahead_stamps: array = field(init=False)  # type: ignore[type-arg]
    base: tuple[list[Any], int, int] = field(init=False)

    def __post_init__(self) -> None:
        spec = self.monitor.spec
        self.name = spec.name
        self.threshold = spec.sort_threshold
        self.letters = array(letter_typecode(self.monitor.table.bits))
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

    @property
    def buffered(self) -> int:
        """Events held in the event buffer plus letters not yet evaluated."""
        return len(self.events) + len(self.letters)

    @property
    def status(self) -> MonitorState:
        if self.halted:
            return "halted"
        if self.step and self.state == self.monitor.table.violated:
            return "violated"
        if self.step and self.state == self.monitor.table.satisfied:
            return "satisfied"
        return "pending"

    def offer(self, stamp: int, seq: int, updates: Sequence[Update]) -> bool:
        """Buffer one event; sort and compress the buffer once it holds sortThreshold events.

        Returns True when letters were produced and :meth:`evaluate` has work.
        """
        if self.halted or stamp <= self.floor:
            return False
        if self.holding:
            self.events.append((stamp, seq, updates))
            return False
        if self.threshold == 1:  # nothing to sort: straight to the compressed buffer
            if self.last_released is not None and stamp < self.last_released:
                self.late_events += 1
            self.last_released = stamp
            self._compress_one(stamp, updates, self.letters, self.stamps)
            return not self.missing
        events = self.events
        events.append((stamp, seq, updates))
        ahead = self.ahead
        if ahead == len(events) - 1 and self.speculate:  # every earlier one is compressed
            if not ahead:
                self.base = (list(self.values), self.valuation, self.missing)
                self._compress_one(stamp, updates, self.ahead_letters, self.ahead_stamps)
                self.ahead = 1
            elif stamp >= events[-2][0]:  # in order (a tie keeps arrival order, as the sort)
                self._compress_one(stamp, updates, self.ahead_letters, self.ahead_stamps)
                self.ahead = ahead + 1
            else:
                self.unspeculate()  # out of order: the sort at the threshold does it all
        if len(events) >= self.threshold:
            return self.flush()
        return False

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
        """Sort and compress the ``count`` oldest arrivals of the event buffer."""
        if not self.events or count <= 0:
            return False
        count = min(count, len(self.events))
        if count == len(self.events):
            batch, self.events = self.events, []
        else:
            batch, self.events = self.events[:count], self.events[count:]
        if self.ahead == count:  # all in order and compressed already: the sort is a no-op
            self.letters.extend(self.ahead_letters)
            self.stamps.extend(self.ahead_stamps)
            self.ahead = 0
            del self.ahead_letters[:]
            del self.ahead_stamps[:]
        else:
            self.unspeculate()
            batch.sort(key=_STAMP)  # stable: equal timestamps keep their arrival order
            self._compress(batch)
        last = self.last_released
        if last is not None and batch[0][0] < last:  # rare: count what came too late
            self.late_events += bisect_left(batch, last, key=_STAMP)
        self.last_released = batch[-1][0]
        return len(self.letters) > 0

    def _full_valuation(self) -> int:
        bits = 0
        for i, fn in enumerate(self.monitor.atom_funcs):
            if fn(self.values):
                bits |= 1 << i
        return bits

    def _compress(self, batch: Sequence[tuple[int, int, Sequence[Update]]]) -> None:
        if len(batch) >= COLUMNS_FROM:
            self._compress_columns(batch)
            return
        letters, stamps = self.letters, self.stamps
        for stamp, _seq, updates in batch:
            self._compress_one(stamp, updates, letters, stamps)

    def _compress_columns(self, batch: Sequence[tuple[int, int, Sequence[Update]]]) -> None:
        """What :meth:`_compress_one` does event by event, for a whole sorted batch at once.

        Each signal's value after each event becomes a column (forward-filled from
        its updates); each placeholder is its comparison over the columns; a letter
        is their bits, from the event at which every signal has a value. The
        columns are object arrays: each element is compared as the Python value it
        holds, so the letters are those of the scalar path (tested side by side).
        """
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
        self.valuation = int(letters[-1])
        self.letters.frombytes(letters.astype(_LETTER_DTYPE[self.letters.typecode]).tobytes())
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
        if self.missing:
            for sig, value in updates:
                if values[sig] is _UNSET:
                    self.missing -= 1
                values[sig] = value
            if self.missing:
                return  # no letter until every signal has a value
            bits = self._full_valuation()
        else:  # only the placeholders that read the updated signals change
            funcs, readers = self.monitor.atom_funcs, self.monitor.atoms_of_signal
            bits = self.valuation
            for sig, value in updates:
                values[sig] = value
                for atom in readers[sig]:
                    if funcs[atom](values):
                        bits |= 1 << atom
                    else:
                        bits &= ~(1 << atom)
        self.valuation = bits
        letters.append(bits)
        stamps.append(stamp)

    def evaluate(self) -> list[Verdict]:
        """Consume every compressed letter; return the verdicts they decided."""
        letters = self.letters
        if not letters or self.halted:
            return []
        table = self.monitor.table
        rows, bits, live = table.table, table.bits, table.live
        halt = self.monitor.spec.on_verdict == "halt"
        verdicts: list[Verdict] = []
        state = self.state
        consumed = len(letters)
        for i, letter in enumerate(letters):
            state = rows[(state << bits) | letter]
            if state >= live:
                kind: VerdictKind = "violated" if state == live else "satisfied"
                verdicts.append(Verdict(self.name, kind, self.stamps[i], self.step + i + 1))
                if halt:
                    self.halted = True
                    consumed = i + 1
                    break
        self.state = state
        self.step += consumed
        del letters[:]
        del self.stamps[:]
        if self.halted:
            self.unspeculate()
            self.events.clear()
        return verdicts


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
    # (runtime, [(signal index, field index)])
    readers: list[tuple[MonitorRuntime, list[tuple[int, int]]]] = field(default_factory=list)

    def field_index(self, path: str, kind: ValueKind) -> int:
        if path not in self.fields:
            self.fields.append(path)
            self.kinds.append(kind)
            self.getters.append(make_getter(path))
            self.checks.append(_checker(kind))
        return self.fields.index(path)

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
            self.routes[topic].readers.append((runtime, pairs))

    def remove(self, name: str) -> MonitorRuntime | None:
        runtime = self.runtimes.pop(name, None)
        if runtime is None:
            return None
        for topic in list(self.routes):
            route = self.routes[topic]
            route.readers = [(rt, b) for rt, b in route.readers if rt is not runtime]
            if not route.readers:
                del self.routes[topic]
        return runtime

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
    ) -> list[MonitorRuntime]:
        """Offer a message's field values (in ``route.fields`` order) to the route's monitors
        (those ``admit`` accepts); return the monitors with letters to evaluate."""
        self.seq += 1
        ready = []
        for runtime, pairs in route.readers:
            if admit is not None and not admit(runtime):
                continue
            if runtime.offer(stamp, self.seq, [(sig, values[f]) for sig, f in pairs]):
                ready.append(runtime)
        return ready


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
    except (KeyError, AttributeError, TypeError, ValueError):
        return None
