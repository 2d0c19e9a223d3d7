"""Service events, as ``ros2 bag record --all-services`` (Jazzy) records them, checked.

A service's events come on ``/<service>/_service_event`` as ``pkg/srv/Name_Event``:
``service_msgs/msg/ServiceEventInfo info``, ``Name_Request[<=1] request``,
``Name_Response[<=1] response``; a request event's ``response`` is empty and a response
event's ``request`` (both, when introspection records metadata only). What rosbag2 writes
for their definition (rosbag2_cpp's LocalMessageDefinitionSource::get_full_text and
SequentialWriter::create_topic, 0.26.x): the ``.srv`` text after a line ``SRV:
pkg/srv/Name``, then each message it depends on (``MSG: pkg/Type`` and its text), under
the encoding ``ros2msg`` (``ros2idl`` where a dependency was found as IDL only,
``unknown`` without dependencies), as the topic's MCAP schema, named ``pkg/srv/Name_Event``,
and in sqlite3's ``message_definitions`` under the service's type ``pkg/srv/Name``. Those
bags are written here by writers independent of edgerv's readers (the ``mcap`` library's,
sqlite3's), the definitions from the installed ``.srv`` files as rosbag2 assembles them,
the CDR bytes by mcap-ros2-support's serializer (and, once, by ROS 2's own typesupport),
and every verdict is computed here from the values written: a field inside an empty
optional holds its signal's last value (sample and hold).
"""

from __future__ import annotations

import json
import math
import random
import re
import sqlite3
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from edgerv.core import msgtypes
from edgerv.core.cdr import MALFORMED, compile_reader
from edgerv.core.cdr_columns import compile_column_reader
from edgerv.core.checker import CheckRun
from edgerv.core.diagnostics import InputError, Location
from edgerv.core.documents import load_monitors_text
from edgerv.core.monitor import compile_monitor, compile_monitors
from edgerv.core.msgtypes import ABSENT, field_kind
from edgerv.core.traces import EventChunk, Trace, TraceEvent
from kit.cli import edgerv
from kit.documents import monitor_yaml, spec_of, write
from kit.sidebyside import outcome, state_of
from kit.traces import write_jsonl

SEP = "=" * 80 + "\n"
SHARE = Path(sys.prefix) / "share"  # the environment's ROS packages (lifecycle_msgs, ...)
INFO = (
    "uint8 event_type\nbuiltin_interfaces/Time stamp\nchar[16] client_gid\nint64 sequence_number\n"
)
TIME = "int32 sec\nuint32 nanosec\n"
REQUEST_SENT, REQUEST_RECEIVED, RESPONSE_SENT, RESPONSE_RECEIVED = range(4)
NOTHING = object()  # this test's own "no value in this message"
MS = 1_000_000


def split_srv(text: str) -> tuple[str, str]:
    request, response = re.split(r"^---[ \t]*$\n?", text, maxsplit=1, flags=re.MULTILINE)
    return request, response


def rosbag2_definition(service: str, srv: str, deps: list[tuple[str, str]]) -> tuple[str, str]:
    """(encoding, text) of a service event topic's definition as rosbag2 Jazzy writes it."""
    text = f"{SEP}SRV: {service}\n{srv}"
    for name, body in deps:
        text += f"\n{SEP}MSG: {name}\n{body}"
    return ("ros2msg" if deps else "unknown"), text


class Service:
    """A service: its .srv text and the messages it depends on (as rosbag2 names them),
    and its events' CDR by mcap-ros2-support, whose parser names no ``srv/`` type (nor one
    with an underscore): the event, request and response are named as messages of the
    service's package here (CDR carries no names)."""

    def __init__(
        self, service: str, srv: str, deps: list[tuple[str, str]], optional: str = "[<=1]"
    ) -> None:
        from mcap_ros2._dynamic import serialize_dynamic

        self.service, self.srv, self.deps = service, srv, deps
        self.event_type = f"{service}_Event"
        pkg, _, name = service.split("/")
        short = name.replace("_", "")
        request, response = split_srv(srv)
        root = (
            f"service_msgs/ServiceEventInfo info\n{pkg}/{short}Request{optional} request\n"
            f"{pkg}/{short}Response{optional} response\n"
        )
        sections = [
            ("service_msgs/ServiceEventInfo", INFO),
            ("builtin_interfaces/Time", TIME),
            (f"{pkg}/{short}Request", request),
            (f"{pkg}/{short}Response", response),
            *deps,
        ]
        schema = f"{pkg}/{short}Event"
        text = root + "".join(f"{SEP}MSG: {n}\n{b}\n" for n, b in sections)
        self._encode = serialize_dynamic(schema, text)[schema]

    def definition(self) -> tuple[str, str]:
        return rosbag2_definition(self.service, self.srv, self.deps)

    def cdr(self, msg: dict[str, Any]) -> bytes:
        return bytes(self._encode(msg))


def installed(service: str, *deps: str) -> Service:
    pkg, _, name = service.split("/")
    srv = (SHARE / pkg / "srv" / f"{name}.srv").read_text()
    texts = []
    for dep in deps:
        dpkg, dname = dep.split("/")
        texts.append((dep, (SHARE / dpkg / "msg" / f"{dname}.msg").read_text()))
    return Service(service, srv, texts)


def srv_event(
    kind: int,
    seq: int,
    request: dict[str, Any] | None = None,
    response: dict[str, Any] | None = None,
) -> dict[str, Any]:
    return {
        "info": {
            "event_type": kind,
            "stamp": {"sec": seq, "nanosec": 250},
            "client_gid": [seq % 128] * 16,  # (mcap-ros2-support writes a char signed)
            "sequence_number": seq,
        },
        "request": [] if request is None else [request],
        "response": [] if response is None else [response],
    }


# -- the bags, as rosbag2 Jazzy writes them ------------------------------------------------

Rows = list[tuple[str, int, dict[str, Any]]]
FLOAT64 = "std_msgs/msg/Float64"


def plain_cdr(msg: dict[str, Any]) -> bytes:
    """A std_msgs/msg/Float64 by mcap-ros2-support."""
    from mcap_ros2._dynamic import serialize_dynamic

    return bytes(serialize_dynamic(FLOAT64, "float64 data")[FLOAT64](msg))


