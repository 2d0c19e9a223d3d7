"""``spec.onViolation``: what a monitor does when violated, read from its document with
every field of the message or request checked against its type where it is written.

Doing it (ROS publishers and clients, once per violation, across moves) is tested in
tests/integration/test_reactions.py and, on engines, in test_engine_handoff.py.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

from edgerv.core.diagnostics import InputError
from edgerv.core.documents import load_monitors_text
from edgerv.core.msgtypes import STD_SRVS
from edgerv.core.reactions import Call, Publish, Reaction

HEAD = "apiVersion: edgerv.io/v1alpha1\nkind: Monitor\nmetadata: {name: m}\n"
GOOD = HEAD + (
    "spec:\n"
    "  assertion: always (speed < 100)\n"
    "  signals:\n"
    "    speed: {topic: /speed, type: std_msgs/msg/Float64}\n"
)


def with_reaction(text: str) -> str:
    return GOOD + "  onViolation:\n" + "".join(f"    {line}\n" for line in text.splitlines())


def errors(text: str) -> list[str]:
    with pytest.raises(InputError) as info:
        load_monitors_text("m.yaml", text)
    return [line for line in str(info.value).splitlines() if ": error: " in line]


def test_off_unless_written() -> None:
    (spec,) = load_monitors_text("m.yaml", GOOD)
    assert spec.on_violation is None


def test_publish_and_call_with_their_fields() -> None:
    (spec,) = load_monitors_text(
        "m.yaml",
        with_reaction(
            "publish:\n"
            "  topic: cmd_vel\n"
            "  type: geometry_msgs/Twist\n"
            "  message: {linear: {x: 0}, angular: {z: 0.5}}\n"
            "call: {service: /estop, type: std_srvs/SetBool, request: {data: true}, "
            "timeoutMs: 250}"
        ),
    )
    assert spec.on_violation == Reaction(
        Publish("/cmd_vel", "geometry_msgs/msg/Twist", (("linear.x", 0), ("angular.z", 0.5))),
        Call("/estop", "std_srvs/srv/SetBool", (("data", True),), 0.25),
    )
    assert spec.on_violation.describe() == (
        "publish geometry_msgs/msg/Twist on /cmd_vel and call /estop (std_srvs/srv/SetBool)"
    )


def test_a_message_left_out_is_all_defaults_and_a_call_times_out_in_a_second() -> None:
    (spec,) = load_monitors_text(
        "m.yaml",
        with_reaction(
            "publish: {topic: /estop, type: std_msgs/msg/Empty}\n"
            "call: {service: /halt, type: std_srvs/srv/Trigger}"
        ),
    )
    assert spec.on_violation == Reaction(
        Publish("/estop", "std_msgs/msg/Empty"), Call("/halt", "std_srvs/srv/Trigger", (), 1.0)
    )


@pytest.mark.parametrize(
    ("reaction", "expected"),
    [
        ("{}", "m.yaml:9:5: error: spec.onViolation: names no reaction"),
        ("stop: {}", "m.yaml:9:5: error: spec.onViolation.stop: unknown field"),
        (
            "publish: {topic: /cmd_vel}",
            "m.yaml:9:14: error: spec.onViolation.publish: missing required field 'type'",
        ),
        (
            "publish: {topic: 'not a topic', type: std_msgs/msg/Bool}",
            "m.yaml:9:22: error: spec.onViolation.publish.topic: "
            "'not a topic' is not a ROS topic name",
        ),
        (
            "publish: {topic: /t, type: std_msgs/msg/Boo}",
            "m.yaml:9:32: error: spec.onViolation.publish.type: "
            "unknown message type 'std_msgs/msg/Boo'",
        ),
        (
            "publish: {topic: /t, type: geometry_msgs/msg/Twist, message: {linear: {w: 0}}}",
            "m.yaml:9:76: error: spec.onViolation.publish.message.linear.w: "
            "geometry_msgs/msg/Vector3 has no field 'w' (at 'linear')",
        ),
        (
            "publish: {topic: /t, type: geometry_msgs/msg/Twist, message: {linear: {x: fast}}}",
            "m.yaml:9:79: error: spec.onViolation.publish.message.linear.x: 'fast' is not a "
            "float value, but geometry_msgs/msg/Twist field 'linear.x' is float",
        ),
        (
            "publish: {topic: /t, type: std_msgs/msg/Bool, message: {data: 1}}",
            "m.yaml:9:67: error: spec.onViolation.publish.message.data: 1 is not a bool "
            "value, but std_msgs/msg/Bool field 'data' is bool",
        ),
        (
            "publish: {topic: /t, type: geometry_msgs/msg/Twist, message: {linear: 0}}",
            "m.yaml:9:67: error: spec.onViolation.publish.message.linear: field 'linear' of "
            "geometry_msgs/msg/Twist is a geometry_msgs/msg/Vector3 message, not a value",
        ),
        (
            "publish: {topic: /t, type: sensor_msgs/msg/LaserScan, message: {ranges: [1]}}",
            "m.yaml:9:77: error: spec.onViolation.publish.message.ranges: "
            "an array cannot be set in a reaction",
        ),
        (
            "publish: {topic: /t, type: std_msgs/msg/Bool, message: true}",
            "m.yaml:9:60: error: spec.onViolation.publish.message: must be a mapping of fields",
        ),
        (
            "call: {service: /s, type: std_srvs/msg/SetBool}",
            "m.yaml:9:31: error: spec.onViolation.call.type: "
            "'std_srvs/msg/SetBool' is not a service type name",
        ),
        (
            "call: {service: /s, type: std_srvs/srv/Reboot}",
            "m.yaml:9:31: error: spec.onViolation.call.type: "
            "unknown service type 'std_srvs/srv/Reboot'",
        ),
        (
            "call: {service: /s, type: std_srvs/srv/SetBool, request: {data: yes please}}",
            "m.yaml:9:69: error: spec.onViolation.call.request.data: 'yes please' is not a "
            "bool value, but std_srvs/srv/SetBool_Request field 'data' is bool",
        ),
        (
            "call: {service: /s, type: std_srvs/srv/SetBool, timeoutMs: 0}",
            "m.yaml:9:64: error: spec.onViolation.call.timeoutMs: "
            "must be above 0 and at most 600000",
        ),
        (
            "call: {service: '', type: std_srvs/srv/Empty}",
            "m.yaml:9:21: error: spec.onViolation.call.service: '' is not a ROS service name",
        ),
    ],
)
def test_a_wrong_reaction_is_named_where_it_is_written(reaction: str, expected: str) -> None:
    assert errors(with_reaction(reaction))[0] == expected


def test_a_reaction_on_a_topic_the_monitor_reads_is_refused() -> None:
    """Its reaction would be its next event: a violation publishing on /speed a value that
    violates again would react without end."""
    found = errors(with_reaction("publish: {topic: speed, type: std_msgs/msg/Float64}"))
    assert found == [
        "m.yaml:9:22: error: spec.onViolation.publish.topic: /speed is a topic this monitor "
        "reads: each reaction would be an event of its own, and could violate it again, "
        "without end"
    ]


def test_every_problem_of_a_reaction_is_told_at_once() -> None:
    found = errors(
        with_reaction(
            "publish: {topic: /t, type: geometry_msgs/msg/Twist, message: {linear: {x: a, q: 1}}}\n"
            "call: {service: /s, type: std_srvs/srv/SetBool, request: {data: 3}}"
        )
    )
    assert [re.sub(r"^m\.yaml:\d+:\d+: error: ([^:]*):.*", r"\1", e) for e in found] == [
        "spec.onViolation.publish.message.linear.x",
        "spec.onViolation.publish.message.linear.q",
        "spec.onViolation.call.request.data",
    ]


def test_a_wrong_field_has_a_hint_naming_the_fields_there_are() -> None:
    with pytest.raises(InputError) as info:
        load_monitors_text(
            "m.yaml",
            with_reaction("call: {service: /s, type: std_srvs/srv/SetBool, request: {on: true}}"),
        )
    assert "hint: its fields: data" in str(info.value)


def _srv_text(path: Path) -> str:
    """A .srv file's lines without comments and blank lines."""
    lines = (line.split("#", 1)[0].strip() for line in path.read_text().splitlines())
    return "".join(line + "\n" for line in lines if line)


def test_std_srvs_known_without_ros_are_the_installed_definitions() -> None:
    """The operator's image has no ROS: std_srvs' three services are known from
    msgtypes.STD_SRVS, equal to Jazzy's own .srv files (ros-jazzy-std-srvs, installed by
    `make install`)."""
    share = Path(sys.prefix) / "share" / "std_srvs" / "srv"
    assert sorted(STD_SRVS) == sorted(f"std_srvs/srv/{p.stem}" for p in share.glob("*.srv"))
    for name, text in STD_SRVS.items():
        assert text == _srv_text(share / f"{name.rsplit('/', 1)[1]}.srv"), name
