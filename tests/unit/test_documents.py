"""Monitor documents: every kind of bad input names its place and its field path."""

from __future__ import annotations

import pytest

from edgerv.core.diagnostics import InputError
from edgerv.core.documents import Placement, load_monitors, load_monitors_text

HEAD = "apiVersion: edgerv.io/v1alpha1\nkind: Monitor\nmetadata: {name: m}\n"
GOOD = HEAD + (
    "spec:\n"
    "  assertion: always (running -> speed < 100)\n"
    "  signals:\n"
    "    running: {topic: /running, type: std_msgs/msg/Bool}\n"
    "    speed: {topic: /odom, type: nav_msgs/msg/Odometry, field: twist.twist.linear.x}\n"
)


def first_error(text: str) -> str:
    with pytest.raises(InputError) as info:
        load_monitors_text("m.yaml", text)
    return str(info.value).splitlines()[0]


def test_a_good_document() -> None:
    (spec,) = load_monitors_text("m.yaml", GOOD)
    assert spec.name == "m"
    assert spec.signals["speed"].kind == "float"
    assert spec.signals["running"].field == "data"
    assert (spec.sort_threshold, spec.on_verdict, spec.buffer_capacity) == (1, "reset", 4096)
    assert spec.topics == ["/running", "/odom"]
    assert spec.placement == Placement()  # no tier: the lowest; moves freely


def test_placement() -> None:
    text = GOOD.replace(
        "  signals:", "  placement: {tier: cloud, migrate: pinned, maxLatencyMs: 50}\n  signals:"
    )
    (spec,) = load_monitors_text("m.yaml", text)
    assert spec.placement == Placement("cloud", "pinned", 50.0)


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (
            ("std_msgs/msg/Bool}", "std_msgs/msg/Boo}"),
            "m.yaml:7:38: error: spec.signals.running.type: "
            "unknown message type 'std_msgs/msg/Boo'",
        ),
        (
            ("twist.twist.linear.x", "twist.twist.linear.w"),
            "m.yaml:8:63: error: spec.signals.speed.field: "
            "geometry_msgs/msg/Vector3 has no field 'w' (at 'twist.twist.linear')",
        ),
        (
            ("twist.twist.linear.x", "twist.covariance"),
            "m.yaml:8:63: error: spec.signals.speed.field: field 'twist.covariance' of "
            "nav_msgs/msg/Odometry is an array",
        ),
        (
            ("twist.twist.linear.x", "twist.twist"),
            "m.yaml:8:63: error: spec.signals.speed.field: field 'twist.twist' of "
            "nav_msgs/msg/Odometry is a geometry_msgs/msg/Twist message, not a value",
        ),
        (
            ("topic: /odom", "topic: 'no good'"),
            "m.yaml:8:20: error: spec.signals.speed.topic: 'no good' is not a ROS topic name",
        ),
        (
            ("  signals:", "  sortThreshold: 0\n  signals:"),
            "m.yaml:6:18: error: spec.sortThreshold: must be at least 1, not 0",
        ),
        (
            ("  signals:", "  onVerdict: stop\n  signals:"),
            "m.yaml:6:14: error: spec.onVerdict: must be reset or halt, not 'stop'",
        ),
        (
            ("  signals:", "  asertion: x\n  signals:"),
            "m.yaml:6:3: error: spec.asertion: unknown field",
        ),
        (
            ("{topic: /running,", "{topic: /running, initial: 3,"),
            "m.yaml:7:41: error: spec.signals.running.initial: 3 is not a bool value, but "
            "std_msgs/msg/Bool field 'data' is bool",
        ),
        (
            ("kind: Monitor", "kind: Deployment"),
            "m.yaml:2:7: error: kind: must be Monitor, not 'Deployment'",
        ),
        (
            ("{name: m}", "{name: Bad_Name}"),
            "m.yaml:3:18: error: metadata.name: 'Bad_Name' is not a valid object name",
        ),
        (("    running:", "    G:"), "m.yaml:7:5: error: spec.signals.G: 'G' cannot name a signal"),
        (
            ("  signals:", "  placement: {tier: Edge_1}\n  signals:"),
            "m.yaml:6:21: error: spec.placement.tier: 'Edge_1' is not a tier name",
        ),
        (
            ("  signals:", "  placement: {migrate: never}\n  signals:"),
            "m.yaml:6:24: error: spec.placement.migrate: must be auto or pinned, not 'never'",
        ),
        (
            ("  signals:", "  placement: {maxLatencyMs: -5}\n  signals:"),
            "m.yaml:6:29: error: spec.placement.maxLatencyMs: must be a number above 0",
        ),
        (
            ("  signals:", "  placement: {maxLatencyMs: true}\n  signals:"),
            "m.yaml:6:29: error: spec.placement.maxLatencyMs: must be a number above 0",
        ),
        (
            ("  signals:", "  placement: {teir: edge}\n  signals:"),
            "m.yaml:6:15: error: spec.placement.teir: unknown field",
        ),
    ],
)
def test_bad_documents(change: tuple[str, str], expected: str) -> None:
    assert first_error(GOOD.replace(*change)) == expected


