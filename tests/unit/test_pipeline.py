"""The event pipeline (Fig. 2) end to end against a direct reference.

The reference orders events by timestamp (ties in arrival order), keeps signal
values, evaluates each atom with plain Python, makes one letter per event once
every signal has a value, and runs the independent LTL3 reference over the
alphabet of letters that signal values can produce (enumerated by brute force).
"""

from __future__ import annotations

import itertools
import math
import random
from collections.abc import Callable
from typing import Any

import pytest
import spot

from edgerv.core.pipeline import MonitorRuntime
from edgerv.core.traces import TraceEvent
from kit.checks import events, run, verdicts
from kit.documents import compiled
from kit.reference import ReferenceMonitor

# Atoms over: x (float64 on /x), y (int32 on /y), b (bool on /b), with their Python meaning.
ATOMS: list[tuple[str, Callable[[dict[str, Any]], bool]]] = [
    ("x < 2.5", lambda v: v["x"] < 2.5),
    ("x >= 1", lambda v: v["x"] >= 1),
    ("y == 3", lambda v: v["y"] == 3),
    ("y > x", lambda v: v["y"] > v["x"]),
    ("b", lambda v: v["b"] is True),
    ("4 <= y", lambda v: v["y"] >= 4),
]
MEANING = {**dict(ATOMS), "x < 1": lambda v: v["x"] < 1}
X_VALUES = [0.0, 1.0, 2.0, 2.5, 3.0, 5.0, math.nan]
Y_VALUES = [0, 1, 3, 4, 6]
SIGNALS = {"x": "float", "y": "int", "b": "bool"}


def alphabet(atom_texts: list[str]) -> set[int]:
    """Every letter that some valuation of x, y, b gives (a fine grid around the constants)."""
    funcs = [MEANING[t] for t in atom_texts]
    xs = [*(v / 4 for v in range(-8, 32)), math.nan, math.inf, -math.inf]
    out = set()
    for x, y, b in itertools.product(xs, range(-2, 9), (False, True)):
        values = {"x": x, "y": y, "b": b}
        out.add(sum(1 << i for i, f in enumerate(funcs) if f(values)))
    return out


def reference_verdicts(
    formula: Any,
    atom_texts: list[str],
    arrivals: list[TraceEvent],
    initial: dict[str, Any],
    halt: bool,
) -> list[tuple[str, int, int]]:
    ordered = sorted(arrivals, key=lambda e: e.stamp)  # stable: ties keep arrival order
    values = dict(initial)
    funcs = [MEANING[t] for t in atom_texts]
    letters, stamps = [], []
    for e in ordered:
        values[e.topic[1:]] = e.msg["data"]
        if len(values) == len(SIGNALS):
            letters.append(sum(1 << i for i, f in enumerate(funcs) if f(values)))
            stamps.append(e.stamp)
    ref = ReferenceMonitor(
        formula, [f"p{i}" for i in range(len(atom_texts))], alphabet(atom_texts), halt=halt
    )
    return [(v, step, stamps[step - 1]) for v, step in ref.run(letters)]


def random_case(
    rng: random.Random, threshold: int, length: int
) -> tuple[list[TraceEvent], list[TraceEvent]]:
    """(events in timestamp order, the same events as they arrive).

    Arrival shuffles events only within consecutive windows of ``threshold``
    events: the out-of-order arrival that a sort threshold is meant to absorb.
    Timestamps repeat (ties) about a third of the time.
    """
    stamp = 1_000
    rows = []
    for _ in range(length):
        stamp += rng.choice([0, 0, 1, 5, 20])
        topic = rng.choice(["/x", "/y", "/b"])
        value = {
            "/x": lambda: rng.choice(X_VALUES),
            "/y": lambda: rng.choice(Y_VALUES),
            "/b": lambda: rng.random() < 0.5,
        }[topic]()
        rows.append((topic, stamp, value))
    arrival: list[tuple[str, int, Any]] = []
    for k in range(0, len(rows), threshold):
        window = rows[k : k + threshold]
        rng.shuffle(window)
        arrival += window
    return events(rows), events(arrival)


