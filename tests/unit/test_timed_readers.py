"""examples/timed.yaml's monitors (time-bounded operators nested in one another and past
operators over them, docs/semantics.md section 6, "Nesting") read from every reader of
``edgerv check`` (section 8): one run written as JSON Lines, as a rosbag2 MCAP file and as
a rosbag2 sqlite3 file gives the same verdicts (kind, step, stamp) and states from each,
with ``onVerdict: reset`` and with ``halt``, and they are the verdicts of the pure pipeline
(helpers.run) and of the monitors fed one message at a time (Router.dispatch). An MCAP
file is read column-wise (edgerv.core.cdr_columns) by ``edgerv check``; that path, the
same file's messages decoded whole, a sqlite3 file's fields read from CDR, and the run
split across the three kinds of trace checked as one are each compared too.

One discrepancy was found, and fixed (edgerv.core.mcap_stream walks a chunk that holds
a Channel or Schema record): the column-wise MCAP reader lost every message of a channel
whose Channel record was in an earlier chunk read from its message indexes (an MCAP file
of small chunks by mcap-ros2-support; a minimal file). Its tests are at the end.

The runs: for each monitor one that keeps it and one that breaks it (written here, with the
instant of the first failure), and random runs of each monitor's signals (seeded) with
stamps equal, a nanosecond apart, on and beside the assertions' bounds, and long gaps
(clock steps). The monitors read disjoint topics, so one trace holds a run of each.
"""

from __future__ import annotations

import contextlib
import io
import itertools
import json
import random
import struct
from functools import cache
from pathlib import Path
from typing import Any

import pytest
import yaml

from edgerv.cli import EXIT_INTERNAL, main
from edgerv.core.checker import CheckRun, MonitorResult
from edgerv.core.documents import MonitorSpec, load_monitors_text
from edgerv.core.language.spot_worker import worker
from edgerv.core.monitor import CompiledMonitor, compile_monitor
from edgerv.core.traces import Trace
from kit.checks import events, run
from kit.traces import ROS_DEFS, write_db3, write_jsonl, write_mcap

EXAMPLES = Path(__file__).parents[2] / "examples" / "timed.yaml"
MS = 1_000_000
S = 1000 * MS
EPOCH = 1_700_000_000 * S  # the runs of a trace end here (a real clock's stamps)
MODES = ("reset", "halt")

Row = tuple[str, int, Any]  # (topic, stamp, msg.data)

