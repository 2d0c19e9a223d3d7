"""The column-wise CDR reader against the per-message one, which is the reference.

Batches of random messages (rosbags' serializer, random strings and sequence lengths that
move every later field to another alignment) sit at random, unaligned offsets of one buffer
with junk bytes between them. A column reader must give, once ``.tolist()``-ed, exactly
what :func:`edgerv.core.cdr.compile_reader` gives message by message, and None exactly when
the per-message reader would raise for one of them or read it by full deserialization (not
little-endian CDR): truncated messages, hostile lengths and random bytes included, never an
exception.
"""

from __future__ import annotations

import functools
import math
import random
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from edgerv.core.cdr import MALFORMED, compile_reader
from edgerv.core.cdr_columns import ColumnReader, Columns, compile_column_reader
from edgerv.core.msgtypes import parse_field_path, register_definition, typestore
from kit.ros_numpy import NUMPY_TYPES

PKG = "edgerv_columns_test/msg/"
DEFINITIONS = {
    "Odd": "float64 x\nuint8 y\n",  # from the second element on, each starts at 1 mod 8
    "Pad": "uint8 a\nuint16 b\n",
    "Wide": "wstring w\nfloat64 x\n",
    # a wanted message is walked to its end: its trailing sequence's count is read too
    "Inner": "float64 v\nfloat32[] tail\n",
    "Outer": "uint8 a\nInner inner\nstring rest\n",
    # a sequence of float64 whose count leaves the offset at 4 mod 8: aligned only if not empty
    "Gap": "float64[] d\nuint32 after_d\nfloat64 x\n",
    # fixed-size messages skipped while the offset is still the same in every message
    "Early": """
uint8 a
Odd[2] pair
uint16 after_pair
uint32 c
Odd[] odds
uint8 after_odds
Pad[] pads
int64 last
""",
    "Mix": """
byte b
char c
int8 i8
uint8 u8
float32 f32
uint64 u64
bool flag
int16 i16
uint16 u16
byte[3] barr
char[2] carr
uint32 before_d
float64[] d
uint32 after_d
int8[] small
uint64 after_small
bool[] flags
int16 after_flags
string name
float32 after_name
uint16[2] pair
geometry_msgs/Point32[] points
uint8 after_points
Odd[] odds
int32 after_odds
Pad[] pads
uint8 after_pads
Odd[2] odd_pair
uint16 after_odd_pair
uint64[] u64s
int64 last
""",
}


def _register() -> None:
    for name, text in DEFINITIONS.items():
        assert register_definition(PKG + name, "ros2msg", text)


_register()

MIX_PATHS = [
    "b",
    "c",
    "i8",
    "u8",
    "f32",
    "u64",
    "flag",
    "i16",
    "u16",
    "barr[2]",
    "barr[0]",
    "carr[1]",
    "before_d",
    "after_d",
    "after_small",
    "after_flags",
    "after_name",
    "pair[1]",
    "after_points",
    "after_odds",
    "after_pads",
    "after_odd_pair",
    "u64s[0]",
    "last",
]

IMU_PATHS = [
    "linear_acceleration.z",
    "orientation_covariance[4]",
    "orientation.w",
    "angular_velocity_covariance[8]",
]

