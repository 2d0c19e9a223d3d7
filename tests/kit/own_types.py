"""A robot's own message types (issue #39), shared by the tests of the handler on them
(test_own_types.py: as a process, the types built at their first use;
test_docker_own_types.py: in the handler's image, the types installed as wheels): two
interface packages of the user's written by the test (nested types, arrays, a type of
another custom package, standard ones), monitors on them, a real rclpy node that
publishes them, and the MCAP bag of what a recorder received, for ``edgerv check``."""

from __future__ import annotations

from pathlib import Path

from edgerv.handler.ros import types as ros_types

COMMON = {"msg/Vec2.msg": "# a package of the user's that another uses\nfloat64 x\nfloat64 y\n"}
ROBOT = {
    "msg/Wheel.msg": "float32 rpm\nbool slipping\ncommon_msgs/Vec2 force\n",
    "msg/State.msg": (
        "std_msgs/Header header\n"
        "float64 battery\n"
        "string mode\n"
        "geometry_msgs/Point target\n"
        "Wheel[] wheels            # nested, of this package, unbounded\n"
        "common_msgs/Vec2[2] corners  # a fixed array of another custom package's type\n"
        "int32[] codes\n"
        "uint8 MODE_AUTO=1\n"
    ),
}
STATE = "my_robot_msgs/msg/State"

MONITORS = f"""\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {{name: battery}}
spec:
  assertion: 'always (mode == "AUTO" -> battery > 20)'
  signals:
    battery: {{topic: /state, type: {STATE}, field: battery}}
    mode: {{topic: /state, type: {STATE}, field: mode}}
  sortThreshold: 1
---
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {{name: no-slip-under-load}}
spec:
  assertion: "always !(slipping & force > 5)"
  signals:
    slipping: {{topic: /state, type: {STATE}, field: "wheels[1].slipping"}}
    force: {{topic: /state, type: {STATE}, field: "wheels[1].force.x"}}
  sortThreshold: 1
---
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {{name: corner-inside}}
spec:
  assertion: "always (corner < 8 & code != 3)"
  signals:
    corner: {{topic: /state, type: {STATE}, field: "corners[1].y"}}
    code: {{topic: /state, type: {STATE}, field: "codes[0]"}}
  sortThreshold: 1
---
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {{name: target-near}}
spec:
  assertion: "always (z < 9.5)"
  signals:
    z: {{topic: /state, type: {STATE}, field: target.z}}
  sortThreshold: 1
"""
MONITOR_NAMES = {"battery", "no-slip-under-load", "corner-inside", "target-near"}

# A real rclpy node that imports the generated classes (from the types cache their build
# is in: $EDGERV_MSG_PATH and $EDGERV_TYPES_CACHE) and publishes N States stamped at their
# publication, 4 ms apart, once `subscribers` subscriptions are matched.
PUBLISHER = r"""
import json, random, sys, time
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from edgerv.handler.ros.types import load_package
load_package("my_robot_msgs")  # the cached build (it loads common_msgs too)
from builtin_interfaces.msg import Time
from common_msgs.msg import Vec2
from geometry_msgs.msg import Point
from my_robot_msgs.msg import State, Wheel
n, subscribers = int(sys.argv[1]), int(sys.argv[2])
rclpy.init()
node = rclpy.create_node("my_robot")
qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
pub = node.create_publisher(State, "/state", qos)
deadline = time.monotonic() + 20
while pub.get_subscription_count() < subscribers and time.monotonic() < deadline:
    time.sleep(0.05)
time.sleep(0.5)
rng = random.Random(39)
for i in range(n):
    now = time.time_ns()
    msg = State(
        battery=rng.uniform(0, 100),
        mode=rng.choice(["AUTO", "AUTO", "MANUAL"]),
        target=Point(x=1.0, y=2.0, z=rng.uniform(0, 10)),
        wheels=[
            Wheel(rpm=float(w), slipping=rng.random() < 0.3, force=Vec2(x=rng.uniform(0, 10)))
            for w in range(rng.randint(2, 4))
        ],
        corners=[Vec2(x=0.0, y=rng.uniform(0, 9)), Vec2(x=1.0, y=rng.uniform(0, 9))],
        codes=[rng.randint(0, 12) for _ in range(rng.randint(1, 3))],
    )
    msg.header.stamp = Time(sec=now // 10**9, nanosec=now % 10**9)
    msg.header.frame_id = "base_link"
    pub.publish(msg)
    time.sleep(0.004)
time.sleep(1.0)
print(json.dumps({"published": n, "matched": pub.get_subscription_count(),
                  "from": sys.modules[State.__module__].__file__}))
"""
N = 300  # the States published


def write_package(top: Path, name: str, files: dict[str, str]) -> None:
    for rel, text in files.items():
        (top / name / rel).parent.mkdir(parents=True, exist_ok=True)
        (top / name / rel).write_text(text)


def write_packages(defs: Path) -> Path:
    """common_msgs and my_robot_msgs as a workspace's ``src`` holds them: ``defs``."""
    write_package(defs, "common_msgs", COMMON)
    write_package(defs, "my_robot_msgs", ROBOT)
    return defs


def ros2msg_definition(msg_type: str) -> str:
    """The definition rosbag2 records for ``msg_type``: its .msg text, then each type it
    uses after a line of 80 ``=`` and ``MSG: pkg/Type`` (found where ``edgerv check``
    finds .msg files: the custom ones under $EDGERV_MSG_PATH, the standard ones in the
    venv's share/)."""
    from edgerv.core.msgtypes import _find_definition

    def text(t: str) -> str:
        path = _find_definition(t)
        assert path is not None, t
        return path.read_text()

    def used(t: str) -> list[str]:
        pkg = t.split("/")[0]
        out = []
        for line in text(t).splitlines():
            line = line.split("#", 1)[0].strip()
            if not line:
                continue
            base = line.split()[0].split("[", 1)[0].split("<=", 1)[0]
            if base in ros_types.PRIMITIVES:
                continue
            dep_pkg, _, name = base.rpartition("/")
            name = name.rpartition("/")[2]
            dep_pkg = (dep_pkg.split("/")[0] if dep_pkg else None) or (
                "std_msgs" if base == "Header" else pkg
            )
            out.append(f"{dep_pkg}/msg/{name}")
        return out

    seen, order, pending = {msg_type}, [], used(msg_type)
    while pending:
        t = pending.pop(0)
        if t not in seen:
            seen.add(t)
            order.append(t)
            pending += used(t)
    parts = [text(msg_type)]
    for t in order:
        pkg, _, name = t.split("/")
        parts.append("=" * 80 + f"\nMSG: {pkg}/{name}\n" + text(t))
    return "\n".join(parts)


def write_bag(path: Path, recorded: list[tuple[bytes, int]]) -> None:
    """An MCAP rosbag2 of /state: the CDR bytes as received, logged at their arrival."""
    from mcap.writer import Writer

    with path.open("wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library="edgerv tests")
        schema = writer.register_schema(STATE, "ros2msg", ros2msg_definition(STATE).encode())
        channel = writer.register_channel("/state", "cdr", schema)
        for i, (raw, at) in enumerate(recorded):
            writer.add_message(channel, log_time=at, data=raw, publish_time=at, sequence=i)
        writer.finish()