# name: (a run that keeps it, one that breaks it, the instant of the latter's first
# violation); stamps from the run's start, equal stamps in the order written
RUNS: dict[str, tuple[list[Row], list[Row], int]] = {
    "reach-and-hold": (
        # reached at 1.999 s and held; goal again at 3 s, withdrawn at that very stamp
        [("/goal", 0, True), ("/at_goal", 0, False), ("/goal", 1 * MS, False),
         ("/at_goal", 1999 * MS, True), ("/goal", 3 * S, True), ("/goal", 3 * S, False),
         ("/goal", 4 * S, False)],
        # held 499 ms only, then reached again too late
        [("/goal", 0, True), ("/at_goal", 0, False), ("/goal", 1 * MS, False),
         ("/at_goal", 1500 * MS, True), ("/at_goal", 1999 * MS, False),
         ("/at_goal", 2100 * MS, True), ("/goal", 4 * S, False)],
        2500 * MS,  # the goal at 0 failed: known 2 s + 500 ms later
    ),
    "stop-and-stay": (
        # stopped 200 ms after the obstacle, for 1 s and 1 ns
        [("/obstacle", 0, True), ("/speed", 0, 1.0), ("/obstacle", 1 * MS, False),
         ("/speed", 200 * MS, 0.005), ("/speed", 1200 * MS + 1, 0.5),
         ("/obstacle", 3 * S, False)],
        # moving again at the last instant of the second
        [("/obstacle", 0, True), ("/speed", 0, 1.0), ("/obstacle", 1 * MS, False),
         ("/speed", 200 * MS, 0.005), ("/speed", 1200 * MS, 0.5), ("/obstacle", 3 * S, False)],
        1200 * MS,
    ),
    "answer-that-lasts": (
        # acknowledged at 300 ms for 100 ms; the second request refused at its stamp
        [("/request", 0, True), ("/ack", 0, False), ("/refused", 0, False),
         ("/request", 1 * MS, False), ("/ack", 300 * MS, True), ("/ack", 400 * MS + 1, False),
         ("/refused", 1 * S, True), ("/request", 1 * S, True), ("/request", 1 * S + 1, False),
         ("/refused", 1 * S + 1, False), ("/ack", 2 * S, False)],
        # acknowledged for 99 ms only
        [("/request", 0, True), ("/ack", 0, False), ("/refused", 0, False),
         ("/request", 1 * MS, False), ("/ack", 250 * MS, True), ("/ack", 349 * MS, False),
         ("/ack", 1 * S, False)],
        400 * MS,
    ),
    "either-sensor": (
        [("/scan_ok", 0, True), ("/frame_ok", 0, False), ("/scan_ok", 1 * MS, False),
         ("/frame_ok", 1000 * MS, True), ("/frame_ok", 1001 * MS, False),
         ("/scan_ok", 2000 * MS, True), ("/scan_ok", 2001 * MS, False),
         ("/frame_ok", 2500 * MS, False)],
        # from 1 ms on, nothing for 1001 ms
        [("/scan_ok", 0, True), ("/frame_ok", 0, False), ("/scan_ok", 1 * MS, False),
         ("/frame_ok", 1002 * MS, True), ("/frame_ok", 3 * S, False)],
        1001 * MS,
    ),
    "steady-aim": (
        # aim lost for 200 ms exactly, 900 ms before firing
        [("/fire", 0, False), ("/aim", 0, True), ("/aim", 500 * MS, False),
         ("/aim", 700 * MS, True), ("/fire", 1600 * MS, True), ("/fire", 1601 * MS, False),
         ("/fire", 2 * S, False)],
        # lost for 201 ms
        [("/fire", 0, False), ("/aim", 0, True), ("/aim", 500 * MS, False),
         ("/aim", 701 * MS, True), ("/fire", 1600 * MS, True), ("/fire", 1601 * MS, False),
         ("/fire", 2 * S, False)],
        1600 * MS,
    ),
    "busy-until-done": (
        # done at 999 ms, and not busy from that stamp on
        [("/go", 0, True), ("/busy", 0, True), ("/ok", 0, True), ("/done", 0, False),
         ("/go", 1 * MS, False), ("/done", 999 * MS, True), ("/busy", 999 * MS, False),
         ("/done", 1500 * MS, False), ("/ok", 2 * S, True)],
        # done 1 ms too late
        [("/go", 0, True), ("/busy", 0, True), ("/ok", 0, True), ("/done", 0, False),
         ("/go", 1 * MS, False), ("/done", 1001 * MS, True), ("/ok", 2 * S, True)],
        1000 * MS,
    ),
    "warm-up": (
        [("/warming", 0, True), ("/ready", 0, False), ("/ready", 4999 * MS, True),
         ("/warming", 5 * S, False), ("/ready", 6 * S, True)],
        [("/warming", 0, True), ("/ready", 0, False), ("/warming", 2 * S, False),
         ("/ready", 3 * S, True)],
        2 * S,
    ),
}  # fmt: skip


def specs_text(mode: str) -> str:
    """examples/timed.yaml, every monitor with ``onVerdict: mode``."""
    docs = list(yaml.safe_load_all(EXAMPLES.read_text()))
    for doc in docs:
        doc["spec"]["onVerdict"] = mode
    return yaml.safe_dump_all(docs, sort_keys=False)


@cache
def specs(mode: str) -> tuple[MonitorSpec, ...]:
    return tuple(load_monitors_text(f"timed-{mode}.yaml", specs_text(mode)))


@cache
def monitors(mode: str) -> tuple[CompiledMonitor, ...]:
    return tuple(compile_monitor(s) for s in specs(mode))


