"""The CDR field reader against rosbags' full deserializer, on random messages.

Random string and sequence lengths move every later field to another
alignment, so each type is tried many times.
"""

from __future__ import annotations

import random
from typing import Any

import numpy as np
import pytest

from edgerv.core.cdr import compile_reader
from edgerv.core.msgtypes import field_kind, make_getter, typestore
from kit.ros_numpy import NUMPY_TYPES


def random_value(node: tuple[Any, Any], rng: random.Random) -> Any:
    kind, payload = int(node[0]), node[1]
    if kind == 1:
        base = payload[0]
        if base == "string":
            return "".join(rng.choice("abcxyz_/") for _ in range(rng.randint(0, 9)))
        if base == "bool":
            return rng.random() < 0.5
        if base == "byte":  # rosbags packs a scalar byte signed
            return rng.randint(-128, 127)
        if base.startswith("float"):
            return float(np.float32(rng.uniform(-1e3, 1e3)))
        info = np.iinfo(NUMPY_TYPES[base])
        return rng.randint(max(int(info.min), -1000), min(int(info.max), 1000))
    if kind == 2:
        return random_message(payload, rng)
    elem, count = payload
    n = count if kind == 3 else rng.randint(0, 5)
    values = [random_value(elem, rng) for _ in range(n)]
    if int(elem[0]) == 1 and elem[1][0] in NUMPY_TYPES:
        return np.array(values, dtype=NUMPY_TYPES[elem[1][0]])
    return values


def random_message(msg_type: str, rng: random.Random) -> Any:
    store = typestore()
    cls = store.types[msg_type]
    return cls(**{name: random_value(node, rng) for name, node in store.fielddefs[msg_type][1]})


CASES = [
    (
        "nav_msgs/msg/Odometry",
        [
            "twist.twist.linear.x",
            "pose.pose.position.y",
            "child_frame_id",
            "pose.covariance[7]",
            "header.frame_id",
            "twist.covariance[35]",
        ],
    ),
    ("nav_msgs/msg/Odometry", ["twist.twist.angular.z"]),
    ("sensor_msgs/msg/LaserScan", ["ranges[3]", "angle_max", "intensities[0]", "range_min"]),
    ("sensor_msgs/msg/JointState", ["position[2]", "name[1]", "velocity[0]", "effort[1]"]),
    (
        "sensor_msgs/msg/Imu",
        ["linear_acceleration.z", "orientation_covariance[4]", "orientation.w"],
    ),
    (
        "sensor_msgs/msg/BatteryState",
        ["percentage", "present", "power_supply_status", "cell_voltage[1]", "serial_number"],
    ),
    (
        "diagnostic_msgs/msg/DiagnosticArray",
        ["status[1].level", "status[0].values[1].value", "status[2].name"],
    ),
    ("geometry_msgs/msg/PointStamped", ["point.x", "point.z"]),
    ("std_msgs/msg/Bool", ["data"]),
    ("std_msgs/msg/String", ["data"]),
    ("std_msgs/msg/Int64", ["data"]),
    ("std_msgs/msg/UInt8MultiArray", ["data[2]", "layout.data_offset", "layout.dim[0].label"]),
]


@pytest.mark.parametrize(("msg_type", "paths"), CASES)
def test_reader_matches_full_deserialization(msg_type: str, paths: list[str]) -> None:
    store = typestore()
    for path in paths:
        field_kind(msg_type, path)  # the paths are valid
    reader = compile_reader(msg_type, paths)
    getters = [make_getter(p) for p in paths]
    has_header = store.fielddefs[msg_type][1][0][0] == "header"
    rng = random.Random(msg_type)
    checked = 0
    for _ in range(300):
        msg = random_message(msg_type, rng)
        raw = bytes(store.serialize_cdr(msg, msg_type))
        decoded = store.deserialize_cdr(raw, msg_type)
        try:
            expected = [g(decoded) for g in getters]
        except IndexError:
            with pytest.raises(IndexError):
                reader(raw)
            continue
        values, stamp = reader(raw)
        assert values == expected
        assert [type(v) for v in values] == [type(v) for v in expected]
        if has_header:
            assert stamp == decoded.header.stamp.sec * 10**9 + decoded.header.stamp.nanosec
        else:
            assert stamp is None
        checked += 1
    assert checked > 50


def test_big_endian_payload_falls_back_to_full_deserialization() -> None:
    store = typestore()
    msg = random_message("nav_msgs/msg/Odometry", random.Random(1))
    raw = bytes(store.serialize_cdr(msg, "nav_msgs/msg/Odometry", little_endian=False))
    assert raw[1] == 0
    reader = compile_reader("nav_msgs/msg/Odometry", ["twist.twist.linear.x", "child_frame_id"])
    assert reader(raw)[0] == [msg.twist.twist.linear.x, msg.child_frame_id]