# (type, paths, fewest elements in each sequence of a message)
CASES: list[tuple[str, list[str], int]] = [
    ("std_msgs/msg/Bool", ["data"], 0),
    ("std_msgs/msg/Float64", ["data"], 0),
    ("std_msgs/msg/Int32", ["data"], 0),
    ("std_msgs/msg/UInt64", ["data"], 0),
    ("std_msgs/msg/String", [], 0),
    ("geometry_msgs/msg/PointStamped", ["point.x", "point.z", "header.stamp.sec"], 0),
    ("geometry_msgs/msg/PoseStamped", ["pose.orientation.w", "pose.position.y"], 0),
    ("geometry_msgs/msg/Twist", ["linear.x", "angular.z"], 0),
    (
        "nav_msgs/msg/Odometry",
        [
            "twist.twist.linear.x",
            "pose.pose.position.x",
            "pose.covariance[7]",
            "twist.covariance[35]",
            "header.stamp.nanosec",
        ],
        0,
    ),
    ("sensor_msgs/msg/LaserScan", ["ranges[0]", "ranges[5]", "angle_max", "range_min"], 0),
    ("sensor_msgs/msg/LaserScan", ["ranges[0]", "ranges[5]", "angle_max", "range_min"], 6),
    ("sensor_msgs/msg/LaserScan", ["scan_time", "intensities[1]"], 2),
    ("sensor_msgs/msg/Imu", IMU_PATHS, 0),
    (
        "sensor_msgs/msg/BatteryState",
        ["percentage", "present", "power_supply_status", "cell_voltage[1]", "cell_temperature[0]"],
        2,
    ),
    (
        "sensor_msgs/msg/NavSatFix",
        ["latitude", "status.service", "status.status", "position_covariance[8]"],
        0,
    ),
    ("sensor_msgs/msg/CameraInfo", ["k[0]", "binning_x", "roi.width", "roi.do_rectify"], 0),
    ("sensor_msgs/msg/CameraInfo", ["d[0]", "p[11]", "height"], 1),
    (PKG + "Mix", MIX_PATHS, 0),
    (PKG + "Mix", MIX_PATHS, 1),
    (PKG + "Early", ["a", "after_pair", "c", "after_odds", "last"], 0),
    (PKG + "Gap", ["after_d", "x"], 0),
    (PKG + "Outer", ["inner.v"], 0),
    ("geometry_msgs/msg/PointStamped", [], 0),  # the stamp alone
]

# -- random messages ---------------------------------------------------------------------


def _scalar(base: str, rng: random.Random) -> Any:
    if base == "bool":
        return rng.random() < 0.5
    if base == "byte":  # rosbags packs a scalar byte signed
        return rng.randint(-128, 127)
    if base in ("float32", "float64"):
        if rng.random() < 0.8:
            return float(np.float32(rng.uniform(-1e6, 1e6)))
        return float(
            np.frombuffer(rng.randbytes(NUMPY_TYPES[base]().itemsize), NUMPY_TYPES[base])[0]
        )
    info = np.iinfo(NUMPY_TYPES[base])
    return rng.randint(int(info.min), int(info.max))


def _value(node: tuple[Any, Any], rng: random.Random, fewest: int) -> Any:
    kind, payload = int(node[0]), node[1]
    if kind == 1:
        if payload[0] == "string":
            return "".join(rng.choice("ab/_é€") for _ in range(rng.randint(0, 12)))
        return _scalar(payload[0], rng)
    if kind == 2:
        return _message(payload, rng, fewest)
    elem, count = payload
    n = count if kind == 3 else rng.randint(fewest, fewest + 6)
    values = [_value(elem, rng, fewest) for _ in range(n)]
    if int(elem[0]) == 1 and elem[1][0] in NUMPY_TYPES:
        dtype = np.uint8 if elem[1][0] == "byte" else NUMPY_TYPES[elem[1][0]]
        return np.array([v & 0xFF if elem[1][0] == "byte" else v for v in values], dtype=dtype)
    return values


def _message(msg_type: str, rng: random.Random, fewest: int = 0) -> Any:
    store = typestore()
    fields = store.fielddefs[msg_type][1]
    return store.types[msg_type](**{name: _value(node, rng, fewest) for name, node in fields})


def _serialize(msg_type: str, rng: random.Random, fewest: int = 0, little: bool = True) -> bytes:
    msg = _message(msg_type, rng, fewest)
    return bytes(typestore().serialize_cdr(msg, msg_type, little_endian=little))


# -- the differential check --------------------------------------------------------------


def _pack(
    raws: list[bytes], rng: random.Random
) -> tuple[np.ndarray[Any, np.dtype[np.uint8]], np.ndarray[Any, Any], np.ndarray[Any, Any]]:
    """The messages in one buffer, at random offsets, with junk bytes between them."""
    parts = [rng.randbytes(rng.randint(0, 7))]
    starts, ends = [], []
    at = len(parts[0])
    for raw in raws:
        junk = rng.randbytes(rng.randint(0, 7))
        starts.append(at)
        ends.append(at + len(raw))
        parts += [raw, junk]
        at += len(raw) + len(junk)
    buf = np.frombuffer(b"".join(parts), np.uint8)
    return buf, np.array(starts, np.int64), np.array(ends, np.int64)


@functools.cache
def _column_reader(msg_type: str, paths: tuple[str, ...]) -> ColumnReader:
    reader = compile_column_reader(msg_type, paths)
    assert reader is not None, (msg_type, paths)
    return reader