def write_mcap(path: Path, rows: Rows, services: dict[str, Service]) -> Path:
    """A rosbag2 MCAP file by the mcap library's own writer: each service event topic with
    its schema as rosbag2 writes it, the others std_msgs/msg/Float64."""
    from mcap.writer import Writer

    with path.open("wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="rosbag2 (written by the test)")
        ids: dict[str, int] = {}
        for topic in dict.fromkeys(t for t, _, _ in rows):
            if topic in services:
                encoding, text = services[topic].definition()
                sid = w.register_schema(services[topic].event_type, encoding, text.encode())
            else:
                sid = w.register_schema(FLOAT64, "ros2msg", b"float64 data")
            meta = {"offered_qos_profiles": "", "topic_type_hash": ""}
            ids[topic] = w.register_channel(topic, "cdr", sid, metadata=meta)
        for topic, stamp, msg in rows:
            data = services[topic].cdr(msg) if topic in services else plain_cdr(msg)
            w.add_message(ids[topic], log_time=stamp, data=data, publish_time=stamp)
        w.finish()
    return path


def write_db3(
    path: Path, rows: Rows, services: dict[str, Service], definitions: bool = True
) -> Path:
    """A rosbag2 sqlite3 file as Jazzy writes it (schema version 4): a service event
    topic's type ``pkg/srv/Name_Event``, its definition under ``pkg/srv/Name``."""
    con = sqlite3.connect(path)
    con.executescript(
        """
        CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);
        CREATE TABLE metadata(id INTEGER PRIMARY KEY, metadata_version INTEGER NOT NULL,
            metadata TEXT NOT NULL);
        CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
            serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL,
            type_description_hash TEXT NOT NULL);
        CREATE TABLE message_definitions(id INTEGER PRIMARY KEY, topic_type TEXT NOT NULL,
            encoding TEXT NOT NULL, encoded_message_definition TEXT NOT NULL,
            type_description_hash TEXT NOT NULL);
        CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
            timestamp INTEGER NOT NULL, data BLOB NOT NULL);
        CREATE INDEX timestamp_idx ON messages (timestamp ASC);
        INSERT INTO schema VALUES (4, 'jazzy');
        """
    )
    ids: dict[str, int] = {}
    for topic in dict.fromkeys(t for t, _, _ in rows):
        ids[topic] = len(ids) + 1
        service = services.get(topic)
        msgtype = FLOAT64 if service is None else service.event_type
        con.execute(
            "INSERT INTO topics VALUES (?, ?, ?, 'cdr', '', 'RIHS01_00')",
            (ids[topic], topic, msgtype),
        )
        if definitions:
            encoding, text = ("ros2msg", "float64 data")
            if service is not None:
                encoding, text = service.definition()
            con.execute(
                "INSERT INTO message_definitions(topic_type, encoding, "
                "encoded_message_definition, type_description_hash) VALUES (?, ?, ?, '')",
                (FLOAT64 if service is None else service.service, encoding, text),
            )
    for topic, stamp, msg in rows:
        data = services[topic].cdr(msg) if topic in services else plain_cdr(msg)
        con.execute(
            "INSERT INTO messages(topic_id, timestamp, data) VALUES (?, ?, ?)",
            (ids[topic], stamp, data),
        )
    con.commit()
    con.close()
    return path


def check(doc: Path, trace: Path) -> tuple[int, Any, str]:
    proc = edgerv("check", doc, trace, "--json")
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc.returncode, json.loads(proc.stdout) if proc.stdout else None, proc.stderr


# -- what the verdicts must be: sample and hold, computed here ------------------------------

Getter = Callable[[dict[str, Any]], Any]


def through(optional: str, *keys: str) -> Getter:
    """A field inside the optional ``optional`` of an event message (dicts), NOTHING when
    it is empty."""

    def get(msg: dict[str, Any]) -> Any:
        held = msg[optional]
        if not held:
            return NOTHING
        value = held[0]
        for key in keys:
            value = value[key]
        return value

    return get


def reference(
    rows: Rows,
    signals: dict[str, tuple[str, Getter, Any]],
    holds: Callable[[dict[str, Any]], bool],
) -> tuple[list[dict[str, Any]], int]:
    """The verdicts of ``always holds`` (reset after each: one at each step where it does
    not hold) and the steps, each signal (topic, getter, initial or NOTHING) holding its
    last value across the messages that have none for it."""
    values = {name: initial for name, (_, _, initial) in signals.items()}
    step, out = 0, []
    for topic, stamp, msg in rows:
        mine = [(name, get) for name, (t, get, _) in signals.items() if t == topic]
        if not mine:
            continue
        for name, get in mine:
            value = get(msg)
            if value is not NOTHING:
                values[name] = value
        if NOTHING in values.values():
            continue
        step += 1
        if not holds(values):
            out.append({"verdict": "violated", "stamp": stamp, "step": step})
    return out, step


CHANGE_TOPIC = "/talker/change_state/_service_event"
ADD_TOPIC = "/add_two_ints/_service_event"
ADD_SRV = "int64 a\nint64 b\n---\nint64 sum\n"

CHANGE_MONITOR = f"""\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {{name: slow-once-activated}}
spec:
  assertion: "always ((transition == 3 & ok) -> speed < 2)"
  signals:
    transition:
      topic: {CHANGE_TOPIC}
      type: lifecycle_msgs/srv/ChangeState_Event
      field: "request[0].transition.id"
    ok:
      topic: {CHANGE_TOPIC}
      type: lifecycle_msgs/srv/ChangeState_Event
      field: "response[0].success"
      initial: true
    kind:
      topic: {CHANGE_TOPIC}
      type: lifecycle_msgs/srv/ChangeState_Event
      field: info.event_type
    speed: {{topic: /speed, type: std_msgs/msg/Float64}}
"""
CHANGE_SIGNALS: dict[str, tuple[str, Getter, Any]] = {
    "transition": (CHANGE_TOPIC, through("request", "transition", "id"), NOTHING),
    "ok": (CHANGE_TOPIC, through("response", "success"), True),
    "kind": (CHANGE_TOPIC, lambda m: m["info"]["event_type"], NOTHING),
    "speed": ("/speed", lambda m: m["data"], NOTHING),
}


def change_holds(v: dict[str, Any]) -> bool:
    return not (v["transition"] == 3 and v["ok"]) or v["speed"] < 2


ADD_MONITOR = f"""\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {{name: small-sums}}
spec:
  assertion: "always (sum < limit | a > 40)"
  signals:
    a:
      topic: {ADD_TOPIC}
      type: example_interfaces/srv/AddTwoInts_Event
      field: "request[0].a"
      initial: 0
    sum:
      topic: {ADD_TOPIC}
      type: example_interfaces/srv/AddTwoInts_Event
      field: "response[0].sum"
      initial: 0
  parameters: {{limit: 60}}
"""
ADD_SIGNALS: dict[str, tuple[str, Getter, Any]] = {
    "a": (ADD_TOPIC, through("request", "a"), 0),
    "sum": (ADD_TOPIC, through("response", "sum"), 0),
}


def add_holds(v: dict[str, Any]) -> bool:
    return bool(v["sum"] < 60 or v["a"] > 40)


def calls(seed: int, n: int = 60) -> Rows:
    """A run: calls of /talker/change_state and /add_two_ints (each a request sent and
    received, a response sent and received; now and then metadata only: both empty) among
    /speed messages, in log-time order."""
    rng = random.Random(seed)
    rows: Rows = []
    stamp = 1_700_000_000 * 10**9
    for seq in range(1, n + 1):
        stamp += rng.randint(1, 40) * MS
        rows.append(("/speed", stamp, {"data": rng.choice([0.5, 1.0, 1.5, 2.5, 3.0])}))
        if rng.random() < 0.6:
            transition = {
                "transition": {"id": rng.choice([1, 3, 3, 4]), "label": rng.choice(["", "on"])}
            }
            result = {"success": rng.random() < 0.7}
            metadata = rng.random() < 0.1
            for kind in range(4):
                stamp += rng.randint(0, 3) * MS
                request = transition if kind < 2 and not metadata else None
                response = result if kind >= 2 and not metadata else None
                rows.append((CHANGE_TOPIC, stamp, srv_event(kind, seq, request, response)))
                if rng.random() < 0.5:
                    stamp += MS
                    rows.append(("/speed", stamp, {"data": rng.choice([0.5, 2.5])}))
        if rng.random() < 0.5:
            a, b = rng.randint(0, 50), rng.randint(0, 50)
            stamp += MS
            rows.append((ADD_TOPIC, stamp, srv_event(REQUEST_RECEIVED, seq, {"a": a, "b": b})))
            stamp += MS
            rows.append((ADD_TOPIC, stamp, srv_event(RESPONSE_SENT, seq, None, {"sum": a + b})))
    return rows


@pytest.fixture(scope="module")
def services() -> dict[str, Service]:
    return {
        CHANGE_TOPIC: installed("lifecycle_msgs/srv/ChangeState", "lifecycle_msgs/Transition"),
        ADD_TOPIC: Service("example_interfaces/srv/AddTwoInts", ADD_SRV, []),
    }


@pytest.fixture
def docs(tmp_path: Path) -> tuple[Path, Path]:
    change, add = tmp_path / "change.yaml", tmp_path / "add.yaml"
    change.write_text(CHANGE_MONITOR)
    add.write_text(ADD_MONITOR)
    return change, add


@pytest.fixture
def add_srv_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """example_interfaces/srv/AddTwoInts.srv under $EDGERV_MSG_PATH (it is not installed)."""
    srv = tmp_path / "defs" / "example_interfaces" / "srv"
    srv.mkdir(parents=True)
    (srv / "AddTwoInts.srv").write_text(ADD_SRV)
    monkeypatch.setenv("EDGERV_MSG_PATH", str(tmp_path / "defs"))
    return srv


def test_rosbag2_writes_what_this_test_writes() -> None:
    """The definition text as rosbag2's own test of it says (rosbag2_py
    test_message_definitions.py, can_find_srv_deps_in_msg), made here by
    :func:`rosbag2_definition`; and edgerv reads that text into the three types."""
    encoding, text = rosbag2_definition(
        "rosbag2_test_msgdefs/srv/ComplexSrvMsg",
        "rosbag2_test_msgdefs/BasicMsg req\n---\nrosbag2_test_msgdefs/BasicMsg resp\n",
        [("rosbag2_test_msgdefs/BasicMsg", "float32 c\n")],
    )
    assert (encoding, text) == (
        "ros2msg",
        "================================================================================\n"
        "SRV: rosbag2_test_msgdefs/srv/ComplexSrvMsg\n"
        "rosbag2_test_msgdefs/BasicMsg req\n"
        "---\n"
        "rosbag2_test_msgdefs/BasicMsg resp\n"
        "\n"
        "================================================================================\n"
        "MSG: rosbag2_test_msgdefs/BasicMsg\n"
        "float32 c\n",
    )
    assert msgtypes.register_definition(
        "rosbag2_test_msgdefs/srv/ComplexSrvMsg_Event", encoding, text
    )
    event = "rosbag2_test_msgdefs/srv/ComplexSrvMsg_Event"
    assert field_kind(event, "request[0].req.c") == field_kind(event, "response[0].resp.c")
    assert field_kind(event, "response[0].resp.c") == "float"
    # a dependency found as IDL only: an empty MSG section, then its IDL (rosbag2's test,
    # can_find_srv_deps_in_idl)
    idl = (
        "================================================================================\n"
        "SRV: rosbag2_test_msgdefs/srv/ComplexSrvIdl\n"
        "rosbag2_test_msgdefs/BasicIdl req\n---\nrosbag2_test_msgdefs/BasicIdl resp\n\n"
        "================================================================================\n"
        "MSG: rosbag2_test_msgdefs/BasicIdl\n\n"
        "================================================================================\n"
        "IDL: rosbag2_test_msgdefs/BasicIdl\n"
        "module rosbag2_test_msgdefs {\n  module msg {\n    struct BasicIdl {\n"
        "        float x;\n    };\n  };\n};\n"
    )
    event = "rosbag2_test_msgdefs/srv/ComplexSrvIdl_Event"
    assert msgtypes.register_definition(event, "ros2idl", idl)
    assert field_kind(event, "request[0].req.x") == "float"


# -- the types: from the installed .srv files, as rosidl describes them ------------------------

# rosidl's type description (type_description_interfaces/msg/FieldType): type ids
_SCALARS = {
    1: "nested", 2: "int8", 3: "uint8", 4: "int16", 5: "uint16", 6: "int32", 7: "uint32",
    8: "int64", 9: "uint64", 10: "float32", 11: "float64", 13: "char", 15: "bool",
    16: "byte", 17: "string", 21: "string",
}  # fmt: skip


def _described(field: dict[str, Any]) -> tuple[Any, ...]:
    """A field of rosidl's type description (the installed .json of a .srv): its base
    type, container (array, bounded sequence, sequence) and size."""
    t = field["type"]
    kind, container = t["type_id"] % 48, t["type_id"] // 48
    base = t["nested_type_name"] if kind == 1 else _SCALARS[kind]
    return (field["name"], base, ("", "array", "bounded", "sequence")[container], t["capacity"])


def _known(msg_type: str) -> list[tuple[Any, ...]]:
    """A type's fields as edgerv knows them, in the same terms."""
    out = []
    for name, node in msgtypes.fielddefs()[msg_type][1]:
        kind, container, size = int(node[0]), "", 0
        if kind in (3, 4):
            elem, size = node[1]
            container = "array" if kind == 3 else "bounded" if size else "sequence"
            node, kind = elem, int(elem[0])
        base = node[1] if kind == 2 else node[1][0]
        out.append((name, base, container, size))
    return out


INSTALLED = sorted(p for p in SHARE.glob("*/srv/*.srv") if p.with_suffix(".json").exists())


@pytest.mark.parametrize("srv", INSTALLED, ids=lambda p: f"{p.parts[-3]}/{p.stem}")
def test_types_made_from_an_installed_srv_are_rosidls(srv: Path) -> None:
    """Every service installed here: the request, response and event edgerv makes from
    its .srv file have the fields rosidl's type description gives (its .json beside it)."""
    assert len(INSTALLED) >= 20
    service = f"{srv.parts[-3]}/srv/{srv.stem}"
    event = f"{service}_Event"
    assert field_kind(event, "info.event_type") == "int"
    described = json.loads(srv.with_suffix(".json").read_text())["type_description_msg"]
    for desc in described["referenced_type_descriptions"]:
        name = desc["type_name"]
        if name.startswith(f"{service}_"):
            assert _known(name) == [_described(f) for f in desc["fields"]], name


def test_the_event_type_names_and_paths() -> None:
    event = "lifecycle_msgs/srv/GetState_Event"
    assert msgtypes.normalize_type(event) == event
    assert field_kind(event, "response[0].current_state.label") == "string"
    assert field_kind(event, "info.stamp.sec") == "int"
    assert field_kind(event, "info.client_gid[15]") == "int"
    assert msgtypes.optional_steps(event, "response[0].current_state.id") == {1}
    assert msgtypes.optional_steps(event, "info.client_gid[3]") == frozenset()
    for wrong in ("lifecycle_msgs/srv/GetState", "lifecycle_msgs/srv/_Event"):
        with pytest.raises(msgtypes.FieldError) as info:
            msgtypes.normalize_type(wrong)
        assert info.value.about == "type"


@pytest.mark.parametrize(
    ("field", "message", "hint"),
    [
        (
            "request.transition.id",
            "field 'request' of lifecycle_msgs/srv/ChangeState_Event is an optional, "
            "so it has no field 'transition'",
            "request is an optional (a sequence of at most 1): write request[0].transition.id",
        ),
        (
            "response[1].success",
            "field 'response' of lifecycle_msgs/srv/ChangeState_Event is an optional: "
            "it has no element [1]",
            "response is an optional (a sequence of at most 1): its element is response[0]",
        ),
        (
            "response",
            "field 'response' of lifecycle_msgs/srv/ChangeState_Event is an optional "
            "(a sequence of at most 1), not a value",
            "read it through its element, e.g. response[0].success",
        ),
        (
            "request[0].transition.nope",
            "lifecycle_msgs/msg/Transition has no field 'nope' (at 'request.transition')",
            "its fields: id, label",
        ),
    ],
)
def test_a_wrong_path_is_named_with_a_hint(field: str, message: str, hint: str) -> None:
    text = (
        "apiVersion: edgerv.io/v1alpha1\nkind: Monitor\nmetadata: {name: m}\nspec:\n"
        '  assertion: "always (x == 1)"\n  signals:\n'
        f"    x: {{topic: /s/_service_event, type: lifecycle_msgs/srv/ChangeState_Event, "
        f'field: "{field}"}}\n'
    )
    with pytest.raises(InputError) as info:
        load_monitors_text("m.yaml", text)
    (d,) = info.value.diagnostics
    assert (d.message, d.hint) == (f"spec.signals.x.field: {message}", hint)
    assert (d.location.line, d.location.col) == (7, text.splitlines()[6].index('"') + 1)


def test_a_wrong_path_exits_2_at_its_place(tmp_path: Path) -> None:
    doc = tmp_path / "m.yaml"
    text = CHANGE_MONITOR.replace("request[0].transition.id", "request.transition.id")
    doc.write_text(text)
    line = next(i for i, t in enumerate(text.splitlines(), 1) if "request.transition" in t)
    col = text.splitlines()[line - 1].index('"') + 1
    proc = edgerv("check", doc, write_jsonl(tmp_path / "t.jsonl", calls(1, 3)))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert (
        f"{doc}:{line}:{col}: error: spec.signals.transition.field: field 'request' of "
        "lifecycle_msgs/srv/ChangeState_Event is an optional" in proc.stderr
    ), proc.stderr
    assert "write request[0].transition.id" in proc.stderr
    doc.write_text(CHANGE_MONITOR.replace("srv/ChangeState_Event\n", "srv/ChangeState\n", 1))
    proc = edgerv("check", doc, write_jsonl(tmp_path / "t.jsonl", calls(1, 3)))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "names a service, not a message type" in proc.stderr
    assert "lifecycle_msgs/srv/ChangeState_Event" in proc.stderr


# -- edgerv check on the bags ------------------------------------------------------------------


@pytest.mark.parametrize("seed", [1, 2])
def test_check_gives_the_verdicts_of_sample_and_hold(
    services: dict[str, Service],
    docs: tuple[Path, Path],
    add_srv_path: Path,
    tmp_path: Path,
    seed: int,
) -> None:
    """An MCAP and a sqlite3 bag as Jazzy records them (the service's own definition in
    each: example_interfaces is not installed), and the same run as JSON Lines (the types
    from the installed .srv and, for AddTwoInts, from $EDGERV_MSG_PATH): the verdicts
    computed here from the values written."""
    rows = calls(seed)
    change_want, _ = reference(rows, CHANGE_SIGNALS, change_holds)
    add_want, add_steps = reference(rows, ADD_SIGNALS, add_holds)
    assert change_want and add_want, "a run whose verdicts the held values decide"
    held = [(t, s) for t, s, m in rows if t == CHANGE_TOPIC and not m["request"]]
    assert any(v["stamp"] in {s for _, s in held} for v in change_want)
    assert add_steps == sum(1 for t, _, _ in rows if t == ADD_TOPIC)  # a step at every event
    jsonl = write_jsonl(tmp_path / "run.jsonl", rows)
    with_srv = {CHANGE_TOPIC: services[CHANGE_TOPIC], ADD_TOPIC: services[ADD_TOPIC]}
    mcap = write_mcap(tmp_path / "run.mcap", rows, with_srv)
    db3 = write_db3(tmp_path / "run.db3", rows, with_srv)
    change, add = docs
    for trace in (jsonl, mcap, db3):
        code, out, err = check(change, trace)
        assert (code, out["monitors"][0]["verdicts"]) == (1, change_want), (trace, err)
        code, out, err = check(add, trace)
        assert (code, out["monitors"][0]["verdicts"]) == (1, add_want), (trace, err)


def test_a_bag_alone_serves_a_service_not_installed(
    services: dict[str, Service], docs: tuple[Path, Path], tmp_path: Path
) -> None:
    """example_interfaces/srv/AddTwoInts is known from the bag's definition only (Jazzy
    wrote it with the encoding 'unknown': a service without dependencies); a bag without
    one and nothing installed: the type is unknown, exit 2, with what to do."""
    rows = [r for r in calls(3) if r[0] == ADD_TOPIC]
    want, _ = reference(rows, ADD_SIGNALS, add_holds)
    _, add = docs
    mine = {ADD_TOPIC: services[ADD_TOPIC]}
    for bag in (
        write_mcap(tmp_path / "add.mcap", rows, mine),
        write_db3(tmp_path / "add.db3", rows, mine),
    ):
        code, out, err = check(add, bag)
        assert (code, out["monitors"][0]["verdicts"]) == (1 if want else 0, want), err
    bare = write_db3(tmp_path / "bare.db3", rows, mine, definitions=False)
    code, _, err = check(add, bare)
    assert code == 2 and "unknown message type 'example_interfaces/srv/AddTwoInts_Event'" in err
    assert "example_interfaces/srv/AddTwoInts.srv" in err


def test_traces_merged_decode_the_events_whole(
    services: dict[str, Service], docs: tuple[Path, Path], tmp_path: Path
) -> None:
    """The service's events in a bag and /speed in a JSON trace, checked as one run (each
    message decoded whole, by rosbags, with the types the bag's definition made): the
    verdicts of sample and hold over the run merged in stamp order (ties: the bag's
    first, as it is named first)."""
    rows = calls(7)
    mine = {CHANGE_TOPIC: services[CHANGE_TOPIC]}
    bag = write_mcap(tmp_path / "events.mcap", [r for r in rows if r[0] == CHANGE_TOPIC], mine)
    speeds = write_jsonl(tmp_path / "speed.jsonl", [r for r in rows if r[0] == "/speed"])
    merged = sorted(rows, key=lambda r: (r[1], r[0] != CHANGE_TOPIC))
    want, _ = reference(merged, CHANGE_SIGNALS, change_holds)
    assert want
    proc = edgerv("check", docs[0], bag, speeds, "--json")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert json.loads(proc.stdout)["monitors"][0]["verdicts"] == want


def _check_in_process(doc: str, trace: Path) -> list[Any]:
    monitors, _ = compile_monitors(load_monitors_text("m.yaml", doc))
    run, source = CheckRun(monitors), Trace(trace)
    try:
        source.open()
        run.feed(source.events(run.topics, fields=run.fields()))
        return run.finish(source.end)
    finally:
        source.close()


def test_a_monitor_of_request_and_response_steps_on_every_event(
    services: dict[str, Service], tmp_path: Path
) -> None:
    """Every event of the service is a step of a monitor reading its request's and its
    response's fields (each holding its value across the events of the other), read from
    JSON Lines, from a sqlite3 bag (message by message) and from an MCAP bag (column-wise:
    at the end, a batch of 5,000 events)."""
    doc = CHANGE_MONITOR.replace(
        '"request[0].transition.id"', '"request[0].transition.id"\n      initial: 0'
    ).replace("    speed: {topic: /speed, type: std_msgs/msg/Float64}\n", "")
    doc = doc.replace("speed < 2", "kind < 2")
    rows = [r for r in calls(4, 2000) if r[0] == CHANGE_TOPIC]
    assert len(rows) > 4000
    signals = {k: v for k, v in CHANGE_SIGNALS.items() if k != "speed"}
    signals["transition"] = (CHANGE_TOPIC, signals["transition"][1], 0)
    want, steps = reference(
        rows, signals, lambda v: not (v["transition"] == 3 and v["ok"]) or v["kind"] < 2
    )
    assert steps == len(rows)
    mine = {CHANGE_TOPIC: services[CHANGE_TOPIC]}
    for trace in (
        write_jsonl(tmp_path / "run.jsonl", rows),
        write_db3(tmp_path / "run.db3", rows, mine),
        write_mcap(tmp_path / "run.mcap", rows, mine),
    ):
        (result,) = _check_in_process(doc, trace)
        assert result.steps == len(rows), trace
        got = [{"verdict": v.verdict, "stamp": v.stamp, "step": v.step} for v in result.verdicts]
        assert got == want, trace


# x: the second parameter of a SetParameters request (a request of one has none)
SECOND_PARAMETER = monitor_yaml(
    "p",
    "always (x < 10)",
    {
        "x": {
            "topic": "/p/_service_event",
            "type": "rcl_interfaces/srv/SetParameters_Event",
            "field": "request[0].parameters[1].value.integer_value",
        }
    },
)


def test_an_index_past_a_sequence_inside_an_optional_is_an_input_error(
    tmp_path: Path,
) -> None:
    """Inside a request that is there, ``parameters[1]`` of a request of one parameter is an
    input error at its message (not a held value); a response event, whose request is
    empty, holds."""
    doc = write(tmp_path, "p.yaml", SECOND_PARAMETER)

    def parameter(name: str, value: int) -> dict[str, Any]:
        return {"name": name, "value": {"type": 2, "integer_value": value}}

    rows = [
        (
            "/p/_service_event",
            10,
            srv_event(1, 1, {"parameters": [parameter("a", 1), parameter("b", 20)]}),
        ),
        ("/p/_service_event", 11, srv_event(2, 1, None, {"results": []})),
        ("/p/_service_event", 12, srv_event(1, 2, {"parameters": [parameter("c", 3)]})),
    ]
    proc = edgerv("check", doc, write_jsonl(tmp_path / "p.jsonl", rows), "--json")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    verdicts = json.loads(proc.stdout)["monitors"][0]["verdicts"]
    assert verdicts == [  # 20, then held by the response event
        {"verdict": "violated", "stamp": 10, "step": 1},
        {"verdict": "violated", "stamp": 11, "step": 2},
    ]
    assert f"{tmp_path / 'p.jsonl'}:3:" in proc.stderr and "message on /p/_service_event" in (
        proc.stderr
    )


def test_an_index_past_a_sequence_inside_an_optional_in_a_bag(tmp_path: Path) -> None:
    """The same in an MCAP bag as Jazzy records it: the error at its message, after the
    verdicts of those before it."""
    doc = write(tmp_path, "p.yaml", SECOND_PARAMETER)
    msg = (SHARE / "rcl_interfaces" / "msg").joinpath
    service = Service(
        "rcl_interfaces/srv/SetParameters",
        (SHARE / "rcl_interfaces" / "srv" / "SetParameters.srv").read_text(),
        [
            ("rcl_interfaces/Parameter", msg("Parameter.msg").read_text()),
            ("rcl_interfaces/SetParametersResult", msg("SetParametersResult.msg").read_text()),
            ("rcl_interfaces/ParameterValue", msg("ParameterValue.msg").read_text()),
        ],
    )

    def parameter(name: str, value: int) -> dict[str, Any]:
        return {"name": name, "value": {"type": 2, "integer_value": value}}

    topic = "/p/_service_event"
    rows = [
        (topic, 10, srv_event(1, 1, {"parameters": [parameter("a", 1), parameter("b", 20)]})),
        (topic, 11, srv_event(2, 1, None, {"results": []})),
        (topic, 12, srv_event(1, 2, {"parameters": [parameter("c", 3)]})),
    ]
    bag = write_mcap(tmp_path / "p.mcap", rows, {topic: service})
    code, out, err = check(doc, bag)
    assert code == 2, err
    assert out["monitors"][0]["verdicts"] == [
        {"verdict": "violated", "stamp": 10, "step": 1},
        {"verdict": "violated", "stamp": 11, "step": 2},
    ]
    assert f"{bag}:3: error: message 3 on {topic} cannot be read" in err


# -- every path gives the same: one message at a time, chunks of rows, columns, JSON ---------

PROBE = "edgerv_service_test/srv/Probe"
PROBE_TOPIC = "/probe/_service_event"
PROBE_SRV = """# a probe: a string and a sequence move what follows them
int64 a
string note
float64[] xs
float64 b
uint8 FAST = 1
---
int64 sum
bool ok
string why
int32[<=1] code
"""
PROBE_SIGNALS = {
    "a": ("request[0].a", 0),
    "b": ("request[0].b", 0.0),
    "s": ("response[0].sum", 0),
    "ok": ("response[0].ok", False),
    "c": ("response[0].code[0]", 0),
    "k": ("info.event_type", 0),
}
ATOMS = [
    "a < 3",
    "b >= 0.5",
    "s != 4",
    "ok",
    "!ok",
    "k >= 2",
    "x < 1",
    "a == s",
    "b < x",
    "c == 1",
    "age(a) < 5ms",
    "age(s) >= 3ms",
    "age(x) < 4ms",
]
SHAPES = [
    "always ({f})",
    "always ((ok) -> ({f}))",
    "eventually! ({f})",
    "always ((k == 1) -> F[0..30ms] ({f}))",
    "always (({f}) -> next (x < 2))",
]


@pytest.fixture(scope="module")
def probe() -> Service:
    service = Service(PROBE, PROBE_SRV, [])
    assert msgtypes.register_definition(f"{PROBE}_Event", *service.definition())
    return service


def probe_event(rng: random.Random, seq: int) -> dict[str, Any]:
    """A probe's event: a request event holds its request, a response event its response;
    now and then neither (metadata only) or both."""
    kind = rng.randrange(4)
    request = {
        "a": rng.randint(-2, 5),
        "note": rng.choice(["", "x", "probe"]),
        "xs": [rng.random() for _ in range(rng.randint(0, 3))],
        "b": rng.choice([0.0, 0.5, 1.0, 2.5]),
    }
    response = {
        "sum": rng.randint(0, 6),
        "ok": rng.random() < 0.5,
        "why": rng.choice(["", "because"]),
        "code": rng.choice([[], [rng.randint(0, 2)]]),
    }
    shape = rng.random()
    has_request = kind < 2 if shape < 0.8 else shape < 0.9
    has_response = kind >= 2 if shape < 0.8 else shape < 0.9
    return srv_event(
        kind, seq, request if has_request else None, response if has_response else None
    )


def random_monitor(rng: random.Random, name: str) -> Any:
    atoms = [rng.choice(ATOMS) for _ in range(rng.randint(1, 3))]
    body = f" {rng.choice(['&', '|', '->'])} ".join(f"({a})" for a in atoms)
    assertion = rng.choice(SHAPES).format(f=body)
    used = set(re.findall(r"\b[a-z]+\b", assertion)) - {"always", "eventually", "next", "age"}
    signals: dict[str, Any] = {}
    for sig in sorted(used | {"ok", "k"} & used):
        if sig == "x":
            signals["x"] = {"topic": "/x", "type": FLOAT64}
            if rng.random() < 0.5:
                signals["x"]["initial"] = 0.5
            continue
        path, initial = PROBE_SIGNALS[sig]
        signals[sig] = {"topic": PROBE_TOPIC, "type": f"{PROBE}_Event", "field": path}
        if rng.random() < 0.5:
            signals[sig]["initial"] = initial
    threshold = rng.choice([1, 1, 2, 3, 5])
    return compile_monitor(spec_of(assertion, signals, name=name, sortThreshold=threshold))


def random_run(rng: random.Random, n: int) -> list[tuple[str, int, dict[str, Any]]]:
    stamp, out = rng.randint(0, 3) * MS, []
    for seq in range(n):
        stamp += rng.choice([0, 1, MS, 2 * MS, 3 * MS + 1, 5 * MS, 11 * MS])
        at = stamp - rng.randint(1, 9 * MS) if rng.random() < 0.1 else stamp
        if rng.random() < 0.35:
            out.append(("/x", at, {"data": rng.choice([0.0, 0.5, 1.5, 3.0])}))
        else:
            out.append((PROBE_TOPIC, at, probe_event(rng, seq)))
    return out


def _pack(raws: list[bytes]) -> tuple[Any, Any, Any]:
    buf = np.frombuffer(b"".join(raws), np.uint8)
    ends = np.cumsum([len(r) for r in raws], dtype=np.int64)
    return buf, ends - np.array([len(r) for r in raws], np.int64), ends


def every_path(
    monitors: list[Any],
    run: list[tuple[str, int, dict[str, Any]]],
    probe: Service,
    size: int,
) -> dict[str, list[tuple[Any, ...]]]:
    """The outcome of each monitor over ``run`` on every path a value takes: one message
    at a time through Router.offer_values with the per-message CDR reader's values (the
    live handler's way), and a check's chunks of ``size``: rows read from CDR (a sqlite3
    bag's), columns (an MCAP bag's), parsed JSON, and messages dispatched one by one.
    After each chunk every path's monitors are in the same state."""
    raws = [probe.cdr(m) if t == PROBE_TOPIC else plain_cdr(m) for t, _, m in run]
    live, rows, columns, parsed, single = (CheckRun(monitors) for _ in range(5))
    readers = {t: compile_reader(r.msg_type, r.fields) for t, r in live.router.routes.items()}
    column_readers = {
        t: compile_column_reader(r.msg_type, r.fields) for t, r in live.router.routes.items()
    }
    for t, reader in column_readers.items():  # a column reader but where it cannot be one
        nested = any("code[0]" in f for f in live.router.routes[t].fields)
        assert (reader is None) == nested, live.router.routes[t].fields
    for first in range(0, len(run), size):
        part = run[first : first + size]
        part_raws = raws[first : first + size]
        for (topic, stamp, _), raw in zip(part, part_raws, strict=True):
            route = live.router.routes.get(topic)
            if route is None:
                continue
            values, _ = readers[topic](raw)
            for rt in live.router.offer_values(route, stamp, values):
                live.results[rt.name].verdicts += rt.evaluate()
        mine = [i for i, (t, _, _) in enumerate(part) if t in readers]
        topics = [part[i][0] for i in mine]
        stamps = [part[i][1] for i in mine]
        places = [first + i + 1 for i in mine]
        if not mine:
            continue
        rows.feed_chunk(
            EventChunk(
                "t",
                topics,
                stamps,
                [part_raws[i] for i in mine],
                places,
                rows=[readers[part[i][0]](part_raws[i])[0] for i in mine],
            )
        )
        cols: dict[str, tuple[Any, list[Any]]] = {}
        for topic in readers:
            at = [j for j, i in enumerate(mine) if part[i][0] == topic]
            if not at:
                continue
            chosen = [part_raws[mine[j]] for j in at]
            reader = column_readers[topic]
            got = None if reader is None else reader(*_pack(chosen))
            if reader is not None:
                assert got is not None
                values = got.values
            else:  # as traces.py reads it: message by message, into columns of objects
                per = [readers[topic](r)[0] for r in chosen]
                values = []
                for held in zip(*per, strict=True):
                    column = np.empty(len(held), object)
                    column[:] = held
                    values.append(column)
            cols[topic] = (np.array(at, np.int64), values)
        columns.feed_chunk(
            EventChunk("t", stamps=np.array(stamps, np.int64), columns=cols, first=first + 1)
        )
        msgs = [json.loads(json.dumps(part[i][2])) for i in mine]
        parsed.feed_chunk(EventChunk("t", topics, stamps, msgs, places, parsed_json=True))
        single._feed_events(
            TraceEvent(t, s, m, Location("t", p))
            for t, s, m, p in zip(topics, stamps, msgs, places, strict=True)
        )
        for path in (live, rows, columns, parsed, single):  # each evaluated as far as fed
            for name, rt in path.router.runtimes.items():
                path.results[name].verdicts += rt.evaluate()
        for path in (rows, columns, parsed, single):
            for name, rt in path.router.runtimes.items():
                assert state_of(rt) == state_of(live.router.runtimes[name]), name
    end = max(s for _, s, _ in run)
    out = {}
    for path, check_run in zip(
        ("live", "rows", "columns", "parsed", "single"),
        (live, rows, columns, parsed, single),
        strict=True,
    ):
        out[path] = [outcome(r, True) for r in check_run.finish(end)]
    return out


STEPPED: list[bool] = []  # whether each run of test_every_path_holds_alike stepped


@pytest.mark.parametrize("seed", range(60))
def test_every_path_holds_alike(probe: Service, seed: int) -> None:
    """Random monitors of a service's request, response and info fields (ages of them
    too, an optional inside the optional, with and without initial values, sort windows)
    and of an ordinary topic, over random runs with late events: every path gives the
    per-message path's verdicts, steps, state and late events."""
    rng = random.Random(seed)
    monitors = [random_monitor(rng, f"m{i}") for i in range(rng.randint(1, 3))]
    run = random_run(rng, rng.randint(1, 150))
    outcomes = every_path(monitors, run, probe, rng.choice([1, 3, 16, 64, 500]))
    assert all(o == outcomes["live"] for o in outcomes.values()), (
        [m.spec.assertion for m in monitors],
        outcomes,
    )
    STEPPED.append(any(o[2] for o in outcomes["live"]))


@pytest.mark.parametrize("seed", range(30))
def test_the_live_handlers_long_batches_hold_alike(probe: Service, seed: int) -> None:
    """The live handler (Engine.ingest) fed the values its per-message CDR reader gives:
    batches of 32 messages or more reach the monitors a column at a time (arrays of
    ABSENT and values), the others one message at a time through the router: the same
    verdicts, state, counts and drops as one message at a time."""
    from kit.sidebyside import engine_with, run_side_by_side

    rng = random.Random(seed)
    monitors = [random_monitor(rng, f"m{i}") for i in range(rng.randint(1, 3))]
    run = random_run(rng, rng.randint(1, 400))
    routes = engine_with(monitors)[0].router.routes  # each topic's fields, as its route reads
    readers = {t: compile_reader(r.msg_type, r.fields) for t, r in routes.items()}
    msgs = [
        (stamp, topic, readers[topic](probe.cdr(m) if topic == PROBE_TOPIC else plain_cdr(m))[0])
        for topic, stamp, m in run
        if topic in readers
    ]
    sizes = [rng.choice([1, 3, 32, 40, 64, 200]) for _ in range(len(msgs))]
    run_side_by_side(monitors, msgs, sizes)


def test_a_held_value_is_the_one_of_the_last_event_in_stamp_order(probe: Service) -> None:
    """With a sort window, an event that arrives late is put in its place before its
    value is held: the request a=7 (stamped 20, arriving after the response stamped 30) is
    the value the response event holds. Every path alike."""
    m = compile_monitor(
        spec_of(
            "always (a < 5)",
            {
                "a": {"topic": PROBE_TOPIC, "type": f"{PROBE}_Event", "field": "request[0].a"},
                "s": {
                    "topic": PROBE_TOPIC,
                    "type": f"{PROBE}_Event",
                    "field": "response[0].sum",
                    "initial": 0,
                },
            },
            sortThreshold=3,
        )
    )
    req = {"a": 1, "note": "", "xs": [], "b": 0.0}
    resp = {"sum": 3, "ok": True, "why": "", "code": []}
    run = [
        (PROBE_TOPIC, 10 * MS, srv_event(REQUEST_RECEIVED, 1, req)),
        (PROBE_TOPIC, 30 * MS, srv_event(RESPONSE_SENT, 1, None, resp)),
        (PROBE_TOPIC, 20 * MS, srv_event(REQUEST_RECEIVED, 2, {**req, "a": 7})),
    ]
    for size in (1, 3):
        outcomes = every_path([m], run, probe, size)
        want = [("violated", 20 * MS, 2), ("violated", 30 * MS, 3)]
        assert all(o == [(want, "violated", 3, 0)] for o in outcomes.values()), outcomes


# -- the column reader against the per-message one -------------------------------------------

COLUMN_PATHS = [
    ["info.event_type", "request[0].a", "request[0].b", "response[0].sum", "response[0].ok"],
    ["response[0].ok"],  # past a request of varying size, where it is there
    ["request[0].b", "info.sequence_number"],
    ["info.stamp.nanosec", "response[0].sum"],
]


def _same(a: Any, b: Any) -> bool:
    if type(a) is not type(b):
        return False
    if isinstance(a, float) and (math.isnan(a) or math.isnan(b)):
        return math.isnan(a) and math.isnan(b)
    return bool(a == b)


PROBE_TWICE = Service(PROBE, PROBE_SRV, [], optional="[]")  # optionals of any length


@st.composite
def probe_batches(draw: st.DrawFn) -> tuple[list[str], list[bytes], bool]:
    """A batch of a probe's events: valid, cut short, overwritten, a hostile length, or an
    optional holding two elements (written as an unbounded sequence: what a sequence of
    at most 1 cannot hold, which the per-message reader reads the first of)."""
    paths = draw(st.sampled_from(COLUMN_PATHS))
    rng = random.Random(draw(st.integers(0, 2**32)))
    raws, twice = [], False
    for seq in range(draw(st.integers(1, 8))):
        msg = probe_event(rng, seq)
        how = draw(st.sampled_from(["valid", "valid", "valid", "cut", "hostile", "flip", "two"]))
        if how == "two":
            twice = twice or bool(msg["request"] or msg["response"])
            msg["request"] *= 2
            msg["response"] *= 2
        raw = bytearray(PROBE_TWICE.cdr(msg))
        if how == "cut":
            raw = raw[: draw(st.integers(0, len(raw)))]
        elif how == "hostile":
            at = draw(st.integers(4, max(4, len(raw) - 4)))
            raw[at : at + 4] = b"\xff\xff\xff\xff"
        elif how == "flip":
            raw[draw(st.integers(0, len(raw) - 1))] = draw(st.integers(0, 255))
        raws.append(bytes(raw))
    return paths, raws, twice


@settings(deadline=None, max_examples=400, suppress_health_check=[HealthCheck.too_slow])
@given(batch=probe_batches())
def test_optionals_read_column_wise_are_the_per_message_values(
    probe: Service, batch: tuple[list[str], list[bytes], bool]
) -> None:
    """The column reader gives, ``.tolist()``-ed, what the per-message reader gives message
    by message (ABSENT where an optional is empty), and None where that one raises for a
    message or reads it in full (not little-endian); also where an optional holds two."""
    paths, raws, twice = batch
    event_type = f"{PROBE}_Event"
    reader = compile_column_reader(event_type, paths)
    assert reader is not None
    want: list[Any] | None = []
    one = compile_reader(event_type, paths)
    for raw in raws:
        if len(raw) < 2 or raw[1] != 1:
            want = None
            break
        try:
            assert want is not None
            want.append(one(raw)[0])
        except MALFORMED:
            want = None
            break
    got = reader(*_pack(raws))
    if want is None or (got is None and twice):
        assert got is None
        event("refused")
        return
    assert got is not None, (paths, want)
    columns = [c.tolist() for c in got.values]
    expected = [list(c) for c in zip(*want, strict=True)]
    assert all(
        _same(a, b)
        for column, values in zip(columns, expected, strict=True)
        for a, b in zip(column, values, strict=True)
    ), (columns, expected)
    event("read")


def test_a_valid_batch_of_events_is_read_column_wise(probe: Service) -> None:
    rng = random.Random(5)
    raws = [probe.cdr(probe_event(rng, i)) for i in range(300)]
    for paths in COLUMN_PATHS:
        reader = compile_column_reader(f"{PROBE}_Event", paths)
        assert reader is not None
        got = reader(*_pack(raws))
        assert got is not None
        one = compile_reader(f"{PROBE}_Event", paths)
        assert [c.tolist() for c in got.values] == [
            list(c) for c in zip(*(one(r)[0] for r in raws), strict=True)
        ]
        assert all(c.dtype == object for c, p in zip(got.values, paths, strict=True) if "[0]" in p)
    empty = compile_column_reader(f"{PROBE}_Event", COLUMN_PATHS[0])
    assert empty is not None
    got = empty(np.zeros(0, np.uint8), np.zeros(0, np.int64), np.zeros(0, np.int64))
    assert got is not None and [c.tolist() for c in got.values] == [[]] * 5
    # an optional inside an optional: read message by message
    assert compile_column_reader(f"{PROBE}_Event", ["response[0].code[0]"]) is None


# -- the bytes ROS 2 itself writes -----------------------------------------------------------

ROS_EVENTS = """
import json, sys
from rclpy.serialization import serialize_message
from lifecycle_msgs.srv import ChangeState, GetState
out = []
for i in range(12):
    m = (ChangeState if i % 2 else GetState).Event()
    m.info.event_type = i % 4
    m.info.sequence_number = 1000 + i
    m.info.stamp.sec = i
    if i % 4 < 2 and i % 3:
        m.request = [(ChangeState if i % 2 else GetState).Request()]
        if i % 2:
            m.request[0].transition.id = i
            m.request[0].transition.label = "t" * i
    if i % 4 >= 2 and i % 3:
        r = (ChangeState if i % 2 else GetState).Response()
        if i % 2:
            r.success = bool(i % 3 == 1)
        else:
            r.current_state.id = i
            r.current_state.label = "s" * (i % 5)
        m.response = [r]
    out.append([("ChangeState" if i % 2 else "GetState"), serialize_message(m).hex()])
json.dump(out, sys.stdout)
"""


def test_events_serialized_by_ros_2_itself_read_right() -> None:
    """ROS 2's own serialization (rclpy, the rmw's typesupport: its alignment padding
    left as whatever was in memory) of lifecycle_msgs' GetState and ChangeState events,
    made in another process: both readers give the values set."""
    proc = subprocess.run(
        [sys.executable, "-c", ROS_EVENTS], capture_output=True, text=True, timeout=120
    )
    if proc.returncode and "No module named 'rclpy'" in proc.stderr:
        pytest.skip("rclpy is not installed")
    assert proc.returncode == 0, proc.stderr
    made = json.loads(proc.stdout)
    expected: dict[str, list[list[Any]]] = {"ChangeState": [], "GetState": []}
    raws: dict[str, list[bytes]] = {"ChangeState": [], "GetState": []}
    for i, (kind, data) in enumerate(made):
        request = i % 4 < 2 and i % 3 != 0
        response = i % 4 >= 2 and i % 3 != 0
        if kind == "ChangeState":
            values = [
                i % 4,
                1000 + i,
                i if request else ABSENT,
                "t" * i if request else ABSENT,
                (i % 3 == 1) if response else ABSENT,
            ]
        else:
            values = [
                i % 4,
                1000 + i,
                0 if request else ABSENT,
                i if response else ABSENT,
                "s" * (i % 5) if response else ABSENT,
            ]
        expected[kind].append(values)
        raws[kind].append(bytes.fromhex(data))
    paths = {
        "ChangeState": [
            "info.event_type",
            "info.sequence_number",
            "request[0].transition.id",
            "request[0].transition.label",
            "response[0].success",
        ],
        "GetState": [
            "info.event_type",
            "info.sequence_number",
            "request[0].structure_needs_at_least_one_member",
            "response[0].current_state.id",
            "response[0].current_state.label",
        ],
    }
    for kind, want in expected.items():
        event_type = f"lifecycle_msgs/srv/{kind}_Event"
        one = compile_reader(event_type, paths[kind])
        assert [one(raw)[0] for raw in raws[kind]] == want, kind
        numeric = [p for p in paths[kind] if not p.endswith("label")]
        reader = compile_column_reader(event_type, numeric)
        assert reader is not None
        got = reader(*_pack(raws[kind]))
        assert got is not None
        keep = [i for i, p in enumerate(paths[kind]) if p in numeric]
        assert [c.tolist() for c in got.values] == [[row[i] for row in want] for i in keep], kind
