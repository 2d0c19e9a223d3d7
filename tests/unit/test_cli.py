"""``edgerv check`` as a user runs it: exit codes, the exact JSON, errors, bags.

Most tests here (and in test_bags, test_trace_set, test_service_events, ...) run the
command in this process (:func:`kit.cli.edgerv`: edgerv.cli.main, its exit code, stdout and
stderr); what only a process of its own shows (the exit codes 0, 1 and 2 through
os._exit, input that overflowed a parser's stack, the progress bar on a terminal) runs
it as one (:func:`kit.cli.edgerv_process`). The run is kit.speed_run's."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from edgerv.cli import main
from kit.cli import edgerv, edgerv_process
from kit.speed_run import MONITORS, RUN, TYPES
from kit.traces import write_jsonl, write_mcap

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "speed-limit.yaml"


@pytest.fixture
def monitors(tmp_path: Path) -> Path:
    path = tmp_path / "monitors.yaml"
    path.write_text(MONITORS)
    return path


def test_json_output_is_exact(monitors: Path, tmp_path: Path) -> None:
    """In a process of its own: exit 1 through os._exit, once stdout is out."""
    proc = edgerv_process("check", monitors, write_jsonl(tmp_path / "run.jsonl", RUN), "--json")
    assert proc.returncode == 1, proc.stderr
    assert proc.stderr == ""
    assert json.loads(proc.stdout) == {
        "monitors": [
            # sorted in pairs: running@100 speed@110 (step 1) | speed@120, speed@130 (steps 2, 3)
            {
                "name": "speed-limit",
                "verdicts": [{"verdict": "violated", "stamp": 130, "step": 3}],
                "state": "pending",
            },
            {
                "name": "target-reached",
                "verdicts": [{"verdict": "satisfied", "stamp": 145, "step": 2}],
                "state": "halted",
            },
        ]
    }


def test_exit_0_without_violation_and_the_readable_table(monitors: Path, tmp_path: Path) -> None:
    """In a process of its own: exit 0 through os._exit."""
    rows = [r for r in RUN if r[2].get("data") != 120.0 and r[2].get("data") != 150.0]
    proc = edgerv_process("check", monitors, write_jsonl(tmp_path / "ok.jsonl", rows))
    assert proc.returncode == 0, proc.stderr
    assert "speed-limit" in proc.stdout and "pending" in proc.stdout
    assert "satisfied at step 2 @ 0.000000145" in proc.stdout


def test_bad_assertion_exit_2_with_position(tmp_path: Path) -> None:
    """In a process of its own: exit 2 through os._exit, no traceback."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(MONITORS.replace("speed < limit", "sped < limit"))
    proc = edgerv_process("check", bad, write_jsonl(tmp_path / "run.jsonl", RUN))
    assert proc.returncode == 2
    assert proc.stderr.startswith(f"{bad}:5:35: error: unknown signal or parameter 'sped'")
    assert "Traceback" not in proc.stderr
    assert proc.stdout == ""


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ('{"topic": "/speed", "stamp": 5, "msg": {"data": 1.0}', ":3:53: error: invalid JSON"),
        (
            '{"topic": "/speed", "msg": {"data": 1.0}}',
            ":3: error: missing 'stamp' (integer nanoseconds) and msg has no header.stamp",
        ),
        (
            '{"topic": "/speed", "stamp": 5, "msg": {"data": "fast"}}',
            ":3: error: message on /speed: field 'data' is 'fast', not a float value",
        ),
        (
            '{"topic": "/speed", "stamp": 5, "msg": {"value": 1.0}}',
            ":3: error: message on /speed: no field 'data' in the message",
        ),
        (
            '{"topic": "/speed", "stamp": 5, "msg": ' + "[" * 50_000 + "]" * 50_000 + "}",
            ":3: error: nested too deep to read",
        ),
        (
            '{"topic": "/speed", "stamp": 1.5, "msg": {"data": 1.0}}',
            ":3: error: stamp 1.5 is not an integer: a stamp is integer nanoseconds (of ROS "
            "time, or since the run began); if it is in seconds, 1.5 s is 1500000000",
        ),
        (
            '{"topic": "/speed", "stamp": "12:00:01", "msg": {"data": 1.0}}',
            ':3: error: stamp "12:00:01" is not a number: a stamp is integer nanoseconds',
        ),
    ],
)
def test_bad_trace_lines(monitors: Path, tmp_path: Path, line: str, expected: str) -> None:
    trace = write_jsonl(tmp_path / "t.jsonl", RUN[:2])
    trace.write_text(trace.read_text() + line + "\n")
    deep = len(line) > 10_000  # what overflows the stack crashes a process: a process of its own
    proc = (edgerv_process if deep else edgerv)("check", monitors, trace, "--json")
    assert proc.returncode == 2
    assert proc.stderr.startswith(f"{trace}{expected}"), proc.stderr
    assert "Traceback" not in proc.stderr
    # the verdicts of the events before the bad line are not lost
    assert [m["name"] for m in json.loads(proc.stdout)["monitors"]] == [
        "speed-limit",
        "target-reached",
    ]


