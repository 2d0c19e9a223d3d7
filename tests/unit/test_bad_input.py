"""What `edgerv check` does with input that is big, binary or written twice (issue 38):
linear in blank lines, errors that quote a bounded and printable excerpt, invalid UTF-8
and duplicate keys as located errors, a byte order mark read alike in YAML and JSON Lines.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from edgerv.cli import EXIT_INTERNAL
from edgerv.core.diagnostics import MAX_QUOTED, Diagnostic, InputError, Location
from edgerv.core.documents import load_monitors_text
from edgerv.core.traces import _scan_lines

MONITOR = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: m}
spec:
  assertion: "always (speed < 100)"
  signals:
    speed: {topic: /speed, type: std_msgs/msg/Float64}
"""


def line(stamp: int, speed: float = 1.0) -> str:
    return json.dumps({"topic": "/speed", "stamp": stamp, "msg": {"data": speed}}) + "\n"


def check(tmp_path: Path, trace: bytes, monitor: bytes = MONITOR.encode()) -> tuple[int, str]:
    """``edgerv check`` as a user runs it: its exit code and stderr."""
    (tmp_path / "m.yaml").write_bytes(monitor)
    (tmp_path / "t.jsonl").write_bytes(trace)
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "edgerv",
            "check",
            str(tmp_path / "m.yaml"),
            str(tmp_path / "t.jsonl"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode != EXIT_INTERNAL, proc.stderr
    return proc.returncode, proc.stderr


class Counted(list[str]):
    """A list that counts the items its iterators hand out."""

    handed = 0

    def __iter__(self) -> Iterator[str]:
        for item in super().__iter__():
            Counted.handed += 1
            yield item


def test_lines_the_scanner_refuses_are_passed_over_once() -> None:
    """Each blank line ended the scanner's run and the next run started from the first
    line again (islice): 100,000 blank lines took 10 s, quadratic. Now each line is handed
    out once, whatever fails."""
    lines = Counted(["", line(1).strip(), " \t", "", "{", line(2).strip()] * 1000)
    Counted.handed = 0
    parsed = _scan_lines(lines)
    assert len(parsed) == len(lines) and Counted.handed == len(lines)
    assert [p is not None for p in parsed[:6]] == [False, True, False, False, False, True]


def test_a_trace_of_blank_lines_is_checked(tmp_path: Path) -> None:
    trace = line(1) + "\n" * 200_000 + " \t\n" * 100_000 + line(2, 500.0)
    code, err = check(tmp_path, trace.encode())
    assert code == 1, err  # the second speed is read: violated


def test_an_error_quotes_at_most_a_short_excerpt_with_control_characters_escaped() -> None:
    loc = Location("t.jsonl", 3, 50_001, 1, "\x00" * 50_000 + "\x1b[31m" + "x" * 50_000)
    shown = Diagnostic(loc, "invalid JSON: \x1b]0;title\x07", hint="h\x1b").render()
    assert "\x1b" not in shown and "\x00" not in shown and "\x07" not in shown
    quoted, caret = shown.splitlines()[1:3]
    assert len(quoted) < MAX_QUOTED * 4 + 20  # escaped: up to 4 characters each
    assert quoted[caret.index("^") :].startswith("\\x1b[31m")  # the caret under the place
    assert "\\x1b]0;title\\x07" in shown.splitlines()[0]


def test_a_bad_line_of_megabytes_prints_a_line_of_text(tmp_path: Path) -> None:
    trace = line(1) + '{"topic": "/speed", "stamp": 2, "msg": ' + "\x01" * 3_000_000 + "\n"
    code, err = check(tmp_path, trace.encode())
    assert code == 2 and len(err) < 5_000 and "\x01" not in err, err[:300]
    assert "t.jsonl:2:" in err


def test_invalid_utf8_in_a_trace_is_an_error_at_its_place(tmp_path: Path) -> None:
    bad = b'{"topic": "/speed", "stamp": 3, "msg": {"data": 1.0, "note": "\xff"}}\n'
    code, err = check(tmp_path, (line(1) + line(2)).encode() + bad + line(4).encode())
    assert code == 2
    assert "t.jsonl:3:63: error: invalid UTF-8 (byte 0xff)" in err, err


@pytest.mark.parametrize("bom_in", ["yaml", "jsonl", "both"])
def test_a_byte_order_mark_is_read_alike_in_yaml_and_json_lines(
    tmp_path: Path, bom_in: str
) -> None:
    bom = b"\xef\xbb\xbf"
    trace = (line(1) + line(2, 500.0)).encode()
    monitor = MONITOR.encode()
    if bom_in in ("yaml", "both"):
        monitor = bom + monitor
    if bom_in in ("jsonl", "both"):
        trace = bom + trace
    code, err = check(tmp_path, trace, monitor)
    assert code == 1 and "error" not in err, err


def test_a_key_written_twice_is_an_error_naming_both_places() -> None:
    text = MONITOR + '  assertion: "always (speed < 200)"\n'
    with pytest.raises(InputError) as info:
        load_monitors_text("m.yaml", text)
    (diag,) = info.value.diagnostics
    assert str(diag.location) == "m.yaml:8:3"
    assert "spec.assertion: 'assertion' is written twice in this mapping (first at line 5, " in (
        diag.message
    )


def test_a_key_written_twice_deep_in_a_document_is_an_error() -> None:
    text = MONITOR.replace("type: std_msgs/msg/Float64}", "type: std_msgs/msg/Float64, topic: /x}")
    with pytest.raises(InputError) as info:
        load_monitors_text("m.yaml", text)
    assert "spec.signals.speed.topic: 'topic' is written twice" in str(info.value)


def test_json_with_a_key_longer_than_yaml_reads_says_so() -> None:
    doc = {"apiVersion": "edgerv.io/v1alpha1", "kind": "Monitor", "metadata": {"name": "m"},
           "spec": {"assertion": "a", "k" * 2_000: 1}}  # fmt: skip
    with pytest.raises(InputError) as info:
        load_monitors_text("m.json", json.dumps(doc))
    assert "a key of 2,000 characters" in str(info.value)
    assert "did not find expected" not in str(info.value)