FORMULAS = [
    str(f)
    for f in itertools.islice(spot.randltl(6, seed=5, tree_size=(4, 14)), 60)
    if spot.atomic_prop_collect(f)
]


@pytest.mark.parametrize("case", range(len(FORMULAS)))
def test_pipeline_matches_reference(case: int) -> None:
    rng = random.Random(case)
    raw = spot.formula(FORMULAS[case])
    # substitute atoms for p0..p5, in a random order so every atom kind is exercised
    chosen = rng.sample(ATOMS, 6)
    mapping = {f"p{i}": f"({text})" for i, (text, _) in enumerate(chosen)}
    assertion = " ".join(
        mapping.get(tok, tok)
        for tok in raw.to_str("spot", parenth=True).replace("(", " ( ").replace(")", " ) ").split()
    )
    threshold = rng.choice([1, 2, 3, 5])
    halt = rng.random() < 0.25
    initial = {"b": False} if rng.random() < 0.5 else {}
    signals: dict[str, Any] = {
        "x": "float",
        "y": "int",
        "b": {
            "topic": "/b",
            "type": "std_msgs/msg/Bool",
            **({"initial": False} if initial else {}),
        },
    }
    m = compiled(assertion, signals, sortThreshold=threshold, onVerdict="halt" if halt else "reset")
    texts = [a.text.strip("()") for a in m.parsed.atoms]
    placeholders = spot.formula(m.parsed.formula)
    for trial in range(4):
        _, arrival = random_case(random.Random(case * 100 + trial), threshold, 40)
        got = verdicts(run([m], arrival)[0])
        expected = reference_verdicts(
            placeholders, [_canonical(t) for t in texts], arrival, initial, halt
        )
        assert got == expected, (assertion, threshold, [(e.topic, e.stamp, e.msg) for e in arrival])


def _canonical(text: str) -> str:
    for atom, _ in ATOMS:
        if atom == text:
            return atom
    raise KeyError(text)


def test_papers_fig2_example() -> None:
    """Threshold 3: the three events are sorted before any is evaluated."""
    m = compiled(
        "always (running -> (speed < 100 until stop))",
        {"running": "bool", "speed": "float", "stop": "bool"},
        sortThreshold=3,
    )
    arrival = events(
        [
            ("/speed", 10022, 17.3),
            ("/stop", 10021, False),
            ("/running", 10023, True),
            ("/speed", 10030, 150.0),
            ("/stop", 10031, True),
            ("/speed", 10029, 99.0),
        ]
    )
    result = run([m], arrival)[0]
    # sorted: stop@21 speed@22 running@23 -> first letter at 10023; then 99@29, 150@30 violates
    assert verdicts(result) == [("violated", 3, 10030)]
    assert result.late_events == 0


def test_ties_keep_arrival_order() -> None:
    m = compiled("always (a -> b)", {"a": "bool", "b": "bool"}, sortThreshold=4)
    # a and b change at the same instant; arrival order decides which letter comes first
    first_b = events([("/a", 1, False), ("/b", 1, False), ("/b", 5, True), ("/a", 5, True)])
    first_a = events([("/a", 1, False), ("/b", 1, False), ("/a", 5, True), ("/b", 5, True)])
    assert verdicts(run([m], first_b)[0]) == []
    assert verdicts(run([m], first_a)[0]) == [("violated", 2, 5)]


def test_no_step_until_every_signal_has_a_value_or_initial() -> None:
    sig = {"a": "bool", "b": {"topic": "/b", "type": "std_msgs/msg/Bool"}}
    m = compiled("always (a -> b)", sig)
    assert verdicts(run([m], events([("/a", 1, True), ("/a", 2, True)]))[0]) == []
    sig["b"] = {"topic": "/b", "type": "std_msgs/msg/Bool", "initial": False}
    m = compiled("always (a -> b)", sig)
    assert verdicts(run([m], events([("/a", 1, True), ("/a", 2, True)]))[0]) == [
        ("violated", 1, 1),
        ("violated", 2, 2),
    ]


