"""Time-bounded F and G (docs/semantics.md, "Time") against RTAMT's bounded-future monitors.

RTAMT (a test dependency, independent of edgerv) computes an STL formula's robustness
over whole signals, offline; its sign is the formula's truth at each instant. Its
dense-time interpretation is the one section 6 states, so it is the one used: each
sample holds from its instant until the next (piecewise constant, left-closed), time is
real, and ``eventually[a:b]``/``always[a:b]`` look at the closed window ``[t + a, t + b]``.
No sampling grid is needed: RTAMT's time is the stamps themselves, in nanoseconds from
the run's first message (bounds are plain numbers in the same unit), with one-nanosecond
offsets on stamps and bounds so that every closed or open end is exercised. RTAMT reads
the raw signal values and evaluates P and Q itself, past operators included (bool
signals as 0/1 against ``>= 0.5``, the float signal's integer values against
half-integer thresholds: no robustness is ever 0, its sign is the truth).

For each instant t, RTAMT's ``P -> eventually[a:b] Q`` (``always[a:b]``; or
``eventually[a:b] Q`` alone) says whether the obligation opened at t is met, the whole
run known (its last values held forever after it: only windows that end within the run
are compared). Q is written ``Q or m`` with a mask signal m that excuses Q where it is
true. edgerv's verdicts follow:

* ``always (P -> F[a..b] Q)`` and ``always (F[a..b] Q)``: Q could still come at the last
  instant of the window, so the obligation of t is certain to fail at ``t + b``. With
  ``onVerdict: reset`` edgerv is violated at exactly the steps u at which RTAMT (m false)
  is false at ``u - b``, and each instant of the run at which that changes is one of
  edgerv's steps (a clock step when no message comes then).
* ``always (P -> G[a..b] Q)``: an obligation fails at each instant of its window where Q
  fails; with Q excused outside ``[lo, hi)``, RTAMT finds a failing obligation exactly
  when one fails at an instant of ``[lo, hi)``. With ``onVerdict: reset`` edgerv is
  violated at a step s exactly when one fails at the instant s, and when it is not, none
  fails from s to its next step (no instant at which one starts to fail is missed).
* ``onVerdict: halt``, all three shapes: a failure is certain at the first instant u
  such that, whatever follows u, an obligation fails (LTL3). With Q excused after u (the
  most favourable future: P after u opens obligations that excused Q meets), RTAMT finds
  a failing obligation exactly when the run up to u is such, which is monotone in u. So
  edgerv's single verdict (the reset run's first, same stamp and step) is at u exactly
  when RTAMT finds a failure with Q excused after u and none with Q excused from u on;
  no verdict exactly when RTAMT finds none with Q excused after the run's end.

Stamps are distinct and every signal has an initial value: RTAMT has one value per
signal and instant and starts with every signal valued, edgerv steps at each message,
from its first one, and its windows do not reach before it. Where the two differ by
definition, equal stamps and obligations that outlast the run, focused tests below say
how (docs/semantics.md, section 6).
"""

from __future__ import annotations

import random
from typing import Any

import pytest

from edgerv.core.monitor import CompiledMonitor
from edgerv.core.pipeline import MonitorRuntime
from kit.checks import events, run, truth_at, verdicts
from kit.documents import compiled

MS = 1_000_000
SIGNALS = {
    "a": {"topic": "/a", "type": "std_msgs/msg/Bool", "initial": False},
    "b": {"topic": "/b", "type": "std_msgs/msg/Bool", "initial": False},
    "x": {"topic": "/x", "type": "std_msgs/msg/Float64", "initial": 0.0},
}
# (edgerv text, RTAMT text) of each atom; x takes the values 0..4
ATOMS = [("a", "(a >= 0.5)"), ("b", "(b >= 0.5)"), ("x < 2.5", "(x < 2.5)"),
         ("x >= 1.5", "(x >= 1.5)"), ("x > 3.5", "(x > 3.5)")]  # fmt: skip

