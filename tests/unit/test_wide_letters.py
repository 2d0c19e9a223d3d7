"""Assertions over more than 16 placeholders (docs/semantics.md, "Wide letters").

The automaton reads one placeholder per maximal boolean subformula under its temporal
operators, computed at each step from the atoms and past operators (a letter of up to
63 bits); the verdicts must be those of the assertion itself. The references share
nothing with that abstraction: Spot's monitors of the unabstracted formula over the
atoms' own truth values (computed here from the run), and the dense-time brute force of
tests/kit/dense.py for past and time-bounded operators. Offline (one event at a time, a
check's chunks, columns), live (Engine.ingest) and across a snapshot's wire form.
"""

from __future__ import annotations

import random
from typing import Any

import numpy as np
import pytest
import spot
from spot import buddy

from edgerv.core.checker import CheckRun
from edgerv.core.diagnostics import InputError, Location
from edgerv.core.handoff import decode, encode
from edgerv.core.language.past import BoolProgram
from edgerv.core.monitor import CompiledMonitor
from edgerv.core.pipeline import MonitorRuntime
from edgerv.core.traces import EventChunk, TraceEvent
from kit.checks import events, run, verdicts
from kit.counts import scaled
from kit.dense import Formula, evaluator, horizon, text
from kit.documents import compiled
from kit.engines import ManualClock

MS = 1_000_000


def bools(n: int, initial: bool | None = False) -> dict[str, Any]:
    """``n`` bool signals a0..a<n-1>, each on a topic of its own."""
    extra = {} if initial is None else {"initial": initial}
    return {f"a{i}": {"topic": f"/a{i}", "type": "std_msgs/msg/Bool", **extra} for i in range(n)}


def disjunction(names: list[str]) -> str:
    return " | ".join(names)


# -- the reference: Spot's monitors of the unabstracted formula -------------------------------


class _Live:
    """A Büchi automaton of a formula (Spot's, nondeterministic) and the states from which
    it accepts some word (emptiness checked from each one): a prefix is bad when no run on
    it is in such a state. Letters are BDD cubes over the atoms: no alphabet enumerated,
    no table, no abstraction."""

    def __init__(self, f: Any) -> None:
        self.aut = aut = spot.translate(f, "Buchi", "state-based")
        self.live = set()
        for s in range(aut.num_states()):
            copy = spot.make_twa_graph(aut, spot.twa_prop_set.all())
            copy.set_init_state(s)
            if not copy.is_empty():
                self.live.add(s)
        self.dict = aut.get_dict()

    def start(self) -> frozenset[int]:
        init = self.aut.get_init_state_number()
        return frozenset({init} & self.live)

    def step(self, states: frozenset[int], letter: dict[str, bool]) -> frozenset[int]:
        cube = buddy.bddtrue
        for ap in self.aut.ap():
            var = self.dict.varnum(ap)
            cube &= buddy.bdd_ithvar(var) if letter[ap.ap_name()] else buddy.bdd_nithvar(var)
        return frozenset(
            e.dst
            for s in states
            for e in self.aut.out(s)
            if e.dst in self.live and (e.cond & cube) != buddy.bddfalse
        )


class SpotReference:
    """LTL3 verdicts of a formula over named atoms, with reset (tests/kit/reference.py's
    construction, its letters as BDD cubes: 2^40 letters are not enumerated)."""

    def __init__(self, formula: str) -> None:
        f = spot.formula(formula)
        self.pos, self.neg = _Live(f), _Live(spot.formula.Not(f))

    def run(self, letters: list[dict[str, bool]]) -> list[tuple[str, int]]:
        out = []
        p, n = self.pos.start(), self.neg.start()
        for step, letter in enumerate(letters, 1):
            p, n = self.pos.step(p, letter), self.neg.step(n, letter)
            verdict = "violated" if not p else "satisfied" if not n else None
            if verdict:
                out.append((verdict, step))
                p, n = self.pos.start(), self.neg.start()
        return out


