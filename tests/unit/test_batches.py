"""A check's batches against one event at a time: the same events, letters, verdicts, state.

`edgerv check` reads a JSON Lines trace a block of lines at a time (the JSON scanner on
each line; a line of any other shape read as the reader always did), hands each monitor
a chunk of its events column by column (:meth:`MonitorRuntime.offer_arrivals`: a run of
equal letters made at once), and evaluates a run of equal letters at once. Each is held
here against the way it replaced, on random and on hostile input.
"""

from __future__ import annotations

import json
import random
from array import array
from pathlib import Path
from typing import Any

import pytest

from edgerv.core import traces
from edgerv.core.checker import CheckRun, MonitorResult
from edgerv.core.diagnostics import InputError, Location
from edgerv.core.monitor import CompiledMonitor
from edgerv.core.pipeline import MonitorRuntime, Verdict
from edgerv.core.traces import Trace, TraceEvent, chunks_of
from edgerv.report import to_json
from kit.documents import compiled
from kit.randomruns import SIGNALS, random_assertion, random_events
from kit.sidebyside import outcome, state_of

MS = 1_000_000


@pytest.mark.parametrize("seed", range(120))
def test_chunks_give_what_one_event_at_a_time_gives(seed: int) -> None:
    """Random monitors (past operators timed or not, nested; ages; two signals compared;
    one topic read for two signals; signals with and without an initial value; time-bounded
    F, G, U), random runs cut into chunks of random sizes, against the same events offered
    one at a time: the same verdicts, steps, state and late events, and after each chunk
    the same signal values, time, clock deadline and past operators' state."""
    rng = random.Random(seed)
    halt = rng.random() < 0.2
    m: CompiledMonitor = compiled(
        random_assertion(rng), SIGNALS, onVerdict="halt" if halt else "reset"
    )
    events = random_events(rng, rng.randint(1, 160))
    size = rng.choice([1, 2, 3, 7, 16, 50, 500])
    batched, single = CheckRun([m]), CheckRun([m])
    fed = 0
    for chunk in chunks_of(events, size):
        batched.feed_chunk(chunk)
        single._feed_events(events[fed : fed + len(chunk)])
        fed += len(chunk)
        (b_rt,), (s_rt,) = batched.router.runtimes.values(), single.router.runtimes.values()
        single.results["m"].verdicts += s_rt.evaluate()  # evaluated as the chunk is
        if not b_rt.halted:
            assert state_of(b_rt) == state_of(s_rt), (m.spec.assertion, seed)
    end = max(e.stamp for e in events) + rng.choice([0, 3 * MS, 100 * MS])
    (b,), (s,) = batched.finish(end), single.finish(end)
    # with halt, a batch stops at the chunk it halted in: late events after the halt differ
    assert outcome(b, not halt) == outcome(s, not halt), (m.spec.assertion, seed)