def topic_types() -> dict[str, str]:
    return {sig.topic: sig.msg_type for s in specs("reset") for sig in s.signals.values()}


def one_trace(runs: list[list[Row]]) -> list[Row]:
    """The monitors' runs as one trace, each moved to end at EPOCH (a check's time ends at
    the trace's last stamp: so at each run's own), in stamp order, equal stamps in the
    order of the runs and within each run as written."""
    rows = []
    for r in runs:
        shift = EPOCH - max(stamp for _, stamp, _ in r)
        rows += [(topic, stamp + shift, value) for topic, stamp, value in r]
    return sorted(rows, key=lambda row: row[1])  # stable


# the assertions' bounds and horizons
BOUNDS = [b * MS for b in (100, 200, 300, 400, 500, 1000, 1200, 2000, 2500, 5000)]


def random_run(rng: random.Random, spec: MonitorSpec, n: int) -> list[Row]:
    """``n`` messages of the monitor's signals: each signal valued at the start (in a random
    order, close together), then any; stamps equal, 1-3 ns apart, on and beside the bounds,
    anything below 1.5 s, or a long gap; a bool true with a chance of the signal's own."""
    sigs = list(spec.signals.values())
    bias = {s.topic: rng.uniform(0.15, 0.85) for s in sigs}

    def value(sig: Any) -> Any:
        if sig.msg_type == "std_msgs/msg/Float64":
            return rng.choice([0.0, 0.005, 0.01, 0.5, 1.0])
        return rng.random() < bias[sig.topic]

    def gap() -> int:
        r = rng.random()
        if r < 0.15:
            return 0
        if r < 0.25:
            return rng.randint(1, 3)
        if r < 0.55:
            return rng.choice(BOUNDS) + rng.choice((-1, 0, 1))
        if r < 0.93:
            return rng.randint(1, 1500 * MS)
        return rng.randint(3 * S, 12 * S)

    first = rng.sample(sigs, len(sigs))
    stamp, rows = 0, []
    for i in range(n):
        sig = first[i] if i < len(first) else rng.choice(sigs)
        stamp += rng.choice((0, 0, 1, 1000)) if i < len(first) else gap()
        rows.append((sig.topic, stamp, value(sig)))
    return rows


def random_trace(seed: int, n: int = 40) -> list[Row]:
    rng = random.Random(seed)
    return one_trace([random_run(rng, s, n) for s in specs("reset")])


def scenario(name: str) -> list[Row]:
    if name == "keeps":
        return one_trace([RUNS[s.name][0] for s in specs("reset")])
    if name == "breaks":
        return one_trace([RUNS[s.name][1] for s in specs("reset")])
    return random_trace(int(name.removeprefix("random-")))


SCENARIOS = ["keeps", "breaks", *(f"random-{seed}" for seed in range(4))]


# -- what each reader gives -----------------------------------------------------------------


def written(rows: list[Row], tmp: Path, kind: str, chunk_size: int = 1 << 20) -> Path:
    """The rows as a trace of this kind: jsonl, mcap or db3."""
    path = tmp / f"run.{kind}"
    msgs = [(topic, stamp, {"data": value}) for topic, stamp, value in rows]
    if kind == "jsonl":
        write_jsonl(path, msgs)
    elif kind == "mcap":
        write_mcap(path, msgs, topic_types(), chunk_size)
    else:
        write_db3(path, msgs, topic_types())
    return path


def check(monitors_file: Path, *traces: Path) -> tuple[int, Any]:
    """``edgerv check MONITORS TRACES --json`` run here by edgerv.cli.main: its exit code
    and output (the process's global it sets, the synthesis budget, put back after)."""
    out, err = io.StringIO(), io.StringIO()
    budget = worker.budget
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(["--debug", "check", str(monitors_file), *map(str, traces), "--json"])
    finally:
        worker.budget = budget
    assert code != EXIT_INTERNAL, err.getvalue()
    assert "Traceback" not in err.getvalue(), err.getvalue()
    return code, json.loads(out.getvalue())


