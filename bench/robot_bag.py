"""A robot's recording as `ros2 bag record` writes it, for the benchmarks: a rosbag2 MCAP
file, the same events as JSON Lines, and ten monitors to check them with.

The robot (one step of its model every 10 ms of recorded time) docks, waits, drives
missions at slowly changing cruise speeds, returns to charge when its battery runs low,
and now and then something goes wrong: a wheel slips and its speed jumps over 100 cm/s for
a sample or three (about once every 400 s of driving), a sensor driver hiccups and a topic
is silent for 120-300 ms (about once an hour or two per topic), an emergency stop is
pressed (about once an hour) and the controller, once in four, reacts a cycle late. So the
monitors below report a few hundred violations in 10 M events, not millions.

Topics (190 messages a second in all):

* ``/odom``    nav_msgs/msg/Odometry  50 Hz, header stamped (frame ids "odom", "base_link")
* ``/speed``   std_msgs/msg/Float64  100 Hz, the drive's speed in cm/s
* ``/battery`` std_msgs/msg/Float64   10 Hz, the charge in percent
* ``/running``, ``/estop``, ``/stop``  std_msgs/msg/Bool  10 Hz each

The MCAP file is written with the ``mcap`` package's writer as rosbag2's MCAP storage
writes it: profile "ros2", one schema a type (encoding "ros2msg", the message definition
with its dependencies concatenated), one channel a topic (encoding "cdr", with the QoS
metadata), zstd chunks of the writer's default size, message indexes and the summary. The
CDR bytes are packed with ``struct`` directly (Odometry's layout is constant with fixed
frame ids); :func:`check_serialization` compares them with rosbags' serializer.

    python bench/robot_bag.py 1000000 run.mcap [--monitors monitors.yaml]
    python bench/robot_bag.py 300000 run.jsonl
"""

from __future__ import annotations

import argparse
import json
import math
import random
import struct
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

ODOM, SPEED, BATTERY, RUNNING, ESTOP, STOP = range(6)
TOPICS = [
    ("/odom", "nav_msgs/msg/Odometry"),
    ("/speed", "std_msgs/msg/Float64"),
    ("/battery", "std_msgs/msg/Float64"),
    ("/running", "std_msgs/msg/Bool"),
    ("/estop", "std_msgs/msg/Bool"),
    ("/stop", "std_msgs/msg/Bool"),
]
START = 1_700_000_000_000_000_000  # ns
TICK = 10_000_000  # the model's step: 10 ms
PHASES = {1: BATTERY, 3: RUNNING, 5: ESTOP, 7: STOP}  # the 10 Hz topics' ticks in 100 ms

# diff_drive_controller's default covariance diagonals
COVARIANCE = [0.0] * 36
for _i, _v in enumerate([0.001, 0.001, 0.001, 0.001, 0.001, 0.01]):
    COVARIANCE[_i * 7] = _v