@pytest.mark.parametrize(
    "assertion",
    [
        "always (a -> historically[0..2s] (x < 0.1))",
        "always (age(x) < 15ms & (a -> age(a) <= 400ms))",
        "always (a -> (once[0..30ms] x >= 0.5 | age(x) > 12ms))",
    ],
)
def test_a_long_run_of_equal_messages_is_one_run_of_letters(
    assertion: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The door monitor of the timed benchmark, and ages: stretches of equal letters with
    clock steps between (a window closing 2 s after the robot stops, a message 20 ms
    late), in chunks of the trace's size; most events are not compressed one by one."""
    m = compiled(
        assertion,
        {"a": {"topic": "/a", "type": "std_msgs/msg/Bool", "initial": False}, "x": "float"},
    )
    rng = random.Random(3)
    rows, speed = [], 0.0
    for i in range(20_000):
        if i % 50 == 0:
            rows.append(TraceEvent("/a", i * 10 * MS, {"data": rng.random() < 0.3}, Location("t")))
        else:
            speed = (0.05 if speed > 0.1 else 0.5) if rng.random() < 0.01 else speed
            rows.append(TraceEvent("/x", i * 10 * MS, {"data": speed}, Location("t")))
    batched, single = CheckRun([m]), CheckRun([m])
    single._feed_events(rows)
    one_by_one = 0
    compress_one = MonitorRuntime._compress_one

    def counted(rt: MonitorRuntime, *args: Any) -> None:
        nonlocal one_by_one
        one_by_one += 1
        compress_one(rt, *args)

    monkeypatch.setattr(MonitorRuntime, "_compress_one", counted)
    batched.feed(rows)
    (b,), (s,) = batched.finish(rows[-1].stamp), single.finish(rows[-1].stamp)
    assert outcome(b, True) == outcome(s, True)
    assert len(b.verdicts) > 100
    assert one_by_one < len(rows) / 4


def plain_evaluate(rt: MonitorRuntime) -> list[Verdict]:
    """One letter at a time, as the pipeline evaluated before runs of letters."""
    table = rt.monitor.table
    out, state = [], rt.state
    consumed = len(rt.letters)
    for i, letter in enumerate(rt.letters):
        state = table.table[(state << table.bits) | letter]
        if state >= table.live:
            kind = "violated" if state == table.live else "satisfied"
            out.append(Verdict(rt.name, kind, rt.stamps[i], rt.step + i + 1))
            if rt.monitor.spec.on_verdict == "halt":
                consumed = i + 1
                break
    rt.state, rt.step = state, rt.step + consumed
    return out


@pytest.mark.parametrize("seed", range(40))
def test_runs_of_equal_letters_are_evaluated_as_one_at_a_time(seed: int) -> None:
    rng = random.Random(seed)
    halt = rng.random() < 0.3
    assertion = rng.choice(
        ["always (a -> x < 2)", "a until x < 2", "always (a -> next !a)", "eventually! a",
         "always (a -> eventually! x < 2)", "!a until (x < 2 & b)"]
    )  # fmt: skip
    m = compiled(assertion, SIGNALS, onVerdict="halt" if halt else "reset")
    runs, plain = MonitorRuntime(m), MonitorRuntime(m)
    for _ in range(5):
        letters: list[int] = []
        while len(letters) < 60:
            letters += [rng.randrange(1 << m.table.bits)] * rng.choice([1, 1, 2, 5, 30])
        for rt in (runs, plain):
            rt.letters = array(rt.letters.typecode, letters)
            rt.stamps = array("q", range(len(letters)))
        expected = [] if plain.halted else plain_evaluate(plain)
        plain.halted = plain.halted or bool(expected and halt)
        assert runs.evaluate() == expected
        assert (runs.state, runs.step, runs.halted) == (plain.state, plain.step, plain.halted)


# -- the reader ---------------------------------------------------------------------------------

TOPICS = {"/a", "/x"}
TRICKY = [
    b'{"topic": "/a", "stamp": 1, "msg": {"data": true}}',
    b'{"topic": "/x", "stamp": 2, "msg": {"data": 1.5}, "topic": "/a"}',  # a duplicate key
    b'{"topic": "/x", "stamp": 3, "msg": {"data": NaN}}',
    b'{"topic": "/x", "stamp": 3, "msg": {"data": -Infinity}}',
    b'{"topic": "/x", "stamp": 3, "msg": {"data": 12345678901234567890123}}',
    b'{"topic": "/x", "stamp": 99999999999999999999999, "msg": {"data": 1.0}}',
    b'{"topic": "/x", "stamp": -9223372036854775808, "msg": {"data": 1.0}}',
    b'{"topic": "/x", "stamp": 9223372036854775808, "msg": {"data": 1.0}}',
    b'{"topic": "/x", "stamp": ' + b"1" * 5000 + b', "msg": {"data": 1.0}}',
    b'{"topic": "/x", "stamp": 4.0, "msg": {"data": 1.0}}',
    b'{"topic": "/x", "stamp": true, "msg": {"data": 1.0}}',
    b'{"topic": "/a", "stamp": 5, "msg": {"data": true, "header": {"stamp": '
    b'{"sec": 1, "nanosec": 5}}}}',
    b'{"topic": "/a", "stamp": 5, "msg": {"header": {"stamp": {"sec": 0, "nanosec": 0}}}}',
    b'{"topic": "/a", "msg": {"data": true, "header": {"stamp": {"sec": 1e999, "nanosec": 0}}}}',
    b'{"topic": "/other", "stamp": 77, "msg": {"data": 1}}',  # not read: time passes
    b'{"topic": "/other", "msg": {"header": {"stamp": {"sec": 9, "nanosec": 1}}}}',
    b'{"topic": "/\xc3\xa9t\xc3\xa9", "stamp": 6, "msg": {"data": "\\u00e9\xe2\x82\xac"}}',
    b'{"topic": "/a", "stamp": 7, "msg": {"data": "tab\there"}}',  # a raw control character
    b'{"topic": "/a", "stamp": 7, "msg": {"data": "\xff\xfe"}}',  # not UTF-8
    b'{"topic": "/a", "stamp": 8, "msg": {"data": true}}\r',
    b'  {"topic": "/a", "stamp": 8, "msg": {"data": true}}  ',
    b'\xef\xbb\xbf{"topic": "/a", "stamp": 8, "msg": {"data": true}}',
    b'{"topic": "/a", "stamp": 9, "msg": {"data": true}} {"topic": "/a"}',
    b'{"topic": "/a", "stamp": 9, "msg": {"data": true}',
    b'{"topic": "/a", "stamp": 9, "msg": [1, 2]}',
    b'{"topic": 5, "stamp": 9, "msg": {"data": true}}',
    b'{"topic": ["/a"], "stamp": 9, "msg": {"data": true}}',
    b'{"stamp": 9, "msg": {"data": true}}',
    b'["/a", 9, {"data": true}]',
    b'"just a string"',
    b"",
    b"   \t ",
    b"[" * 50_000,
    b'{"a": ' * 3000 + b"1" + b"}" * 3000,
    b'{"topic": "/x", "stamp": 10, "msg": {"data": 1e400}}',
    b'{"topic": "/x", "stamp": 11, "msg": {"data": 1.0, "more": {"deep": [[[]]]}}}',
]


def careful_read(path: Path) -> tuple[list[tuple[Any, ...]], int | None, str | None]:
    """Every line through the careful reader alone, as the reader read every line before."""
    trace = Trace(path)
    out: list[tuple[Any, ...]] = []
    try:
        with path.open("rb") as handle:
            for lineno, raw in enumerate(handle, start=1):
                if raw.strip():
                    event = traces._jsonl_event(str(path), lineno, raw, TOPICS, trace._saw)
                    if event is not None:
                        out.append((event.topic, event.stamp, repr(event.msg), event.where))
    except InputError as exc:
        return out, trace.end, str(exc)
    return out, trace.end, None


def quick_read(path: Path) -> tuple[list[tuple[Any, ...]], int | None, str | None]:
    trace = Trace(path)
    out: list[tuple[Any, ...]] = []
    try:
        for e in trace.events(TOPICS):
            out.append((e.topic, e.stamp, repr(e.msg), e.where))
    except InputError as exc:
        return out, trace.end, str(exc)
    return out, trace.end, None


@pytest.mark.parametrize("seed", range(60))
def test_the_quick_reader_reads_every_line_as_the_careful_one(
    seed: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Tricky lines (duplicate keys, NaN, huge and out-of-range numbers, headers, topics
    not read, non-ASCII, control characters, invalid UTF-8, CRLF, whitespace, a BOM, two
    objects on a line, nesting 50,000 deep), among good ones, in blocks of random sizes
    (a line longer than a block, a last line without its newline): the same events, the
    same end of time, the same error at the same place."""
    rng = random.Random(seed)
    monkeypatch.setattr(traces, "BLOCK_BYTES", rng.choice([1, 7, 64, 300, 1 << 17]))
    good = [b'{"topic": "/x", "stamp": %d, "msg": {"data": %d.5}}' % (i, i) for i in range(30)]
    lines = rng.sample(good, rng.randint(0, 30))
    for _ in range(rng.randint(0, 3)):
        lines.insert(rng.randint(0, len(lines)), rng.choice(TRICKY))
    data = b"\n".join(lines) + rng.choice([b"\n", b"", b"\r\n"])
    path = tmp_path / "t.jsonl"
    path.write_bytes(data)
    assert quick_read(path) == careful_read(path)


def test_a_bad_line_stops_the_check_after_the_events_before_it(tmp_path: Path) -> None:
    m = compiled("always (x < 9)", {"x": "float"})
    good = b'{"topic": "/x", "stamp": %d, "msg": {"data": 1.0}}\n'
    data = b"".join(good % i for i in range(5000)) + b'{"topic": "/x", "stamp": 1, "msg": }\n'
    (tmp_path / "t.jsonl").write_bytes(data + good % 9)
    run, trace = CheckRun([m]), Trace(tmp_path / "t.jsonl")
    with pytest.raises(InputError, match=r"t.jsonl:5001:36: error: invalid JSON"):
        run.feed(trace.events(run.topics))
    (result,) = run.finish(trace.end)
    assert (result.steps, trace.end) == (5000, 4999)


def test_a_message_without_its_field_stops_at_its_place_in_a_chunk() -> None:
    m = compiled("always (x < 9)", {"x": "float", "a": "bool"})
    rows = [TraceEvent("/x", i, {"data": 1.0}, Location("t", i + 1)) for i in range(100)]
    rows[60] = TraceEvent("/a", 60, {"data": "yes"}, Location("t", 61))
    rows[70] = TraceEvent("/x", 70, {"datum": 1.0}, Location("t", 71))
    run = CheckRun([m])
    with pytest.raises(InputError, match="t:61: error: message on /a: field 'data' is 'yes'"):
        run.feed(rows)
    assert run.router.runtimes["m"].values[0] == 1.0


# -- the report ---------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(10))
def test_the_json_report_is_what_json_dumps_writes(seed: int) -> None:
    rng = random.Random(seed)
    results = []
    for i in range(rng.randint(0, 3)):
        name = rng.choice(["m", "é-\u2603", 'q"uote\\', f"m{i}"])
        r = MonitorResult(name, state=rng.choice(["pending", "violated", "halted"]))
        r.verdicts = [
            Verdict(
                name,
                rng.choice(["violated", "satisfied"]),
                rng.randint(-(2**63), 2**63 - 1),
                rng.randint(1, 10**9),
            )
            for _ in range(rng.randint(0, 5))
        ]
        results.append(r)
    assert to_json(results) == json.dumps({"monitors": [r.as_dict() for r in results]})