def test_missing_files_and_bad_arguments(monitors: Path, tmp_path: Path) -> None:
    proc = edgerv("check", monitors, tmp_path / "nope.jsonl")
    assert (proc.returncode, proc.stderr.strip()) == (
        2,
        f"{tmp_path / 'nope.jsonl'}: error: no such file or directory",
    )
    proc = edgerv("check", tmp_path / "none.yaml", tmp_path / "nope.jsonl")
    assert proc.returncode == 2 and "no such file or directory" in proc.stderr
    proc = edgerv("check", monitors)
    assert proc.returncode == 2 and "the following arguments are required: trace" in proc.stderr
    assert edgerv("--version").stdout.strip() == "edgerv 0.1.0"
    proc = edgerv("handler", "--name", "h")  # no monitors and no API to receive them by
    assert proc.returncode == 2 and "give --listen HOST:PORT" in proc.stderr


def test_a_bad_deadline_option_exits_2_with_its_place(monitors: Path) -> None:
    for value, error in [
        ("/cmd_vel=fast", "--deadline: error: 'fast' is not a duration"),
        ("/cmd_vel", "--deadline: error: '/cmd_vel' is not TOPIC=DURATION"),
    ]:
        proc = edgerv("handler", "--name", "h", "--monitors", monitors, "--deadline", value)
        assert proc.returncode == 2, proc.stderr
        assert proc.stderr.startswith(error) and "Traceback" not in proc.stderr