def random_bool(rng: random.Random, names: list[str], depth: int) -> str:
    """A boolean formula over ``names``, wide: a few literals up to all of them."""
    if depth == 0 or rng.random() < 0.3:
        picked = rng.sample(names, rng.randint(1, min(len(names), 12)))
        lits = [f"!{n}" if rng.random() < 0.3 else n for n in picked]
        return "(" + (" | " if rng.random() < 0.5 else " & ").join(lits) + ")"
    op = rng.choice(["&", "|", "->", "<->", "xor"])
    return f"({random_bool(rng, names, depth - 1)} {op} {random_bool(rng, names, depth - 1)})"


def random_ltl(rng: random.Random, names: list[str], depth: int) -> str:
    if depth == 0:
        return random_bool(rng, names, 1)
    kind = rng.choice(["X", "F", "G", "U", "W", "R", "&", "|", "!", "b"])
    a = random_ltl(rng, names, depth - 1)
    if kind in ("X", "F", "G", "!"):
        return f"{kind}({a})"
    if kind == "b":
        return random_bool(rng, names, 2)
    return f"({a}) {kind} ({random_ltl(rng, names, depth - 1)})"


def bool_run(rng: random.Random, n: int, count: int) -> list[tuple[str, int, bool]]:
    """``count`` messages on random topics of a0..a<n-1>, 1 ms apart (all start false)."""
    return [(f"/a{rng.randrange(n)}", (i + 1) * MS, rng.random() < 0.35) for i in range(count)]


def atom_letters(rows: list[tuple[str, int, bool]], n: int) -> list[dict[str, bool]]:
    """Each step's truth of a0..a<n-1>, straight from the messages."""
    held = {f"a{i}": False for i in range(n)}
    out = []
    for topic, _, value in rows:
        held[topic[1:]] = value
        out.append(dict(held))
    return out


# -- the example -----------------------------------------------------------------------


def test_eighteen_signals_under_one_implication_are_one_placeholder() -> None:
    """``always (a0 -> (a1 | ... | a17))``: 18 atoms, refused before; its automaton reads one
    placeholder (the whole body), the letter holds 19 bits."""
    body = f"a0 -> ({disjunction([f'a{i}' for i in range(1, 18)])})"
    m = compiled(f"always ({body})", bools(18))
    assert (m.table.bits, m.table.live, m.letter_bits, m.shift) == (1, 1, 19, 18)
    rows = [
        ("/a0", MS, True),
        ("/a5", 2 * MS, True),
        ("/a5", 3 * MS, False),
        ("/a0", 4 * MS, False),
    ]
    (result,) = run([m], events(rows))
    assert [(v, stamp) for v, _, stamp in verdicts(result)] == [
        ("violated", MS),
        ("violated", 3 * MS),
    ]


# -- untimed LTL over 17 to 40 atoms, against Spot on the unabstracted formula -----------------


def wide_ltl(seed: int) -> tuple[str, int]:
    rng = random.Random(seed)
    n = rng.randint(17, 40)
    names = [f"a{i}" for i in range(n)]
    while True:
        f = random_ltl(rng, names, rng.randint(1, 3))
        used = {ap.ap_name() for ap in spot.atomic_prop_collect(spot.formula(f))}
        if len(used) > 16:
            return f, n


@pytest.mark.parametrize("seed", range(scaled(12)))
def test_wide_ltl_verdicts_are_spots_on_the_unabstracted_formula(seed: int) -> None:
    formula, n = wide_ltl(seed)
    try:
        m = compiled(formula, bools(n))
    except InputError as exc:  # more than 16 boolean subformulas: refused, and located
        (error,) = exc.errors
        assert "at most 16 are supported" in error.message and error.location.line
        return
    assert m.derived is not None and m.table.bits <= 16
    rng = random.Random(seed)
    rows = bool_run(rng, n, rng.randint(20, 120))
    (result,) = run([m], events(rows))
    expected = SpotReference(formula).run(atom_letters(rows, n))
    assert [(v, step) for v, step, _ in verdicts(result)] == expected, formula


# -- past and time-bounded operators, against the dense-time brute force -----------------------


def wide_atoms(rng: random.Random, names: list[str]) -> Formula:
    """A disjunction or conjunction of many atoms (negated some)."""
    picked = rng.sample(names, rng.randint(17, len(names)))
    f: Formula = ("atom", picked[0])
    for name in picked[1:]:
        atom: Formula = ("atom", name) if rng.random() < 0.7 else ("not", ("atom", name))
        f = (rng.choice(["or", "or", "and"]), f, atom)
    return f


