"""A simulated robot for the case study (seed paper, section VI), in plain rclpy.

Three kinds of process, as on the paper's robot, each a ROS 2 node:

* ``base``: the robot's hardware side. A camera (8 frames/s, ``/camera/image``,
  a small mono image into which the simulator renders the robot's pose), the
  motor driver (at each frame tick, 8 Hz, it applies the newest velocity command
  it has, and a watchdog, as ``diff_drive_controller``'s ``cmd_vel_timeout``:
  a command older than ``--stale`` frame periods is not run, the motors stop;
  with the default 1.5 a loop that misses its deadline stops the robot at that
  tick, and one that misses every deadline never gets it anywhere; ``--stale 0``:
  the newest command runs however old, a late loop only steers late), a
  kinematic simulator (unicycle,
  integrated at 200 Hz) publishing ``/odom`` (50 Hz), ``/imu`` (200 Hz),
  ``/scan`` (20 Hz), ``/battery`` (1 Hz) and ``/bumper``. The robot drives in a
  corridor around its path: leaving it by more than ``--corridor`` is a
  collision, the bumper stops the robot until the next mission.
* ``slam``: the real-time stage (the paper's SLAM + local planner). For each
  frame it does a fixed amount of CPU work (CPU seconds of this thread, so the
  work is the same on any machine and only its wall time grows when something
  else uses the core), reads the pose from the frame, steers along the path and
  publishes ``/cmd_vel`` (``geometry_msgs/msg/TwistStamped``) stamped with the
  frame's stamp. Its ``--calibrate`` period sets the work so that the makespan
  (frame stamp to command) is ``--target`` on this machine: the target minus the
  lower quartile of what frames took besides the work (robust to a disturbance
  during calibration), then freezes it. At its goal the robot parks: the stage
  idles (``--park-work`` per frame, still a command a frame) until a new goal.
* the mission planner lives in the demo driver (``demo.py``): it publishes the
  path (``/path``, transient local) and a new goal (``/goal``).

The base writes what the demo measures as JSON lines (``--log``): every command's
makespan as the motor driver received it, every frame's deadline (met: its
command arrived before the next frame's tick), the pose at 10 Hz, collisions and
arrivals. That is the simulator's instrumentation, not something monitors read.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import struct
import sys
import threading
import time
from typing import Any, TextIO

import rclpy
from geometry_msgs.msg import PoseStamped, TwistStamped
from nav_msgs.msg import Odometry, Path
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import BatteryState, Image, Imu, LaserScan
from std_msgs.msg import Bool, Empty, Float64

FRAME_PERIOD = 0.125  # 8 frames/s: the camera, the motor updates and the deadline
WIDTH, HEIGHT = 160, 120
POSE = struct.Struct("<3d")
LATCHED = QoSProfile(
    depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
)
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
DEEP = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)  # a slow reader loses nothing


def wait_for_readers(publishers: list[tuple[Any, int]], timeout: float = 30.0) -> bool:
    """Until each publisher has its count of matched subscriptions: its first message
    then reaches every observer (reliable writers resend to a reader that matched)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if all(p.get_subscription_count() >= n for p, n in publishers):
            return True
        time.sleep(0.02)
    return False