Run = list[tuple[str, int, Any]]


def random_boolean(rng: random.Random, atoms: list[tuple[str, str]], depth: int) -> tuple[str, str]:
    """(edgerv, RTAMT) text of a random boolean formula over ``atoms``, now and then with
    a past operator (``once``/``historically``, timed or not: over the steps, untimed
    ones mean the same over time, as a signal holds its value between steps)."""
    if depth == 0 or rng.random() < 0.35:
        return rng.choice(atoms)
    kind = rng.choice(["not", "and", "or", "not", "and", "or", "past"])
    e1, r1 = random_boolean(rng, atoms, depth - 1)
    if kind == "not":
        return f"(!{e1})", f"(not {r1})"
    if kind == "past":
        word = rng.choice(["once", "historically"])
        if rng.random() < 0.3:
            return f"({word} {e1})", f"({word} {r1})"
        lo = rng.choice([0, 0, 10, 20]) * MS + rng.choice([0, 1])
        hi = lo + rng.choice([0, 5, 20, 40]) * MS + rng.choice([0, 1])
        return f"({word}[{lo}ns..{hi}ns] {e1})", f"({word}[{lo}:{hi}] {r1})"
    e2, r2 = random_boolean(rng, atoms, depth - 1)
    return (f"({e1} & {e2})", f"({r1} and {r2})") if kind == "and" else (
        f"({e1} | {e2})", f"({r1} or {r2})")  # fmt: skip


def random_case(rng: random.Random) -> tuple[str, str, str, int]:
    """(shape, edgerv assertion, RTAMT formula with Q excused where m holds, b)."""
    shape = rng.choice(["F", "G", "F0"])
    a = rng.choice([0, 0, 10, 20, 35]) * MS + rng.choice([0, 0, 1])
    b = a + rng.choice([0, 5, 20, 40, 60]) * MS + rng.choice([0, 0, 1])
    atoms = rng.sample(ATOMS, rng.choice([2, 3]))
    p, rp = random_boolean(rng, atoms, 2)
    q, rq = random_boolean(rng, atoms, 2)
    window, excused = f"[{a}ns..{b}ns]", f"({rq} or (m >= 0.5))"
    if shape == "F0":
        return shape, f"always (F{window} {q})", f"eventually[{a}:{b}] {excused}", b
    stl = "eventually" if shape == "F" else "always"
    return shape, f"always ({p} -> {shape}{window} {q})", f"{rp} -> ({stl}[{a}:{b}] {excused})", b


def random_run(rng: random.Random, n: int) -> Run:
    stamp, out = rng.choice([0, 1000]) * MS, []
    for _ in range(n):
        stamp += rng.choice([1, 3, 5, 10, 20, 30]) * MS + rng.choice([0, 0, 1, -1])
        name = rng.choice("abx")
        value = float(rng.randrange(5)) if name == "x" else rng.random() < 0.5
        out.append((f"/{name}", stamp, value))
    return out