def wide_body(seed: int) -> tuple[Formula, int]:
    """``wide | nested`` or ``wide -> once[..] (wide)``...: two time-bounded or past
    operators at least, over many atoms."""
    rng = random.Random(seed)
    n = rng.randint(17, 30)
    names = [f"a{i}" for i in range(n)]
    lo = rng.randint(0, 2)
    hi = lo + rng.randint(0, 3)
    shape = seed % 4
    if shape == 0:  # a deadline over a wide answer, beside a wide disjunction, read late
        inner: Formula = ("F", lo, hi, wide_atoms(rng, names))
        return ("or", wide_atoms(rng, names), ("G", 0, 2, inner)), n
    if shape == 1:  # a timed past operator over a wide operand
        return ("or", ("not", ("atom", "a0")), ("once", lo, hi, wide_atoms(rng, names))), n
    if shape == 2:  # untimed since over wide operands
        return ("since", 0, None, wide_atoms(rng, names), wide_atoms(rng, names)), n
    return (
        "or",
        ("historically", lo, hi, wide_atoms(rng, names)),
        ("F", lo, hi, ("G", 0, 1, wide_atoms(rng, names))),
    ), n


def dense_run(rng: random.Random, n: int, end: int) -> list[tuple[str, int, bool]]:
    """Every signal at 0, then a change now and then (one message a stamp), one at ``end``."""
    rows = [(f"/a{i}", 0, rng.random() < 0.5) for i in range(n)]
    rows += [
        (f"/a{rng.randrange(n)}", t, rng.random() < 0.5)
        for t in range(1, end)
        if rng.random() < 0.5
    ]
    rows.append((f"/a{rng.randrange(n)}", end, rng.random() < 0.5))
    return rows


@pytest.mark.parametrize("seed", range(scaled(12)))
def test_wide_past_and_timed_verdicts_are_the_dense_reference(seed: int) -> None:
    """Under ``always``: a body with time-bounded operators is violated its horizon after
    its first failure; a past one at its first failure (halt: the first verdict)."""
    body, n = wide_body(seed)
    h = horizon(body)
    rng = random.Random(seed)
    m = compiled(f"always ({text(body)})", bools(n, initial=None), onVerdict="halt")
    assert m.derived is not None
    for _ in range(2):
        end = rng.randint(h + 2, 20)
        rows = dense_run(rng, n, end)
        at = evaluator(rows)
        failures = [t for t in range(0, end - h + 1) if not at(body, t)]
        expected = [("violated", failures[0] + h)] if failures else []
        (result,) = run([m], events(rows))
        got = [(v, stamp) for v, _, stamp in verdicts(result)]
        assert got == expected, (text(body), rows)


# -- every path: chunks, columns, the live engine, a snapshot -----------------------------------


def wide_assertions() -> list[str]:
    names = [f"a{i}" for i in range(24)]
    many = disjunction(names[4:])
    return [
        f"always (a0 -> ({many}))",
        f"always (a0 -> X ({many})) & G (a1 -> F (a2 & !a3))",
        f"always ((a0 & a1) -> once[0..3ms] ({many}))",
        f"always (a0 -> F[0..5ms] ({many}))",
        f"always ((a1 since ({many})) | !a0)",
    ]


def wide_events(rng: random.Random, count: int) -> list[TraceEvent]:
    out, stamp = [], 0
    for i in range(count):
        stamp += rng.choice([1, MS, 2 * MS, 7 * MS])
        topic = f"/a{rng.choice([0, 0, 1, 2, 3, *range(4, 24)])}"
        value = rng.random() < (0.6 if topic in ("/a0", "/a1") else 0.08)
        out.append(TraceEvent(topic, stamp, {"data": value}, Location("t", i + 1)))
    return out