@functools.cache
def _message_reader(msg_type: str, paths: tuple[str, ...]) -> Any:
    return compile_reader(msg_type, paths)


def _reference(msg_type: str, paths: tuple[str, ...], raws: list[bytes]) -> list[Any] | None:
    """Each message's (values, stamp), or None when one is read by full deserialization
    or refused."""
    reader = _message_reader(msg_type, paths)
    rows = []
    for raw in raws:
        if len(raw) < 2 or raw[1] != 1:
            return None
        try:
            rows.append(reader(raw))
        except MALFORMED:
            return None
    return rows


def _same(a: Any, b: Any) -> bool:
    if type(a) is not type(b):
        return False
    if isinstance(a, float):
        if math.isnan(a) or math.isnan(b):
            return math.isnan(a) and math.isnan(b)
        return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)
    return bool(a == b)


def _dtype(msg_type: str, path: str) -> Any:
    """The dtype of a column: bool, uint64, float64 for both floats, int64 for other ints."""
    node: Any = (2, msg_type)
    for step in parse_field_path(path):
        node = dict(typestore().fielddefs[node[1]][1])[step.name]
        for _ in step.indexes:
            node = node[1][0]
    base = node[1][0]
    return {"bool": np.bool_, "uint64": np.uint64}.get(
        base, np.float64 if base.startswith("float") else np.int64
    )


def _check(msg_type: str, paths: list[str], raws: list[bytes], rng: random.Random) -> bool:
    """The column reader against the reference on ``raws``; whether it read them."""
    key = tuple(paths)
    got = _column_reader(msg_type, key)(*_pack(raws, rng))
    want = _reference(msg_type, key, raws)
    if want is None:
        assert got is None
        return False
    assert isinstance(got, Columns)
    assert [c.dtype for c in got.values] == [_dtype(msg_type, p) for p in paths]
    assert all(c.shape == (len(raws),) for c in got.values)
    columns = [c.tolist() for c in got.values]
    expected = [[values[i] for values, _ in want] for i in range(len(paths))]
    assert all(
        _same(a, b)
        for column, values in zip(columns, expected, strict=True)
        for a, b in zip(column, values, strict=True)
    ), (columns, expected)
    stamps = [stamp for _, stamp in want]
    if stamps[0] is None:
        assert got.stamps is None
    else:
        assert got.stamps is not None and got.stamps.dtype == np.int64
        assert got.stamps.tolist() == stamps
    return True


# -- valid messages ----------------------------------------------------------------------


@pytest.mark.parametrize(("msg_type", "paths", "fewest"), CASES)
@settings(deadline=None, max_examples=25, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32), size=st.integers(1, 12))
def test_columns_are_the_per_message_values(
    msg_type: str, paths: list[str], fewest: int, seed: int, size: int
) -> None:
    rng = random.Random(seed)
    raws = [_serialize(msg_type, rng, fewest) for _ in range(size)]
    read = _check(msg_type, paths, raws, rng)
    short = any(f"[{i}]" in p for p in paths for i in range(fewest, 9))
    assert read or short  # only a wanted index beyond a short sequence refuses valid messages


def test_many_messages_with_the_same_layout() -> None:
    rng = random.Random(3)
    raws = [_serialize("sensor_msgs/msg/Imu", rng) for _ in range(300)]
    assert _check("sensor_msgs/msg/Imu", IMU_PATHS, raws, rng)
    raws = [_serialize(PKG + "Mix", rng, fewest=1) for _ in range(300)]
    assert _check(PKG + "Mix", MIX_PATHS, raws, rng)


def test_a_path_twice_fills_both_columns() -> None:
    # (the per-message reader leaves the first of two equal paths None: not the reference here)
    rng = random.Random(6)
    raws = [_serialize("geometry_msgs/msg/Twist", rng) for _ in range(3)]
    reader = _column_reader("geometry_msgs/msg/Twist", ("linear.x", "angular.z", "linear.x"))
    got = reader(*_pack(raws, rng))
    assert got is not None
    store = typestore()
    xs = [store.deserialize_cdr(raw, "geometry_msgs/msg/Twist").linear.x for raw in raws]
    assert got.values[0].tolist() == got.values[2].tolist() == xs