def test_reset_restarts_and_halt_stops() -> None:
    rows = [("/a", t, v) for t, v in enumerate([True, False, True, True, False], start=1)]
    reset = compiled("always a", {"a": "bool"})
    halt = compiled("always a", {"a": "bool"}, onVerdict="halt")
    r_reset, r_halt = run([reset], events(rows))[0], run([halt], events(rows))[0]
    assert verdicts(r_reset) == [("violated", 2, 2), ("violated", 5, 5)]
    assert r_reset.state == "violated"
    assert verdicts(r_halt) == [("violated", 2, 2)]
    assert r_halt.state == "halted"


def test_events_on_other_topics_do_not_step() -> None:
    m = compiled("next a", {"a": "bool"})
    other = compiled("always c", {"c": "bool"}, name="other")
    result = run([m, other], events([("/a", 1, False), ("/c", 2, True), ("/a", 3, True)]))
    assert verdicts(result[0]) == [("satisfied", 2, 3)]


def test_one_message_feeds_two_signals_in_one_step() -> None:
    sigs = {
        "x": {"topic": "/odom", "type": "nav_msgs/msg/Odometry", "field": "pose.pose.position.x"},
        "v": {"topic": "/odom", "type": "nav_msgs/msg/Odometry", "field": "twist.twist.linear.x"},
    }
    m = compiled("always (x < 10 | v < 1)", sigs)
    odom = [
        TraceEvent(
            "/odom",
            t,
            {"pose": {"pose": {"position": {"x": x}}}, "twist": {"twist": {"linear": {"x": v}}}},
            e.where,
        )
        for (t, x, v), e in zip(
            [(1, 5.0, 3.0), (2, 12.0, 0.5), (3, 12.0, 2.0)], events([("/", 0, 0)] * 3), strict=True
        )
    ]
    result = run([m], odom)[0]
    assert verdicts(result) == [("violated", 3, 3)]
    assert result.steps == 3


def test_late_events_beyond_the_window_are_counted() -> None:
    m = compiled("always a", {"a": "bool"}, sortThreshold=2)
    result = run([m], events([("/a", 5, True), ("/a", 6, True), ("/a", 1, True), ("/a", 7, True)]))[
        0
    ]
    assert result.late_events == 1


@pytest.mark.parametrize(
    ("assertion", "expected"),
    [
        # x < 1 implies x < 2.5 for every value: the prefix is good at once (satisfied, reset, ...)
        ("always ((x < 1) -> (x < 2.5))", "satisfied"),
        # x < 1 and x >= 1 never hold together: no continuation can satisfy it
        ("eventually! ((x < 1) & (x >= 1))", "violated"),
    ],
)
def test_verdicts_use_only_letters_that_values_can_make(assertion: str, expected: str) -> None:
    m = compiled(assertion, SIGNALS)
    arrival = events([("/b", 1, True), ("/y", 2, 3), ("/x", 3, 0.5), ("/x", 4, 2.0)])
    texts = [a.text for a in m.parsed.atoms]
    want = reference_verdicts(m.parsed.formula, texts, arrival, {}, halt=False)
    assert verdicts(run([m], arrival)[0]) == want == [(expected, 1, 3), (expected, 2, 4)]


COLUMN_CASES = [
    ("always (a -> x < 5)", {"a": "bool", "x": "float"}),
    ("always (x <= y | s == mode)", {"x": "float", "y": "float", "s": "string"}),
    ("always (n != 3 -> next (n >= 2 & !a))", {"n": "int", "a": "bool"}),
    ("eventually! (x > 9.5 & x < y)", {"x": "float", "y": "float"}),
]


