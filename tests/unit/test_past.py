"""Past operators (docs/semantics.md, "Past"): untimed and timed, against Reelay.

Reelay's dense-time monitors (a test dependency, independent of edgerv) read the
same piecewise-constant signals and give each formula's truth over time. Random
past formulas over two signals, on random stamped runs: at every step edgerv takes
(each message, and each clock step) the formula's truth is Reelay's at that
instant, and every instant at which Reelay's truth changes is one of edgerv's
steps. ``prev``, which Reelay's dense monitors do not have, is checked against its
definition.
"""

from __future__ import annotations

import functools
import random
from collections.abc import Iterator
from typing import Any

import pytest
import spot

from edgerv.core.diagnostics import InputError
from edgerv.core.language.assertion import parse_assertion
from edgerv.core.pipeline import MonitorRuntime
from kit.checks import events, run, truth_at, verdicts
from kit.documents import compiled, spec_of
from kit.randomruns import random_mixed

MS = 1_000_000
BOOLS = {"a": {"topic": "/a", "type": "std_msgs/msg/Bool", "initial": False},
         "b": {"topic": "/b", "type": "std_msgs/msg/Bool", "initial": False}}  # fmt: skip


def error_of(assertion: str) -> str:
    with pytest.raises(InputError) as info:
        parse_assertion(spec_of(assertion, {"a": "bool", "b": "bool", "x": "float"}))
    return str(info.value)


@pytest.mark.parametrize(
    ("assertion", "expected"),
    [
        ("always (once[0..2] a)", "test.yaml:6:26: error: a past operator's interval counts time"),
        ("always (once[2s..1s] a)", "the interval [2s..1s] ends before it starts"),
        ("always (once[0..2q] a)", "bad interval [0..2q]: two durations"),
        ("always (once[1..2s] a)", "bad interval [1..2s]"),
        ("always (once (a U b))", "'once' needs a formula without future operators"),
        ("always (historically X a)", "'historically' needs a formula without future"),
        ("always (a since[0..2] b)", "a past operator's interval counts time"),
        ("always (once)", "'once' needs a formula"),
    ],
)
def test_bad_past_operators_are_reported_at_their_place(assertion: str, expected: str) -> None:
    message = error_of(assertion)
    assert expected in message, message
    assert "Traceback" not in message


def test_past_operators_become_placeholders_inner_first() -> None:
    """Numbered after the atoms, left to right, each after the ones in its operands."""
    m = compiled("always (once a -> b since (a & !historically b))", BOOLS)
    assert [(p.kind, p.bit, p.text) for p in m.past] == [
        ("once", 2, "once a"),
        ("historically", 3, "historically b"),
        ("since", 4, "b since (a & !historically b)"),
    ]
    assert m.parsed.formula == spot.formula("G(p2 -> p4)")