def test_an_empty_batch() -> None:
    reader = _column_reader("nav_msgs/msg/Odometry", ("twist.twist.linear.x", "header.stamp.sec"))
    got = reader(np.zeros(0, np.uint8), np.zeros(0, np.int64), np.zeros(0, np.int64))
    assert got is not None
    assert [c.tolist() for c in got.values] == [[], []]
    assert [c.dtype for c in got.values] == [np.float64, np.int64]
    assert got.stamps is not None and got.stamps.tolist() == []
    reader = _column_reader("std_msgs/msg/Bool", ("data",))
    got = reader(np.zeros(3, np.uint8), np.zeros(0, np.int64), np.zeros(0, np.int64))
    assert got is not None and got.stamps is None
    assert len(got.values) == 1 and got.values[0].dtype == np.bool_ and not len(got.values[0])


# -- what a batch is refused for ---------------------------------------------------------


def _odometry_batch(rng: random.Random, n: int = 5) -> list[bytes]:
    return [_serialize("nav_msgs/msg/Odometry", rng) for _ in range(n)]


ODOMETRY = ["twist.twist.linear.x", "pose.pose.position.x"]


@pytest.mark.parametrize(
    ("msg_type", "paths", "fewest"),
    [c for c in CASES if c[0].split("/")[-1] in ("Odometry", "Early", "Bool")]
    + [
        ("sensor_msgs/msg/LaserScan", ["ranges[0]", "ranges[5]", "angle_max", "range_min"], 6),
        (PKG + "Mix", MIX_PATHS, 1),
        ("geometry_msgs/msg/PointStamped", [], 0),
        ("sensor_msgs/msg/CameraInfo", ["d[0]"], 1),
        (PKG + "Outer", ["inner.v"], 1),
    ],
)
def test_a_message_cut_short_anywhere(msg_type: str, paths: list[str], fewest: int) -> None:
    rng = random.Random(7)
    raws = [_serialize(msg_type, rng, fewest) for _ in range(2)]
    assert _check(msg_type, paths, raws, rng)
    cut = raws[0]
    for end in range(len(cut)):
        raws[0] = cut[:end]
        _check(msg_type, paths, raws, rng)


def test_a_big_endian_message_refuses_the_batch() -> None:
    rng = random.Random(1)
    raws = _odometry_batch(rng)
    raws[2] = _serialize("nav_msgs/msg/Odometry", rng, little=False)
    assert raws[2][1] == 0
    reader = _column_reader("nav_msgs/msg/Odometry", tuple(ODOMETRY))
    assert reader(*_pack(raws, rng)) is None
    assert not _check("nav_msgs/msg/Odometry", ODOMETRY, raws, rng)


def test_an_index_beyond_a_short_sequence_refuses_the_batch() -> None:
    rng = random.Random(2)
    raws = [_serialize("sensor_msgs/msg/LaserScan", rng, fewest=6) for _ in range(4)]
    assert _check("sensor_msgs/msg/LaserScan", ["ranges[5]"], raws, rng)
    short = _message("sensor_msgs/msg/LaserScan", rng, 6)
    short.ranges = short.ranges[:5]
    raws.insert(2, bytes(typestore().serialize_cdr(short, "sensor_msgs/msg/LaserScan")))
    reader = _column_reader("sensor_msgs/msg/LaserScan", ("ranges[5]",))
    assert reader(*_pack(raws, rng)) is None
    assert _check("sensor_msgs/msg/LaserScan", ["ranges[4]"], raws, rng)


def test_hostile_lengths_refuse_the_batch() -> None:
    rng = random.Random(4)
    raws = _odometry_batch(rng)
    hostile = bytearray(raws[3])
    hostile[12:16] = b"\xff\xff\xff\xff"  # header.frame_id's length
    raws[3] = bytes(hostile)
    assert not _check("nav_msgs/msg/Odometry", ODOMETRY, raws, rng)

    scan = _message("sensor_msgs/msg/LaserScan", rng, 6)
    scan.header.frame_id = ""
    raw = bytearray(typestore().serialize_cdr(scan, "sensor_msgs/msg/LaserScan"))
    # stamp, frame_id's length and NUL (padded to 4), seven float32: the ranges' count
    assert int.from_bytes(raw[48:52], "little") == len(scan.ranges)
    raw[48:52] = b"\xff\xff\xff\xff"
    raws = [_serialize("sensor_msgs/msg/LaserScan", rng, 6), bytes(raw)]
    for paths in (["ranges[0]"], ["intensities[0]"], ["angle_max", "ranges[1]"]):
        assert not _check("sensor_msgs/msg/LaserScan", paths, raws, rng)


