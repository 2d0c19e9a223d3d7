"""Time in assertions: durations, age(x), clock steps (docs/semantics.md, "Time").

The differential test computes the steps of a timed run by brute force, without
edgerv's deadlines: every instant at which some atom could change (each message
time, and each message time plus a duration, plus one nanosecond) is examined
directly from the definition of age, a clock step is kept where the letter
changes, and the letters go through the independent LTL3 reference
(tests/kit/reference.py) over the letters that values and ages can make.
"""

from __future__ import annotations

import itertools
import json
import math
import random
from pathlib import Path
from typing import Any

import pytest
import spot

from edgerv.core.diagnostics import InputError
from edgerv.core.language.assertion import parse_assertion
from edgerv.core.monitor import CompiledMonitor
from edgerv.core.pipeline import MonitorRuntime
from kit.checks import events, run, verdicts
from kit.cli import edgerv
from kit.documents import compiled, spec_of
from kit.reference import ReferenceMonitor

MS = 1_000_000
SIGNALS = {"a": "bool", "b": "bool", "speed": "float"}


def error_of(assertion: str) -> str:
    with pytest.raises(InputError) as info:
        parse_assertion(spec_of(assertion, SIGNALS, parameters={"limit": 3}))
    return str(info.value)


@pytest.mark.parametrize(
    ("text", "ns"),
    [("500ms", 500 * MS), ("1.5s", 1_500_000_000), ("2min", 120_000_000_000), ("3us", 3000),
     ("7ns", 7), (".5s", 500 * MS), ("1e3ms", 10**9)],
)  # fmt: skip
def test_durations_carry_their_unit(text: str, ns: int) -> None:
    m = compiled(f"always (age(a) < {text})", SIGNALS)
    assert [(t.op, t.duration) for t in m.timed] == [("<", ns)]


@pytest.mark.parametrize(
    ("assertion", "expected"),
    [
        ("always (age(a) < 500sec)", "test.yaml:6:34: error: unknown unit 'sec' in '500sec'"),
        ("always (age(a) < 125)", "type mismatch in 'age(a) < 125': age(a) is a duration, 125"),
        ("always (speed < 5ms)", "speed is a number, 5000000 is a duration"),
        ("always (age(c) < 1s)", "age() takes a signal: 'c' is not a signal"),
        ("always (age(limit) < 1s)", "age() takes a signal: 'limit' is a parameter"),
        ("always (age(a) > -1s)", "a duration cannot be negative: '-1s'"),
        ("always (age(a) < 1.5ns)", "'1.5ns' is not a whole number of nanoseconds"),
        ("always ({a;b}[0..1s] |-> b)", "a time bound here (on a SERE) is not supported"),
        ("X F[0..1s] a", "a time-bounded F beside X, a step count or a SERE"),
        ("always (a -> X F[0..1s] b)", "a time-bounded F beside X, a step count or a SERE"),
        ("always ({a;b} |-> F[0..1s] b)", "a time-bounded F beside X, a step count or a SERE"),
        ("always (a -> X[2s] b)", "'X' counts steps: it takes no duration"),
        ("always (a -> (b U[0..3] a))", "'U' takes a time bound, not steps"),
        ("always (a -> (F b U[0..1s] a))", "an untimed future operator inside the operand of U"),
        ("always (a -> F[0..1s] G b)", "an untimed future operator inside the operand of F"),
        ("always (a -> F[2s..1s] b)", "the interval [2s..1s] ends before it starts"),
        ("always (age(a) & b)", "age(x) is a duration, not a proposition"),
        ("always (a -> 5ms)", "duration 5ms outside a comparison"),
        ("always (age(a) < age(b))", "must compare one age(x) with a duration"),
    ],
)
def test_bad_time_is_reported_at_its_place(assertion: str, expected: str) -> None:
    message = error_of(assertion)
    assert expected in message, message
    assert "Traceback" not in message


def test_a_duration_on_the_left_and_not_equal_mean_what_they_say() -> None:
    m = compiled("always (200ms > age(a) & age(b) != 1s)", SIGNALS)
    assert [(t.op, t.duration) for t in m.timed] == [("<", 200 * MS), ("==", 10**9)]
    assert "!" in m.parsed.spot_text  # != is the negation of ==


