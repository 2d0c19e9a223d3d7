"""The live handler's long batches for monitors whose placeholders time alone changes
(timed past operators, time-bounded operators read late, ages), against the same messages
ingested one at a time, with buffers small enough to fill.

:meth:`Engine.ingest` hands such a monitor its messages of a long batch as arrays, and
:meth:`MonitorRuntime.take_arrivals` makes their letters a run of equal letters at a
time, clock steps included, testing the buffer's capacity (events plus letters) where it
makes them: an event is taken while the buffer holds fewer than ``bufferCapacity``, as the
engine's admission does one message at a time, and dropped otherwise. Held here against
the engine fed one message at a time: after each batch the same letters and stamps not
yet evaluated, signal values, time, clock deadline, past operators' state, counts of
events taken and dropped; the same verdicts; the same snapshot at a handoff's cut, and
the same handoffs between two engines.
"""

from __future__ import annotations

import logging
import random
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

import pytest

from edgerv.core.diagnostics import InputError
from edgerv.core.handoff import decode_frames, encode
from edgerv.core.monitor import CompiledMonitor
from edgerv.core.pipeline import MonitorRuntime
from edgerv.handler import engine as engine_module
from edgerv.handler.engine import Engine
from kit.counts import scaled
from kit.documents import compiled
from kit.randomruns import SIGNALS, random_assertion, random_events, random_run
from kit.sidebyside import Collect, messages, state_of

MS = 1_000_000
ATOMS = ["a", "b", "!a", "x < 2", "x >= y", "z == 3", "age(a) < 15ms", "age(x) >= 7ms"]
Message = tuple[int, str, list[Any]]


def random_nested(rng: random.Random, depth: int) -> str:
    """Time-bounded F, G, U, W, R, M and timed once, historically, since, nested at
    random in boolean combinations (read late: derived placeholders that time changes)."""
    if depth == 0 or rng.random() < 0.2:
        return rng.choice(ATOMS)
    kind = rng.choice(["!", "&", "|", "F", "G", "U", "W", "R", "M", "once", "historically",
                       "since", "F", "G", "once"])  # fmt: skip
    x = random_nested(rng, depth - 1)
    if kind == "!":
        return f"!({x})"
    if kind in "&|":
        return f"({x}) {kind} ({random_nested(rng, depth - 1)})"
    lo = rng.choice([0, 0, 2, 5])
    hi = lo + rng.choice([3, 10, 20])
    bound = f"[{lo}ms..{hi}ms]"
    if kind in ("U", "W", "R", "M", "since"):
        return f"({x}) {kind}{bound} ({random_nested(rng, depth - 1)})"
    return f"{kind}{bound} ({x})"


def random_monitor(rng: random.Random, name: str) -> CompiledMonitor:
    """A monitor of timed past operators (nested, with untimed ones and prev, in the
    shapes of kit.randomruns) or of nested time-bounded operators, under always or at the
    top; a sort window now and then, a buffer small enough to fill now and then."""
    threshold = rng.choice([1, 1, 1, 1, 2, 3, 7])
    capacity = rng.choice([4096, rng.randint(max(threshold, 2), 30), rng.randint(30, 200)])
    while True:
        if rng.random() < 0.5:
            text = random_assertion(rng)
        else:
            body = random_nested(rng, rng.randint(1, 3))
            text = rng.choice(["always ({f})", "always (a -> ({f}))", "{f}"]).format(f=body)
        try:
            return compiled(
                text,
                SIGNALS,
                name=name,
                sortThreshold=threshold,
                bufferCapacity=capacity,
                onVerdict="halt" if rng.random() < 0.2 else "reset",
            )
        except InputError:  # past the placeholders' limit: another one
            continue


def engine_with(monitors: Sequence[CompiledMonitor]) -> tuple[Engine, Collect]:
    sink = Collect()
    # released by count, at the clock advanced by hand and at the end (no tick here)
    e = Engine("edge", [sink], flush_after=0.0)
    for m in monitors:
        e.put(m, active=True)
    return e, sink


def observe(e: Engine) -> list[Any]:
    """Everything a batch leaves in each monitor: its letters and stamps not evaluated
    yet, its sort buffer, state (values, time, deadline, past operators), counts."""
    out: list[Any] = []
    for slot in e.slots.values():
        rt = slot.runtime
        if rt is None:
            out.append((slot.name, None))
            continue
        out.append((slot.name, state_of(rt), rt.late_events, slot.events, slot.dropped))
        out.append((slot.pending_since, slot.name in e.waiting))
        out.append((list(rt.letters), list(rt.stamps), repr([(s, u) for s, _, u in rt.events])))
    return out