def test_historically_over_a_window_reads_the_value_held_into_it() -> None:
    """The door may open only if speed stayed under 0.1 for the last 2 s: a value
    published before the window holds into it."""
    m = compiled(
        "always (door -> historically[0..2s] (speed < 0.1))", {"door": "bool", "speed": "float"}
    )
    s = 10**9
    trace = [("/speed", 0, 0.5), ("/door", 0, False), ("/speed", 3 * s // 2, 0.05),
             ("/door", 3 * s, True), ("/door", 36 * s // 10, True)]  # fmt: skip
    (result,) = run([m], events(trace))
    # at 3 s the window [1 s, 3 s] holds 0.5 until 1.5 s; at 3.6 s it is all 0.05
    assert verdicts(result) == [("violated", 3, 3 * s)]


def test_prev_is_the_operand_at_the_step_before() -> None:
    m = compiled("always (prev a -> b)", BOOLS)
    trace = [("/a", 1, True), ("/b", 2, False), ("/a", 3, False), ("/b", 4, True)]
    (result,) = run([m], events(trace))
    # a held at steps 1 and 2 (its value at step 2 is still the one from step 1)
    assert verdicts(result) == [("violated", 2, 2), ("violated", 3, 3)]


# -- differential: Reelay's monitors ----------------------------------------------------------


@pytest.fixture(scope="module", autouse=True)
def reelay_inspects_a_pattern_once() -> Iterator[None]:
    """Each Reelay monitor (reelay.discrete_timed_monitor, dense_timed_monitor) first
    inspects its pattern, a parse of the text as long as building the monitor itself, to
    choose the kind to build; the tests below build each pattern four times, a run each.
    The inspection, a pure function of the text, is kept; every monitor is built anew."""
    from reelay import _pybind11_module as rym

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(rym, "inspect", functools.cache(rym.inspect))
        yield


def random_past(rng: random.Random, depth: int, timed: bool) -> tuple[str, str, int]:
    """(edgerv text, Reelay text, reach) of a random past formula over a and b: untimed
    operators (once, historically, since, prev), or timed once and historically; reach:
    how far back from a step its truth looks (0 for untimed ones, unused)."""
    if depth == 0 or rng.random() < 0.25:
        name = rng.choice("ab")
        return name, "{" + name + "}", 0
    kinds = ["not", "and", "or"] + (["once", "hist"] if timed else
                                    ["once", "hist", "since", "prev"])  # fmt: skip
    kind = rng.choice(kinds)
    e1, r1, reach1 = random_past(rng, depth - 1, timed)
    if kind in ("and", "or", "since"):
        e2, r2, reach2 = random_past(rng, depth - 1, timed)
        if kind == "or":  # Reelay 25's dense `or` loses segments: its De Morgan form
            reelay_or = f"(not ((not {r1}) and (not {r2})))" if timed else f"({r1} or {r2})"
            return f"({e1} | {e2})", reelay_or, max(reach1, reach2)
        op = {"and": ("&", "and"), "since": ("since", "since")}[kind]
        return f"({e1} {op[0]} {e2})", f"({r1} {op[1]} {r2})", max(reach1, reach2)
    if kind == "not":
        return f"(!{e1})", f"(not {r1})", reach1
    if kind == "prev":
        return f"(prev {e1})", f"(pre {r1})", reach1
    word = "once" if kind == "once" else "historically"
    if not timed:
        return f"({word} {e1})", f"({word} {r1})", reach1
    lo = rng.choice([0, 0, 10, 20]) * MS
    hi = lo + rng.choice([5, 20, 40]) * MS
    return f"({word}[{lo}ns..{hi}ns] {e1})", f"({word}[{lo}:{hi}] {r1})", reach1 + hi


def random_run(rng: random.Random, n: int, ties: bool) -> list[tuple[str, int, bool]]:
    stamp, out = 0, []
    for _ in range(n):
        stamp += rng.choice([0, 1, 3] if ties else [1, 3, 5, 10, 20, 30]) * MS + rng.choice([0, 1])
        out.append((rng.choice(["/a", "/b"]), stamp, rng.random() < 0.5))
    return out


def edgerv_steps(text: str, run_: list[tuple[str, int, bool]], end: int) -> list[tuple[int, bool]]:
    """(stamp, truth) of ``text`` at each step edgerv takes over the run (``always``
    reports each step where it is false)."""
    rt = MonitorRuntime(compiled(f"always {text}", BOOLS))
    rt.plain = False  # every step's letter kept, to be read (a plain one walks its own)
    for seq, (topic, stamp, value) in enumerate(run_):
        rt.offer(stamp, seq, [(0 if topic == "/a" else 1, value)])
    rt.advance(end)
    stamps = list(rt.stamps)
    violated = {v.step for v in rt.evaluate() if v.verdict == "violated"}
    return [(t, i + 1 not in violated) for i, t in enumerate(stamps)]


@pytest.mark.parametrize("seed", range(40))
def test_untimed_past_formulas_match_reelays_discrete_monitors(seed: int) -> None:
    """One step a message (ties included): Reelay's discrete monitors, one update a step."""
    import reelay

    rng = random.Random(seed)
    text, pattern, _ = random_past(rng, 3, timed=False)
    for _ in range(4):
        run_ = random_run(rng, 30, ties=True)
        monitor = reelay.discrete_timed_monitor(pattern=pattern, condense=False)
        held, expected = {"a": False, "b": False}, []
        for topic, stamp, value in run_:
            held[topic[1]] = value
            expected.append((stamp, bool(monitor.update(dict(held))["value"])))
        assert edgerv_steps(text, run_, run_[-1][1]) == expected, (text, run_)


def reelay_dense(
    pattern: str, run_: list[tuple[str, int, bool]], end: int
) -> list[tuple[int, bool]]:
    """Reelay's (instant, truth from then on) changes of the formula over the run.

    Reelay's time starts at 0 and each update gives the values from then on: the run
    is shifted so that its first message is at 0 (edgerv's first step)."""
    import reelay

    monitor = reelay.dense_timed_monitor(pattern=pattern)
    held = {"a": False, "b": False}
    changes: list[tuple[int, bool]] = []
    t0 = run_[0][1]
    # the last update, after the end, changes a value: Reelay reports a segment once a
    # change ends it
    for topic, stamp, value in [*run_, ("/a", end + 1, not held_last(run_, "/a"))]:
        held[topic[1]] = value
        for rec in monitor.update({"time": stamp - t0, **held}):
            if not changes or changes[-1][1] != rec["value"]:
                changes.append((t0 + int(rec["time"]), bool(rec["value"])))
    return changes


def held_last(run_: list[tuple[str, int, bool]], topic: str) -> bool:
    return next((v for t, _, v in reversed(run_) if t == topic), False)


def reelay_safe(rng: random.Random, depth: int) -> tuple[str, str, int]:
    """A timed formula Reelay's dense monitors evaluate right: timed operators nested
    over boolean combinations of the signals (Reelay 25 loses segments when a boolean
    connective combines a timed operator's output: see the test below)."""
    if depth == 0 or rng.random() < 0.3:
        e, r, _ = random_past(rng, 2, timed=False)
        while "once" in e or "historically" in e or "since" in e or "prev" in e:
            e, r, _ = random_past(rng, 2, timed=False)
        return e, r, 0
    e1, r1, reach = reelay_safe(rng, depth - 1)
    if rng.random() < 0.2:
        return f"(!{e1})", f"(not {r1})", reach
    word = rng.choice(["once", "historically"])  # not since[..]: see the test below
    lo = rng.choice([0, 0, 10, 20]) * MS
    hi = lo + rng.choice([5, 20, 40]) * MS
    return f"({word}[{lo}ns..{hi}ns] {e1})", f"({word}[{lo}:{hi}] {r1})", reach + hi


@pytest.mark.parametrize("seed", range(40))
def test_timed_past_formulas_match_reelays_dense_monitors(seed: int) -> None:
    """Signals held between messages, time windows: Reelay's dense monitors. Compared
    from the instant the formula's windows no longer reach before the run's first
    message (before it, Reelay takes each signal's first value, edgerv nothing)."""
    rng = random.Random(seed)
    text, pattern, reach = reelay_safe(rng, 3)
    for _ in range(4):
        run_ = random_run(rng, 40, ties=False)
        end = run_[-1][1] + rng.choice([0, 30, 80]) * MS
        changes = reelay_dense(pattern, run_, end)
        start = run_[0][1] + reach
        got = [(t, v) for t, v in edgerv_steps(text, run_, end) if t >= start]
        assert got == [(t, truth_at(changes, t)) for t, _ in got], (text, run_, end)
        stamps = {t for t, _ in got}
        missed = [t for t, _ in changes if start < t <= end and t not in stamps]
        assert not missed, (text, missed)


def test_reelays_dense_or_loses_what_its_de_morgan_dual_keeps() -> None:
    """Why the Reelay comparison keeps boolean connectives below the timed operators:
    b is false from 403 to 406 and a from 426.5 to 456, so `historically[0:40] b` is
    false until 446 and `(historically[0:40] b) or a` is false from 426.5 to 446, as
    edgerv says. Reelay 25's dense monitor says true throughout; its De Morgan dual,
    `(not historically[0:40] b) and (not a)`, does report that segment."""
    import reelay

    seq = [(0, True, True), (403, True, False), (406, True, True), (426.5, False, True),
           (456, True, True), (500, False, True)]  # fmt: skip

    def segments(pattern: str) -> list[tuple[float, bool]]:
        monitor = reelay.dense_timed_monitor(pattern=pattern)
        out = []
        for t, a, b in seq:
            out += [(r["time"], r["value"]) for r in monitor.update({"time": t, "a": a, "b": b})]
        return out

    assert segments("(historically[0:40] {b}) or {a}") == [(0.0, True)]  # not the definition
    assert segments("(not (historically[0:40] {b})) and (not {a})") == [
        (0.0, False), (426.5, True), (446.0, False)]  # fmt: skip
    run_ = [("/a", 0, True), ("/b", 0, True), ("/b", 403 * MS, False),
            ("/b", 406 * MS, True), ("/a", 4265 * MS // 10, False), ("/a", 456 * MS, True),
            ("/a", 500 * MS, False)]  # fmt: skip
    got = edgerv_steps("((historically[0ms..40ms] b) | a)", run_, 500 * MS)
    assert [(t / MS, v) for t, v in got if 400 * MS < t < 460 * MS] == [
        (403.0, True), (406.0, True), (426.5, False), (446.0, True), (456.0, True)]  # fmt: skip


def test_reelays_dense_since_differs_at_two_boundaries() -> None:
    """`f since[lo..hi] g` at t: some instant s of [t - hi, t - lo] where g held, and f
    at every instant of (s, t] (docs/semantics.md, "Past"). Two boundary points where
    Reelay 25's dense monitor answers otherwise, which is why its differential test
    leaves `since[..]` out (the brute-force definition below covers it):

    * the present instant is a witness: with lo = 0, f since[0..hi] g holds wherever
      g does, as the untimed `f since g` does at a step where g holds (Reelay's dense
      since needs f too);
    * a value holds from its message to the next one, that one excluded: where g
      stops exactly as f starts, no instant of g has f at every instant after it
      (Reelay's dense since counts the junction)."""
    import reelay

    def both(
        text: str, pattern: str, run_: list[tuple[str, int, bool]], t: int
    ) -> tuple[bool, bool]:
        end = run_[-1][1] + 50 * MS
        ours = dict(edgerv_steps(text, run_, end))
        return ours[t], truth_at(reelay_dense(pattern, run_, end), t)

    assert reelay  # a test dependency: its dense monitors, through reelay_dense
    present = [("/a", 0, False), ("/b", 1 * MS, False), ("/b", 2 * MS, True)]
    assert both("(a since[0ns..5000000ns] b)", "({a} since[0:5000000] {b})", present, 2 * MS) == (
        True,
        False,
    )
    assert dict(edgerv_steps("(a since b)", present, 3 * MS))[2 * MS] is True
    # g = b & !a holds from 10 ms until a starts at 20 ms, f = a from then on
    junction = [
        ("/a", 0, False),
        ("/b", 10 * MS, True),
        ("/a", 20 * MS, True),
        ("/a", 30 * MS, True),
    ]
    text = "(a since[5000000ns..30000000ns] (b & (!a)))"
    pattern = "({a} since[5000000:30000000] ({b} and (not {a})))"
    assert both(text, pattern, junction, 30 * MS) == (False, True)
    assert Definition(text).steps(junction, 30 * MS)[-1] == (30 * MS, False)


# -- differential: the definition, step by step ---------------------------------------------


class Definition:
    """A formula's truth straight from docs/semantics.md, by brute force: each step's
    letter holds from its instant to the next step; ``once[lo..hi] f`` at t asks
    whether f held at some instant of [t - hi, t - lo] (after the first step), looking
    at every step's whole interval; ``since`` and ``prev`` look at the steps before.
    A clock step is taken at each instant where a timed operator's truth changes with
    every operand held since the last step (time alone); there everything is
    evaluated anew, as at any step. The instants tried are every message time plus
    every sum of window bounds (and one nanosecond more)."""

    def __init__(self, text: str) -> None:
        self.tree = _parse(text)

    def steps(self, run_: list[tuple[str, int, bool]], end: int) -> list[tuple[int, bool]]:
        nodes = _nodes(self.tree)
        offsets = {0}
        for node in nodes:
            if node[0] in ("once_t", "hist_t", "since_t"):
                offsets = offsets | {o + d for o in offsets for d in (node[1], node[2])}
        # instants to try: each message's, and each step's (a clock step's too: a `prev`
        # read at it can start a window) plus every sum of window bounds, and 1 ns more
        tries = {s for _, s, _ in run_}
        held = {"a": False, "b": False}
        history: list[tuple[int, dict[int, bool]]] = []  # (instant, every node's truth)
        out: list[tuple[int, bool]] = []
        events = list(run_)
        i = 0
        while tries:
            t = min(tries)
            tries.discard(t)
            if t > end:
                break
            if t < run_[0][1]:
                continue
            took = False
            while i < len(events) and events[i][1] == t:  # each message is a step
                held[events[i][0][1]] = events[i][2]
                values = self._values(t, held, history)
                history.append((t, values))
                out.append((t, values[id(self.tree)]))
                i += 1
                took = True
            if not took and history and self._time_changes(t, nodes, history):  # a clock step
                values = self._values(t, held, history)
                history.append((t, values))
                out.append((t, values[id(self.tree)]))
                took = True
            if took:
                tries |= {t + o + d for o in offsets if o for d in (0, 1)}
        return out

    @staticmethod
    def _window(n: Any, t: int, spans: list[tuple[int, bool]]) -> bool:
        """once/historically[lo..hi] at t over (instant, operand) spans, each lasting
        until the next one (the last: until t)."""
        lo, hi = n[1], n[2]
        seen = []
        for k, (s, val) in enumerate(spans):
            stop = spans[k + 1][0] if k + 1 < len(spans) else None
            if s <= t - lo and (stop is None or stop > t - hi):
                seen.append(val)
        return any(seen) if n[0] == "once_t" else all(seen)

    @staticmethod
    def _since(n: Any, t: int, spans: list[tuple[int, bool, bool]]) -> bool:
        """f since[lo..hi] g at t over (instant, f, g) spans, each lasting until the next
        one (the last: until t, included): some instant s of [t - hi, t - lo] where g
        held, and f at every instant of (s, t]."""
        lo, hi = n[1], n[2]
        for k, (s, f, g) in enumerate(spans):
            if not g:
                continue
            if k == len(spans) - 1:  # s in [start, t]; s = t needs no f after it
                if lo == 0 or (f and s <= t - lo):
                    return True
            elif s <= t - lo and spans[k + 1][0] > t - hi and all(x[1] for x in spans[k:]):
                return True
        return False

    def _time_changes(self, t: int, nodes: list[Any], history: list[Any]) -> bool:
        last = history[-1][1]
        for n in nodes:
            if n[0] in ("once_t", "hist_t"):
                spans = [(s, h[id(n[3])]) for s, h in history]  # the operand held since
                if self._window(n, t, spans) != last[id(n)]:
                    return True
            if n[0] == "since_t":
                fg = [(s, h[id(n[3])], h[id(n[4])]) for s, h in history]
                if self._since(n, t, [*fg, (t, fg[-1][1], fg[-1][2])]) != last[id(n)]:
                    return True
        return False

    def _values(self, t: int, held: dict[str, bool], history: list[Any]) -> dict[int, bool]:
        values: dict[int, bool] = {}

        def ev(n: Any) -> bool:
            kind = n[0]
            if kind == "sig":
                v = held[n[1]]
            elif kind == "not":
                v = not ev(n[1])
            elif kind in ("and", "or"):
                x, y = ev(n[1]), ev(n[2])
                v = (x and y) if kind == "and" else (x or y)
            elif kind == "prev":
                ev(n[1])
                v = history[-1][1][id(n[1])] if history else False
            elif kind in ("once", "hist"):
                now = ev(n[1])
                past = [h[id(n[1])] for _, h in history]
                v = any([*past, now]) if kind == "once" else all([*past, now])
            elif kind == "since":
                f, g = ev(n[1]), ev(n[2])
                before = history[-1][1][id(n)] if history else False
                v = g or (f and before)
            elif kind == "since_t":
                f, g = ev(n[3]), ev(n[4])
                fg = [(s, h[id(n[3])], h[id(n[4])]) for s, h in history]
                v = self._since(n, t, [*fg, (t, f, g)])
            else:  # once_t / hist_t: [lo, hi] back, each step's value over its interval
                now = ev(n[3])
                v = self._window(n, t, [(s, h[id(n[3])]) for s, h in history] + [(t, now)])
            values[id(n)] = v
            return v

        ev(self.tree)
        return values


def _parse(text: str) -> Any:
    """The random formulas' own grammar (fully parenthesized) as a tree."""
    tokens = text.replace("(", " ( ").replace(")", " ) ").split()
    pos = 0

    def expr() -> Any:
        nonlocal pos
        tok = tokens[pos]
        pos += 1
        if tok in ("a", "b"):
            return ("sig", tok)
        assert tok == "("
        head = tokens[pos]
        if head.startswith("!"):
            if head == "!":
                tokens.pop(pos)
            else:
                tokens[pos] = head[1:]
            node: Any = ("not", expr())
        elif head in ("prev", "once", "historically") or head.startswith(
            ("once[", "historically[")
        ):
            pos += 1
            if "[" in head:
                lo, hi = (int(x[:-2]) for x in head[head.index("[") + 1 : -1].split(".."))
                node = ("once_t" if head.startswith("once") else "hist_t", lo, hi, expr())
            else:
                node = ({"prev": "prev", "once": "once", "historically": "hist"}[head], expr())
        else:
            left = expr()
            op = tokens[pos]
            pos += 1
            if op.startswith("since["):
                lo, hi = (int(x[:-2]) for x in op[6:-1].split(".."))
                node = ("since_t", lo, hi, left, expr())
            else:
                node = ({"&": "and", "|": "or", "since": "since"}[op], left, expr())
        assert tokens[pos] == ")"
        pos += 1
        return node

    return expr()


def _nodes(tree: Any) -> list[Any]:
    out = [tree]
    for child in tree[1:]:
        if isinstance(child, tuple):
            out += _nodes(child)
    return out


@pytest.mark.parametrize("seed", range(40))
def test_mixed_past_formulas_match_the_definition(seed: int) -> None:
    rng = random.Random(seed)
    text = random_mixed(rng, 3)
    definition = Definition(text)
    for _ in range(3):
        run_ = random_run(rng, 25, ties=False)
        end = run_[-1][1] + rng.choice([0, 30, 80]) * MS
        assert edgerv_steps(text, run_, end) == definition.steps(run_, end), (text, run_, end)


def test_a_timed_since_state_moves_and_a_malformed_one_is_refused() -> None:
    m = compiled("always (a since[0ns..5ns] b)", BOOLS)
    rt = MonitorRuntime(m)
    assert rt.past is not None
    rt.past.step(10, 0b10)  # b now, a not: the present instant is a witness
    saved = rt.past.save()
    assert saved == [{"runs": [], "live": False, "g": True}]
    rt.past.load(saved)
    for bad in ([{"runs": [], "live": "yes", "g": True}], [[[1, None]]], [{"live": True}]):
        with pytest.raises((ValueError, TypeError)):
            rt.past.load(bad)