def test_a_deadline_is_reported_at_the_instant_it_passes_offline() -> None:
    """cmd at 0, 100, 200 ms, then silence while another topic shows time passing."""
    m = compiled("always (age(cmd) < 125ms)", {"cmd": "float"}, name="deadline")
    trace = [("/cmd", t * MS, 1.0) for t in (0, 100, 200)] + [("/odom", 900 * MS, 0.0)]
    (result,) = run([m], events(trace))  # the helper ends the check at the last event
    assert verdicts(result) == [("violated", 4, 325 * MS)]  # 200 ms + 125 ms: a clock step


def test_a_check_ends_its_clock_at_the_traces_last_stamp(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`edgerv check` on JSON Lines: lines of topics no monitor reads still show time."""
    (tmp_path / "m.yaml").write_text(
        "apiVersion: edgerv.io/v1alpha1\nkind: Monitor\nmetadata: {name: fresh}\nspec:\n"
        '  assertion: "always (age(cmd) < 125ms)"\n'
        "  signals: {cmd: {topic: /cmd, type: std_msgs/msg/Float64}}\n"
    )
    lines = [{"topic": "/cmd", "stamp": t * MS, "msg": {"data": 1.0}} for t in (0, 100)]
    lines.append({"topic": "/other", "stamp": 400 * MS, "msg": {"data": 1}})
    (tmp_path / "t.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
    monkeypatch.chdir(tmp_path)
    done = edgerv("check", "m.yaml", "t.jsonl", "--json")
    assert done.returncode == 1, done.stderr
    (mon,) = json.loads(done.stdout)["monitors"]
    assert mon["verdicts"] == [{"verdict": "violated", "stamp": 225 * MS, "step": 3}]


def test_live_time_passing_gives_the_same_steps_as_a_trace() -> None:
    """advance() (the handler's clock) and a later event give the same clock steps."""
    m = compiled("always (age(a) < 10ns | b)", {"a": "bool", "b": "bool"})
    by_event, by_clock = MonitorRuntime(m), MonitorRuntime(m)
    for rt in (by_event, by_clock):
        rt.offer(0, 0, [(0, True), (1, False)])  # a and b share no topic here: one event
    by_event.offer(50, 1, [(1, False)])
    assert by_clock.advance(49)
    by_clock.offer(50, 1, [(1, False)])
    got = [[(v.verdict, v.step, v.stamp) for v in rt.evaluate()] for rt in (by_event, by_clock)]
    assert got[0] == got[1] == [("violated", 2, 10), ("violated", 3, 50)]


def test_age_is_infinite_before_the_first_message() -> None:
    m = compiled(
        "always (age(b) > 1s)",
        {"a": "bool", "b": {"topic": "/b", "type": "std_msgs/msg/Bool", "initial": False}},
    )
    (result,) = run(
        [m], events([("/a", 0, True), ("/a", 5 * 10**9, True), ("/b", 6 * 10**9, True)])
    )
    assert verdicts(result) == [("violated", 3, 6 * 10**9)]  # only once /b has spoken


# -- differential: brute-force steps and the independent LTL3 reference -------------------------

TIMED_ATOMS = [
    "age(a) < 30ms", "age(b) >= 20ms", "age(a) <= 45ms", "age(b) == 25ms", "age(a) > 10ms",
]  # fmt: skip
_CMP = {"<": int.__lt__, "<=": int.__le__, ">": int.__gt__, ">=": int.__ge__, "==": int.__eq__}


def atom_value(text: str, now: int, last: dict[str, int | None], values: dict[str, bool]) -> bool:
    """An atom's truth at ``now`` straight from its definition."""
    if not text.startswith("age("):
        return values[text]
    name, op, d = text[4], text.split()[1], int(text.split()[2][:-2]) * MS
    if last[name] is None:
        return op in (">", ">=")  # never published: an infinite age
    return bool(_CMP[op](now - last[name], d))


def reference_steps(
    texts: list[str], trace: list[tuple[str, int, bool]], end: int
) -> list[tuple[int, int]]:
    """(letter, stamp) of every step: each event, and each instant between events (up to
    ``end``) at which the letter changes, found by trying every instant where it could."""
    values = {"a": False, "b": False}  # both signals have initial: false
    last: dict[str, int | None] = {"a": None, "b": None}
    durations = {int(t.split()[2][:-2]) * MS for t in texts if t.startswith("age(")}

    def letter(now: int) -> int:
        return sum(1 << i for i, t in enumerate(texts) if atom_value(t, now, last, values))

    steps: list[tuple[int, int]] = []
    current = letter(0)
    bounds = [stamp for _, stamp, _ in trace[1:]] + [end + 1]
    for (topic, stamp, value), until in zip(trace, bounds, strict=True):
        values[topic[1]], last[topic[1]] = value, stamp
        current = letter(stamp)
        steps.append((current, stamp))
        candidates = sorted(
            {m + d + k for m in last.values() if m is not None for d in durations for k in (0, 1)}
        )
        for t in candidates:
            if stamp < t < until and letter(t) != current:
                current = letter(t)
                steps.append((current, t))
    return steps


def feasible(texts: list[str]) -> list[int]:
    """The letters values and ages can make: every bool value and, per signal, every age
    around the durations it is compared with (and infinite)."""
    ages = sorted({0, *(int(t.split()[2][:-2]) * MS + k for t in texts if "age" in t
                        for k in (-1, 0, 1))})  # fmt: skip
    out = set()
    for va, vb, age_a, age_b in itertools.product(
        (False, True), (False, True), [*ages, math.inf], [*ages, math.inf]
    ):
        now = 10**12
        last = {"a": None if age_a == math.inf else now - age_a,
                "b": None if age_b == math.inf else now - age_b}  # fmt: skip
        out.add(sum(1 << i for i, t in enumerate(texts)
                    if atom_value(t, now, last, {"a": va, "b": vb})))  # fmt: skip
    return sorted(out)


def timed_formulas(count: int, seed: int) -> list[str]:
    gen = spot.randltl(["a", "b", "t0", "t1"], seed=seed, tree_size=(4, 14), simplify=0)
    rng = random.Random(seed)
    out: list[str] = []
    while len(out) < count:
        f = str(next(gen))
        if "t0" in f or "t1" in f:
            pick = rng.sample(TIMED_ATOMS, 2)
            out.append(f.replace("t0", f"({pick[0]})").replace("t1", f"({pick[1]})"))
    return out


def random_trace(rng: random.Random, n: int) -> list[tuple[str, int, bool]]:
    stamp, out = 0, []
    for _ in range(n):
        stamp += rng.choice([0, 1, 5, 15, 20, 25, 30, 50]) * MS + rng.choice([0, 0, 1, -1])
        stamp = max(stamp, out[-1][1] if out else 0)
        out.append((rng.choice(["/a", "/b"]), stamp, rng.random() < 0.5))
    return out


@pytest.mark.parametrize(("seed", "formula"), list(enumerate(timed_formulas(30, seed=7))))
def test_timed_verdicts_match_the_brute_force_reference(seed: int, formula: str) -> None:
    signals = {n: {"topic": f"/{n}", "type": "std_msgs/msg/Bool", "initial": False} for n in "ab"}
    m: CompiledMonitor = compiled(formula, signals)
    texts = [atom.text for atom in m.parsed.atoms]  # bit i of a letter is this atom
    names = [f"q{i}" for i in range(len(texts))]
    spot_text = m.parsed.spot_text
    for i in reversed(range(len(texts))):
        spot_text = spot_text.replace(f"p{i}", names[i])
    ref = ReferenceMonitor(spot.formula(spot_text), names, alphabet=feasible(texts))
    rng = random.Random(seed)
    for _ in range(6):
        trace = random_trace(rng, 25)
        end = trace[-1][1] + rng.choice([0, 10, 100]) * MS
        steps = reference_steps(texts, trace, end)
        expected = [(v, step, steps[step - 1][1]) for v, step in ref.run(s for s, _ in steps)]
        check = run([m], events([*trace, ("/clock", end, 0)]))
        assert verdicts(check[0]) == expected, (formula, trace, end)


# -- time-bounded F and G: always (P -> F[a..b] Q), always (P -> G[a..b] Q) ------------------


def held(run_: list[tuple[str, int, bool]], topic: str, u: int) -> bool | None:
    """The value of the signal on ``topic`` at instant u (None before the run)."""
    if u < run_[0][1]:
        return None
    value = False  # initial: false
    for t, s, v in run_:
        if s > u:
            break
        if t == topic:
            value = v
    return value


def q_sometime(run_: list[tuple[str, int, bool]], lo: int, hi: int) -> bool:
    """Q held at some instant of [lo, hi]: at lo, or at a message on /q within it."""
    return bool(held(run_, "/q", lo)) or any(t == "/q" and v and lo < s <= hi for t, s, v in run_)


def obligation_fails(
    kind: str, lo: int, hi: int, run_: list[tuple[str, int, bool]], t: int
) -> bool:
    """Straight from the future form: at instant t, is some obligation certain to fail?
    F: the obligation of P at t - hi saw no Q in [t - hi + lo, t]. G: Q fails at t
    while P held at some instant of [t - hi, t - lo] (each looked up in the run)."""
    if kind == "F":
        tau = t - hi
        return bool(held(run_, "/p", tau)) and not q_sometime(run_, tau + lo, tau + hi)
    if held(run_, "/q", t):
        return False
    start = max(t - hi, run_[0][1])
    return start <= t - lo and (
        bool(held(run_, "/p", start))
        or any(x == "/p" and v and start < s <= t - lo for x, s, v in run_)
    )


@pytest.mark.parametrize("seed", range(30))
def test_bounded_future_deadlines_fail_exactly_when_certain(seed: int) -> None:
    rng = random.Random(seed)
    kind = rng.choice(["F", "G"])
    lo = rng.choice([0, 0, 10, 20]) * MS
    hi = lo + rng.choice([5, 20, 40]) * MS
    signals = {n: {"topic": f"/{n}", "type": "std_msgs/msg/Bool", "initial": False} for n in "pq"}
    m = compiled(f"always (p -> {kind}[{lo}ns..{hi}ns] q)", signals)
    for _ in range(4):
        run_, stamp = [], 0
        for _ in range(30):
            stamp += rng.choice([1, 3, 5, 10, 20, 30]) * MS + rng.choice([0, 1])
            run_.append((rng.choice(["/p", "/q"]), stamp, rng.random() < 0.4))
        end = stamp + rng.choice([0, 30, 80]) * MS
        rt = MonitorRuntime(m)
        for i, (topic, t, v) in enumerate(run_):
            rt.offer(t, i, [(0 if topic == "/p" else 1, v)])
        rt.advance(end)
        steps = list(rt.stamps)
        violated = {v.step for v in rt.evaluate() if v.verdict == "violated"}
        got = [(t, i + 1 in violated) for i, t in enumerate(steps)]
        assert got == [(t, obligation_fails(kind, lo, hi, run_, t)) for t in steps], (
            kind, lo, hi, run_, end)  # fmt: skip
        # every instant at which an obligation starts to fail is a step
        tries = {s + d + k for _, s, _ in run_ for d in (0, lo, hi) for k in (0, 1)}
        starts = [t for t in sorted(tries) if run_[0][1] < t <= end
                  and obligation_fails(kind, lo, hi, run_, t)
                  and not obligation_fails(kind, lo, hi, run_, t - 1)]  # fmt: skip
        assert set(starts) <= set(steps), (kind, lo, hi, sorted(set(starts) - set(steps)))


# -- time-bounded until: always (P -> R U[a..b] Q), always (P -> R W[a..b] Q) ----------------
# Brute force over every nanosecond: stamps and bounds are a few nanoseconds, so each
# instant of the run is looked at, straight from the definition (docs/semantics.md).

Trace = list[tuple[str, int, bool]]


def obligation_met(kind: str, lo: int, hi: int, at: Any, tau: int) -> bool:
    """The obligation opened at instant tau, signals read by ``at(topic, x)``: U needs Q
    at some t' of [tau+lo, tau+hi] with R at every instant of [tau, t'); W also takes R
    at every instant of [tau, tau+hi]."""
    for t2 in range(tau + lo, tau + hi + 1):
        if at("/q", t2) and all(at("/r", x) for x in range(tau, t2)):
            return True
    return kind == "W" and all(at("/r", x) for x in range(tau, tau + hi + 1))


def first_certain_failure(kind: str, lo: int, hi: int, run_: Trace, end: int) -> int | None:
    """LTL3: the first instant u up to which the run leaves no way out: with the most
    favourable future after u (R and Q true, no new P), some obligation fails."""
    t0 = run_[0][1]
    for u in range(t0, end + 1):

        def at(topic: str, x: int, u: int = u) -> bool:
            return bool(held(run_, topic, x)) if x <= u else topic != "/p"

        opened = (tau for tau in range(t0, u + 1) if at("/p", tau))
        if any(not obligation_met(kind, lo, hi, at, tau) for tau in opened):
            return u
    return None


def failure_shown_at(kind: str, lo: int, hi: int, run_: Trace, u: int) -> bool:
    """Is some obligation's failure shown at instant u: its deadline u (U, no Q in its
    window), or R failing at u while it waits for Q (U and W)? (semantics.md)"""
    t0 = run_[0][1]

    def at(topic: str, x: int) -> bool:
        return bool(held(run_, topic, x))

    def no_q(a: int, b: int) -> bool:
        return not any(at("/q", x) for x in range(a, b + 1))

    if kind == "U" and u - hi >= t0 and at("/p", u - hi) and no_q(u - hi + lo, u):
        return True
    return not at("/r", u) and any(
        at("/p", tau) and no_q(tau + lo, u) for tau in range(max(t0, u - hi), u + 1)
    )


@pytest.mark.parametrize("seed", range(40))
def test_bounded_until_fails_exactly_when_certain(seed: int) -> None:
    rng = random.Random(seed)
    kind = rng.choice(["U", "W"])
    lo = rng.choice([0, 0, 1, 3, 6])
    hi = lo + rng.choice([0, 1, 4, 9])
    signals = {n: {"topic": f"/{n}", "type": "std_msgs/msg/Bool", "initial": False}
               for n in "prq"}  # fmt: skip
    assertion = f"always (p -> (r {kind}[{lo}ns..{hi}ns] q))"
    reset, halt = compiled(assertion, signals), compiled(assertion, signals, onVerdict="halt")
    for _ in range(4):
        run_: Trace = []
        stamp = rng.choice([0, 100])
        for _ in range(rng.choice([10, 20, 30])):
            stamp += rng.choice([1, 1, 2, 3, 5, 8])
            run_.append((rng.choice(["/p", "/r", "/q", "/r"]), stamp, rng.random() < 0.5))
        end = stamp + rng.choice([0, 3, 12])
        rt = MonitorRuntime(reset)
        for i, (topic, t, v) in enumerate(run_):
            rt.offer(t, i, [(["/p", "/r", "/q"].index(topic), v)])
        rt.advance(end)
        steps = list(rt.stamps)
        violated = {v.step for v in rt.evaluate() if v.verdict == "violated"}
        got = [(t, i + 1 in violated) for i, t in enumerate(steps)]
        why = (assertion, run_, end)
        assert got == [(t, failure_shown_at(kind, lo, hi, run_, t)) for t in steps], why
        # every instant at which a failure starts to show is a step (a clock step if no
        # message comes then)
        t0 = run_[0][1]
        onsets = {u for u in range(t0 + 1, end + 1) if failure_shown_at(kind, lo, hi, run_, u)
                  and not failure_shown_at(kind, lo, hi, run_, u - 1)}  # fmt: skip
        assert onsets <= set(steps), (*why, sorted(onsets - set(steps)))
        # onVerdict: halt: one verdict, where the failure became certain
        (result,) = run([halt], events([*run_, ("/clock", end, 0)]))
        first = first_certain_failure(kind, lo, hi, run_, end)
        assert [t for _, _, t in verdicts(result)] == ([] if first is None else [first]), why


def test_until_with_a_time_bound_reads_as_the_issue_says() -> None:
    """busy until done within 1 s: done may come as busy ends (one message)."""
    signals = {n: "bool" for n in ["go", "busy", "done"]}
    m = compiled("always (go -> (busy U[0..1s] done))", signals)
    ok = [("/go", 0, False), ("/busy", 0, False), ("/done", 0, False), ("/busy", 10 * MS, True),
          ("/go", 10 * MS, True), ("/go", 20 * MS, False), ("/done", 600 * MS, True),
          ("/busy", 600 * MS, False), ("/odom", 3000 * MS, 0)]  # fmt: skip
    (result,) = run([m], events(ok))
    assert verdicts(result) == []
    # done never comes: violated at the deadline, 1 s after go (a clock step)
    (result,) = run([m], events([*ok[:6], ("/odom", 3000 * MS, 0)]))
    assert [(v, t) for v, _, t in verdicts(result)] == [("violated", 1010 * MS)]
    # busy ends before done: violated there
    broke = [*ok[:6], ("/busy", 300 * MS, False), ("/done", 600 * MS, True)]
    (result,) = run([m], events(broke))
    assert [(v, t) for v, _, t in verdicts(result)] == [("violated", 300 * MS)]
    # weak: busy for the whole second and no done is fine; busy ending without done is not
    w = compiled("always (go -> (busy until[0..1s] done))", signals)
    (result,) = run([w], events([*ok[:6], ("/odom", 3000 * MS, 0)]))
    assert verdicts(result) == []
    (result,) = run([w], events(broke))
    assert [(v, t) for v, _, t in verdicts(result)] == [("violated", 300 * MS)]


@pytest.mark.parametrize("seed", range(10))
def test_time_bounded_operators_combine_under_always(seed: int) -> None:
    """Several in one assertion, each in its shape: the first failure of the whole is the
    first of its parts', checked as monitors of their own. (``always`` binds loosely: the
    second part is inside the first's ``always``, which changes nothing.)"""
    rng = random.Random(seed)
    parts = ["always (a -> F[0..20ms] b)", "always (b -> (a U[5ms..30ms] !b))",
             "always (a -> G[0..10ms] !b)", "always (b -> (!a until[0..15ms] a))"]  # fmt: skip
    chosen = rng.sample(parts, 2)
    signals = {n: {"topic": f"/{n}", "type": "std_msgs/msg/Bool", "initial": False} for n in "ab"}
    whole = compiled(" && ".join(chosen), signals, onVerdict="halt")
    alone = [compiled(t, signals, name=f"part{k}", onVerdict="halt") for k, t in enumerate(chosen)]
    for _ in range(5):
        stamp, rows = 0, []
        for _ in range(20):
            stamp += rng.choice([1, 4, 9, 17]) * MS
            rows.append((rng.choice(["/a", "/b"]), stamp, rng.random() < 0.5))
        rows.append(("/clock", stamp + 40 * MS, 0))
        firsts = [t for r in run(alone, events(rows)) for v, _, t in verdicts(r)]
        (result,) = run([whole], events(rows))
        assert [t for _, _, t in verdicts(result)] == sorted(firsts)[:1], (chosen, rows)


def test_the_issues_deadline_is_violated_where_it_became_certain() -> None:
    m = compiled("always (go -> F[0..500ms] done)", {"go": "bool", "done": "bool"})
    trace = [("/go", 0, True), ("/done", 0, False), ("/go", 100 * MS, False),
             ("/done", 300 * MS, True), ("/done", 320 * MS, False),
             ("/go", 1000 * MS, True), ("/go", 1100 * MS, False),
             ("/odom", 3000 * MS, 0)]  # fmt: skip
    (result,) = run([m], events(trace))
    # go from 1000 ms on: no done within 500 ms, certain at 1500 ms (a clock step)
    assert [(v, t) for v, _, t in verdicts(result)] == [("violated", 1500 * MS)]