class Rtamt:
    """RTAMT's dense-time offline monitor of one formula over a run: ``changes(lo, hi)``
    is its (instant, truth) changes with Q excused outside [lo, hi) (the mask m)."""

    def __init__(self, spec: Any, run_: Run) -> None:
        self.spec = spec
        self.t0 = run_[0][1]
        held: dict[str, float] = {"a": 0.0, "b": 0.0, "x": 0.0}  # the initial values
        samples: dict[str, list[list[float]]] = {n: [] for n in held}
        for topic, stamp, value in run_:
            held[topic[1]] = float(value)
            for name, v in held.items():  # every signal's value from each instant on
                at = stamp - self.t0
                if samples[name] and samples[name][-1][0] == at:
                    samples[name][-1][1] = v
                elif not samples[name] or samples[name][-1][1] != v:
                    samples[name].append([at, v])
        self.samples = samples

    def changes(self, lo: int | None = None, hi: int | None = None) -> list[tuple[int, bool]]:
        if lo is None or hi is None:
            m = [[0, 0.0]]  # nothing excused
        else:
            lo, hi = max(lo - self.t0, 0), hi - self.t0
            if hi <= lo:
                m = [[0, 1.0]]  # everything excused
            else:
                m = [[0, 1.0], [lo, 0.0], [hi, 1.0]] if lo > 0 else [[0, 0.0], [hi, 1.0]]
        out = self.spec.evaluate(*([n, s] for n, s in self.samples.items()), ["m", m])
        changes: list[tuple[int, bool]] = []
        for t, rob in out:
            if not changes or changes[-1][1] != (rob > 0):
                changes.append((self.t0 + int(t), rob > 0))
        return changes

    def fails(self, lo: int, hi: int) -> bool:
        """Some obligation fails (with Q excused outside [lo, hi))."""
        return not all(v for _, v in self.changes(lo, hi))


def rtamt_spec(formula: str) -> Any:
    import rtamt

    spec = rtamt.StlDenseTimeSpecification()
    for name in ("a", "b", "x", "m"):
        spec.declare_var(name, "float")
    spec.spec = formula
    spec.parse()
    return spec


def edgerv_reset(m: CompiledMonitor, run_: Run, end: int) -> list[tuple[int, str | None]]:
    """(stamp, verdict or None) of each step edgerv takes over the run, onVerdict: reset."""
    rt = MonitorRuntime(m)
    index = {f"/{n}": i for i, n in enumerate(m.signal_names)}
    for seq, (topic, stamp, value) in enumerate(run_):
        rt.offer(stamp, seq, [(index[topic], value)])
    rt.advance(end)
    stamps = list(rt.stamps)
    decided = {v.step: v.verdict for v in rt.evaluate()}
    return [(t, decided.get(i + 1)) for i, t in enumerate(stamps)]


CASES = 120


@pytest.mark.parametrize("seed", range(CASES))
def test_bounded_future_verdicts_match_rtamt(seed: int) -> None:
    rng = random.Random(seed)
    shape, assertion, formula, b = random_case(rng)
    spec = rtamt_spec(formula)
    reset = compiled(assertion, SIGNALS)
    halt = compiled(assertion, SIGNALS, onVerdict="halt")
    for _ in range(3):
        run_ = random_run(rng, rng.choice([20, 30, 40]))
        end = run_[-1][1] + rng.choice([0, 30, 80]) * MS
        t0 = run_[0][1]
        monitor = Rtamt(spec, run_)
        decided = edgerv_reset(reset, run_, end)
        steps = [(t, v == "violated") for t, v in decided]
        stamps = [t for t, _ in steps]
        if shape in ("F", "F0"):
            whole = monitor.changes()  # the obligation of t, for every t of the run
            # edgerv at u: the obligation of u - b failed (none before the run started)
            expected = [(u, u - b >= t0 and not truth_at(whole, u - b)) for u in stamps]
            assert steps == expected, (assertion, run_, end)
            # where that changes: RTAMT's changes, and the first deadline if it failed
            moves = [t + b for t, _ in whole[1:]] + ([] if whole[0][1] else [t0 + b])
            missed = sorted({u for u in moves if t0 < u <= end} - set(stamps))
            assert not missed, (assertion, run_, end, missed)
        else:  # an obligation fails at s; or none from s to the next step
            for (s, violated), nxt in zip(steps, [*stamps[1:], end + 1], strict=True):
                if violated:
                    assert monitor.fails(s, s + 1), (assertion, run_, end, s)
                else:
                    assert not monitor.fails(s, nxt), (assertion, run_, end, s, nxt)
        # onVerdict: halt: one verdict, the reset run's first, where a failure became
        # certain: the run up to it (Q excused after it) fails an obligation, up to the
        # nanosecond before it does not (monotone: that instant is the first)
        (result,) = run([halt], events([*run_, ("/clock", end, 0)]))
        first = [(v, i + 1, t) for i, (t, v) in enumerate(decided) if v][:1]
        assert verdicts(result) == first, (assertion, run_, end)
        if shape in ("F", "F0"):  # the first failing obligation's t + b, if the run got there
            deadline = next((t + b for t, v in whole if not v), end + 1)
            assert [t for _, _, t in first] == ([deadline] if deadline <= end else [])
        if not first or first[0][0] == "satisfied":  # none by the end; or Q always holds
            limit = end if not first else end + 10**12
            assert not monitor.fails(t0, limit + 1), (assertion, run_, end)
        else:
            u = first[0][2]
            assert monitor.fails(t0, u + 1) and not monitor.fails(t0, u), (assertion, run_, end)