def test_the_hint_lists_what_exists() -> None:
    with pytest.raises(InputError) as info:
        load_monitors_text("m.yaml", GOOD.replace("linear.x", "linear.w"))
    assert "hint: its fields: x, y, z" in str(info.value)
    with pytest.raises(InputError) as info:
        load_monitors_text(
            "m.yaml",
            GOOD.replace("asertion", "x").replace("  signals:", "  asertion: 1\n  signals:"),
        )
    assert "did you mean 'assertion'?" in str(info.value)


def test_missing_fields_and_all_errors_at_once() -> None:
    text = HEAD + "spec:\n  signals: {a: {topic: /a}}\n"
    with pytest.raises(InputError) as info:
        load_monitors_text("m.yaml", text)
    messages = [d.message for d in info.value.diagnostics]
    assert messages == [
        "spec: missing required field 'assertion'",
        "spec.signals.a: missing required field 'type'",
    ]


def test_invalid_yaml_points_at_the_problem() -> None:
    error = first_error(GOOD + "  onVerdict: [halt\n")
    # libyaml and the pure-Python parser word it differently, at the same place
    assert error.startswith("m.yaml:10:1: error: invalid YAML: ")
    assert "expected ',' or ']'" in error


def test_duplicate_names_across_documents(tmp_path) -> None:  # type: ignore[no-untyped-def]
    (tmp_path / "a.yaml").write_text(GOOD)
    (tmp_path / "b.yaml").write_text(GOOD)
    with pytest.raises(InputError) as info:
        load_monitors(tmp_path)
    assert "monitor 'm' is defined twice (first at" in str(info.value)


def test_multi_document_files() -> None:
    specs = load_monitors_text("m.yaml", GOOD + "---\n" + GOOD.replace("{name: m}", "{name: n}"))
    assert [s.name for s in specs] == ["m", "n"]


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (("  signals:", "  bufferCapacity: 0\n  signals:"),
         "m.yaml:6:19: error: spec.bufferCapacity: must be at least 1, not 0"),
        (("  signals:", "  bufferCapacity: 2\n  sortThreshold: 3\n  signals:"),
         "m.yaml:7:18: error: spec.sortThreshold: 3 is more than bufferCapacity (2)"),
        (("  signals:", "  sortThreshold: 100000000000\n  signals:"),
         "m.yaml:6:18: error: spec.sortThreshold: must be at most 100000000, not 100000000000"),
        (("metadata: {name: m}", "metadata: " + "{a: " * 70 + "1" + "}" * 70),
         "m.yaml:3:"),
    ],
)  # fmt: skip
def test_counts_and_nesting_are_bounded(change: tuple[str, str], expected: str) -> None:
    assert first_error(GOOD.replace(*change)).startswith(expected)


def test_block_nesting_is_bounded_too() -> None:
    nested = "".join("  " * i + f"k{i}:\n" for i in range(80)) + "  " * 80 + "v\n"
    message = first_error(GOOD + "---\n" + nested)
    assert "nested more than 64 levels deep" in message


def test_a_document_too_large_is_refused_before_parsing() -> None:
    message = first_error(GOOD + "#" * (5 << 20))
    assert "larger than" in message
