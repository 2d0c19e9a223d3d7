"""Reactions (spec.onViolation): latency from a violating message to its reaction.

One handler, one monitor `always (speed < 100)` that resets after each verdict and
reacts to a violation by publishing a geometry_msgs/Twist on /cmd_vel and calling a
std_srvs/SetBool service /estop. This process publishes std_msgs/Float64 on /speed at
1,000 messages/s, one in ten violating (100 violations/s), and is the robot's side: it
subscribes to /cmd_vel, serves /estop and listens to /edgerv/verdicts. The k-th
reaction answers the k-th violating message (one violation each, in order; each side's
count is checked), so each latency is the reaction's arrival here minus the violating
message's publication here, on one clock: the DDS hop in, evaluation (one topic: the
handler's reorder window does not wait), the reaction, the DDS hop out.

Side by side in one run: the violation's verdict on /edgerv/verdicts (the baseline: what
a listener learns without reactions), the Twist and the service request.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any

from ros_env import ros_env

RATE = 1000.0
SECONDS = 10.0
EVERY = 10  # one message in EVERY violates
DOMAIN = "93"

MONITOR = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: speed-cap}
spec:
  assertion: "always (speed < 100)"
  signals:
    speed: {topic: /speed, type: std_msgs/msg/Float64, qos: {reliability: reliable}}
  onViolation:
    publish: {topic: /cmd_vel, type: geometry_msgs/msg/Twist}
    call: {service: /estop, type: std_srvs/srv/SetBool, request: {data: true}}
"""


def env() -> dict[str, str]:
    return ros_env(DOMAIN)


def percentiles(ms: list[float]) -> tuple[float, float]:
    ms = sorted(ms)
    return statistics.median(ms), ms[max(0, int(len(ms) * 0.99) - 1)]


class Robot:
    """The robot's side, in this process: publisher, /cmd_vel, /estop, verdicts."""

    def __init__(self) -> None:
        os.environ.update(env())
        import rclpy
        from geometry_msgs.msg import Twist
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Float64, String
        from std_srvs.srv import SetBool

        rclpy.init()
        self.rclpy, self.Float64 = rclpy, Float64
        self.node = rclpy.create_node("reaction_bench")
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.node.create_publisher(Float64, "/speed", qos)
        self.sent: list[int] = []  # publication of each violating message (ns)
        self.twists: list[int] = []
        self.requests: list[int] = []
        self.verdicts: list[int] = []
        self.node.create_subscription(Twist, "/cmd_vel", self._twist, qos)
        self.node.create_subscription(String, "/edgerv/verdicts", self._verdict, qos)
        self.node.create_service(SetBool, "/estop", self._estop)
        # one thread: rclpy's MultiThreadedExecutor fell behind here (its own queue grew
        # to seconds at 300 callbacks/s while the handler kept up), which a latency
        # measured in this process would have charged to the handler
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _twist(self, _msg: Any) -> None:
        self.twists.append(time.time_ns())

    def _verdict(self, msg: Any) -> None:
        if json.loads(msg.data)["verdict"] == "violated":
            self.verdicts.append(time.time_ns())

    def _estop(self, request: Any, response: Any) -> Any:
        self.requests.append(time.time_ns())
        response.success = True
        return response

    def matched(self) -> bool:
        return bool(
            self.pub.get_subscription_count() > 0
            and self.node.count_publishers("/cmd_vel") > 0
            and self.node.count_subscribers("/edgerv/verdicts") > 0
        )

    def publish(self) -> int:
        n = int(RATE * SECONDS)
        start = time.perf_counter()
        for i in range(n):
            ahead = start + i / RATE - time.perf_counter()
            if ahead > 0:
                time.sleep(ahead)
            bad = i % EVERY == EVERY - 1
            msg = self.Float64(data=150.0 if bad else 1.0)
            if bad:
                self.sent.append(time.time_ns())
            self.pub.publish(msg)
        return n

    def close(self) -> None:
        self.executor.shutdown()
        self.thread.join(timeout=10)  # (a thread still in rclpy at exit aborts the process)
        self.node.destroy_node()
        self.rclpy.try_shutdown()


def run() -> dict[str, Any]:
    robot = Robot()
    port = 19500 + os.getpid() % 400
    try:
        with tempfile.TemporaryDirectory() as tmp:
            doc = Path(tmp) / "monitor.yaml"
            doc.write_text(MONITOR)
            proc = subprocess.Popen(
                [sys.executable, "-m", "edgerv", "handler", "--name", "bench",
                 "--monitors", str(doc), "--listen", f"127.0.0.1:{port}",
                 "--log-level", "warning"],
                env=env(),
            )  # fmt: skip
            try:
                deadline = time.monotonic() + 60
                while not robot.matched():
                    if proc.poll() is not None or time.monotonic() > deadline:
                        raise RuntimeError("the handler did not start or match")
                    time.sleep(0.2)
                time.sleep(1.0)
                sent = robot.publish()
                time.sleep(3.0)
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=30) as r:
                    metrics = r.read().decode()
            finally:
                proc.terminate()
                proc.wait(timeout=60)
    finally:
        robot.close()
    violations = len(robot.sent)
    for name, got in (("verdicts", robot.verdicts), ("twists", robot.twists),
                      ("requests", robot.requests)):  # fmt: skip
        if len(got) != violations:
            raise RuntimeError(f"{violations} violations sent, {len(got)} {name} received")

    def lat(at: list[int]) -> list[float]:
        return [(b - a) / 1e6 for a, b in zip(robot.sent, at, strict=True)]

    lost = [line for line in metrics.splitlines() if line.startswith("edgerv_messages_lost_total{")]
    return {
        "sent": sent,
        "violations": violations,
        "verdict": percentiles(lat(robot.verdicts)),
        "twist": percentiles(lat(robot.twists)),
        "request": percentiles(lat(robot.requests)),
        "lost": sum(float(line.split()[-1]) for line in lost),
    }


def main() -> list[dict[str, Any]]:
    r = run()
    v, t, q = r["verdict"], r["twist"], r["request"]
    return [
        {
            "name": "reactions: a violating message to its reaction, at 1,000 msg/s",
            "detail": f"{r['sent']:,} std_msgs/Float64 messages on /speed in {SECONDS:.0f} s, "
            f"one in {EVERY} violating always (speed < 100) (reset after each): "
            f"{r['violations']:,} violations, each reacted to once (a Twist on /cmd_vel, a "
            "SetBool call on /estop; each count checked); publication to arrival in the "
            "publishing process, one clock (one topic: no reorder wait); "
            f"messages lost {r['lost']:.0f}",
            "baseline": f"the verdict on /edgerv/verdicts: p50 {v[0]:.1f} ms, p99 {v[1]:.1f} ms",
            "measured": f"the Twist: p50 {t[0]:.1f} ms, p99 {t[1]:.1f} ms; the service "
            f"request: p50 {q[0]:.1f} ms, p99 {q[1]:.1f} ms",
            "ratio": f"the Twist {t[0] - v[0]:+.1f} ms (p50), {t[1] - v[1]:+.1f} ms (p99) "
            "from the verdict",
        }
    ]


if __name__ == "__main__":
    print(json.dumps(main(), indent=1))