def column_chunk(evs: list[TraceEvent], first: int) -> EventChunk:
    cols: dict[str, tuple[Any, list[Any]]] = {}
    for topic in sorted({e.topic for e in evs}):
        at = [i for i, e in enumerate(evs) if e.topic == topic]
        data = np.array([evs[i].msg["data"] for i in at], dtype=bool)
        cols[topic] = (np.array(at, np.int64), [data])
    stamps = np.array([e.stamp for e in evs], np.int64)
    return EventChunk("t", stamps=stamps, columns=cols, first=first)


def outcome(result: Any) -> list[tuple[str, int, int]]:
    return [(v.verdict, v.stamp, v.step) for v in result.verdicts]


@pytest.mark.parametrize("index", range(len(wide_assertions())))
def test_every_path_gives_what_one_event_at_a_time_gives(index: int) -> None:
    """Column chunks (the MCAP path, vectorized placeholders), a JSON trace's chunks,
    and the live engine's ingest, against one event at a time; and a snapshot taken
    halfway, through its wire form, restored, gives the rest of the same verdicts."""
    assertion = wide_assertions()[index]
    m = compiled(assertion, bools(24))
    assert m.derived is not None
    rng = random.Random(index)
    evs = wide_events(rng, 600)
    end = evs[-1].stamp

    single = CheckRun([m])
    single._feed_events(evs)
    (expected,) = single.finish(end)

    columns = CheckRun([m])
    for k in range(0, len(evs), 150):
        columns.feed_chunk(column_chunk(evs[k : k + 150], k + 1))
    (got,) = columns.finish(end)
    assert outcome(got) == outcome(expected)

    (chunked,) = run([m], evs)
    assert outcome(chunked) == outcome(expected)

    assert live(m, evs) == [(v, s) for v, s, _ in outcome(expected)]
    assert handed_off(m, evs) == [(v, s) for v, s, _ in outcome(expected)]


def test_the_column_path_is_taken_and_gives_the_scalar_letters() -> None:
    """columns.compress, for a wide monitor, computes its derived placeholders over the
    columns: the same letters as the scalar path, bit for bit."""
    from edgerv.core import columns

    m = compiled(wide_assertions()[1], bools(24))
    evs = wide_events(random.Random(5), 400)
    scalar, by_columns = CheckRun([m]), CheckRun([m])
    scalar._feed_events(evs)
    made: list[Any] = []
    real = columns.compress

    def spy(*args: Any) -> Any:
        got = real(*args)
        made.append(got)
        return got

    columns.compress = spy  # type: ignore[assignment]
    try:
        for k in range(0, 400, 100):
            by_columns.feed_chunk(column_chunk(evs[k : k + 100], k + 1))
    finally:
        columns.compress = real  # type: ignore[assignment]
    assert len(made) == 4 and all(got is not None for got in made)
    (a,), (b,) = scalar.router.runtimes.values(), by_columns.router.runtimes.values()
    assert [int(x) for got in made for x in got.letters] == list(a.letters)
    assert a.valuation == b.valuation and a.valuation >> m.shift


def live(m: CompiledMonitor, evs: list[TraceEvent]) -> list[tuple[str, int]]:
    """The verdicts of the live engine's per-message path: Engine.ingest in batches of
    field values (as the CDR reader gives them), a scheduler round after each."""
    from edgerv.handler.engine import Engine

    engine = Engine("edge", flush_after=3600.0, clock=ManualClock())
    engine.put(m, active=True)
    out: list[Any] = []
    for k in range(0, len(evs), 37):
        engine.ingest([(e.stamp, e.topic, [e.msg["data"]]) for e in evs[k : k + 37]])
        out += engine.evaluate()
    engine.drain()
    out += engine.evaluate()
    return [(v.verdict, v.stamp) for v in out]


