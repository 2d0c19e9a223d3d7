"""A robot's own message package: read from its .msg files, checked, read from CDR and bags."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from edgerv.core.cdr import compile_reader
from edgerv.core.diagnostics import InputError
from edgerv.core.documents import load_monitors_text
from edgerv.core.msgtypes import field_kind, typestore
from kit.cli import edgerv

STATUS = "float64 battery\nstring mode\ngeometry_msgs/Point target\nmy_robot_msgs/Wheel[] wheels\n"
WHEEL = "float32 rpm\nbool slipping\n"

MONITOR = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: battery}
spec:
  assertion: 'always (mode == "AUTO" -> (battery > 20 & !slip))'
  signals:
    battery: {topic: /status, type: my_robot_msgs/msg/Status, field: battery}
    mode: {topic: /status, type: my_robot_msgs/msg/Status, field: mode}
    slip: {topic: /status, type: my_robot_msgs/msg/Status, field: "wheels[1].slipping"}
"""


@pytest.fixture
def msg_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    pkg = tmp_path / "defs" / "my_robot_msgs" / "msg"
    pkg.mkdir(parents=True)
    (pkg / "Status.msg").write_text(STATUS)
    (pkg / "Wheel.msg").write_text(WHEEL)
    monkeypatch.setenv("EDGERV_MSG_PATH", str(tmp_path / "defs"))
    return tmp_path / "defs"


def test_a_custom_type_and_its_dependencies_are_read(msg_path: Path) -> None:
    assert field_kind("my_robot_msgs/msg/Status", "target.x") == "float"
    assert field_kind("my_robot_msgs/msg/Status", "wheels[0].slipping") == "bool"
    spec = load_monitors_text("m.yaml", MONITOR)[0]
    assert spec.signals["slip"].kind == "bool"


def test_the_cdr_reader_works_on_it(msg_path: Path) -> None:
    field_kind("my_robot_msgs/msg/Status", "mode")
    store = typestore()
    Status, Wheel = (store.types[f"my_robot_msgs/msg/{n}"] for n in ("Status", "Wheel"))
    Point = store.types["geometry_msgs/msg/Point"]
    msg = Status(
        battery=42.5,
        mode="AUTO",
        target=Point(x=1.0, y=2.0, z=3.0),
        wheels=[Wheel(rpm=1.0, slipping=False), Wheel(rpm=2.0, slipping=True)],
    )
    raw = bytes(store.serialize_cdr(msg, "my_robot_msgs/msg/Status"))
    reader = compile_reader(
        "my_robot_msgs/msg/Status", ["battery", "mode", "wheels[1].slipping", "target.z"]
    )
    assert reader(raw) == ([42.5, "AUTO", True, 3.0], None)


def test_an_unknown_package_says_where_definitions_are_looked_up(msg_path: Path) -> None:
    with pytest.raises(InputError) as info:
        load_monitors_text("m.yaml", MONITOR.replace("my_robot_msgs", "other_msgs"))
    assert "$EDGERV_MSG_PATH" in str(info.value)


def test_check_on_an_mcap_bag_of_custom_messages(msg_path: Path, tmp_path: Path) -> None:
    from mcap_ros2.writer import Writer

    defs = (
        STATUS
        + "=" * 80
        + "\nMSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n"
        + "=" * 80
        + "\nMSG: my_robot_msgs/Wheel\n"
        + WHEEL
    )
    bag = tmp_path / "run.mcap"
    rows = [
        (10, 50.0, "AUTO", False),
        (20, 30.0, "AUTO", True),
        (30, 10.0, "MANUAL", False),
        (40, 10.0, "AUTO", False),
    ]
    with bag.open("wb") as f:
        w = Writer(f)
        schema = w.register_msgdef("my_robot_msgs/msg/Status", defs)
        for stamp, battery, mode, slipping in rows:
            w.write_message(
                topic="/status",
                schema=schema,
                log_time=stamp,
                publish_time=stamp,
                message={
                    "battery": battery,
                    "mode": mode,
                    "target": {"x": 0.0, "y": 0.0, "z": 0.0},
                    "wheels": [{"rpm": 1.0, "slipping": False}, {"rpm": 1.0, "slipping": slipping}],
                },
            )
        w.finish()
    doc = tmp_path / "m.yaml"
    doc.write_text(MONITOR)
    proc = edgerv("check", doc, bag, "--json")  # $EDGERV_MSG_PATH: msg_path's
    assert proc.returncode == 1, proc.stderr
    verdicts = json.loads(proc.stdout)["monitors"][0]["verdicts"]
    assert [(v["step"], v["stamp"]) for v in verdicts] == [(2, 20), (4, 40)]