def test_warnings_do_not_fail_the_check(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    doc = tmp_path / "w.yaml"
    doc.write_text(
        MONITORS.split("---")[0].replace(
            "always (running -> (speed < limit until stop))", "always (running | !running)"
        )
    )
    code = main(["check", str(doc), str(write_jsonl(tmp_path / "r.jsonl", RUN)), "--json"])
    out, err = capsys.readouterr()
    assert code == 0
    assert "warning: the assertion always holds" in err
    assert json.loads(out)["monitors"][0]["verdicts"][0]["verdict"] == "satisfied"


def test_mcap_bag_gives_the_same_verdicts_as_jsonl(monitors: Path, tmp_path: Path) -> None:
    jsonl = edgerv("check", monitors, write_jsonl(tmp_path / "run.jsonl", RUN), "--json")
    bag = edgerv("check", monitors, write_mcap(tmp_path / "run.mcap", RUN, TYPES), "--json")
    assert bag.returncode == jsonl.returncode == 1, bag.stderr
    assert json.loads(bag.stdout) == json.loads(jsonl.stdout)
    assert json.loads(bag.stdout)["monitors"][1]["verdicts"][0]["stamp"] == 145  # header.stamp


def test_bag_with_another_type_for_a_topic(monitors: Path, tmp_path: Path) -> None:
    rows = [("/ignored" if t == "/speed" else t, s, m) for t, s, m in RUN]
    bag = write_mcap(tmp_path / "run.mcap", rows, TYPES)
    doc = tmp_path / "m.yaml"
    doc.write_text(MONITORS.replace("topic: /speed", "topic: /ignored"))
    proc = edgerv("check", doc, bag)
    assert proc.returncode == 2
    assert (
        "reads /ignored as std_msgs/msg/Float64, but the bag records it as std_msgs/msg/String"
        in proc.stderr
    )


def test_damaged_bag(monitors: Path, tmp_path: Path) -> None:
    bag = write_mcap(tmp_path / "run.mcap", RUN, TYPES)
    data = bag.read_bytes()
    bag.write_bytes(data[: len(data) // 4])  # in its one chunk (the second half is indexes)
    proc = edgerv("check", monitors, bag)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and str(bag) in proc.stderr


def test_the_shipped_example(tmp_path: Path) -> None:
    proc = edgerv("check", EXAMPLE, ROOT / "examples" / "speed-limit.jsonl", "--json")
    assert proc.returncode == 1
    result = json.loads(proc.stdout)["monitors"]
    assert result[0]["verdicts"] == [{"verdict": "violated", "stamp": 10025, "step": 3}]


def test_a_monitor_file_nested_too_deep_is_an_input_error_not_a_crash(tmp_path: Path) -> None:
    """libyaml's composer recurses in C: 50,000 nested brackets used to crash the process
    (exit 139); the shape is checked before any parser sees the text."""
    deep = tmp_path / "deep.yaml"
    deep.write_text(MONITORS + "---\nspec: " + "[" * 50_000 + "]" * 50_000 + "\n")
    trace = write_jsonl(tmp_path / "t.jsonl", RUN[:2])
    proc = edgerv_process("check", deep, trace)
    assert proc.returncode == 2, proc.stderr
    assert "error: nested more than 64 levels deep" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_an_assertion_spot_cannot_build_in_time_exits_2_with_a_hint(tmp_path: Path) -> None:
    """``X[30]`` needs 2^30 states: Spot would run for ever (holding the GIL); the check
    gives up after --synthesis-budget and says why, at the assertion."""
    slow = tmp_path / "slow.yaml"
    slow.write_text(MONITORS.replace("speed < limit", "speed > limit -> X[30] speed < limit"))
    proc = edgerv(
        "check", slow, write_jsonl(tmp_path / "run.jsonl", RUN), "--synthesis-budget", "0.5"
    )
    assert proc.returncode == 2, proc.stderr
    assert f"{slow}:5:" in proc.stderr
    assert "error: building this monitor's automaton took more than 0.5 s" in proc.stderr
    assert "hint: write the bound as a duration" in proc.stderr
    assert "Traceback" not in proc.stderr and proc.stdout == ""


def test_a_long_check_on_a_terminal_shows_events_per_second(monitors: Path, tmp_path: Path) -> None:
    """On a terminal (stderr a tty), a progress bar with the events checked per second;
    stdout (here a file) gets the verdicts alone."""
    import os
    import pty

    trace = tmp_path / "long.jsonl"  # the lines write_jsonl writes, without 300,000 json.dumps
    trace.write_text(
        "".join(
            f'{{"topic": "/speed", "stamp": {1000 + i}, "msg": {{"data": {float(i % 90)!r}}}}}\n'
            for i in range(300_000)
        )
    )
    out_path = tmp_path / "out.json"
    pid, fd = pty.fork()
    if pid == 0:
        import fcntl
        import struct
        import termios

        fcntl.ioctl(
            0, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0)
        )  # the child: stderr on the terminal, stdout into a file
        out = os.open(out_path, os.O_WRONLY | os.O_CREAT)
        os.dup2(out, 1)
        os.execv(
            sys.executable,
            [sys.executable, "-m", "edgerv", "check", str(monitors), str(trace), "--json"],
        )
    shown = b""
    while True:
        try:
            data = os.read(fd, 65536)
        except OSError:  # the terminal closed: the child ended
            break
        if not data:
            break
        shown += data
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0, shown
    assert b"events/s" in shown and b"checking long.jsonl" in shown, shown
    assert b"it has /speed" in shown  # the topics without messages: what the trace has
    assert json.loads(out_path.read_text())["monitors"][0]["name"] == "speed-limit"


FAULT = """
import sys
import edgerv.cli

def fault(args):
    raise RecursionError("maximum recursion depth exceeded")

edgerv.cli.cmd_check = fault  # a fault of edgerv's own, as the crashes of issue 34 were
sys.exit(edgerv.cli.main(sys.argv[1:]))
"""


@pytest.mark.parametrize("debug", [[], ["--debug"]])
def test_an_internal_error_exits_70_in_one_line_never_as_a_verdict(
    monitors: Path, tmp_path: Path, debug: list[str]
) -> None:
    """A fault inside edgerv exits 70 (never 0 or 1, which a CI job reads as verdicts),
    with one line saying so and how to report it; the traceback with --debug only."""
    trace = write_jsonl(tmp_path / "t.jsonl", [("/running", 1, {"data": True})])
    args = ["check", *debug, str(monitors), str(trace)]
    done = subprocess.run([sys.executable, "-c", FAULT, *args], capture_output=True,
                          text=True, timeout=120)  # fmt: skip
    assert done.returncode == 70
    assert "edgerv: internal error: RecursionError: maximum recursion depth exceeded" in (
        done.stderr
    )
    assert ("Traceback (most recent call last)" in done.stderr) == bool(debug)
    assert ("run it again with --debug" in done.stderr) != bool(debug)


FRESH = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: fresh}
spec:
  assertion: "always (age(speed) < 500ms)"
  signals:
    speed: {topic: /speed, type: std_msgs/msg/Float64}
"""


@pytest.mark.parametrize("per_second", [1, 1000])  # seconds, milliseconds
def test_stamps_that_look_like_seconds_warn_at_the_first_line(
    tmp_path: Path, per_second: int
) -> None:
    """A speed every second for 3 s, then a 2 s gap: read as nanoseconds the gap is 2 ns
    and the freshness monitor passes; the trace is said to look like seconds."""
    monitors = tmp_path / "m.yaml"
    monitors.write_text(FRESH)
    stamps = [0, 1, 2, 3, 5, 6]
    rows = [("/speed", s * per_second, {"data": 1.0}) for s in stamps]
    trace = write_jsonl(tmp_path / "t.jsonl", rows)
    proc = edgerv("check", monitors, trace)
    assert proc.returncode == 0  # read as nanoseconds, as documented: nothing is late
    first = f"{trace}:1: warning: stamps are integer nanoseconds, and these are "
    assert first in proc.stderr and "look like seconds or milliseconds" in proc.stderr, proc.stderr
    in_ns = write_jsonl(tmp_path / "ns.jsonl", [(t, s * 10**9, m) for t, s, m in rows])
    late = edgerv("check", monitors, in_ns)
    assert late.returncode == 1 and "warning" not in late.stderr, late.stderr


def test_stamps_close_together_do_not_warn_where_no_monitor_reads_time(
    monitors: Path, tmp_path: Path
) -> None:
    """An untimed monitor's verdicts depend on the stamps' order only: no warning."""
    trace = write_jsonl(tmp_path / "t.jsonl", [(t, i, m) for i, (t, _, m) in enumerate(RUN)])
    assert "warning" not in edgerv("check", monitors, trace).stderr
