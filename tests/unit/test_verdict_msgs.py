"""edgerv's own interfaces (interfaces/edgerv_msgs), read as edgerv reads any robot's .msg
files: they parse, have exactly the fields the handler's typed verdicts carry, and
recorded verdicts can be read from CDR and checked by `edgerv check` (a monitor of
monitors). No ROS needed: rosbags and edgerv's own CDR reader; the integration test
(test_typed_verdicts.py) checks the handler's bytes against the built package."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from edgerv.core.cdr import compile_reader
from edgerv.core.documents import load_monitors_text
from edgerv.core.msgtypes import field_kind, typestore
from kit.cli import edgerv

INTERFACES = Path(__file__).parents[2] / "interfaces"
MSG = INTERFACES / "edgerv_msgs" / "msg"

# what the handler fills in (cdr_out.encode_verdict), in this order: a field renamed,
# retyped, added, removed or moved in the .msg fails here
VERDICT_FIELDS = [
    ("monitor", "string"),
    ("verdict", "string"),
    ("stamp", "builtin_interfaces/msg/Time"),
    ("step", "uint64"),
    ("handler", "string"),
    ("assertion", "string"),
    ("epoch", "uint64"),
]
ARRAY_FIELDS = [
    ("stamp", "builtin_interfaces/msg/Time"),
    ("handler", "string"),
    ("verdicts", "edgerv_msgs/msg/Verdict[]"),
]
# rosbags' node kinds: 1 a base type, 2 a message, 4 a sequence
BASE, NAME, SEQUENCE = 1, 2, 4


@pytest.fixture
def edgerv_msgs(monkeypatch: pytest.MonkeyPatch) -> Path:
    """interfaces/ on edgerv's message path, before any edgerv_msgs installed in the venv."""
    monkeypatch.setenv("EDGERV_MSG_PATH", str(INTERFACES))
    return INTERFACES


def spelled(node: tuple[int, object]) -> str:
    kind, what = node
    if kind == BASE:
        return str(what[0])  # type: ignore[index]
    if kind == NAME:
        return str(what)
    if kind == SEQUENCE:
        return spelled(what[0]) + "[]"  # type: ignore[index]
    raise AssertionError(f"unexpected field node {node!r}")


def fields_of(msg_type: str) -> tuple[list[tuple[str, str]], list[tuple[str, str, object]]]:
    consts, fields = typestore().fielddefs[msg_type]
    return [(name, spelled(node)) for name, node in fields], list(consts)


def test_the_messages_have_exactly_the_verdicts_fields(edgerv_msgs: Path) -> None:
    assert field_kind("edgerv_msgs/msg/VerdictArray", "verdicts[0].step") == "int"
    fields, consts = fields_of("edgerv_msgs/msg/Verdict")
    assert fields == VERDICT_FIELDS
    assert sorted(consts) == [
        ("PENDING", "string", "pending"),
        ("SATISFIED", "string", "satisfied"),
        ("VIOLATED", "string", "violated"),
    ]
    assert fields_of("edgerv_msgs/msg/VerdictArray") == (ARRAY_FIELDS, [])
    names = [name for name, _ in VERDICT_FIELDS if name != "stamp"] + ["stamp.sec"]
    kinds = {name: field_kind("edgerv_msgs/msg/Verdict", name) for name in names}
    assert kinds == {
        "stamp.sec": "int",
        "monitor": "string",
        "verdict": "string",
        "step": "int",
        "handler": "string",
        "assertion": "string",
        "epoch": "int",
    }


def test_every_field_is_commented() -> None:
    """Each field of the .msg files has a comment right above it (ros2 interface show
    prints them: they are the message's documentation)."""
    for path in sorted(MSG.glob("*.msg")):
        lines = path.read_text().splitlines()
        for i, line in enumerate(lines):
            if line and not line.startswith("#") and "=" not in line:
                assert lines[i - 1].startswith("#"), f"{path.name}: no comment above {line!r}"


