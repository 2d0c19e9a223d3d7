"""A fleet without Kubernetes, on real ROS 2 traffic: ten robots, each publishing in its
own graph (its ROS namespace, ``/amr_K/...``) with an edge handler of its own, and one
cloud handler serving all; ``edgerv orchestrate --handlers edge@amr-K=...,cloud=...``
moves the instances of the robots whose real-time task runs late (their edge handlers'
``--deadline``) up to the cloud, and each back to its own robot's edge once the task is on
time again; no instance ever runs on another robot's handler, the others never move, and
every instance's verdicts over its edge and the cloud equal ``edgerv check`` on its
robot's recording (docs/protocol.md, "Fleet").
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest

from edgerv.core.robots import ros_namespace
from edgerv_operator.documents import document_text, instance_document
from kit.ros import TOKEN, HandlerProcess, live_verdicts, offline_verdicts, ros_env, wait_for

pytestmark = pytest.mark.integration

ROBOTS = [f"amr-{k}" for k in range(10)]
LATE = ROBOTS[:4]  # their task runs late until told otherwise: their instances move up
SPEC: dict[str, Any] = {
    "assertion": "always (speed < limit)",
    "signals": {
        "speed": {"topic": "/speed", "type": "std_msgs/msg/Float64", "qos": {"depth": 1000}}
    },
    "parameters": {"limit": 50},
}

# Each robot: /NS/speed (0..99, a robot's own phase; over the limit half the time) and its
# task's output /NS/cmd, stamped 140 ms before it is published while late (the deadline
# is 100 ms), 50 ms after SIGUSR1; every 50 ms. The speeds are recorded as a trace.
ROBOT = r"""
import json, signal, sys, time, rclpy, rclpy.signals
from geometry_msgs.msg import TwistStamped
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64
robots, late, out = sys.argv[1].split(","), set(sys.argv[2].split(",")), sys.argv[3]
state = {"late": True, "stop": False}
signal.signal(signal.SIGUSR1, lambda *_: state.update(late=False))
signal.signal(signal.SIGTERM, lambda *_: state.update(stop=True))
# (rclpy's own SIGTERM handler would shut its context down: a publish after it raises,
# and the recording below would never be written)
rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
node = rclpy.create_node("fleet")
ns = {r: "/" + r.replace("-", "_") for r in robots}
reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
speed = {r: node.create_publisher(Float64, ns[r] + "/speed", reliable) for r in robots}
cmd = {r: node.create_publisher(TwistStamped, ns[r] + "/cmd", 10) for r in robots}
give_up = time.monotonic() + 60
while not all(p.get_subscription_count() for p in speed.values()):  # each robot's edge
    if time.monotonic() > give_up:
        counts = {r: p.get_subscription_count() for r, p in speed.items()}
        sys.exit(f"the handlers did not subscribe within 60 s: {counts}")
    time.sleep(0.05)
print("publishing", flush=True)
lines, i = [], 0
while not state["stop"]:
    for k, r in enumerate(robots):
        value = float((i + 13 * k) % 100)
        m = Float64(); m.data = value
        speed[r].publish(m)
        lines.append(json.dumps({"topic": ns[r] + "/speed", "stamp": 1000 + i,
                                 "msg": {"data": value}}))
        c = TwistStamped()
        age = 0.140 if state["late"] and r in late else 0.050
        c.header.stamp.sec, c.header.stamp.nanosec = divmod(time.time_ns() - int(age * 1e9), 10**9)
        cmd[r].publish(c)
    i += 1
    time.sleep(0.05)