# The ten monitors of the bag benchmark: untimed safety on each topic, two deadlines
# (`age`), one liveness property that halts once decided, several reading three topics.
MONITORS = """\
# whenever running, the drive's speed stays under 100 cm/s
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: speed-limit}
spec:
  assertion: "always (running -> speed < 100)"
  signals:
    running: {topic: /running, type: std_msgs/msg/Bool}
    speed: {topic: /speed, type: std_msgs/msg/Float64}
---
# the paper's running example, on odometry: under 1 m/s until stopped
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: odom-speed-until-stop}
spec:
  assertion: "always (running -> (v < limit until stop))"
  signals:
    running: {topic: /running, type: std_msgs/msg/Bool}
    v: {topic: /odom, type: nav_msgs/msg/Odometry, field: twist.twist.linear.x}
    stop: {topic: /stop, type: std_msgs/msg/Bool, initial: false}
  parameters: {limit: 1.0}
---
# turning rate within the base's limits
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: turn-rate}
spec:
  assertion: "always (w < 1.0 & w > -1.0)"
  signals:
    w: {topic: /odom, type: nav_msgs/msg/Odometry, field: twist.twist.angular.z}
---
# never run the battery flat
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: battery-floor}
spec:
  assertion: "always (battery > 10)"
  signals:
    battery: {topic: /battery, type: std_msgs/msg/Float64}
---
# after an emergency stop the controller's next report says it is not running
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: estop-stops}
spec:
  assertion: "always (estop -> next !running)"
  signals:
    estop: {topic: /estop, type: std_msgs/msg/Bool}
    running: {topic: /running, type: std_msgs/msg/Bool}
---
# stopped means still
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: stopped-is-still}
spec:
  assertion: "always (stop -> speed < 5)"
  signals:
    stop: {topic: /stop, type: std_msgs/msg/Bool}
    speed: {topic: /speed, type: std_msgs/msg/Float64}
---
# odometry keeps coming (50 Hz: every 20 ms)
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: odom-fresh}
spec:
  assertion: "always (age(x) < 100ms)"
  signals:
    x: {topic: /odom, type: nav_msgs/msg/Odometry, field: pose.pose.position.x}
---
# while running, the drive reports its speed (100 Hz: every 10 ms)
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: speed-fresh}
spec:
  assertion: "always (running -> age(speed) < 100ms)"
  signals:
    running: {topic: /running, type: std_msgs/msg/Bool}
    speed: {topic: /speed, type: std_msgs/msg/Float64}
---
# the robot sets off on a mission at all (decided once: halt)
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: mission-starts}
spec:
  assertion: "eventually! (running & speed > 20)"
  signals:
    running: {topic: /running, type: std_msgs/msg/Bool}
    speed: {topic: /speed, type: std_msgs/msg/Float64}
  onVerdict: halt
---
# on a low battery the robot drives slowly
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: low-battery-slow}
spec:
  assertion: "always ((battery < 20 & running) -> speed < 50)"
  signals:
    battery: {topic: /battery, type: std_msgs/msg/Float64}
    running: {topic: /running, type: std_msgs/msg/Bool}
    speed: {topic: /speed, type: std_msgs/msg/Float64}
"""