def test_edgervs_cdr_reader_reads_recorded_verdicts(edgerv_msgs: Path) -> None:
    """Verdicts serialized from the .msg text alone (rosbags) read back by edgerv's own
    CDR reader, field by field: what `edgerv check` does with a recording of them."""
    field_kind("edgerv_msgs/msg/VerdictArray", "handler")
    store = typestore()
    Verdict = store.types["edgerv_msgs/msg/Verdict"]
    Array = store.types["edgerv_msgs/msg/VerdictArray"]
    Time = store.types["builtin_interfaces/msg/Time"]
    epoch = 1_761_000_000_123_456_789  # a driver's clock in ns: more than 32 bits
    one = Verdict(
        monitor="speed-cap",
        verdict="violated",
        stamp=Time(sec=1_700_000_000, nanosec=5),
        step=21,
        handler="edge",
        assertion="always (speed < 100)",
        epoch=epoch,
    )
    paths = ["monitor", "verdict", "stamp.sec", "stamp.nanosec", "step", "handler"]
    read = compile_reader("edgerv_msgs/msg/Verdict", [*paths, "assertion", "epoch"])
    values, stamp = read(bytes(store.serialize_cdr(one, "edgerv_msgs/msg/Verdict")))
    assert stamp is None  # no header: a recording's own time stamps it
    assert values == [
        "speed-cap", "violated", 1_700_000_000, 5, 21, "edge", "always (speed < 100)", epoch
    ]  # fmt: skip
    two = Verdict(
        monitor="m2",
        verdict="satisfied",
        stamp=Time(sec=3, nanosec=4),
        step=2**40,
        handler="edge",
        assertion="eventually p",
        epoch=0,
    )
    array = Array(stamp=Time(sec=9, nanosec=8), handler="edge", verdicts=[one, two])
    read = compile_reader(
        "edgerv_msgs/msg/VerdictArray",
        ["handler", "stamp.sec", "verdicts[0].monitor", "verdicts[1].step", "verdicts[1].epoch"],
    )
    raw = bytes(store.serialize_cdr(array, "edgerv_msgs/msg/VerdictArray"))
    assert read(raw) == (["edge", 9, "speed-cap", 2**40, 0], None)


MONITOR_OF_MONITORS = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: no-violation}
spec:
  assertion: 'always (verdict != "violated" | monitor == "tolerated")'
  signals:
    verdict: {topic: /edgerv/verdict, type: edgerv_msgs/msg/Verdict, field: verdict}
    monitor: {topic: /edgerv/verdict, type: edgerv_msgs/msg/Verdict, field: monitor}
"""


def test_edgerv_check_reads_a_bag_of_recorded_verdicts(edgerv_msgs: Path, tmp_path: Path) -> None:
    """An MCAP of /edgerv/verdict (written by mcap_ros2 from the .msg text, as rosbag2
    records it): edgerv check monitors the verdicts themselves."""
    from mcap_ros2.writer import Writer

    spec = load_monitors_text("m.yaml", MONITOR_OF_MONITORS)[0]
    assert {s.kind for s in spec.signals.values()} == {"string"}
    definition = (
        (MSG / "Verdict.msg").read_text()
        + "=" * 80
        + "\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
    )
    recorded = [
        ("a", "satisfied"),
        ("tolerated", "violated"),
        ("b", "violated"),  # step 3: the one violation
        ("a", "satisfied"),
    ]
    bag = tmp_path / "verdicts.mcap"
    with bag.open("wb") as f:
        w = Writer(f)
        schema = w.register_msgdef("edgerv_msgs/msg/Verdict", definition)
        for i, (monitor, verdict) in enumerate(recorded, start=1):
            w.write_message(
                topic="/edgerv/verdict",
                schema=schema,
                log_time=i * 10,
                publish_time=i * 10,
                message={
                    "monitor": monitor,
                    "verdict": verdict,
                    "stamp": {"sec": 0, "nanosec": i},
                    "step": i,
                    "handler": "edge",
                    "assertion": "always p",
                    "epoch": 0,
                },
            )
        w.finish()
    doc = tmp_path / "m.yaml"
    doc.write_text(MONITOR_OF_MONITORS)
    proc = edgerv("check", doc, bag, "--json")
    assert proc.returncode == 1, proc.stderr  # a violation
    verdicts = json.loads(proc.stdout)["monitors"][0]["verdicts"]
    assert [(v["verdict"], v["step"], v["stamp"]) for v in verdicts] == [("violated", 3, 30)]