def ros_values(msgs: list[Message]) -> list[Message]:
    """The values as the ROS layer reads them: a Float64's data is a float (random_events
    writes some as ints, which NumPy's float columns, rightly, make floats)."""
    return [
        (stamp, topic, [float(v) if type(v) is int else v for v in values])
        for stamp, topic, values in msgs
    ]


def batched(e: Engine, part: list[Message], now: float) -> None:
    assert e.ingest(part, now=now)


def each(e: Engine, part: list[Message], now: float) -> None:
    for message in part:
        assert e.ingest([message], now=now)


Feed = Callable[[Engine, list[Message], float], None]


def spy_takes(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, int, int]]:
    """Each take_arrivals call: the monitor, its events offered and taken."""
    calls: list[tuple[str, int, int]] = []
    real = MonitorRuntime.take_arrivals

    def spy(rt: MonitorRuntime, arrivals: Any, capacity: int | None = None) -> Any:
        got = real(rt, arrivals, capacity)
        calls.append((rt.name, len(arrivals.stamps), got[0]))
        return got

    monkeypatch.setattr(MonitorRuntime, "take_arrivals", spy)
    return calls


@pytest.mark.parametrize("seed", range(scaled(60)))  # make fuzz: more
def test_timed_batches_give_what_one_message_at_a_time_gives(
    seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """One to three random monitors (timed past operators, nested time-bounded operators,
    ages, prev, sort windows, halting, buffers of 2 to 200), random runs with ties, late
    messages and gaps the clock steps through, in batches of random sizes; after some the
    clock advanced, after some the letters evaluated (else they wait, and the buffer
    fills across batches). At the end a drain, or a handoff's snapshot at a cut."""
    rng = random.Random(seed)
    monitors = [random_monitor(rng, f"m{i}") for i in range(rng.randint(1, 3))]
    if rng.random() < 0.5:
        events = random_run(rng, rng.randint(1, 700), late=0.0 if seed % 2 else 0.03)
    else:
        events = random_events(rng, rng.randint(1, 700))
    msgs = ros_values(messages(events))
    sizes = [rng.choice([1, 3, 15, 32, 40, 64, 200, 700]) for _ in range(700)]
    calls = spy_takes(monkeypatch)
    one, one_sink = engine_with(monitors)
    many, many_sink = engine_with(monitors)
    fed, long_batches = 0, False
    for i, size in enumerate(sizes):
        part = msgs[fed : fed + size]
        if not part:
            break
        batched(many, part, float(i))  # (the monotonic now: when a buffer waits from)
        each(one, part, float(i))
        fed += len(part)
        on_one = max(Counter(topic for _, topic, _ in part).values())
        long_batches = long_batches or on_one >= engine_module.COLUMNS_FROM
        if rng.random() < 0.3:  # time passes: clock steps up to a moment between stamps
            until = part[-1][0] + rng.choice([-5 * MS, 0, 3 * MS, 30 * MS])
            many.advance_clocks(until)
            one.advance_clocks(until)
        assert observe(many) == observe(one), (fed, [m.spec.assertion for m in monitors])
        if rng.random() < 0.6:
            many.emit(many.evaluate())
            one.emit(one.evaluate())
        assert many_sink.verdicts == one_sink.verdicts, fed
    assert many.messages == one.messages and many.newest == one.newest
    if rng.random() < 0.5:
        many.drain()
        one.drain()
        assert observe(many) == observe(one)
    else:  # the handoff's snapshot (docs/protocol.md): what H1 sends H2, byte for byte
        cut = max(m[0] for m in msgs) + rng.choice([-10 * MS, 0, 50 * MS])
        for name in many.slots:
            rts = [e.slots[name].runtime for e in (many, one)]
            snaps = [rt.snapshot(cut, 1) for rt in rts if rt is not None]
            assert encode(snaps[0]) == encode(snaps[1]), name
    assert many_sink.verdicts == one_sink.verdicts
    # the batches with a topic of COLUMNS_FROM messages went to take_arrivals whole
    assert bool(calls) == long_batches, (calls, long_batches)


def test_a_run_of_equal_letters_is_cut_where_the_buffer_fills(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A timed window over long stretches of equal messages, into a buffer of 50: the
    batch is taken a run at a time (few events compressed one by one), the run that fills
    the buffer is cut there and the rest of the batch dropped, counted as one at a time
    counts them; the next batch finds it full and drops all; evaluated, it takes again."""
    m = compiled(
        "always (a -> historically[0..20ms] (x < 2))",
        {"a": {"topic": "/a", "type": "std_msgs/msg/Bool", "initial": False}, "x": "float"},
        bufferCapacity=50,
    )
    msgs: list[Message] = []
    for i in range(400):
        x = 1.0 if (i // 60) % 2 == 0 else 3.0  # stretches of 60 equal messages
        msgs.append((i * MS, "/x", [x]) if i % 25 else (i * MS, "/a", [i % 50 == 0]))
    one, one_sink = engine_with([m])
    many, many_sink = engine_with([m])
    counted = 0
    compress_one = MonitorRuntime._compress_one

    def counting(rt: MonitorRuntime, *args: Any) -> None:
        nonlocal counted
        counted += 1
        compress_one(rt, *args)

    for lo, hi, evaluate in [(0, 100, False), (100, 200, True), (200, 400, True)]:
        each(one, msgs[lo:hi], 0.0)
        monkeypatch.setattr(MonitorRuntime, "_compress_one", counting)
        batched(many, msgs[lo:hi], 0.0)
        monkeypatch.setattr(MonitorRuntime, "_compress_one", compress_one)
        assert observe(many) == observe(one)
        if evaluate:
            many.emit(many.evaluate())
            one.emit(one.evaluate())
    slot = many.slots["m"]
    assert slot.dropped == one.slots["m"].dropped > 100
    assert counted < slot.events / 4
    assert many_sink.verdicts == one_sink.verdicts


def test_clock_steps_that_fill_the_buffer_drop_the_message_after_them() -> None:
    """Gaps long enough for a timed window to step by the clock several times between two
    messages: the message after the clock steps that fill the buffer is dropped, as one
    at a time (the capacity counts clock steps, tested before each message's own)."""
    m = compiled(
        "always (once[0..2ms] a | once[3ms..5ms] a | historically[1ms..4ms] !a)",
        {"a": "bool"},
        bufferCapacity=40,
    )
    rng = random.Random(4)
    msgs: list[Message] = []
    stamp = 0
    for _ in range(120):
        stamp += rng.choice([1, MS // 2, 3 * MS, 9 * MS])
        msgs.append((stamp, "/a", [rng.random() < 0.5]))
    for size in (40, 64, 120):
        one, one_sink = engine_with([m])
        many, many_sink = engine_with([m])
        for lo in range(0, len(msgs), size):
            each(one, msgs[lo : lo + size], 0.0)
            batched(many, msgs[lo : lo + size], 0.0)
            assert observe(many) == observe(one), (size, lo)
            rt = many.slots["m"].runtime
            assert rt is not None
            assert len(rt.letters) > len(msgs[lo : lo + size]) or many.slots["m"].dropped
            many.emit(many.evaluate())
            one.emit(one.evaluate())
        assert many.slots["m"].dropped == one.slots["m"].dropped > 0
        assert many_sink.verdicts == one_sink.verdicts


def test_drops_are_counted_and_logged_as_one_at_a_time(caplog: pytest.LogCaptureFixture) -> None:
    """The warnings at the 1st, 10th, 100th, 1000th and every 10,000th dropped event, for
    drops counted a batch at a time."""
    rng = random.Random(1)
    engine = Engine("edge")
    for i in range(200):
        start, count = rng.choice([0, 5, 99, 998, 9_990, 19_999, 123_456]), rng.randint(1, 25_000)
        got, want = _Slot(start), _Slot(start)
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="edgerv.handler"):
            engine._dropped(got, count)  # type: ignore[arg-type]
        assert engine.alarms == i + 1  # (a drop may change a status's level: health.py)
        logged = [r.getMessage() for r in caplog.records]
        expected = []
        for _ in range(count):
            want.dropped += 1
            d = want.dropped
            if d in (1, 10, 100, 1000) or d % 10000 == 0:
                expected.append(f"monitor m: buffer full (7 events), {d} events dropped")
        assert (got.dropped, logged) == (want.dropped, expected)


class _Slot:
    name, capacity = "m", 7

    def __init__(self, dropped: int) -> None:
        self.dropped = dropped


def _pair(monitor: CompiledMonitor) -> tuple[list[Engine], list[Collect]]:
    sinks = [Collect(), Collect()]
    engines = [Engine(f"h{i}", [sinks[i]], flush_after=1e9) for i in (0, 1)]
    engines[0].put(monitor, active=True)
    engines[1].put(monitor, active=False)
    return engines, sinks


@pytest.mark.parametrize("seed", range(scaled(15)))  # make fuzz: more
def test_handoffs_of_timed_monitors_in_long_batches(seed: int) -> None:
    """Two handlers handing a random timed monitor back and forth (the sender holding its
    events, the receiver holding its own, both in the per-event way with the capacity
    tested), fed long batches, against the same handoffs fed a message at a time: the
    same snapshots at each release, the same state after each batch, the same verdicts."""
    rng = random.Random(seed)
    monitor = random_monitor(rng, "m")
    msgs = messages(random_run(rng, rng.randint(200, 900), late=0.0))
    sizes = [rng.choice([1, 15, 32, 64, 150]) for _ in range(900)]
    worlds = [_pair(monitor), _pair(monitor)]
    feeds: list[Feed] = [batched, each]
    owner, epoch, phase, cut, fed, moves = 0, 0, None, None, 0, 0
    for i, size in enumerate(sizes):
        part = msgs[fed : fed + size]
        if not part:
            break
        fed += len(part)
        now = float(i)
        if phase is None and i > 1 and rng.random() < 0.4:
            epoch += 1
            phase = "started"
            for engines, _ in worlds:
                engines[owner].handoffs.hold("m", epoch, now=now)
                engines[1 - owner].handoffs.receive("m", epoch)
        cuts, snaps = [], []
        for (engines, _), feed in zip(worlds, feeds, strict=True):
            src, dst = engines[owner], engines[1 - owner]
            feed(src, part, now)
            if phase is not None:
                feed(dst, part, now)
                cuts.append(dst.handoffs.cut("m", epoch) if cut is None else cut)
                if cuts[-1] is not None:
                    snaps.append(src.handoffs.release("m", epoch, cuts[-1], grace=1e9, now=now))
        assert len(set(cuts)) <= 1, cuts
        cut = cuts[0] if cuts else None
        if snaps:
            a, b = snaps
            assert (a is None) == (b is None)
            if a is not None and b is not None:
                assert encode(a) == encode(b)
                for (engines, _), snap in zip(worlds, (a, b), strict=True):
                    (data,) = decode_frames([encode(snap)])  # as the wire gives it
                    engines[1 - owner].handoffs.adopt("m", epoch, data)
                    assert engines[owner].handoffs.commit("m", epoch) == "committed"
                owner, phase, cut, moves = 1 - owner, None, None, moves + 1
        for engines, _ in worlds:
            for e in engines:
                e.emit(e.evaluate())
        assert [observe(e) for e in worlds[0][0]] == [observe(e) for e in worlds[1][0]], i
    if phase is not None:
        for engines, _ in worlds:
            engines[owner].handoffs.abort("m", epoch)
            engines[1 - owner].handoffs.abort("m", epoch)
    for engines, _ in worlds:
        for e in engines:
            e.drain()
    assert [observe(e) for e in worlds[0][0]] == [observe(e) for e in worlds[1][0]]
    assert [s.verdicts for s in worlds[0][1]] == [s.verdicts for s in worlds[1][1]]
    assert moves or epoch <= 1  # (it moved, unless the one handoff never reached its cut)


@pytest.mark.parametrize("threshold", [1, 3])
@pytest.mark.parametrize(
    "assertion",
    [
        "always (age(x) < 7ms & (a -> x < 2))",  # ages alone: columns.compress
        "always (a -> historically[0..5ms] (x < 2))",  # a timed past operator
        "always (a -> F[0..3ms] (x < 2 & G[0..2ms] !a))",  # nested, read late
        "always (a -> x < 2)",  # untimed
    ],
)
def test_every_capacity_around_what_a_batch_makes(assertion: str, threshold: int) -> None:
    """Every capacity from the sort window's to a little more than two batches make
    (events, letters and clock steps): each boundary, where the last message of a batch
    just fits or just does not, and the next batch finding the buffer full or not."""
    rng = random.Random(assertion)
    msgs: list[Message] = []
    stamp, x = 0, 1.0
    for _ in range(120):
        stamp += rng.choice([1, MS, MS, 3 * MS, 8 * MS])
        if rng.random() < 0.3:
            x = rng.choice([1.0, 3.0])
        a = rng.random() < 0.5
        msgs.append((stamp, "/x", [x]) if rng.random() < 0.8 else (stamp, "/a", [a]))
    signals = {
        "a": {"topic": "/a", "type": "std_msgs/msg/Bool", "initial": False},
        "x": {"topic": "/x", "type": "std_msgs/msg/Float64", "initial": 1.0},
    }
    plenty = compiled(assertion, signals, sortThreshold=threshold)
    most, _ = engine_with([plenty])
    batched(most, msgs[:62], 0.0)  # (62: two events left in the sort window of 3)
    batched(most, msgs[62:], 0.0)
    made = most.slots["m"].runtime.buffered  # type: ignore[union-attr]
    for capacity in range(threshold, made + 5):
        m = compiled(assertion, signals, sortThreshold=threshold, bufferCapacity=capacity)
        one, one_sink = engine_with([m])
        many, many_sink = engine_with([m])
        for part in (msgs[:62], msgs[62:]):
            each(one, part, 0.0)
            batched(many, part, 0.0)
            assert observe(many) == observe(one), capacity
        many.drain()
        one.drain()
        assert many_sink.verdicts == one_sink.verdicts, capacity