def robot_events(n: int, seed: int = 1) -> Iterator[tuple[int, int, Any]]:
    """The first ``n`` messages of the recording, in log-time order: ``(topic, log_time,
    value)`` with ``topic`` an index into :data:`TOPICS` and ``value`` a float or a bool,
    or for /odom ``(stamp, x, y, qz, qw, vx, wz)`` (its header stamp: the sensor's time,
    before the log time)."""
    rng = random.Random(seed)
    rnd, randint, uniform = rng.random, rng.randint, rng.uniform
    sin, cos = math.sin, math.cos
    count = 0
    tick = 0
    # the robot: docked and stopped, full battery; counters in ticks
    running = estop = False
    stop = True
    mission = stopping = charging = False
    speed = target = 0.0
    battery = 100.0
    x = y = yaw = turn = turn_target = 0.0
    mode_left = 500  # the first mission starts after 5 s
    cruise_left = go_in = release_in = reaction_in = 0
    spike_in, spike_left, spike = randint(2_000, 20_000), 0, 0.0
    estop_in, estop_left = randint(300_000, 700_000), 0
    odom_gap_in, odom_gap_left = randint(300_000, 1_000_000), 0
    speed_gap_in, speed_gap_left = randint(200_000, 600_000), 0
    sent = [False, False, True]  # running, estop, stop as last published
    while True:
        t = START + tick * TICK
        # --- the robot's step ---
        if estop_left:
            estop_left -= 1
            if not estop_left:
                estop = False
                mode_left = randint(1_000, 3_000)  # wait, then the next mission
        elif estop_in:
            estop_in -= 1
        else:
            estop, estop_left = True, randint(200, 600)
            estop_in = randint(300_000, 700_000)
            reaction_in = -1  # the controller reacts once it reads the estop message
        if reaction_in > 0:
            reaction_in -= 1
            if not reaction_in:  # stop now; `stop` once still (below)
                running, go_in = False, 0
                if mission:
                    stopping = True
        if mission:
            mode_left -= 1
            if go_in:
                go_in -= 1
                if not go_in:
                    running = True
            elif not stopping:
                cruise_left -= 1
                if cruise_left <= 0:
                    cruise_left = randint(1_000, 6_000)
                    target = uniform(20.0, 85.0)
                    turn_target = uniform(-0.5, 0.5) if rnd() < 0.5 else 0.0
                if battery < 25.0:  # back to the dock, slowly
                    target = min(target, 35.0)
                    mode_left = min(mode_left, 6_000)
                if mode_left <= 0:
                    stopping, target, turn_target = True, 0.0, 0.0
            elif speed < 1.0 and not release_in:
                running = False
                release_in = 20
        elif not estop:
            mode_left -= 1
            if charging:
                battery += 0.0008
                if battery >= 95.0:
                    charging, mode_left = False, min(mode_left, 500)
            if mode_left <= 0 and not charging and stop:
                stop = False
                mission, stopping, go_in = True, False, 20
                mode_left, cruise_left = randint(12_000, 60_000), 0
        if release_in:
            release_in -= 1
            if not release_in:
                stop, mission, stopping = True, False, False
                charging = battery < 30.0
                mode_left = randint(3_000, 18_000)
        if estop or not running:
            target = 0.0
        speed += (target - speed) * (0.1 if estop else 0.01)
        turn += ((turn_target if running else 0.0) - turn) * 0.02
        battery -= 0.0001 + speed * 0.000002 if running else 0.00004
        measured = speed + (rnd() - 0.5) * 0.6
        if running and not spike_left:
            spike_in -= 1
            if not spike_in:  # a wheel slips
                spike_left, spike = randint(1, 3), uniform(101.0, 110.0)
                spike_in = randint(20_000, 60_000)
        if spike_left:
            spike_left -= 1
            measured = spike
        # --- what the robot publishes at this tick, in log-time order ---
        k = 0
        if speed_gap_left:
            speed_gap_left -= 1
        elif speed_gap_in:
            speed_gap_in -= 1
        else:
            speed_gap_left, speed_gap_in = randint(12, 30), randint(200_000, 600_000)
        if not speed_gap_left:
            yield SPEED, t + 150_000 + int(rnd() * 100_000), measured
            count += 1
            if count == n:
                return
            k = 1
        if not tick & 1:
            v = measured / 100.0
            yaw += turn * 0.02
            x += v * cos(yaw) * 0.02
            y += v * sin(yaw) * 0.02
            if odom_gap_left:
                odom_gap_left -= 1
            elif odom_gap_in:
                odom_gap_in -= 1
            else:
                odom_gap_left, odom_gap_in = randint(6, 15), randint(300_000, 1_000_000)
            if not odom_gap_left:
                half = yaw / 2.0
                value = (t, x, y, sin(half), cos(half), v + (rnd() - 0.5) * 0.01, turn)
                yield ODOM, t + 150_000 + k * 200_000 + int(rnd() * 100_000), value
                count += 1
                if count == n:
                    return
                k += 1
        topic = PHASES.get(tick % 10)
        if topic is not None:
            log = t + 150_000 + k * 200_000 + int(rnd() * 100_000)
            if topic == BATTERY:
                yield BATTERY, log, battery + (rnd() - 0.5) * 0.1
            elif topic == RUNNING:
                sent[0] = running
                yield RUNNING, log, running
            elif topic == ESTOP:
                yield ESTOP, log, estop
                if estop and not sent[1] and reaction_in < 0:
                    # read it: stop at this tick, or (one in four) a cycle late
                    reaction_in = 1 if rnd() < 0.75 else 11
                sent[1] = estop
            else:
                yield STOP, log, stop
            count += 1
            if count == n:
                return
        tick += 1


# --- CDR, packed directly (little endian, XCDR1: a 4-byte encapsulation header, then each
# primitive aligned to its size, counted from after the header) ---
CDR_LE = b"\x00\x01\x00\x00"
BOOL = struct.Struct("<4s?").pack
FLOAT64 = struct.Struct("<4sd").pack
# header.stamp sec, nanosec; frame_id "odom" (length with NUL), 3 bytes of padding;
# child_frame_id "base_link", 6 bytes of padding up to the first float64 at 40;
# pose position xyz, orientation xyzw, covariance; twist linear xyz, angular xyz, covariance
ODOMETRY = struct.Struct("<4siI9s3x14s6x7d288s6d288s").pack
FRAME = struct.pack("<I5s", 5, b"odom\0")
CHILD = struct.pack("<I10s", 10, b"base_link\0")
COV = struct.pack("<36d", *COVARIANCE)


