"""The case study's monitors, as Monitor YAML: ``python monitors.py OUT.yaml [--extra N]``.

The paper ran 200 monitors on its robot; these are 200 over the simulated
robot's topics (examples/robot/robot.py), in families a robotics team would
write, generated where they repeat (one per zone of the room, one per sector of
the laser). The committed file ``case-study.yaml`` is this script's output
without ``--extra``.

``--extra N`` adds N more monitors that read the 200 Hz IMU: acceleration and
turn-rate envelopes per zone and per speed band (a denser safety envelope). The
demo adds them to raise the verification load until the robot's loop misses its
deadline with every monitor on the edge, as the paper's heavier monitors did
(see README: edgerv's handler is lighter than the paper's).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml

START = (0.0, 0.0)
GOAL = (0.0, 3.0)
WAYPOINTS = ((4.0, 0.0), (4.0, 3.0))
ROOM = (-1.0, 5.0, -1.0, 4.0)  # x min, x max, y min, y max
TOL = 0.2  # metres: "at a point" means within this box

ODOM = "nav_msgs/msg/Odometry"
SIGNALS: dict[str, dict[str, Any]] = {
    "x": {"topic": "/odom", "type": ODOM, "field": "pose.pose.position.x"},
    "y": {"topic": "/odom", "type": ODOM, "field": "pose.pose.position.y"},
    "v": {"topic": "/odom", "type": ODOM, "field": "twist.twist.linear.x"},
    "w": {"topic": "/odom", "type": ODOM, "field": "twist.twist.angular.z"},
    "goal_x": {
        "topic": "/goal",
        "type": "geometry_msgs/msg/PoseStamped",
        "field": "pose.position.x",
    },
    "goal_y": {
        "topic": "/goal",
        "type": "geometry_msgs/msg/PoseStamped",
        "field": "pose.position.y",
    },
    "cmd_v": {
        "topic": "/cmd_vel",
        "type": "geometry_msgs/msg/TwistStamped",
        "field": "twist.linear.x",
    },
    "cmd_w": {
        "topic": "/cmd_vel",
        "type": "geometry_msgs/msg/TwistStamped",
        "field": "twist.angular.z",
    },
    "ax": {"topic": "/imu", "type": "sensor_msgs/msg/Imu", "field": "linear_acceleration.x"},
    "ay": {"topic": "/imu", "type": "sensor_msgs/msg/Imu", "field": "linear_acceleration.y"},
    "az": {"topic": "/imu", "type": "sensor_msgs/msg/Imu", "field": "linear_acceleration.z"},
    "gyro_z": {"topic": "/imu", "type": "sensor_msgs/msg/Imu", "field": "angular_velocity.z"},
    "image_h": {"topic": "/camera/image", "type": "sensor_msgs/msg/Image", "field": "height"},
    "battery": {"topic": "/battery", "type": "sensor_msgs/msg/BatteryState", "field": "percentage"},
    "bumper": {"topic": "/bumper", "type": "std_msgs/msg/Bool", "initial": False},
}


def near(px: str, py: str, x: float, y: float) -> str:
    return f"{px} > {x - TOL:g} & {px} < {x + TOL:g} & {py} > {y - TOL:g} & {py} < {y + TOL:g}"


def monitor(
    name: str,
    assertion: str,
    signals: list[str],
    extra: dict[str, dict[str, Any]] | None = None,
    **spec: Any,
) -> dict[str, Any]:
    sigs = {s: dict(SIGNALS[s]) for s in signals}
    sigs.update(extra or {})
    return {
        "apiVersion": "edgerv.io/v1alpha1",
        "kind": "Monitor",
        "metadata": {"name": name},
        "spec": {"assertion": assertion, "signals": sigs, **spec},
    }


def mission() -> Iterator[dict[str, Any]]:
    new_goal = "age(goal_x) == 0ms"
    # The paper's goal assertion: a new goal given at the start is reached in time.
    yield monitor(
        "goal-reached",
        f"always (({new_goal} & {near('x', 'y', *START)}) -> F[0..20s] ({near('x', 'y', *GOAL)}))",
        ["x", "y", "goal_x"],
    )
    for i, (wx, wy) in enumerate(WAYPOINTS):
        yield monitor(
            f"waypoint-{i + 1}-reached",
            f"always ({new_goal} -> F[0..{6 * (i + 1)}s] ({near('x', 'y', wx, wy)}))",
            ["x", "y", "goal_x"],
        )
    yield monitor("starts-moving", f"always ({new_goal} -> F[0..3s] v > 0.1)", ["v", "goal_x"])
    yield monitor(
        "goal-inside-room",
        "always (goal_x > {:g} & goal_x < {:g} & goal_y > {:g} & goal_y < {:g})".format(*ROOM),
        ["goal_x", "goal_y"],
    )


def real_time() -> Iterator[dict[str, Any]]:
    # The loop's deadline as a monitor: a command for every frame (8 Hz), none skipped.
    yield monitor("command-period", "always (age(cmd_v) < 200ms)", ["cmd_v"])
    yield monitor("camera-period", "always (age(image_h) < 200ms)", ["image_h"])
    yield monitor("odom-fresh", "always (age(x) < 100ms)", ["x"])
    yield monitor("imu-fresh", "always (age(ax) < 50ms)", ["ax"])
    yield monitor(
        "scan-fresh",
        "always (age(front) < 200ms)",
        [],
        {"front": {"topic": "/scan", "type": "sensor_msgs/msg/LaserScan", "field": "ranges[180]"}},
    )


def safety() -> Iterator[dict[str, Any]]:
    yield monitor("speed-limit", "always (v < 1.2)", ["v"])
    yield monitor("reverse-limit", "always (v > -0.3)", ["v"])
    yield monitor("turn-limit", "always (w < 3.2 & w > -3.2)", ["w"])
    yield monitor(
        "command-limits", "always (cmd_v < 1.2 & cmd_w < 3.2 & cmd_w > -3.2)", ["cmd_v", "cmd_w"]
    )
    yield monitor("gyro-limit", "always (gyro_z < 3.5 & gyro_z > -3.5)", ["gyro_z"])
    yield monitor("accel-limit", "always (ax < 4 & ax > -4 & ay < 4 & ay > -4)", ["ax", "ay"])
    yield monitor("upright", "always (az > 8 & az < 11.5)", ["az"])
    yield monitor("no-collision", "always (!bumper)", ["bumper"])
    yield monitor("stopped-after-collision", "always (bumper -> v < 0.01)", ["bumper", "v"])
    x0, x1, y0, y1 = ROOM
    yield monitor(
        "inside-room", f"always (x > {x0:g} & x < {x1:g} & y > {y0:g} & y < {y1:g})", ["x", "y"]
    )
    yield monitor("battery-ok", "always (battery > 0.2)", ["battery"])
    yield monitor(
        "slow-after-turn",
        "always ((w > 1.5 | w < -1.5) -> historically[0..500ms] (v < 1.1))",
        ["v", "w"],
    )


def zones() -> Iterator[dict[str, Any]]:
    """A speed and a turn-rate limit for each 1 m cell of the room (tighter near walls)."""
    x0, x1, y0, y1 = (int(b) for b in ROOM)
    for ix in range(x0, x1):
        for iy in range(y0, y1):
            wall = ix in (x0, x1 - 1) or iy in (y0, y1 - 1)
            inside = f"x >= {ix} & x < {ix + 1} & y >= {iy} & y < {iy + 1}"
            tag = f"{ix + 1 - x0}-{iy + 1 - y0}"
            limit = 0.6 if wall else 1.1
            yield monitor(
                f"zone-{tag}-speed", f"always (({inside}) -> v < {limit})", ["x", "y", "v"]
            )
            yield monitor(
                f"zone-{tag}-turn", f"always (({inside}) -> (w < 3.1 & w > -3.1))", ["x", "y", "w"]
            )


def scan_sectors(count: int) -> Iterator[dict[str, Any]]:
    """Stop before an obstacle, per laser sector; and each sector's ranges are sane."""
    for i in range(count):
        beam = i * 360 // count
        r = {
            "r": {"topic": "/scan", "type": "sensor_msgs/msg/LaserScan", "field": f"ranges[{beam}]"}
        }
        yield monitor(f"obstacle-stop-{beam:03d}", "always (r < 0.3 -> v < 0.05)", ["v"], r)
        yield monitor(f"range-valid-{beam:03d}", "always (r >= 0.05 & r <= 12)", [], r)


def paper_set() -> list[dict[str, Any]]:
    docs = [*mission(), *real_time(), *safety(), *zones()]
    docs += list(scan_sectors((200 - len(docs)) // 2))
    return docs


def imu_envelopes(count: int) -> Iterator[dict[str, Any]]:
    """Acceleration and turn-rate envelopes per zone and speed band, on the 200 Hz IMU."""
    for i in range(count):
        band = 0.1 * (i % 12)
        limit = 2.0 + 0.05 * (i % 40)
        yield monitor(
            f"imu-envelope-{i:04d}",
            f"always (v >= {band:.1f} -> (ax < {limit:.2f} & ax > -{limit:.2f} & gyro_z < 3.4))",
            ["v", "ax", "gyro_z"],
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--extra", type=int, default=0, metavar="N")
    args = parser.parse_args(argv)
    docs = paper_set() + list(imu_envelopes(args.extra))
    head = "# Generated by examples/robot/monitors.py (see its docstring): do not edit.\n"
    args.out.write_text(head + yaml.safe_dump_all(docs, sort_keys=False, width=200))
    print(f"{len(docs)} monitors written to {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
