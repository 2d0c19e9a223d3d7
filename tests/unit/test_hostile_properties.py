"""Hostile input, property by property (issue #15, "fuzzing as a habit").

For each parser and protocol the strategies build *valid* input first (a Monitor
document, an assertion from a small grammar, a JSON Lines trace, a CDR message
serialized by rosbags, a real snapshot bundle, a handoff step's body) and then
mutate it: keys deleted, values of the wrong type, huge and negative numbers,
infinities, deep nesting, random unicode, truncation, bytes flipped. The property
is always the project's contract for bad input:

* documents, assertions, traces: accepted, or :class:`InputError` whose every
  diagnostic is located in the input (the CLI prints them and exits 2);
* CDR readers: values, or one of :data:`edgerv.core.cdr.MALFORMED` (the handler's
  take loop counts the message as malformed and goes on); and when rosbags reads
  the same bytes, the same values;
* the snapshot bundle: frames and snapshots, or :class:`HandoffError`; a snapshot
  that restores runs on without error;
* the control API: a 2xx or 4xx answer, never a 500, and it answers on; its requests
  also as a stream of bytes (heads, bodies chunked or not, pipelined, cut short, damaged):
  every answer JSON, none a 500, and ``/healthz`` answered after;
* bundles whose content is valid but huge (runs of letters swollen): read within their
  budget, or refused for it before they are decoded.

Never another exception, and never a hang: each example runs under a timer
(:func:`bounded`). The examples are derandomized, so a run in CI is reproducible;
``EDGERV_PROPERTY_EXAMPLES=N`` runs N random examples a property instead (``make
fuzz`` does): a failure found so becomes an ``@example`` here.
"""

from __future__ import annotations

import contextlib
import dataclasses
import http.client
import json
import math
import socket
import struct
import sys
import tempfile
import tracemalloc
import urllib.parse
from collections.abc import Callable, Iterator
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import event, example, given
from hypothesis import strategies as st
from prometheus_client import CollectorRegistry

from edgerv.core.cdr import MALFORMED, compile_reader, header_stamp_ns
from edgerv.core.checker import CheckRun, check_types
from edgerv.core.diagnostics import InputError
from edgerv.core.documents import load_monitors_text
from edgerv.core.handoff import (
    BundleTooLarge,
    HandoffError,
    bundle,
    decode,
    encode,
    read_bundle,
    unbundle,
)
from edgerv.core.monitor import CompiledMonitor, compile_monitor, compile_monitors
from edgerv.core.msgtypes import make_getter, typestore
from edgerv.core.pipeline import MonitorRuntime
from edgerv.core.traces import Trace
from edgerv.handler import api as api_module
from edgerv.handler.api import ControlApi
from edgerv.handler.engine import Engine
from edgerv.handler.limits import Limits
from kit.bounded import Hang, bounded
from kit.counts import props
from kit.documents import compiled, spec_of

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "fuzz"))
import fuzz_bundle  # tests/fuzz: the events and the run a restored monitor takes

# -- running examples ------------------------------------------------------------------------------


def assert_located(exc: InputError, path: str, lines: int) -> None:
    """The contract of bad input: errors, each in the file, at a line it has (or none)."""
    assert exc.errors, exc
    for d in exc.diagnostics:
        loc = d.location
        assert loc.path == path, d.render()
        assert loc.line is None or 1 <= loc.line <= lines + 1, d.render()
        assert loc.col is None or loc.col >= 1, d.render()
        assert d.render()


# -- mutating values -------------------------------------------------------------------------------

HUGE = [2**63, 2**64 + 1, -(2**63) - 1, 10**30, -(10**30), 10**8 + 1, -1, 0]
junk: st.SearchStrategy[Any] = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(),
    st.sampled_from(HUGE),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
    st.lists(st.integers(), max_size=3),
    st.dictionaries(st.text(max_size=4), st.integers(), max_size=2),
)