def odometry_cdr(value: tuple[int, float, float, float, float, float, float]) -> bytes:
    stamp, x, y, qz, qw, vx, wz = value
    sec, nanosec = divmod(stamp, 1_000_000_000)
    return ODOMETRY(
        CDR_LE, sec, nanosec, FRAME, CHILD, x, y, 0.0, 0.0, 0.0, qz, qw, COV,
        vx, 0.0, 0.0, 0.0, 0.0, wz, COV,
    )  # fmt: skip


def msgdef(msgtype: str) -> str:
    """The definition rosbag2 stores in a schema: the type's fields, then each dependency
    as ``MSG: pkg/Type`` after a line of 80 ``=``; rosbags gives ROS 1's ``time`` for the
    header's stamp, which rosbag2 writes as ``builtin_interfaces/Time`` with its own
    section."""
    from rosbags.typesys import Stores, get_typestore

    text, _ = get_typestore(Stores.ROS2_JAZZY).generate_msgdef(msgtype)
    sep = "=" * 80 + "\n"
    time_section = f"{sep}MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
    if "\ntime stamp\n" in text:
        text = text.replace("\ntime stamp\n", "\nbuiltin_interfaces/Time stamp\n")
        # after the Header section, as rosbag2 orders dependencies (depth first)
        head, _, rest = text.partition(f"{sep}MSG: std_msgs/Header\n")
        header, nxt, tail = rest.partition(sep)
        text = f"{head}{sep}MSG: std_msgs/Header\n{header}{time_section}{nxt}{tail}"
    return text


QOS = """\
- history: 3
  depth: 0
  reliability: 1
  durability: 2
  deadline:
    sec: 9223372036
    nsec: 854775807
  lifespan:
    sec: 9223372036
    nsec: 854775807
  liveliness: 1
  liveliness_lease_duration:
    sec: 9223372036
    nsec: 854775807
  avoid_ros_namespace_conventions: false"""


def write_bag(path: Path | str, n: int, seed: int = 1) -> dict[str, int]:
    """The first ``n`` messages of the recording as a rosbag2 MCAP file; the count of
    messages a topic."""
    from mcap.writer import CompressionType, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    counts = [0] * len(TOPICS)
    with open(path, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="mcap-python (edgerv bench/robot_bag.py)")
        schemas: dict[str, int] = {}
        channels = []
        for topic, msgtype in TOPICS:
            if msgtype not in schemas:
                schemas[msgtype] = writer.register_schema(
                    msgtype, "ros2msg", msgdef(msgtype).encode()
                )
            metadata = {
                "offered_qos_profiles": QOS,
                "topic_type_hash": store.hash_rihs01(msgtype),
            }
            channels.append(writer.register_channel(topic, "cdr", schemas[msgtype], metadata))
        add = writer.add_message
        packs = (
            [odometry_cdr] + [lambda v: FLOAT64(CDR_LE, v)] * 2 + [lambda v: BOOL(CDR_LE, v)] * 3
        )
        for topic, log, value in robot_events(n, seed):
            counts[topic] += 1
            add(channels[topic], log, packs[topic](value), log - 50_000, counts[topic])
        writer.finish()
    return {TOPICS[i][0]: c for i, c in enumerate(counts)}


def odometry_dict(value: tuple[int, float, float, float, float, float, float]) -> dict[str, Any]:
    stamp, x, y, qz, qw, vx, wz = value
    sec, nanosec = divmod(stamp, 1_000_000_000)
    return {
        "header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": "odom"},
        "child_frame_id": "base_link",
        "pose": {
            "pose": {
                "position": {"x": x, "y": y, "z": 0.0},
                "orientation": {"x": 0.0, "y": 0.0, "z": qz, "w": qw},
            },
            "covariance": COVARIANCE,
        },
        "twist": {
            "twist": {
                "linear": {"x": vx, "y": 0.0, "z": 0.0},
                "angular": {"x": 0.0, "y": 0.0, "z": wz},
            },
            "covariance": COVARIANCE,
        },
    }