def as_json(results: list[MonitorResult]) -> Any:
    return {"monitors": [r.as_dict() for r in results]}


def one_at_a_time(mode: str, rows: list[Row]) -> Any:
    """The monitors fed one message at a time (Router.dispatch, as the live handler's
    messages are), their clocks ended at the last stamp."""
    checking = CheckRun(monitors(mode))
    for topic, stamp, value in rows:
        checking.router.dispatch(topic, stamp, {"data": value})
    return as_json(checking.finish(max(stamp for _, stamp, _ in rows)))


@cache
def expected(mode: str, name: str) -> Any:
    """The pure pipeline's verdicts (helpers.run), which one message at a time gives too."""
    rows = scenario(name)
    want = as_json(run(monitors(mode), events(rows)))
    assert one_at_a_time(mode, rows) == want
    return want


def exit_code(report: Any) -> int:
    """edgerv check's exit code for its report: 1 when a monitor was violated, else 0."""
    violated = any(v["verdict"] == "violated" for m in report["monitors"] for v in m["verdicts"])
    return 1 if violated else 0


def first_violations(report: Any) -> dict[str, int | None]:
    return {
        m["name"]: next((v["stamp"] for v in m["verdicts"] if v["verdict"] == "violated"), None)
        for m in report["monitors"]
    }


# -- the tests ------------------------------------------------------------------------------


def test_every_monitor_has_its_runs() -> None:
    assert [s.name for s in specs("reset")] == list(RUNS)
    assert len({sig.topic for s in specs("reset") for sig in s.signals.values()}) == sum(
        len(s.signals) for s in specs("reset")
    )  # no topic read by two monitors: one trace holds a run of each


@pytest.mark.parametrize("mode", MODES)
def test_each_run_keeps_or_breaks_where_it_says(mode: str) -> None:
    """The runs mean what they say, each alone and all in one trace (moved to end at
    EPOCH): the first violation where it is written, none in a run that keeps."""
    for m in monitors(mode):
        keeps, breaks, at = RUNS[m.name]
        assert first_violations(as_json(run([m], events(keeps)))) == {m.name: None}
        assert first_violations(as_json(run([m], events(breaks)))) == {m.name: at}
    assert set(first_violations(expected(mode, "keeps")).values()) == {None}
    shifted = {
        name: EPOCH - max(stamp for _, stamp, _ in broken) + at
        for name, (_, broken, at) in RUNS.items()
    }
    assert first_violations(expected(mode, "breaks")) == shifted


@pytest.mark.parametrize("name", SCENARIOS)
@pytest.mark.parametrize("mode", MODES)
def test_every_reader_gives_the_pipelines_verdicts(mode: str, name: str, tmp_path: Path) -> None:
    """JSON Lines, MCAP (read column-wise) and sqlite3: the same report, exit code and
    verdicts (kind, step, stamp) as the pure pipeline."""
    doc = tmp_path / f"timed-{mode}.yaml"
    doc.write_text(specs_text(mode))
    rows = scenario(name)
    want = expected(mode, name)
    for kind in ("jsonl", "mcap", "db3"):
        assert check(doc, written(rows, tmp_path, kind)) == (exit_code(want), want), kind


def test_the_random_runs_decide_every_monitor() -> None:
    """The random runs are no vacuous test: their stamps are equal, a few nanoseconds
    apart and seconds apart within a monitor's run; every monitor is violated in some,
    and those under always take clock steps; reset gives more verdicts than halt."""
    randoms = SCENARIOS[2:]
    gaps = set()
    for name in randoms:
        for s in specs("reset"):
            stamps = [t for topic, t, _ in scenario(name) if topic in s.topics]
            gaps |= {b - a for a, b in itertools.pairwise(stamps)}
    assert {0, 1, 2, 3} <= gaps and max(gaps) > 3 * S
    for mode in MODES:
        violated, clocked = set(), set()
        for name in randoms:
            violated |= {
                n for n, at in first_violations(expected(mode, name)).items() if at is not None
            }
            rows = scenario(name)
            for result, s in zip(run(monitors(mode), events(rows)), specs(mode), strict=True):
                if result.steps > sum(1 for topic, _, _ in rows if topic in s.topics):
                    clocked.add(s.name)  # more steps than messages
        assert violated == set(RUNS), mode
        if mode == "reset":  # (warm-up's one window, at the run's start, ends at a message)
            assert clocked >= set(RUNS) - {"warm-up"}, clocked
    count = {
        mode: sum(len(m["verdicts"]) for n in SCENARIOS for m in expected(mode, n)["monitors"])
        for mode in MODES
    }
    assert count["reset"] > count["halt"] > 0