# -- points of definition: equal stamps, the end of the run -----------------------------------


def test_messages_at_one_stamp_are_steps_in_order() -> None:
    """edgerv steps once a message, also at one stamp (section 2): a value replaced at the
    same stamp still held at that instant, and each step there is judged with the messages
    up to it, so a deadline at a stamp is missed by a Q in a later message of that stamp.
    RTAMT has one value per signal and instant, the last: it says otherwise on both."""
    deadline = "always (a -> F[0ms..10ms] b)"
    f_formula = f"(a >= 0.5) -> (eventually[0:{10 * MS}] ((b >= 0.5) or (m >= 0.5)))"
    # b comes at the deadline, 110 ms, after a message on /x with the same stamp
    late = [("/a", 100 * MS, True), ("/a", 101 * MS, False), ("/x", 110 * MS, 1.0),
            ("/b", 110 * MS, True)]  # fmt: skip
    (result,) = run([compiled(deadline, SIGNALS)], events([*late, ("/clock", 300 * MS, 0)]))
    assert verdicts(result) == [("violated", 3, 110 * MS)]
    in_time = [late[0], late[1], late[3], late[2]]  # b first at 110 ms: in time
    (result,) = run([compiled(deadline, SIGNALS)], events([*in_time, ("/clock", 300 * MS, 0)]))
    assert verdicts(result) == []
    for run_ in (late, in_time):  # RTAMT: b holds at 110 ms, the obligation is met
        assert Rtamt(rtamt_spec(f_formula), run_).changes() == [(100 * MS, True)]
    # b true then false at 100 ms: it held then (edgerv), it did not (RTAMT)
    blink = [("/a", 95 * MS, True), ("/a", 96 * MS, False), ("/b", 100 * MS, True),
             ("/b", 100 * MS, False)]  # fmt: skip
    (result,) = run([compiled(deadline, SIGNALS)], events([*blink, ("/clock", 300 * MS, 0)]))
    assert verdicts(result) == []
    assert Rtamt(rtamt_spec(f_formula), blink).changes() == [(95 * MS, False), (96 * MS, True)]
    never = "always (a -> G[0ms..10ms] !b)"
    (result,) = run([compiled(never, SIGNALS)], events([*blink, ("/clock", 300 * MS, 0)]))
    assert verdicts(result) == [("violated", 3, 100 * MS)]
    g_formula = f"(a >= 0.5) -> (always[0:{10 * MS}] ((not (b >= 0.5)) or (m >= 0.5)))"
    assert Rtamt(rtamt_spec(g_formula), blink).changes() == [(95 * MS, True)]