def write_jsonl(path: Path | str, n: int, seed: int = 1) -> dict[str, int]:
    """The same messages as JSON Lines, as `edgerv check` reads them: ``{"topic", "stamp",
    "msg"}`` a line, ``stamp`` the log time in integer nanoseconds (/odom's header stamp,
    in its message, is its event's stamp, as in the bag); the count of messages a topic."""
    counts = [0] * len(TOPICS)
    names = [json.dumps(topic) for topic, _ in TOPICS]
    dumps = json.dumps
    with open(path, "w") as f:
        lines: list[str] = []
        for topic, log, value in robot_events(n, seed):
            counts[topic] += 1
            msg = odometry_dict(value) if topic == ODOM else {"data": value}
            lines.append(f'{{"topic": {names[topic]}, "stamp": {log}, "msg": {dumps(msg)}}}\n')
            if len(lines) == 4096:
                f.writelines(lines)
                lines.clear()
        f.writelines(lines)
    return {TOPICS[i][0]: c for i, c in enumerate(counts)}


def check_serialization() -> None:
    """The packed CDR bytes are what rosbags' serializer writes for the same messages."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types = store.types
    for value, pack, msgtype in (
        (True, lambda v: BOOL(CDR_LE, v), "std_msgs/msg/Bool"),
        (17.25, lambda v: FLOAT64(CDR_LE, v), "std_msgs/msg/Float64"),
    ):
        assert pack(value) == store.serialize_cdr(types[msgtype](data=value), msgtype)
    value = (START + 123_456_789, 1.5, -2.25, 0.1, 0.995, 0.75, -0.125)
    d = odometry_dict(value)
    vec, point, quat = (
        types["geometry_msgs/msg/Vector3"],
        types["geometry_msgs/msg/Point"],
        types["geometry_msgs/msg/Quaternion"],
    )
    import numpy as np

    cov = np.array(COVARIANCE, dtype=np.float64)
    msg = types["nav_msgs/msg/Odometry"](
        header=types["std_msgs/msg/Header"](
            stamp=types["builtin_interfaces/msg/Time"](**d["header"]["stamp"]), frame_id="odom"
        ),
        child_frame_id="base_link",
        pose=types["geometry_msgs/msg/PoseWithCovariance"](
            pose=types["geometry_msgs/msg/Pose"](
                position=point(**d["pose"]["pose"]["position"]),
                orientation=quat(**d["pose"]["pose"]["orientation"]),
            ),
            covariance=cov,
        ),
        twist=types["geometry_msgs/msg/TwistWithCovariance"](
            twist=types["geometry_msgs/msg/Twist"](
                linear=vec(**d["twist"]["twist"]["linear"]),
                angular=vec(**d["twist"]["twist"]["angular"]),
            ),
            covariance=cov,
        ),
    )
    assert odometry_cdr(value) == store.serialize_cdr(msg, "nav_msgs/msg/Odometry")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("events", type=int, help="how many messages")
    parser.add_argument("out", type=Path, help="a .mcap file, or .jsonl for JSON Lines")
    parser.add_argument("--monitors", type=Path, help="write the ten monitors' YAML here too")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    check_serialization()
    start = time.perf_counter()
    write = write_jsonl if args.out.suffix == ".jsonl" else write_bag
    counts = write(args.out, args.events, args.seed)
    seconds = time.perf_counter() - start
    if args.monitors:
        args.monitors.write_text(MONITORS)
    print(
        f"{args.out}: {sum(counts.values()):,} messages in {seconds:.1f} s "
        f"({args.out.stat().st_size / 2**20:,.1f} MiB): "
        + ", ".join(f"{t} {c:,}" for t, c in counts.items()),
        file=sys.stderr,
    )


if __name__ == "__main__":
    main()