def _paths(tree: Any, here: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [here]
    if isinstance(tree, dict):
        for k, v in tree.items():
            out += _paths(v, (*here, k))
    elif isinstance(tree, list):
        for i, v in enumerate(tree):
            out += _paths(v, (*here, i))
    return out


def _at(tree: Any, path: tuple[Any, ...]) -> Any:
    for step in path:
        tree = tree[step]
    return tree


@st.composite
def mutated(draw: st.DrawFn, tree: Any, rounds: int = 3) -> Any:
    """``tree`` (JSON-like) after a few structural mutations: a key deleted or renamed,
    a value replaced by one of the wrong type or range, wrapped in a list or a mapping."""
    tree = json.loads(json.dumps(tree))  # a deep copy
    for _ in range(draw(st.integers(1, rounds))):
        paths = _paths(tree)
        path = draw(st.sampled_from(paths))
        action = draw(st.sampled_from(["delete", "replace", "rename", "wrap"]))
        if not path:
            if action == "replace":
                tree = draw(junk)
            continue
        parent, key = _at(tree, path[:-1]), path[-1]
        if action == "delete":
            del parent[key]
        elif action == "replace":
            parent[key] = draw(junk)
        elif action == "rename" and isinstance(parent, dict):
            parent[draw(st.text(max_size=8))] = parent.pop(key)
        elif action == "wrap":
            parent[key] = draw(st.sampled_from([[parent[key]], {"x": parent[key]}]))
    return tree


YAML_TOKENS = ["&a ", "*a", "<<: *a", "!!python/object:os.system ", "!!binary ", "!!float ",
               "? ", "- ", "\t", "%YAML 1.1\n", "---\n", "...\n", "{", "}", "[", "]", ":", ",",
               "'", '"', "#", "|", ">", "\\", "\x00", "\x1f", "\ufeff", "\u2028", "1e999", ".nan",
               "1" * 5000]  # fmt: skip


@st.composite
def mutated_text(draw: st.DrawFn, text: str) -> str:
    """Text-level damage: truncation, insertions (random unicode, YAML syntax), a range
    deleted or doubled, brackets or blocks nested far too deep."""
    for _ in range(draw(st.integers(0, 3))):
        at = draw(st.integers(0, len(text)))
        action = draw(
            st.sampled_from(["truncate", "insert", "token", "delete", "double", "deep", "blocks"])
        )
        if action == "truncate":
            text = text[:at]
        elif action == "insert":
            text = text[:at] + draw(st.text(max_size=8)) + text[at:]
        elif action == "token":
            text = text[:at] + draw(st.sampled_from(YAML_TOKENS)) + text[at:]
        elif action == "delete":
            text = text[:at] + text[at + draw(st.integers(1, 20)) :]
        elif action == "double":
            text = text[:at] + text[at : at + 40] + text[at:]
        elif action == "deep":
            depth = draw(st.sampled_from([63, 65, 1000, 50_000]))
            text = text[:at] + "[" * depth + "]" * depth + text[at:]
        else:
            depth = draw(st.sampled_from([30, 70, 2000]))
            text = text[:at] + "".join(f"\n{'  ' * i}k{i}:" for i in range(depth)) + text[at:]
    return text


# -- assertions: a small grammar -------------------------------------------------------------------

SIGNALS: dict[str, tuple[str, str, str]] = {  # name -> (topic, type, field)
    "a": ("/a", "std_msgs/msg/Bool", "data"),
    "x": ("/x", "std_msgs/msg/Float64", "data"),
    "s": ("/s", "std_msgs/msg/String", "data"),
    "v": ("/odom", "nav_msgs/msg/Odometry", "twist.twist.linear.x"),
}
ATOMS = ["a", "x < 5", "5 > x", "x >= lim", "v != 0.5", "s == \"AUTO\"", "true", "!a",
         "age(x) < 100ms", "age(a) >= 1s"]  # fmt: skip
UNARY = ["!", "G", "F", "X", "always", "never", "eventually!", "next", "F[0..3]", "G[1:2]",
         "once", "historically", "prev", "X[2]"]  # fmt: skip
BINARY = ["&", "|", "->", "<->", "U", "W", "R", "M", "xor", "&&", "||", "until", "until!",
          "before", "until_", "since"]  # fmt: skip
JUNK_TOKENS = ["(", ")", "[", "]", "..", "{", "}", ";", "[*]", "|->", "1e999", "-", "age(",
               "ms", "lim", "nosuch", "\"", "=", "!=", "F[", "0..500ms]", "once[0..2s]",
               "\u00e9", "\x00", "G[", "next_e[1..2]", "::", "*", "9" * 5000, "1e-999"]  # fmt: skip

formulas: st.SearchStrategy[list[str]] = st.recursive(
    st.sampled_from(ATOMS).map(lambda a: [a]),
    lambda sub: st.one_of(
        st.tuples(st.sampled_from(UNARY), sub).map(lambda t: [t[0], "(", *t[1], ")"]),
        st.tuples(sub, st.sampled_from(BINARY), sub).map(
            lambda t: ["(", *t[0], ")", t[1], "(", *t[2], ")"]
        ),
    ),
    max_leaves=5,
)


@st.composite
def assertion_tokens(draw: st.DrawFn) -> list[str]:
    tokens = list(draw(formulas))
    for _ in range(draw(st.integers(0, 2))):
        i = draw(st.integers(0, len(tokens) - 1))
        action = draw(st.sampled_from(["delete", "double", "swap", "replace", "insert"]))
        if action == "delete" and len(tokens) > 1:
            del tokens[i]
        elif action == "double":
            tokens.insert(i, tokens[i])
        elif action == "swap" and i + 1 < len(tokens):
            tokens[i], tokens[i + 1] = tokens[i + 1], tokens[i]
        elif action == "replace":
            tokens[i] = draw(st.sampled_from(JUNK_TOKENS + ATOMS + BINARY) | st.text(max_size=3))
        else:
            tokens.insert(i, draw(st.sampled_from(JUNK_TOKENS + UNARY)))
    return tokens


def signal_docs() -> dict[str, Any]:
    return {n: {"topic": t, "type": ty, "field": f} for n, (t, ty, f) in SIGNALS.items()}


@props(150)
@given(assertion_tokens(), st.sampled_from([" ", ""]))
@example(["always", "(", "a", "->", "F[0..500ms]", "x", "<", "5", ")"], " ")
@example(["always", "(", "x", "<", "9" * 5000, ")"], " ")
@example(["always", "(", "age(x)", "<", "1e9999999ms", ")"], " ")  # Fraction took 13 s
@example(["always", "(", "historically[0..1e9999999s]", "a", ")"], " ")
def test_assertions_compile_or_are_refused_at_their_place(tokens: list[str], sep: str) -> None:
    assertion = sep.join(tokens)
    text = yaml.safe_dump(
        {
            "apiVersion": "edgerv.io/v1alpha1",
            "kind": "Monitor",
            "metadata": {"name": "m"},
            "spec": {"assertion": assertion, "signals": signal_docs(), "parameters": {"lim": 3}},
        },
        allow_unicode=True,
    )
    with bounded(20):
        try:
            compile_monitor(load_monitors_text("a.yaml", text)[0])
            event("compiled")
        except InputError as exc:
            assert_located(exc, "a.yaml", text.count("\n") + 1)
            event("refused")


# -- Monitor documents -----------------------------------------------------------------------------


@st.composite
def monitor_docs(draw: st.DrawFn) -> dict[str, Any]:
    signals = signal_docs()
    for sig in signals.values():
        if draw(st.booleans()):
            sig["qos"] = {
                "reliability": draw(st.sampled_from(["auto", "reliable", "best_effort"])),
                "depth": draw(st.integers(1, 1_000_000)),
            }
    if draw(st.booleans()):
        signals["a"]["initial"] = draw(st.booleans())
    threshold = draw(st.integers(1, 50))
    spec: dict[str, Any] = {
        "assertion": " ".join(draw(formulas)),
        "signals": signals,
        "parameters": {"lim": draw(st.integers(-5, 100) | st.floats(-5, 100))},
        "sortThreshold": threshold,
        "bufferCapacity": draw(st.integers(threshold, 10_000)),
        "onVerdict": draw(st.sampled_from(["reset", "halt"])),
    }
    if draw(st.booleans()):
        spec["placement"] = {
            "tier": draw(st.sampled_from(["edge", "cloud"])),
            "migrate": draw(st.sampled_from(["auto", "pinned"])),
            "maxLatencyMs": draw(st.floats(0.5, 1000)),
        }
    return {
        "apiVersion": "edgerv.io/v1alpha1",
        "kind": "Monitor",
        "metadata": {"name": draw(st.from_regex(r"[a-z][a-z0-9-]{0,8}[a-z0-9]", fullmatch=True))},
        "spec": spec,
    }


@st.composite
def document_texts(draw: st.DrawFn) -> str:
    docs = [draw(mutated(draw(monitor_docs()))) if draw(st.booleans()) else draw(monitor_docs())
            for _ in range(draw(st.integers(1, 2)))]  # fmt: skip
    if draw(st.booleans()):
        text = "---\n".join(yaml.safe_dump(d, allow_unicode=True, sort_keys=False) for d in docs)
    else:
        text = "\n---\n".join(json.dumps(d) for d in docs)  # JSON is YAML (the API takes it)
    return str(draw(mutated_text(text)))


def check_documents(text: str, path: str = "m.yaml") -> None:
    """What ``edgerv check`` and ``POST /v1/monitors`` do with a file's text."""
    lines = text.count("\n") + 1
    try:
        specs = load_monitors_text(path, text)
        compile_monitors(specs)
        event("loaded")
    except InputError as exc:
        assert_located(exc, path, lines)
        event("refused")


@props(120)
@given(document_texts())
@example("spec: " + "[" * 50_000 + "]" * 50_000)
@example("a: &a [1, 2]\nb: [*a, *a, *a]\nc: !!python/object:os.system ls\n")
@example("metadata: {name: m\x1f}\n")
@example("spec: {sortThreshold: " + "1" * 5000 + "}\n")
def test_monitor_documents_load_or_are_refused_at_their_place(text: str) -> None:
    with bounded(20):
        check_documents(text)


# -- JSON Lines traces -----------------------------------------------------------------------------


@cache
def trace_monitors() -> tuple[CompiledMonitor, ...]:
    sig = signal_docs()
    return tuple(
        compiled(a, {k: sig[k] for k in ks}, name=f"t{i}", sortThreshold=t)
        for i, (a, ks, t) in enumerate(
            [
                ("always (a -> x < 5)", "ax", 1),
                ('always (age(x) < 50ns | s == "ok")', "xs", 3),
                ("always ((once a) -> v >= 0)", "av", 2),
            ]
        )
    )


@st.composite
def trace_records(draw: st.DrawFn) -> dict[str, Any]:
    stamp = draw(st.integers(0, 10**6))
    topic = draw(st.sampled_from(["/a", "/x", "/s", "/odom", "/other"]))
    msg: dict[str, Any] = {
        "/a": lambda: {"data": draw(st.booleans())},
        "/x": lambda: {"data": draw(st.floats(-10, 10))},
        "/s": lambda: {"data": draw(st.sampled_from(["ok", "no", ""]))},
        "/odom": lambda: {
            "header": {"stamp": {"sec": stamp // 10**9, "nanosec": stamp % 10**9}},
            "twist": {"twist": {"linear": {"x": draw(st.floats(-1, 1))}}},
        },
        "/other": lambda: {"data": 1},
    }[topic]()
    return {"topic": topic, "stamp": stamp, "msg": msg}


@st.composite
def trace_lines(draw: st.DrawFn) -> bytes:
    records = draw(st.lists(trace_records(), min_size=1, max_size=12))
    lines = []
    for r in records:
        if draw(st.integers(0, 3)) == 0:
            r = draw(mutated(r, rounds=2))
        line = json.dumps(r).encode()
        if draw(st.integers(0, 5)) == 0:  # damage the bytes themselves
            at = draw(st.integers(0, len(line)))
            line = (
                line[:at]
                + draw(
                    st.binary(max_size=6)
                    | st.sampled_from([b"[" * 5000, b"\xff\xfe", b"\n", b"{", b'"', b"9" * 5000])
                )
                + line[at:]
            )
        lines.append(line)
    return b"\n".join(lines) + b"\n"


_TRACES = tempfile.TemporaryDirectory(prefix="edgerv-props-")


def check_trace(data: bytes) -> None:
    """What ``edgerv check`` does with a JSON Lines trace: InputError (exit 2), located at
    a line of it, or verdicts; the verdicts before a bad line are still reported."""
    path = Path(_TRACES.name) / "t.jsonl"
    path.write_bytes(data)
    run = CheckRun(trace_monitors())
    trace = Trace(path)
    try:
        trace.inspect(run.topics)
        assert not check_types(run.monitors, trace.msgtypes)
        run.feed(trace.events(run.topics))
        event("checked to the end")
    except InputError as exc:
        assert_located(exc, str(path), data.count(b"\n") + 1)
        event("stopped at a line")
    run.finish(trace.end)  # always: cmd_check prints them


@props(150)
@given(trace_lines())
@example(
    b'{"topic": "/a", "msg": {"data": true, "header": {"stamp": {"sec": 1e999, "nanosec": 0}}}}\n'
)
@example(
    b'{"topic": "/x", "stamp": 1, "msg": {"data": 1.0}}\n'
    b'{"topic": "/a", "stamp": 99999999999999999999999, "msg": {"data": true}}\n'
)
@example(
    b'{"topic": "/a", "stamp": 1, "msg": {"data": true}}\n'
    b'{"topic": "/odom", "msg": {"header": {"stamp": {"sec": 9223372036, "nanosec": 854775808}}, '
    b'"twist": {"twist": {"linear": {"x": 0.5}}}}}\n'
)
@example(b"[" * 50_000 + b"\n")
@example(b'{"topic": "/a", "stamp": ' + b"1" * 5000 + b', "msg": {"data": true}}\n')
def test_json_lines_traces_check_or_stop_at_a_located_line(data: bytes) -> None:  # fmt: skip
    with bounded(20):
        check_trace(data)


# -- CDR readers -----------------------------------------------------------------------------------

CDR_PATHS: dict[str, list[str]] = {
    "std_msgs/msg/String": ["data"],
    "sensor_msgs/msg/LaserScan": ["header.stamp.sec", "ranges[0]", "intensities[2]", "range_max",
                                  "header.frame_id"],
    "nav_msgs/msg/Odometry": ["twist.twist.linear.x", "pose.covariance[35]", "child_frame_id",
                              "header.frame_id"],
    "geometry_msgs/msg/PolygonInstance": ["id", "polygon.points[1].y"],
    "sensor_msgs/msg/JointState": ["name[1]", "position[0]", "effort[2]"],
}  # fmt: skip


@cache
def reader(msg_type: str, paths: tuple[str, ...]) -> Callable[[bytes], Any]:
    return compile_reader(msg_type, paths)


def _header(store: Any, draw: st.DrawFn) -> Any:
    t = store.types
    stamp = t["builtin_interfaces/msg/Time"](
        sec=draw(st.integers(-(2**31), 2**31 - 1)), nanosec=draw(st.integers(0, 2**32 - 1))
    )
    return t["std_msgs/msg/Header"](stamp=stamp, frame_id=draw(st.text(max_size=6)))


def _floats(draw: st.DrawFn, dtype: Any, n: int | None = None) -> Any:
    size = draw(st.integers(0, 5)) if n is None else n
    width = 32 if dtype == np.float32 else 64
    return np.array(draw(st.lists(st.floats(width=width), min_size=size, max_size=size)), dtype)


@st.composite
def cdr_messages(draw: st.DrawFn) -> tuple[str, bytes]:
    """A message of one of the types, as a publisher sends it (rosbags' CDR)."""
    store = typestore()
    t = store.types
    name = draw(st.sampled_from(sorted(CDR_PATHS)))
    if name == "std_msgs/msg/String":
        msg = t[name](data=draw(st.text(max_size=10)))
    elif name == "sensor_msgs/msg/LaserScan":
        f = [draw(st.floats(width=32)) for _ in range(7)]
        msg = t[name](
            _header(store, draw), *f, _floats(draw, np.float32), _floats(draw, np.float32)
        )
    elif name == "nav_msgs/msg/Odometry":
        g = "geometry_msgs/msg/"
        vec = t[g + "Vector3"](*(draw(st.floats()) for _ in range(3)))
        pose = t[g + "Pose"](t[g + "Point"](1.0, 2.0, 3.0), t[g + "Quaternion"](0.0, 0.0, 0.0, 1.0))
        msg = t[name](
            _header(store, draw),
            draw(st.text(max_size=4)),
            t[g + "PoseWithCovariance"](pose, _floats(draw, np.float64, 36)),
            t[g + "TwistWithCovariance"](t[g + "Twist"](vec, vec), _floats(draw, np.float64, 36)),
        )
    elif name == "geometry_msgs/msg/PolygonInstance":
        points = [t["geometry_msgs/msg/Point32"](*(draw(st.floats(width=32)) for _ in range(3)))
                  for _ in range(draw(st.integers(0, 3)))]  # fmt: skip
        msg = t[name](
            t["geometry_msgs/msg/Polygon"](points), draw(st.integers(-(2**63), 2**63 - 1))
        )
    else:
        names = draw(st.lists(st.text(max_size=3), max_size=3))
        msg = t[name](_header(store, draw), names, *(_floats(draw, np.float64) for _ in range(3)))
    return name, bytes(store.serialize_cdr(msg, name))


@st.composite
def damaged(draw: st.DrawFn, data: bytes) -> bytes:
    """Bytes damaged as a buggy or hostile publisher might: truncated, bytes flipped, a
    length word set huge, random bytes appended, the encapsulation changed."""
    buf = bytearray(data)
    for _ in range(draw(st.integers(0, 3))):
        action = draw(st.sampled_from(["truncate", "flip", "length", "append", "endian"]))
        # (a position drawn apart from the length: a deflated bundle's length varies with
        # its content, and what is drawn must not depend on it)
        at = draw(st.integers(0, 1 << 16)) % max(1, len(buf))
        if action == "truncate":
            del buf[at:]
        elif action == "flip" and buf:
            buf[at] = draw(st.integers(0, 255))
        elif action == "length":
            at -= at % 4
            word = draw(st.sampled_from([0, 1, 2, 3, 7, 2**16, 2**24, 2**31 - 1, 2**32 - 1]))
            buf[at : at + 4] = struct.pack("<I", word)
        elif action == "append":
            buf += draw(st.binary(max_size=8))
        elif len(buf) > 1:
            buf[1] = draw(st.sampled_from([0, 1, 2, 3]))  # CDR_BE, CDR_LE, PL_CDR_...
    return bytes(buf)


def _same(got: Any, want: Any) -> bool:
    if isinstance(got, float) and isinstance(want, float) and math.isnan(got):
        return math.isnan(want)
    return bool(got == want and type(got) is type(want))


@props(300)
@given(cdr_messages().flatmap(lambda m: st.tuples(st.just(m[0]), damaged(m[1]))), st.data())
@example(("geometry_msgs/msg/PolygonInstance", b"\x00\x01\x00\x00\xff\xff\xff\xff" + bytes(8)),
         None)  # fmt: skip
def test_cdr_readers_read_what_rosbags_reads_or_raise_malformed(
    message: tuple[str, bytes], data: st.DataObject | None
) -> None:
    msg_type, raw = message
    paths = CDR_PATHS[msg_type]
    if data is not None:
        paths = data.draw(st.lists(st.sampled_from(paths), min_size=1, max_size=3, unique=True))
    read = reader(msg_type, tuple(paths))
    with bounded(5):
        try:
            got: list[Any] | None = read(raw)[0]
        except MALFORMED:
            got = None
        event("read" if got is not None else "malformed")
        with contextlib.suppress(MALFORMED):
            header_stamp_ns(raw)
    try:  # what `edgerv check` on a bag of these bytes reads
        msg = typestore().deserialize_cdr(raw, msg_type)
        want = [make_getter(p)(msg) for p in paths]
    except Exception:
        return  # not a message rosbags reads: the reader may read it or refuse it
    assert got is not None, f"rosbags reads {want}, the reader refused"
    assert all(_same(g, w) for g, w in zip(got, want, strict=True)), (got, want)


@props(200)
@given(st.sampled_from(sorted(CDR_PATHS)), st.binary(max_size=64), st.sampled_from([0, 1]))
def test_cdr_readers_take_random_bytes(msg_type: str, payload: bytes, endian: int) -> None:
    read = reader(msg_type, tuple(CDR_PATHS[msg_type]))
    with bounded(5), contextlib.suppress(MALFORMED):
        read(bytes([0, endian, 0, 0]) + payload)


# -- the snapshot bundle ---------------------------------------------------------------------------

HANDOFF_ASSERTIONS = [
    "always (a -> x < 5)",
    "always (a -> age(x) < 4ns)",
    "always (historically[1ns..6ns] (x < 8) | a)",
    "always ((once a) -> x > 1)",
]


@cache
def handoff_monitor(i: int) -> CompiledMonitor:
    return compiled(HANDOFF_ASSERTIONS[i], {"a": "bool", "x": "float"}, sortThreshold=8)


def _events(seed: int, n: int, start: int = 100) -> list[tuple[int, int, list[tuple[int, Any]]]]:
    return fuzz_bundle.events(seed, n, start)


@cache
def real_frame(i: int, seed: int) -> bytes:
    rt = MonitorRuntime(handoff_monitor(i))
    rt.holding = True
    for stamp, seq, updates in _events(seed, 60):
        rt.offer(stamp, seq, updates)
    return encode(rt.snapshot(cut=100 + 40 * (seed % 3 + 1), epoch=7))


def _reframe(header: Any, body: bytes) -> bytes:
    h = header if isinstance(header, bytes) else json.dumps(header, allow_nan=True).encode()
    return struct.pack("!4sII", b"ERV3", len(h), len(body)) + h + body


@st.composite
def frames(draw: st.DrawFn) -> tuple[int, bytes]:
    """A real snapshot frame of one of the monitors, with its JSON header mutated (and
    the frame's lengths kept right, so the damage reaches the checks behind them), or
    its bytes damaged."""
    i = draw(st.integers(0, len(HANDOFF_ASSERTIONS) - 1))
    frame = real_frame(i, draw(st.integers(0, 5)))
    hlen = struct.unpack_from("!I", frame, 4)[0]
    header, body = json.loads(frame[12 : 12 + hlen]), frame[12 + hlen :]
    how = draw(st.sampled_from(["header", "values", "body", "bytes", "as is"]))
    if how == "header":
        frame = _reframe(draw(mutated(header)), body)
    elif how == "values":  # the signal values a restored monitor goes on from
        values = header["values"]
        values[draw(st.integers(0, len(values) - 1))] = draw(
            st.text(max_size=3) | st.sampled_from([[1], {"k": 1}, True, None, 2**70, math.nan])
        )
        frame = _reframe(header, body)
    elif how == "body":
        frame = _reframe(header, draw(damaged(body)))
    elif how == "bytes":
        frame = draw(damaged(frame))
    return i, frame


def check_frames(i: int, wire: bytes) -> None:
    try:
        for frame in unbundle(wire, limit=1 << 20):
            snap = decode(frame)
            at = max(-(2**62), min(snap.cut, 2**62))  # real stamps: 64 bits
            fuzz_bundle.run_on(
                MonitorRuntime.restored(handoff_monitor(i), snap, fuzz_bundle.held(at)), at
            )
            event("restored and ran on")
    except HandoffError:
        event("refused")


@props(300)
@given(st.lists(frames(), min_size=1, max_size=2), st.sampled_from(["bundle", "damaged bundle"]),
       st.data())  # fmt: skip
@example([(0, _reframe([], b""))], "bundle", None)
@example([(0, _reframe({"v": 3, "n": 1e999}, b""))], "bundle", None)
@example([(0, _reframe(b"[" * 5000 + b"]" * 5000, b""))], "bundle", None)
def test_bundles_unbundle_decode_and_restore_or_raise_handoff_errors(
    items: list[tuple[int, bytes]], how: str, data: st.DataObject | None
) -> None:
    wire = bundle(frame for _, frame in items)
    if how == "damaged bundle" and data is not None:
        wire = data.draw(damaged(wire))
    with bounded(10):
        check_frames(items[0][0], wire)


# -- the control API: handoff steps and Monitor documents over HTTP --------------------------------

TOKEN = "props-token"


class Api:
    """A real handler API (aiohttp, its own thread) over an engine with two monitors: ``m``
    runs here, ``n`` is only defined (a receiver's side)."""

    def __init__(self, limits: Limits | None = None) -> None:
        self.engine = Engine("props", flush_after=1e9)
        monitor = handoff_monitor(0)
        self.engine.put(monitor, active=True)
        other = compile_monitor(spec_of("always (a -> x < 5)", {"a": "bool", "x": "float"}, "n"))
        self.engine.put(other, active=False)
        self.api = ControlApi(
            self.engine, CollectorRegistry(), TOKEN, on_change=lambda: None, limits=limits
        )
        self.api.start("127.0.0.1", 0)
        self.conn = http.client.HTTPConnection("127.0.0.1", self.api.port, timeout=20)
        self.epoch = 10**15  # for the steps a test prepares (above what strategies draw)

    def call(self, method: str, path: str, body: bytes = b"") -> tuple[int, bytes]:
        headers = {"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"}
        for attempt in (1, 2):
            try:
                self.conn.request(method, path, body=body or None, headers=headers)
                resp = self.conn.getresponse()
                return resp.status, resp.read()
            except (http.client.HTTPException, ConnectionError):
                self.conn.close()  # the server closed a kept-alive connection: once more
                if attempt == 2:
                    raise
        raise AssertionError("unreachable")

    def reset(self) -> None:
        """Undo whatever a request left (a hold, a receive, a release, new monitors)."""
        e = self.engine
        for name, slot in list(e.slots.items()):
            if name not in ("m", "n"):
                e.remove(name)
            elif slot.handoff is not None:
                e.handoffs.abort(name, slot.epoch)
        if e.slots["n"].runtime is not None:  # adopted: a receiver's side again
            e.set_active("n", False)
        if e.slots["m"].runtime is None:
            e.set_active("m", True)

    def close(self) -> None:
        self.conn.close()
        self.api.stop()


@pytest.fixture(scope="module")
def api() -> Iterator[Api]:
    wait = api_module.MAX_WAIT
    api_module.MAX_WAIT = 0.05  # a release waits this long at most for events (not 5 s)
    server = Api()
    yield server
    server.close()
    api_module.MAX_WAIT = wait


STEPS = ["hold", "receive", "cut", "release", "commit", "abort", "adopt"]


@st.composite
def step_bodies(draw: st.DrawFn) -> tuple[str, Any]:
    step = draw(st.sampled_from(STEPS))
    names = draw(st.lists(st.sampled_from(["m", "n", "nosuch"]), min_size=1, max_size=2))
    body: dict[str, Any] = {"epoch": draw(st.integers(1, 10**12)), "monitors": names}
    if step == "hold":
        body["peer"] = "http://127.0.0.1:1"
    if step == "release":
        body.update(cuts={n: draw(st.integers(0, 10**6)) for n in names},
                    quiet={n: ["/a"] for n in names}, grace=0.0, wait=0.01)  # fmt: skip
    return step, draw(mutated(body)) if draw(st.integers(0, 3)) else body


def _prepare(api: Api, step: str, epoch: Any) -> bool:
    """Bring the engine to where a step applies (a hold before a release, a receive before a
    cut or an adoption): mutations then reach the step's own checks. False: no valid epoch."""
    if not isinstance(epoch, int) or isinstance(epoch, bool) or not 1 < epoch < 2**62:
        return False
    e = api.engine
    with contextlib.suppress(HandoffError):
        if step in ("release", "commit"):
            e.handoffs.hold("m", epoch - 1)
        elif step in ("cut", "adopt"):
            e.handoffs.receive("n", epoch)
    return True


def adoptable(api: Api, epoch: int) -> bytes:
    """A snapshot bundle of ``n`` for the handoff ``epoch``: what a sender releases."""
    rt = MonitorRuntime(api.engine.slots["n"].compiled)
    rt.holding = True
    for stamp, seq, updates in _events(3, 40):
        rt.offer(stamp, seq, updates)
    return bundle([encode(rt.snapshot(cut=150, epoch=epoch))])


@props(150)
@given(step_bodies(), st.booleans(), st.data())
@example(("cut", {"epoch": 1e999, "monitors": ["m"]}), False, None)
@example(("release", {"epoch": 5, "monitors": ["m"], "cuts": {"m": 1e999}}), True, None)
@example(("release", {"epoch": 5, "monitors": ["m"], "cuts": {"m": 1}, "quiet": []}), True, None)
@example(("hold", [1, 2]), False, None)
def test_handoff_steps_answer_2xx_or_4xx_never_500(
    api: Api, call: tuple[str, Any], prepared: bool, data: st.DataObject | None
) -> None:
    step, body = call
    epoch = body.get("epoch") if isinstance(body, dict) else None
    if prepared and isinstance(epoch, int) and not isinstance(epoch, bool) and epoch > 1:
        api.epoch += 10  # newer than any before: epochs fence stale steps
        epoch = body["epoch"] = api.epoch
    try:
        with bounded(10):
            if prepared and _prepare(api, step, epoch) and step == "adopt":
                assert isinstance(epoch, int)
                wire = adoptable(api, epoch)
                if data is not None and data.draw(st.booleans()):
                    wire = data.draw(damaged(wire))
            else:
                wire = json.dumps(body).encode()
            query = urllib.parse.quote(str(epoch))
            path = f"/v1/handoff/adopt?epoch={query}" if step == "adopt" else f"/v1/handoff/{step}"
            status, answer = api.call("POST", path, wire)
            assert status < 500, (status, answer)
            event(f"{step}: {status}")
            assert api.call("GET", "/healthz")[0] == 200
            for _ in range(3):  # and the engine runs on
                api.engine.emit(api.engine.tick())
    finally:
        api.reset()


@props(60)
@given(document_texts())
def test_posted_documents_answer_2xx_or_4xx_never_500(api: Api, text: str) -> None:
    try:
        with bounded(20):
            status, answer = api.call("POST", "/v1/monitors", text.encode())
            assert status in (201, 400, 409, 413), (status, answer)
            event(str(status))
            if status == 400:
                errors = json.loads(answer)["errors"]
                assert errors and all(e["location"].startswith("request") for e in errors)
    finally:
        api.reset()


# -- the control API's requests as a stream of bytes -------------------------------------------

WIRE_LIMITS = Limits(read_seconds=0.5, idle_seconds=0.5, bodies=8 << 20, bundle=4 << 20)
CALLS = [
    ("GET", "/healthz"), ("GET", "/metrics"), ("GET", "/v1/monitors"), ("GET", "/v1/load"),
    ("GET", "/v1/monitors/m"), ("POST", "/v1/monitors"), ("PUT", "/v1/monitors/p"),
    ("DELETE", "/v1/monitors/p"), ("POST", "/v1/monitors/m/deactivate"),
    ("POST", "/v1/monitors/n/activate"), ("GET", "/nosuch"), ("PATCH", "/v1/monitors"),
    *(("POST", f"/v1/handoff/{step}") for step in STEPS),
]  # fmt: skip
HEAD_JUNK = [b"Transfer-Encoding: chunked\r\n", b"Content-Length: -1\r\n",
             b"Content-Length: 99999999999999999999\r\n", b"Expect: 100-continue\r\n",
             b"Content-Encoding: gzip\r\n", b"X: " + b"y" * 9000 + b"\r\n", b"\x00\r\n",
             b"Authorization: Bearer " + b"t" * 5000 + b"\r\n", b"Host\r\n"]  # fmt: skip


def _document(name: str) -> bytes:
    return json.dumps(
        {"apiVersion": "edgerv.io/v1alpha1", "kind": "Monitor", "metadata": {"name": name},
         "spec": {"assertion": "always (a -> x < 5)",
                  "signals": {"a": {"topic": "/a", "type": "std_msgs/msg/Bool"},
                              "x": {"topic": "/x", "type": "std_msgs/msg/Float64"}}}}
    ).encode()  # fmt: skip


@dataclasses.dataclass
class Call:
    """One request of :func:`http_requests`, described; :func:`wire_of` makes its bytes."""

    method: str
    path: str
    token: str | None
    body: bytes  # b"<bundle>", b"<huge bundle>": one made at run time, for the epoch
    framing: str  # length, chunked, short (one byte less), long (more), none
    junk: bytes  # a header line, or nothing
    chunks: list[int]  # chunked: the chunks' sizes
    bad_chunk: bytes  # chunked: a bad size line before the chunks, or nothing


@st.composite
def http_requests(draw: st.DrawFn) -> tuple[int, list[Call]]:
    """A request or two pipelined, built valid (a call of the API, its token, a body framed
    by its length or in chunks) and then damaged: a wrong length, a bad chunk, a junk
    header. Returns the epoch an ``adopt`` is for (its bundle is made then: it needs a
    receiving monitor), and the calls."""
    epoch = draw(st.integers(10, 10**6))
    calls = []
    for _ in range(draw(st.integers(1, 2))):
        method, path = draw(st.sampled_from(CALLS))
        step = path.rsplit("/", 1)[-1]
        if step == "adopt":
            path += f"?epoch={epoch}"
            body = draw(st.sampled_from([b"<bundle>", b"<huge bundle>", b"not a bundle"]))
        elif path.startswith("/v1/handoff/"):
            names = draw(st.lists(st.sampled_from(["m", "n", "nosuch"]), min_size=1, max_size=2))
            request = {"epoch": draw(st.sampled_from([epoch, 10**29, -1])), "monitors": names,
                       "cuts": dict.fromkeys(names, 200), "grace": 0.0, "wait": 0.01}  # fmt: skip
            body = json.dumps(request).encode()
        elif method in ("POST", "PUT"):
            body = _document(path.rsplit("/", 1)[-1] if method == "PUT" else "q")
        else:
            body = b""
        calls.append(
            Call(
                method, path, draw(st.sampled_from([TOKEN, TOKEN, "wrong", None])), body,
                draw(st.sampled_from(["length"] * 4 + ["chunked"] * 2 + ["short", "long", "none"])),
                draw(st.sampled_from(HEAD_JUNK)) if draw(st.integers(0, 4)) == 3 else b"",
                draw(st.lists(st.integers(1, 4096), max_size=4)),
                draw(st.sampled_from([b"zz\r\n", b"-1\r\n", b"ffffffffffff\r\n"]))
                if draw(st.integers(0, 3)) == 2 else b"",
            )
        )  # fmt: skip
    return epoch, calls


def wire_of(call: Call, bundles: dict[bytes, bytes]) -> bytes:
    """A call's bytes (``bundles``: what the placeholders stand for)."""
    body = bundles.get(call.body, call.body)
    head = [f"{call.method} {call.path} HTTP/1.1\r\nHost: edge\r\n".encode()]
    if call.token:
        head.append(f"Authorization: Bearer {call.token}\r\n".encode())
    if call.framing == "chunked":
        head.append(b"Transfer-Encoding: chunked\r\n")
        body = call.bad_chunk + _chunked(body, call.chunks)
    elif call.framing != "none":
        size = {"short": -1, "long": 7}.get(call.framing, 0) + len(body)
        head.append(f"Content-Length: {max(0, size)}\r\n".encode())
    if call.framing == "long":
        head.append(b"Connection: close\r\n")  # it waits for the rest: the last one
    return b"".join(head) + call.junk + b"\r\n" + body


def _chunked(body: bytes, sizes: list[int]) -> bytes:
    out, at = b"", 0
    for size in [*sizes, len(body)]:
        if at < len(body):
            out += b"%x\r\n%s\r\n" % (len(body[at : at + size]), body[at : at + size])
            at += size
    return out + b"0\r\n\r\n"


def _answers(data: bytes) -> list[tuple[int, bytes, bytes]]:
    """The answers in what the API sent back, each whole one: status, head, body."""
    out = []
    while data:
        top, sep, rest = data.partition(b"\r\n\r\n")
        if not sep:
            break
        status = int(top.split(b" ", 2)[1])
        length = 0
        for line in top.split(b"\r\n")[1:]:
            name, _, value = line.partition(b":")
            if name.strip().lower() == b"content-length":
                length = int(value)
        out.append((status, top, rest[:length]))
        data = rest[length:]
    return out


@pytest.fixture(scope="module")
def wire_api() -> Iterator[Api]:
    wait = api_module.MAX_WAIT
    api_module.MAX_WAIT = 0.05
    server = Api(WIRE_LIMITS)
    yield server
    server.close()
    api_module.MAX_WAIT = wait


@props(80)
@given(http_requests(), st.data())
@example((10, [Call("GET", "/healthz", None, b"", "none", HEAD_JUNK[0], [], b"")]), None)
@example((10, [Call("POST", "/v1/monitors", TOKEN, b"x", "length", b"Content-Encoding: gzip\r\n",
                    [], b"")]), None)  # fmt: skip
def test_the_apis_requests_as_bytes_answer_json_never_500(
    wire_api: Api, call: tuple[int, list[Call]], data: st.DataObject | None
) -> None:
    epoch, calls = call
    try:
        with contextlib.suppress(HandoffError):
            wire_api.engine.handoffs.receive("n", epoch)  # an adopt finds a handoff receiving
        real = adoptable(wire_api, epoch)
        bundles = {  # the huge one: valid, and past the budget once decoded
            b"<bundle>": real,
            b"<huge bundle>": bundle([fuzz_bundle.swollen(unbundle(real)[0], 10**5)]),
        }
        wire = b"".join(wire_of(c, bundles) for c in calls)
        wire += b"GET /healthz HTTP/1.1\r\nHost: e\r\nConnection: close\r\n\r\n"
        if data is not None and data.draw(st.integers(0, 5)) == 3:  # (0: the likeliest)
            wire = data.draw(damaged(wire))
        with bounded(20), socket.create_connection(("127.0.0.1", wire_api.api.port or 0)) as sock:
            sock.settimeout(10)
            with contextlib.suppress(OSError):  # the API may close before it has all
                sock.sendall(wire)
            got = b""
            with contextlib.suppress(OSError):
                while chunk := sock.recv(65536):
                    got += chunk
        assert b"Traceback" not in got
        for status, top, body in _answers(got):
            if status < 200:
                continue  # 100 Continue: the answer follows
            event(f"{status}")
            assert status < 500 or status == 503, (status, top, body)
            if top.lower().find(b"content-type: text/plain; version=") >= 0:
                assert status == 200  # /metrics (an empty registry here)
            else:
                assert b"application/json" in top, (top, body)
                json.loads(body)
        with bounded(20):
            assert wire_api.call("GET", "/healthz")[0] == 200
            for _ in range(3):  # and the engine runs on
                wire_api.engine.emit(wire_api.engine.tick())
    finally:
        wire_api.reset()


# -- bundles whose content is valid but huge -----------------------------------------------------


@props(60)
@given(
    st.lists(st.tuples(st.integers(0, len(HANDOFF_ASSERTIONS) - 1), st.integers(0, 5),
                       st.sampled_from([1, 3, 100, 10**4, 10**5, 4 * 10**5, 10**6, 2**32])),
             min_size=1, max_size=4),
    st.sampled_from([1 << 20, 4 << 20]),
)  # fmt: skip
def test_valid_but_huge_bundles_are_read_within_their_budget_or_refused_undecoded(
    frames: list[tuple[int, int, int]], budget: int
) -> None:
    """Snapshots whose runs of letters are swollen (each run ``factor`` times as long: a
    valid snapshot, as small on the wire): :func:`read_bundle` returns them, having taken
    no more than its budget (tracemalloc), or refuses them before any is decoded."""
    wire = bundle(fuzz_bundle.swollen(real_frame(i, seed), factor) for i, seed, factor in frames)
    tracemalloc.start()
    try:
        with bounded(20):
            snaps = read_bundle(wire, budget)
        event("read")
        assert len(snaps) == len(frames)
        _, peak = tracemalloc.get_traced_memory()
        assert peak <= budget + (256 << 10), (peak, budget)
    except BundleTooLarge:
        event("over the budget")
        _, peak = tracemalloc.get_traced_memory()
        assert peak < 256 << 10, peak  # refused before anything was decoded
    except HandoffError as exc:  # a run past 2^32 - 1 letters, or more than 16 Mi letters
        event("refused")
        assert "out of range" in str(exc) or "count" in str(exc), exc
    finally:
        tracemalloc.stop()


def test_the_timer_catches_a_hang() -> None:
    """``bounded`` itself: a loop that never ends fails the example instead of the run."""
    with pytest.raises(Hang), bounded(0.05):
        while True:
            pass


MONITOR = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: m}
spec:
  assertion: "always (a -> x < 5)"
  signals:
    a: {topic: /a, type: std_msgs/msg/Bool}
    x: {topic: /x, type: std_msgs/msg/Float64}
"""
GOOD_LINE = b'{"topic": "/x", "stamp": 1, "msg": {"data": 1.0}}\n'


@pytest.mark.parametrize(
    ("monitors", "trace", "expected"),
    [
        (MONITOR.replace("{name: m}", "{name: m\x1f}"), GOOD_LINE,
         "m.yaml:3:19: error: invalid YAML: control characters are not allowed (U+001F)"),
        (MONITOR + "  sortThreshold: " + "1" * 5000 + "\n", GOOD_LINE,
         "m.yaml:9:18: error: spec.sortThreshold: invalid value: a number too long to read"),
        (MONITOR.replace("x < 5", "age(x) < 1e9999999ms"), GOOD_LINE,
         "m.yaml:5:37: error: '1e9999999ms' is not a whole number of nanoseconds"),
        (MONITOR, GOOD_LINE + b'{"topic": "/a", "stamp": 99999999999999999999999, "msg": '
         b'{"data": true}}\n', "t.jsonl:2: error: stamp 99999999999999999999999 is out of the "
         "range of 64-bit nanoseconds"),
        (MONITOR, b'{"topic": "/a", "msg": {"data": true, "header": {"stamp": '
         b'{"sec": 1e999, "nanosec": 0}}}}\n', "t.jsonl:1: error: missing 'stamp'"),
        (MONITOR, b'{"topic": "/a", "stamp": ' + b"1" * 5000 + b"}\n",
         "t.jsonl:1: error: invalid JSON: a number too long to read"),
    ],
)  # fmt: skip
def test_what_the_properties_found_exits_2_with_its_place(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monitors: str, trace: bytes, expected: str
) -> None:
    """``edgerv check`` on inputs the properties found (a traceback and exit 1 before)."""
    from edgerv.cli import main

    (tmp_path / "m.yaml").write_text(monitors)
    (tmp_path / "t.jsonl").write_bytes(trace)
    with bounded(20):
        code = main(["check", str(tmp_path / "m.yaml"), str(tmp_path / "t.jsonl")])
    err = capsys.readouterr().err
    assert code == 2, err
    assert expected in err.replace(f"{tmp_path}/", ""), err