def test_an_obligation_past_the_end_of_the_run_stays_pending() -> None:
    """A run that ends before a deadline decides nothing about it: edgerv leaves it
    pending, where RTAMT, whose signals keep their last values forever, says it fails."""
    deadline = "always (a -> F[0ms..500ms] b)"
    trace = [("/a", 1000 * MS, True), ("/a", 1100 * MS, False), ("/x", 1200 * MS, 1.0)]
    (result,) = run([compiled(deadline, SIGNALS)], events(trace))
    assert verdicts(result) == [] and result.state == "pending"
    formula = f"(a >= 0.5) -> (eventually[0:{500 * MS}] ((b >= 0.5) or (m >= 0.5)))"
    assert Rtamt(rtamt_spec(formula), trace).changes() == [
        (1000 * MS, False), (1100 * MS, True)]  # fmt: skip
    # once the run shows 1500 ms, the failure is certain there
    (result,) = run([compiled(deadline, SIGNALS)], events([*trace, ("/x", 1600 * MS, 2.0)]))
    assert verdicts(result) == [("violated", 4, 1500 * MS)]


# -- nested: F and G in any boolean combination, read their horizon late -----------------


def _top_and(stl: str) -> bool:
    """Is RTAMT formula ``(x and y)`` a conjunction at its top?"""
    depth = 0
    for i, ch in enumerate(stl):
        depth += {"(": 1, ")": -1}.get(ch, 0)
        if depth == 1 and stl.startswith(" and ", i):
            return True
    return False


def random_nested(rng: random.Random, depth: int) -> tuple[str, str, int]:
    """(edgerv, RTAMT, horizon) of a random formula nesting time-bounded F and G over
    boolean formulas of ``ATOMS`` (past operators among them)."""
    if depth == 0 or rng.random() < 0.25:
        e, r = random_boolean(rng, ATOMS, 1)
        return e, r, 0
    kind = rng.choice(["F", "G", "F", "G", "not", "and", "or"])
    e1, r1, h1 = random_nested(rng, depth - 1)
    if kind == "not":
        return f"(!{e1})", f"(not {r1})", h1
    if kind in ("and", "or"):
        e2, r2, h2 = random_nested(rng, depth - 1)
        word = "and" if kind == "and" else "or"
        return f"({e1} {'&' if kind == 'and' else '|'} {e2})", f"({r1} {word} {r2})", max(h1, h2)
    a = rng.choice([0, 0, 5, 10]) * MS + rng.choice([0, 0, 1])
    b = a + rng.choice([0, 5, 20, 40]) * MS + rng.choice([0, 0, 1])
    stl = "eventually" if kind == "F" else "always"
    return f"({kind}[{a}ns..{b}ns] {e1})", f"({stl}[{a}:{b}] {r1})", b + h1


@pytest.mark.parametrize("seed", range(60))
def test_nested_bounded_verdicts_match_rtamt(seed: int) -> None:
    """``always (f)``, f nesting F and G, read its horizon H late: with reset edgerv is
    violated at exactly the steps u at which RTAMT's f is false at u - H (none before the
    run is H old), and each instant at which that changes is one of edgerv's steps."""
    rng = random.Random(seed)
    formula, stl, h = random_nested(rng, 3)
    # two time-bounded operators at least, not in a conjunction at the top: one alone, or
    # a conjunct of always, takes the obligations' way (earlier; checked above)
    while formula.count("ns..") < 2 or _top_and(stl):
        formula, stl, h = random_nested(rng, 3)
    spec = rtamt_spec(stl)
    m = compiled(f"always ({formula})", SIGNALS)
    for _ in range(3):
        run_ = random_run(rng, rng.choice([20, 30, 40]))
        end = run_[-1][1] + rng.choice([0, 30, 80]) * MS
        t0 = run_[0][1]
        whole = Rtamt(spec, run_).changes()
        steps = [(t, v == "violated") for t, v in edgerv_reset(m, run_, end)]
        expected = [(u, u - h >= t0 and not truth_at(whole, u - h)) for u, _ in steps]
        assert steps == expected, (formula, run_, end)
        moves = [t + h for t, _ in whole[1:]] + ([] if whole[0][1] else [t0 + h])
        missed = sorted({u for u in moves if t0 < u <= end} - {u for u, _ in steps})
        assert not missed, (formula, run_, end, missed)