def test_offsets_outside_the_buffer_refuse_the_batch() -> None:
    rng = random.Random(5)
    buf, starts, ends = _pack(_odometry_batch(rng, 3), rng)
    reader = _column_reader("nav_msgs/msg/Odometry", tuple(ODOMETRY))
    got = reader(buf, starts, ends)
    assert got is not None
    # a view of the buffer from further on, and a copy that is not contiguous: the same
    cut = int(starts[0])
    again = reader(buf[cut:], starts - cut, ends - cut)
    assert again is not None and again.stamps is not None and got.stamps is not None
    assert [c.tolist() for c in again.values] == [c.tolist() for c in got.values]
    spread = np.zeros(2 * len(buf), np.uint8)
    spread[::2] = buf
    again = reader(spread[::2], starts, ends)
    assert again is not None and [c.tolist() for c in again.values] == [
        c.tolist() for c in got.values
    ]
    assert reader(buf[:-1] if ends[-1] == len(buf) else buf[: ends[-1] - 1], starts, ends) is None
    assert reader(buf, starts - starts[0] - 1, ends) is None
    assert reader(buf, starts, ends[:-1]) is None


@pytest.mark.parametrize(
    ("msg_type", "paths"),
    [
        ("std_msgs/msg/String", ["data"]),
        ("nav_msgs/msg/Odometry", ["child_frame_id"]),
        ("nav_msgs/msg/Odometry", ["pose"]),
        ("nav_msgs/msg/Odometry", ["pose.nope"]),
        ("sensor_msgs/msg/LaserScan", ["ranges"]),
        ("sensor_msgs/msg/Imu", ["orientation_covariance[9]"]),
        ("std_msgs/msg/Float64", ["data[0]"]),
        ("std_msgs/msg/Float64", ["data.x"]),
        ("std_msgs/msg/Float64", ["not a path"]),
        ("sensor_msgs/msg/JointState", ["position[0]"]),  # after a sequence of strings
        ("diagnostic_msgs/msg/DiagnosticArray", ["status[0].level"]),
        ("std_msgs/msg/UInt8MultiArray", ["data[0]"]),  # after dims with a string each
        (PKG + "Mix", ["odd_pair[0].x"]),
        (PKG + "Mix", ["points[1].y"]),
        (PKG + "Wide", ["x"]),
        ("nope_msgs/msg/Nope", ["x"]),
        ("not a type", ["x"]),
    ],
)
def test_paths_not_read_column_wise(msg_type: str, paths: list[str]) -> None:
    assert compile_column_reader(msg_type, paths) is None


# -- any bytes ---------------------------------------------------------------------------


@st.composite
def damaged(draw: st.DrawFn) -> tuple[str, list[str], list[bytes], random.Random]:
    """A batch of valid, truncated, overwritten and random messages of one of the cases."""
    msg_type, paths, fewest = draw(st.sampled_from(CASES))
    rng = random.Random(draw(st.integers(0, 2**32)))
    raws = []
    for _ in range(draw(st.integers(1, 6))):
        how = draw(st.sampled_from(["valid", "truncated", "hostile", "flipped", "random"]))
        raw = bytearray(_serialize(msg_type, rng, fewest))
        if how == "truncated":
            raw = raw[: draw(st.integers(0, len(raw)))]
        elif how == "hostile":
            at = draw(st.integers(4, max(4, len(raw) - 4)))
            raw[at : at + 4] = draw(st.sampled_from([b"\xff\xff\xff\xff", b"\x00\x00\x00\x80"]))
        elif how == "flipped":
            for _ in range(draw(st.integers(1, 4))):
                raw[draw(st.integers(0, len(raw) - 1))] = draw(st.integers(0, 255))
        elif how == "random":
            raw = bytearray(draw(st.binary(max_size=120)))
            if len(raw) > 1 and draw(st.booleans()):
                raw[1] = 1
        raws.append(bytes(raw))
    return msg_type, paths, raws, rng


@settings(deadline=None, max_examples=300, suppress_health_check=[HealthCheck.too_slow])
@given(damaged())
def test_any_bytes_give_the_per_message_values_or_none(
    case: tuple[str, list[str], list[bytes], random.Random],
) -> None:
    msg_type, paths, raws, rng = case
    event("read" if _check(msg_type, paths, raws, rng) else "refused")