time.sleep(0.5)  # (reliable: the last ones delivered)
open(out, "w").write("\n".join(lines) + "\n")
"""


def instance(robot: str) -> str:
    return f"lab.speed.{robot}"


def active(h: HandlerProcess) -> set[str]:
    status, listing = h.request("GET", "/v1/monitors")
    assert status == 200, listing
    return {m["name"] for m in listing["monitors"] if m["active"]}


def test_ten_robots_share_a_cloud_each_instance_moving_up_and_home_to_its_own_robot(
    tmp_path: Path, domain: int
) -> None:
    docs = {r: document_text(instance_document("lab", "speed", SPEC, r)) for r in ROBOTS}
    for r, text in docs.items():
        (tmp_path / f"{r}.json").write_text(text)
    (tmp_path / "all.yaml").write_text("---\n".join(docs.values()))

    def edge(r: str) -> HandlerProcess:
        # every other robot's edge handler is given the chart's form, a relative topic:
        # the robot's, from the instance it runs (/amr_0/cmd); the others the absolute one
        deadline = "cmd=100ms" if ROBOTS.index(r) % 2 == 0 else f"{ros_namespace(r)}/cmd=100ms"
        return HandlerProcess(
            tmp_path, tmp_path / f"{r}.json", domain, "--deadline", deadline, name=f"edge-{r}"
        )

    with ThreadPoolExecutor(4) as pool:  # eleven handlers starting: four at a time
        cloud_started = pool.submit(
            HandlerProcess, tmp_path, tmp_path / "all.yaml", domain, "--active", "none",
            name="cloud",
        )  # fmt: skip
        edges = dict(zip(ROBOTS, pool.map(edge, ROBOTS), strict=True))
        cloud = cloud_started.result()
    robot = subprocess.Popen(
        [sys.executable, "-c", ROBOT, ",".join(ROBOTS), ",".join(LATE), str(tmp_path / "rec")],
        env=ros_env(domain),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    handlers = ",".join(
        [f"edge@{r}=127.0.0.1:{h.port}" for r, h in edges.items()]
        + [f"cloud=127.0.0.1:{cloud.port}"]
    )
    orchestrate = subprocess.Popen(
        [sys.executable, "-m", "edgerv", "orchestrate", "--handlers", handlers,
         "--interval", "0.5", "--calm", "2", "--cooldown", "3", "--max-moves-down", "10",
         "--no-plan"],
        env={**ros_env(domain), "EDGERV_TOKEN": TOKEN},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    try:
        assert robot.stdout is not None and robot.stdout.readline() == "publishing\n", (
            robot.stderr.read() if robot.poll() is not None and robot.stderr else "?"
        )
        # the late robots' instances go up; the others stay on their own edges
        up = {instance(r) for r in LATE}
        assert wait_for(lambda: active(cloud) == up, timeout=90), (active(cloud), cloud.stderr)
        for r, h in edges.items():
            assert active(h) == (set() if r in LATE else {instance(r)}), r
            # each edge measures its own robot's /NS/cmd, the relative ones too (once its
            # graph shows the publisher: the subscription is made then)
            reading = (
                wait_for(
                    lambda h=h: (
                        (d := h.request("GET", "/v1/load")[1]["deadline"])["messagesTotal"] and d
                    ),
                    timeout=30,
                )
                or h.request("GET", "/v1/load")[1]["deadline"]
            )
            assert reading["topic"] == f"{ros_namespace(r)}/cmd", (r, reading, h.stderr)
            assert reading["messagesTotal"] > 0, (r, reading, h.stderr)
        robot.send_signal(signal.SIGUSR1)  # on time again: each comes home
        home = wait_for(
            lambda: not active(cloud) and all(active(h) == {instance(r)} for r, h in edges.items()),
            timeout=90,
        )
        assert home, {r: active(h) for r, h in edges.items()}
    finally:
        orchestrate.send_signal(signal.SIGTERM)
        out, err = orchestrate.communicate(timeout=30)
        robot.send_signal(signal.SIGTERM)
        robot.wait(timeout=30)
        codes = {h.name: h.stop() for h in [*edges.values(), cloud]}
    assert set(codes.values()) == {0}, codes
    moves = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    moved = [m for m in moves if m.get("ok") and m.get("reason") != "start"]
    assert moved, out + err
    where = {f"127.0.0.1:{h.port}": r for r, h in edges.items()}
    for r in LATE:  # up by the deadline, home once calm: each late robot's instance
        trips = [
            (m["reason"], where.get(m["to"].removeprefix("http://"), "cloud"))
            for m in moved
            if instance(r) in m["monitors"]
        ]
        assert trips == [("deadline", "cloud"), ("calm below", r)], (r, trips)
    for m in moved:  # never to or from another robot's handler
        for name in m["monitors"]:
            robot_of = name.rsplit(".", 1)[1]
            assert robot_of in {r for r in LATE}, m
            for end in (m["from"], m["to"]):
                assert where.get(end.removeprefix("http://"), robot_of) == robot_of, m
    # every instance's verdicts, over its edge and the cloud, are edgerv check's
    assert robot.returncode == 0 and (tmp_path / "rec").exists(), (
        robot.returncode,
        robot.stderr.read() if robot.stderr else "",
    )
    for r, h in edges.items():
        trace = tmp_path / f"{r}.jsonl"
        lines = (tmp_path / "rec").read_text().splitlines()
        trace.write_text("".join(x + "\n" for x in lines if f'"{ros_namespace(r)}/speed"' in x))
        live = [v for v in live_verdicts(h, cloud) if v[0] == instance(r)]
        offline = offline_verdicts(tmp_path / f"{r}.json", trace)
        assert offline and live == offline, r