def stamp_of(ns: int) -> Any:
    from builtin_interfaces.msg import Time

    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def ns_of(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def segment_distance(px: float, py: float, a: tuple[float, float], b: tuple[float, float]) -> float:
    dx, dy = b[0] - a[0], b[1] - a[1]
    length2 = dx * dx + dy * dy or 1e-12
    u = max(0.0, min(1.0, ((px - a[0]) * dx + (py - a[1]) * dy) / length2))
    return math.hypot(px - a[0] - u * dx, py - a[1] - u * dy)


def path_points(msg: Path) -> list[tuple[float, float]]:
    return [(p.pose.position.x, p.pose.position.y) for p in msg.poses]


class Base(Node):
    """Camera, motor driver and kinematic simulator."""

    def __init__(self, log: TextIO, corridor: float, stale: float) -> None:
        super().__init__("robot_base")
        self.log = log
        self.corridor = corridor
        self.stale_ns = int(stale * FRAME_PERIOD * 1e9)  # 0: no watchdog
        self.lock = threading.Lock()
        self.x = self.y = self.theta = 0.0
        self.v = self.w = 0.0  # the command the motors run
        self.newest: tuple[int, float, float] | None = None  # (stamp, v, w) of the newest command
        self.arrived: dict[int, float] = {}  # frame stamp -> makespan seconds
        self.previous_frame: int | None = None
        self.path: list[tuple[float, float]] = []
        self.bumped = False
        self.mission = 0
        self.goal: tuple[float, float] | None = None
        self.reached = False
        self.battery = 1.0
        self.started = time.monotonic()
        self.last_step = time.monotonic()
        self.step_count = 0
        self.image = self.create_publisher(Image, "/camera/image", RELIABLE)
        self.odom = self.create_publisher(Odometry, "/odom", DEEP)
        self.imu = self.create_publisher(Imu, "/imu", DEEP)
        self.scan = self.create_publisher(LaserScan, "/scan", DEEP)
        self.battery_pub = self.create_publisher(BatteryState, "/battery", DEEP)
        self.bumper = self.create_publisher(Bool, "/bumper", DEEP)
        self.create_subscription(TwistStamped, "/cmd_vel", self.on_command, 10)
        self.create_subscription(Path, "/path", self.on_path, LATCHED)
        self.create_subscription(PoseStamped, "/goal", self.on_goal, RELIABLE)
        self.create_subscription(Empty, "/sim/reset", self.on_reset, RELIABLE)

    def start(self) -> None:
        self.last_step = time.monotonic()
        self.create_timer(0.005, self.integrate)
        self.create_timer(FRAME_PERIOD, self.frame_tick)
        self.create_timer(0.02, self.publish_odom)
        self.create_timer(0.05, self.publish_scan)
        self.create_timer(1.0, self.publish_slow)
        self.create_timer(0.1, self.record_pose)

    def write(self, record: dict[str, Any]) -> None:
        record["t"] = time.time()
        self.log.write(json.dumps(record) + "\n")

    # -- inputs --------------------------------------------------------------------------------

    def on_command(self, msg: TwistStamped) -> None:
        now = time.time_ns()
        stamp = ns_of(msg.header.stamp)
        makespan = (now - stamp) / 1e9
        with self.lock:
            self.arrived[stamp] = makespan
            if self.newest is None or stamp > self.newest[0]:
                self.newest = (stamp, msg.twist.linear.x, msg.twist.angular.z)
        self.write({"kind": "cmd", "stamp": stamp, "makespanMs": round(makespan * 1000, 3)})

    def on_path(self, msg: Path) -> None:
        with self.lock:
            self.path = path_points(msg)

    def on_goal(self, msg: PoseStamped) -> None:
        with self.lock:
            self.mission += 1
            self.goal = (msg.pose.position.x, msg.pose.position.y)
            self.reached = False
        self.write({"kind": "goal", "mission": self.mission, "goal": self.goal})

    def on_reset(self, _msg: Empty) -> None:
        with self.lock:
            self.x = self.y = self.theta = self.v = self.w = 0.0
            self.newest = None
            self.bumped = False
            self.goal = None
            self.battery = 1.0
        self.bumper.publish(Bool(data=False))
        self.write({"kind": "reset"})

    # -- the world -----------------------------------------------------------------------------

    def integrate(self) -> None:
        now = time.monotonic()
        dt, self.last_step = min(now - self.last_step, 0.05), now
        with self.lock:
            v, w = (0.0, 0.0) if self.bumped else (self.v, self.w)
            self.x += v * math.cos(self.theta) * dt
            self.y += v * math.sin(self.theta) * dt
            self.theta = wrap(self.theta + w * dt)
            self.battery = max(0.0, self.battery - 0.0005 * abs(v) * dt)
            if self.path and self.goal and not self.bumped:
                off = min(
                    segment_distance(self.x, self.y, a, b)
                    for a, b in zip(self.path, self.path[1:], strict=False)
                )
                if off > self.corridor:
                    self.bumped = True
                    self.v = self.w = 0.0
                    self.write({"kind": "collision", "x": self.x, "y": self.y, "offMs": off})
                    self.bumper.publish(Bool(data=True))
            near = self.goal and math.hypot(self.goal[0] - self.x, self.goal[1] - self.y) < 0.2
            if near and not self.reached and not self.bumped:
                self.reached = True
                self.write({"kind": "arrived", "mission": self.mission})
        msg = Imu()
        msg.header.stamp = stamp_of(time.time_ns())
        msg.header.frame_id = "imu"
        msg.angular_velocity.z = w
        msg.linear_acceleration.x = 0.0
        msg.linear_acceleration.z = 9.81
        msg.orientation.z, msg.orientation.w = math.sin(self.theta / 2), math.cos(self.theta / 2)
        self.imu.publish(msg)

    def frame_tick(self) -> None:
        """The 8 Hz tick: the motors take the newest command; then the camera captures."""
        now = time.time_ns()
        with self.lock:
            if self.newest is not None and not self.bumped:
                stamp, v, w = self.newest
                if self.stale_ns and now - stamp > self.stale_ns:
                    v = w = 0.0  # the watchdog: no command from the last frame
                self.v, self.w = v, w
            previous, self.previous_frame = self.previous_frame, now
            met = previous is not None and previous in self.arrived
            self.arrived = {s: m for s, m in self.arrived.items() if s >= now - 2_000_000_000}
            pose = POSE.pack(self.x, self.y, self.theta)
        if previous is not None:
            self.write({"kind": "frame", "stamp": previous, "met": met})
        image = Image()
        image.header.stamp = stamp_of(now)
        image.header.frame_id = "camera"
        image.height, image.width, image.step = HEIGHT, WIDTH, WIDTH
        image.encoding = "mono8"
        image.data = pose + bytes(WIDTH * HEIGHT - len(pose))
        self.image.publish(image)

    def publish_odom(self) -> None:
        msg = Odometry()
        msg.header.stamp = stamp_of(time.time_ns())
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        with self.lock:
            msg.pose.pose.position.x, msg.pose.pose.position.y = self.x, self.y
            msg.pose.pose.orientation.z = math.sin(self.theta / 2)
            msg.pose.pose.orientation.w = math.cos(self.theta / 2)
            moving = not self.bumped
            msg.twist.twist.linear.x = self.v if moving else 0.0
            msg.twist.twist.angular.z = self.w if moving else 0.0
        self.odom.publish(msg)

    def publish_scan(self) -> None:
        """360 rays in a 6 m x 5 m room around the route (cheap geometry, realistic size)."""
        msg = LaserScan()
        msg.header.stamp = stamp_of(time.time_ns())
        msg.header.frame_id = "laser"
        msg.angle_min, msg.angle_max = -math.pi, math.pi
        msg.angle_increment = 2 * math.pi / 360
        msg.range_min, msg.range_max = 0.05, 12.0
        with self.lock:
            x, y, theta = self.x, self.y, self.theta
        ranges = []
        for i in range(360):
            a = theta - math.pi + i * msg.angle_increment
            c, s = math.cos(a), math.sin(a)
            tx = ((5.0 - x) / c if c > 1e-9 else (-1.0 - x) / c) if abs(c) > 1e-9 else 99.0
            ty = ((4.0 - y) / s if s > 1e-9 else (-1.0 - y) / s) if abs(s) > 1e-9 else 99.0
            ranges.append(min(tx, ty, msg.range_max))
        msg.ranges = ranges
        self.scan.publish(msg)

    def publish_slow(self) -> None:
        msg = BatteryState()
        msg.header.stamp = stamp_of(time.time_ns())
        with self.lock:
            msg.percentage = float(self.battery)
            bumped = self.bumped
        msg.voltage = 24.0 * msg.percentage
        self.battery_pub.publish(msg)
        self.bumper.publish(Bool(data=bumped))

    def record_pose(self) -> None:
        with self.lock:
            pose = {"kind": "pose", "x": round(self.x, 4), "y": round(self.y, 4)}
        self.write(pose)
        self.log.flush()


class Slam(Node):
    """The real-time stage: fixed CPU work per frame, then steering along the path."""

    def __init__(
        self,
        work: float,
        calibrate: float,
        target: float,
        gain: float,
        speed: float,
        park_work: float,
    ) -> None:
        super().__init__("slam_planner")
        self.work, self.target, self.gain, self.speed = work, target, gain, speed
        self.park_work = park_work
        self.parked = False  # at the goal: the stage idles until the next one
        self.calibrate_until = time.monotonic() + calibrate if calibrate > 0 else 0.0
        self.samples: list[float] = []
        self.path: list[tuple[float, float]] = []
        self.waypoint = 1 << 30  # no goal yet: stand still
        self.cmd = self.create_publisher(TwistStamped, "/cmd_vel", DEEP)
        self.create_subscription(Image, "/camera/image", self.on_frame, 1)  # newest frame only
        self.create_subscription(Path, "/path", self.on_path, LATCHED)
        self.create_subscription(PoseStamped, "/goal", self.on_goal, RELIABLE)
        self.create_subscription(Float64, "/slam/work", self.on_work, RELIABLE)

    def on_path(self, msg: Path) -> None:
        self.path = path_points(msg)

    def on_goal(self, _msg: PoseStamped) -> None:
        """A new goal: drive the path from its start (until then the robot stands)."""
        self.waypoint = 1
        self.parked = False

    def on_work(self, msg: Float64) -> None:
        self.work = msg.data

    def burn(self) -> int:
        """The work (CPU seconds of this thread's own computation) of one frame."""
        end = time.thread_time() + (self.park_work if self.parked else self.work)
        acc = 0
        while time.thread_time() < end:
            for i in range(500):
                acc ^= i * i
        return acc

    def steer(self, x: float, y: float, theta: float) -> tuple[float, float]:
        if len(self.path) < 2 or self.waypoint >= len(self.path):
            return 0.0, 0.0
        last = len(self.path) - 1
        wx, wy = self.path[self.waypoint]
        distance = math.hypot(wx - x, wy - y)
        if distance < 0.4 and self.waypoint < last:
            self.waypoint += 1
            wx, wy = self.path[self.waypoint]
            distance = math.hypot(wx - x, wy - y)
        if self.waypoint == last and distance < 0.1:
            self.waypoint = len(self.path)  # arrived: stop and park
            self.parked = True
            return 0.0, 0.0
        error = wrap(math.atan2(wy - y, wx - x) - theta)
        w = max(-3.0, min(3.0, self.gain * error))
        v = self.speed if self.waypoint < last else min(self.speed, 0.8 * distance)
        return v, w

    def on_frame(self, msg: Image) -> None:
        self.burn()
        x, y, theta = POSE.unpack(bytes(msg.data[: POSE.size]))
        v, w = self.steer(x, y, theta)
        out = TwistStamped()
        out.header.stamp = msg.header.stamp
        out.header.frame_id = "base_link"
        out.twist.linear.x, out.twist.angular.z = v, w
        self.cmd.publish(out)
        if self.calibrate_until:
            makespan = (time.time_ns() - ns_of(msg.header.stamp)) / 1e9
            # What the frame took besides the work: reading, steering, publishing, and any
            # preemption. Disturbances only add to it, so its lower quartile is the loop's
            # own overhead on an idle CPU: the work is the target minus that.
            self.samples.append(makespan - self.work)
            if len(self.samples) >= 4:
                low = sorted(self.samples)[len(self.samples) // 4]
                self.work = max(0.001, self.target - low)
            if time.monotonic() >= self.calibrate_until:
                self.calibrate_until = 0.0
                print(
                    json.dumps({"calibrated": {"workMs": round(self.work * 1000, 2)}}), flush=True
                )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="node", required=True)
    base = sub.add_parser("base")
    base.add_argument("--log", required=True, metavar="FILE")
    base.add_argument("--corridor", type=float, default=0.25, metavar="METRES")
    base.add_argument(
        "--stale",
        type=float,
        default=1.5,
        metavar="PERIODS",
        help="the motors' watchdog: a command older than this many frame periods "
        "(from its frame's stamp) is not run (0: no watchdog)",
    )
    for p in (base, slam := sub.add_parser("slam")):
        p.add_argument(
            "--observers",
            type=int,
            default=0,
            metavar="N",
            help="start once N subscriptions besides the robot's own match each topic",
        )
    slam.add_argument("--work", type=float, default=0.11, metavar="CPU_SECONDS")
    slam.add_argument("--calibrate", type=float, default=0.0, metavar="SECONDS")
    slam.add_argument("--target", type=float, default=0.115, metavar="SECONDS")
    slam.add_argument("--gain", type=float, default=5.0, help="heading gain (rad/s per rad)")
    slam.add_argument("--speed", type=float, default=1.0, metavar="M_PER_S")
    slam.add_argument(
        "--park-work", type=float, default=0.002, metavar="CPU_SECONDS", help="per frame, parked"
    )
    args = parser.parse_args(argv)
    rclpy.init()
    node: Node
    log = None
    if args.node == "base":
        log = open(args.log, "a", buffering=1 << 16)  # noqa: SIM115 - closed below
        base_node = Base(log, args.corridor, args.stale)
        n = args.observers
        ready = wait_for_readers(
            [(base_node.image, n + 1)]
            + [(p, n) for p in (base_node.odom, base_node.imu, base_node.scan)]
            + [(p, n) for p in (base_node.battery_pub, base_node.bumper)]
        )
        base_node.start()
        node = base_node
    else:
        node = Slam(args.work, args.calibrate, args.target, args.gain, args.speed, args.park_work)
        ready = wait_for_readers([(node.cmd, args.observers + 1)])
    if not ready:
        print(f"{args.node}: not every observer subscribed within 30 s", file=sys.stderr)
    print(json.dumps({"started": args.node}), flush=True)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except KeyboardInterrupt:
        pass
    except Exception as exc:
        if rclpy.ok():
            raise
        print(f"{args.node}: {exc}", file=sys.stderr)
    finally:
        if log:
            log.flush()
            os.fsync(log.fileno())
            log.close()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