def api_check(mode: str, trace: Trace, fields: bool) -> tuple[Any, set[str]]:
    """A check through the API (what edgerv check does, with or without the fields to
    read): the report, and how the chunks came: ``columns`` (an MCAP file read
    column-wise), ``rows`` (fields read from CDR message by message) or ``msgs``
    (messages decoded whole)."""
    checking = CheckRun(monitors(mode))
    trace.open()
    trace.inspect(checking.topics)
    how = set()
    try:
        reads = checking.fields() if fields else None
        for chunk in trace.events(checking.topics, fields=reads).chunks():
            if chunk.columns is not None:
                how.add("columns")
            else:
                how.add("rows" if chunk.rows is not None else "msgs")
            checking.feed_chunk(chunk)
    finally:
        trace.close()
    return as_json(checking.finish(trace.end)), how


@pytest.mark.parametrize("name", ["breaks", "random-0"])
@pytest.mark.parametrize("mode", MODES)
def test_each_path_of_a_bag_is_taken_and_gives_the_verdicts(
    mode: str, name: str, tmp_path: Path
) -> None:
    """The paths of section 8, each checked to be the one taken: an MCAP file read
    column-wise (the fields a check reads, as edgerv check asks), the same file's
    messages decoded whole (no fields), a sqlite3 file's fields read from CDR message
    by message. (Every monitor here has past operators, so each is compressed a run of
    equal letters at a time, not by edgerv.core.columns: section 6, "Not yet".)"""
    rows = scenario(name)
    want = expected(mode, name)
    assert all(m.past for m in monitors(mode))
    mcap = written(rows, tmp_path, "mcap")
    assert api_check(mode, Trace(mcap), fields=True) == (want, {"columns"})
    assert api_check(mode, Trace(mcap), fields=False) == (want, {"msgs"})
    db3 = written(rows, tmp_path, "db3")
    assert api_check(mode, Trace(db3), fields=True) == (want, {"rows"})


@pytest.mark.parametrize("mode", MODES)
def test_a_run_split_across_the_three_kinds_of_trace_is_checked_as_one(
    mode: str, tmp_path: Path
) -> None:
    """Each monitor's messages in one of a JSON Lines trace, an MCAP file and a sqlite3
    file, checked as one run (merged in stamp order, decoded whole): the verdicts of the
    whole run in one trace."""
    rows = scenario("random-1")
    kinds = ("jsonl", "mcap", "db3")
    place = {
        sig.topic: kinds[i % 3] for i, s in enumerate(specs(mode)) for sig in s.signals.values()
    }
    traces = []
    for kind in kinds:
        (tmp_path / kind).mkdir()
        traces.append(written([r for r in rows if place[r[0]] == kind], tmp_path / kind, kind))
    doc = tmp_path / f"timed-{mode}.yaml"
    doc.write_text(specs_text(mode))
    want = expected(mode, "random-1")
    assert check(doc, *traces) == (exit_code(want), want)


# -- a discrepancy: the column-wise MCAP reader loses a channel -------------------------------
#
# edgerv.core.mcap_stream.batches (the path edgerv check takes for an MCAP file) reads a
# chunk from its message indexes when every channel they name is known, skipping the
# records between the messages; a Channel record among them is not taken. A channel whose
# record sits in a chunk holding only other channels' messages (a recorder registers a
# topic when it finds it, and its first message comes after the chunk is closed; the mcap
# writers put Channel records inside chunks) stays unknown, and every later message on it
# is dropped. Reading the same file message by message (no fields) sees them all.