def handed_off(m: CompiledMonitor, evs: list[TraceEvent]) -> list[tuple[str, int]]:
    """One event at a time; halfway, a snapshot through its wire form (encode, decode)
    restored into a new runtime, which takes the rest."""
    rt = MonitorRuntime(m)
    out: list[tuple[str, int]] = []
    half = len(evs) // 2
    index = {n: i for i, n in enumerate(m.signal_names)}
    for e in evs[:half]:
        rt.offer(e.stamp, 0, [(index[e.topic[1:]], e.msg["data"])])
        if rt.step % 3 == 0:  # leave letters unevaluated at the cut, now and then
            out += [(v.verdict, v.stamp) for v in rt.evaluate()]
    snap = rt.snapshot(evs[half - 1].stamp, 1)
    assert snap.wide == m.letter_bits and snap.bits == m.table.bits
    back = decode(encode(snap))
    assert back == snap
    rt = MonitorRuntime.restored(m, back, [])
    for e in evs[half:]:
        rt.offer(e.stamp, 0, [(index[e.topic[1:]], e.msg["data"])])
    out += [(v.verdict, v.stamp) for v in rt.evaluate()]
    if rt.clock is not None:
        rt.advance(evs[-1].stamp)
        out += [(v.verdict, v.stamp) for v in rt.evaluate()]
    return out


# -- the limits ----------------------------------------------------------------------------------


def test_more_atoms_than_a_letter_holds_are_refused_at_the_first_one_past_it() -> None:
    names = [f"a{i}" for i in range(70)]
    assertion = f"always (a0 -> ({disjunction(names[1:])}))"
    with pytest.raises(InputError) as info:
        compiled(assertion, bools(70))
    (error,) = info.value.errors
    assert "more than 61 distinct atoms" in error.message
    where = error.location
    assert where.source_line[where.col - 1 : where.col - 1 + where.length] == "a61"


def test_an_automaton_reading_more_than_16_subformulas_is_refused() -> None:
    """Nine independent responses: eighteen boolean operands under temporal operators, each
    one a placeholder of the automaton's letter (2^18 columns)."""
    parts = [f"G (a{2 * i} -> X a{2 * i + 1})" for i in range(9)]
    with pytest.raises(InputError) as info:
        compiled(" & ".join(parts), bools(18))
    (error,) = info.value.errors
    assert "the automaton reads 18 boolean subformulas" in error.message
    assert "at most 16" in error.message


def test_bool_programs_are_their_formula_on_every_letter() -> None:
    """BoolProgram (scalar and columns) against Spot's own evaluation, over 20 bits."""
    rng = random.Random(3)
    names = [f"p{i}" for i in range(20)]
    for _ in range(30):
        f = spot.formula(random_bool(rng, names, 3))
        program = BoolProgram(f)
        letters = [rng.getrandbits(20) for _ in range(64)]
        truths = program.columns(np.array(letters, np.int64)).tolist()
        for letter, column_truth in zip(letters, truths, strict=True):
            direct = _evaluate(f, letter)
            assert program(letter) == direct == column_truth, (str(f), letter)


def _evaluate(f: Any, letter: int) -> bool:
    k = f.kind()
    if k == spot.op_ap:
        return bool(letter >> int(f.ap_name()[1:]) & 1)
    if k == spot.op_tt:
        return True
    if k == spot.op_ff:
        return False
    kids = [_evaluate(g, letter) for g in f]
    if k == spot.op_Not:
        return not kids[0]
    if k == spot.op_And:
        return all(kids)
    if k == spot.op_Or:
        return any(kids)
    if k == spot.op_Xor:
        return kids[0] != kids[1]
    if k == spot.op_Implies:
        return not kids[0] or kids[1]
    if k == spot.op_Equiv:
        return kids[0] == kids[1]
    raise AssertionError(str(f))


def test_a_past_operator_past_a_letters_width_is_refused_at_its_place() -> None:
    """61 atoms and once take 62 placeholders and one derived: 63 bits, the most a letter
    holds. One more past operator is refused at it; more derived ones at the assertion."""
    many = disjunction([f"a{i}" for i in range(1, 61)])
    m = compiled(f"always (a0 -> once ({many}))", bools(61))
    assert (m.letter_bits, m.table.bits) == (63, 1)
    with pytest.raises(InputError) as info:
        compiled(f"always (a0 -> once ({many}) | historically a3)", bools(61))
    (error,) = info.value.errors
    assert "more than 62 atoms and past or time-bounded operators" in error.message
    where = error.location
    assert where.source_line[where.col - 1 : where.col - 1 + where.length] == "historically"
    with pytest.raises(InputError) as info:
        compiled(f"always (a0 -> once ({many}) | X a3 | X X a4)", bools(61))
    (error,) = info.value.errors
    assert "needs 66 bits" in error.message and error.location.line
