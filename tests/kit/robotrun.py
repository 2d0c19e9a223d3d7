"""A robot's run for the tests of the handler as installed on a robot
(test_docker_run.py, test_systemd_unit.py): a real rclpy node that publishes a random run
on the three topics of kit.odom_run's monitors and records it for ``edgerv check``, and
the handler's API called over TLS as a client on another machine would."""

from __future__ import annotations

import http.client
import json
import re
import socket
import ssl
import subprocess
import sys
from pathlib import Path

from kit.pki import NAME

# A robot's node: publishes a random run on three topics, as any ROS 2 node would (default
# transports, reliable), once the handler's subscriptions are matched, and writes what it
# published as a JSON Lines trace (stamps: the odometry's header stamp, the Bools' publication
# instant) for `edgerv check`.
ROBOT = r"""
import json, random, sys, time, rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Bool
from nav_msgs.msg import Odometry
trace, n, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
rclpy.init()
node = rclpy.create_node("robot")
qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
pubs = {"/running": node.create_publisher(Bool, "/running", qos),
        "/odom": node.create_publisher(Odometry, "/odom", qos),
        "/stop": node.create_publisher(Bool, "/stop", qos)}
deadline = time.monotonic() + 30
while any(p.get_subscription_count() == 0 for p in pubs.values()) and time.monotonic() < deadline:
    time.sleep(0.05)
if any(p.get_subscription_count() == 0 for p in pubs.values()):
    sys.exit("the handler's subscriptions were not matched within 30 s")
time.sleep(0.5)
rng, lines, counts = random.Random(seed), [], {t: 0 for t in pubs}
for _ in range(n):
    topic = rng.choice(["/running", "/odom", "/odom", "/stop"])
    stamp = time.time_ns()
    if topic == "/odom":
        x = rng.choice([20.0, 60.0, 95.0, 120.0])
        msg = Odometry()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
        msg.twist.twist.linear.x = x
        fields = {"twist": {"twist": {"linear": {"x": x}}}}
    else:
        value = rng.random() < (0.8 if topic == "/running" else 0.15)
        msg, fields = Bool(data=value), {"data": value}
    pubs[topic].publish(msg)
    counts[topic] += 1
    lines.append(json.dumps({"topic": topic, "stamp": stamp, "msg": fields}))
    time.sleep(0.005)
with open(trace, "w") as f:
    f.write("\n".join(lines) + "\n")
print(json.dumps(counts), flush=True)
time.sleep(2)  # reliable: the writers stay until the handler has acknowledged
"""


def publish_run(trace: Path, env: dict[str, str], n: int = 300, seed: int = 3) -> dict[str, int]:
    """Publish a run of ``n`` messages as a robot's node (``env``: its ROS network) once
    the handler's subscriptions are matched; the run is written to ``trace``; return the
    number of messages published on each topic."""
    done = subprocess.run(
        [sys.executable, "-c", ROBOT, str(trace), str(n), str(seed)],
        env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def log_verdicts(lines: str) -> list[tuple[str, str, int]]:
    """(monitor, verdict, step) of a verdict log's lines, sorted."""
    return sorted(
        (v["monitor"], v["verdict"], v["step"]) for v in map(json.loads, lines.splitlines())
    )


def https(port: int, path: str, token: str | None, ca: Path) -> tuple[int, str]:
    """A GET of the handler's API as a client on another machine makes it: over TLS, the
    handler's certificate verified against the CA and the name it carries."""
    context = ssl.create_default_context(cafile=str(ca))
    conn = http.client.HTTPSConnection(NAME, port, context=context, timeout=10)
    conn.sock = context.wrap_socket(
        socket.create_connection(("127.0.0.1", port), timeout=10), server_hostname=NAME
    )
    try:
        conn.request("GET", path, headers={"Authorization": f"Bearer {token}"} if token else {})
        resp = conn.getresponse()
        return resp.status, resp.read().decode()
    finally:
        conn.close()


def messages_taken(port: int, ca: Path) -> dict[str, float]:
    _, text = https(port, "/metrics", None, ca)
    taken = {}
    for line in text.splitlines():
        found = re.fullmatch(r'edgerv_messages_total\{topic="([^"]+)"\} (\S+)', line)
        if found:
            taken[found.group(1)] = float(found.group(2))
    return taken