def mcap_with_a_channel_in_an_earlier_chunk(path: Path, rows: list[Row], late: str) -> None:
    """An MCAP file by the mcap library's own writer, a chunk a message (as a recorder
    that flushes often writes), where ``late``'s channel is registered (found) before the
    chunk of the message before its first one is closed: its Channel record is in a
    chunk with another topic's message only."""
    from mcap.writer import CompressionType, Writer

    types = topic_types()
    with path.open("wb") as f:
        writer = Writer(f, compression=CompressionType.NONE)
        writer.start(profile="ros2", library="test_timed_readers")
        schemas = {
            t: writer.register_schema(t, "ros2msg", ROS_DEFS[t].encode())
            for t in sorted({types[topic] for topic, _, _ in rows})
        }
        channels: dict[str, int] = {}

        def channel(topic: str) -> int:
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, "cdr", schemas[types[topic]])
            return channels[topic]

        for i, (topic, stamp, value) in enumerate(rows):
            cdr = b"\x00\x01\x00\x00" + (
                bytes([value]) if isinstance(value, bool) else struct.pack("<d", value)
            )
            writer.add_message(channel(topic), stamp, cdr, stamp)
            if i + 1 < len(rows) and rows[i + 1][0] == late:
                channel(late)
            writer.flush()  # type: ignore[no-untyped-call]
        writer.finish()  # type: ignore[no-untyped-call]


# reach-and-hold broken: /goal from 0, /at_goal false from 1 ns on (violated 2.5 s later)
LATE_CHANNEL_RUN: list[Row] = [
    ("/goal", 0, True), ("/goal", 1, True), ("/at_goal", 1, False), ("/goal", 1 * MS, False),
    ("/goal", 4 * S, False),
]  # fmt: skip


def test_a_file_with_a_channel_in_an_earlier_chunk_read_message_by_message(
    tmp_path: Path,
) -> None:
    """The file of the discrepancy below is well formed: the mcap library and edgerv's
    message-by-message path read every message of it."""
    from mcap.reader import make_reader

    path = tmp_path / "late.mcap"
    mcap_with_a_channel_in_an_earlier_chunk(path, LATE_CHANNEL_RUN, "/at_goal")
    with path.open("rb") as f:
        read = [(c.topic, m.log_time) for _, c, m in make_reader(f).iter_messages()]
    assert read == [(topic, stamp) for topic, stamp, _ in LATE_CHANNEL_RUN]
    want = as_json(run(monitors("reset"), events(LATE_CHANNEL_RUN)))
    assert first_violations(want)["reach-and-hold"] == 2500 * MS + 1
    assert api_check("reset", Trace(path), fields=False) == (want, {"msgs"})


def test_a_channel_registered_in_an_earlier_chunk_is_read_column_wise(tmp_path: Path) -> None:
    """edgerv check on that MCAP file: /at_goal was never read, reach-and-hold never
    stepped and its violation was missing (JSON Lines of the same run has it)."""
    path = tmp_path / "late.mcap"
    mcap_with_a_channel_in_an_earlier_chunk(path, LATE_CHANNEL_RUN, "/at_goal")
    jsonl = written(LATE_CHANNEL_RUN, tmp_path, "jsonl")
    assert check(EXAMPLES, path) == check(EXAMPLES, jsonl)


@pytest.mark.parametrize("mode", MODES)
def test_an_mcap_bag_of_small_chunks_gives_the_verdicts(mode: str, tmp_path: Path) -> None:
    """The runs that break the monitors, in an MCAP file of 64-byte chunks by
    mcap-ros2-support (which registers a topic at its first message; a chunk that the
    Channel record fills is closed before the message): three topics were lost."""
    rows = scenario("breaks")
    small = written(rows, tmp_path, "mcap", chunk_size=64)
    assert api_check(mode, Trace(small), fields=True) == (expected(mode, "breaks"), {"columns"})