@pytest.mark.parametrize("seed", range(24))
def test_batches_compressed_column_wise_give_the_letters_of_one_by_one(seed: int) -> None:
    """The NumPy path of a long batch against the scalar path, on random batches.

    Random values include NaN, ties of stamps, signals that get their first value
    mid-batch (or never), several signals updated by one event.
    """
    from edgerv.core import pipeline

    rng = random.Random(seed)
    assertion, kinds = COLUMN_CASES[seed % len(COLUMN_CASES)]
    m = compiled(assertion, kinds, parameters={"mode": "go"} if "mode" in assertion else {})
    names = list(m.signal_names)

    def value(kind: str) -> object:
        if kind == "bool":
            return rng.random() < 0.5
        if kind == "int":
            return rng.randint(0, 5)
        if kind == "string":
            return rng.choice(["go", "stop", ""])
        return rng.choice([float("nan"), rng.uniform(0, 10), 5.0, 3.0])

    column_rt, scalar_rt = MonitorRuntime(m), MonitorRuntime(m)
    for _ in range(4):
        batch = []
        never = rng.choice([None, *names]) if rng.random() < 0.2 else None
        for i in range(rng.randint(pipeline.COLUMNS_FROM, 300)):
            sigs = rng.sample(range(len(names)), rng.randint(1, len(names)))
            updates = [(s, value(kinds[names[s]])) for s in sigs if names[s] != never]
            batch.append((1000 + i // 3, i, updates))
        column_rt._compress(batch)
        for stamp, _seq, updates in batch:
            scalar_rt._compress_one(stamp, updates, scalar_rt.letters, scalar_rt.stamps)
        assert list(column_rt.letters) == list(scalar_rt.letters)
        assert list(column_rt.stamps) == list(scalar_rt.stamps)
        assert (column_rt.valuation, column_rt.missing) == (scalar_rt.valuation, scalar_rt.missing)
        assert [repr(v) for v in column_rt.values] == [repr(v) for v in scalar_rt.values]
    assert len(column_rt.letters) > 0


@pytest.mark.parametrize("seed", range(30))
def test_compressing_ahead_of_the_sort_changes_nothing(seed: int) -> None:
    """Events of the sort buffer compressed on arrival while they come in order: the
    letters, stamps, late counts and signal values equal those of sorting at the
    threshold, with events out of order now and then, partial flushes (flushAfter,
    a handoff's hold), holds and releases at a cut (:meth:`MonitorRuntime.cover`)
    in between."""
    rng = random.Random(seed)
    assertion, kinds = COLUMN_CASES[seed % len(COLUMN_CASES)]
    m = compiled(
        assertion,
        kinds,
        sortThreshold=rng.choice([2, 3, 8, 60]),
        parameters={"mode": "go"} if "mode" in assertion else {},
    )
    names = list(m.signal_names)
    fast, plain = MonitorRuntime(m), MonitorRuntime(m)
    plain.speculate = False
    stamp = 0
    for seq in range(600):
        stamp += rng.choice([0, 1, 2, 5])
        late = stamp - rng.randint(1, 8) if rng.random() < 0.05 else stamp
        updates = []  # one signal, or now and then two (a message read for two fields)
        for sig in rng.sample(range(len(names)), 2 if rng.random() < 0.2 else 1):
            kind = kinds[names[sig]]
            value: object = (
                rng.random() < 0.5
                if kind == "bool"
                else rng.randint(0, 5)
                if kind == "int"
                else rng.choice(["go", "stop"])
                if kind == "string"
                else rng.choice([float("nan"), rng.uniform(0, 10)])
            )
            updates.append((sig, value))
        for rt in (fast, plain):
            rt.offer(late, seq, updates)
        roll, roll_cut = rng.random(), rng.randint(0, 6)
        for rt in (fast, plain):
            if roll < 0.03:
                rt.flush()
            elif roll < 0.06:
                rt.flush_prefix(len(rt.events) // 2)
            elif roll < 0.08:
                rt.holding = not rt.holding
            elif roll < 0.09:  # a handoff's release: what is at or before the cut, only
                rt.cover(stamp - roll_cut)
        assert list(fast.letters) == list(plain.letters)
        assert list(fast.stamps) == list(plain.stamps)
        assert fast.events == plain.events
        if 0.08 <= roll < 0.09:  # the state as of the cut, as a snapshot takes it
            assert [repr(v) for v in fast.values] == [repr(v) for v in plain.values]
            assert (fast.valuation, fast.missing) == (plain.valuation, plain.missing)
    for rt in (fast, plain):
        rt.holding = False
        rt.flush()
    assert list(fast.letters) == list(plain.letters) and len(fast.letters) > 100
    assert (fast.late_events, fast.valuation, fast.missing) == (
        plain.late_events,
        plain.valuation,
        plain.missing,
    )
    assert [repr(v) for v in fast.values] == [repr(v) for v in plain.values]
