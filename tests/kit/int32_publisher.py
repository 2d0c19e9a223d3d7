"""A robot's node publishing std_msgs/Int32 0, 1, 2, ... on a topic at a steady rate
(reliable, as a robot's default), once a subscription is matched: the load of the
verdict storm (test and bench) and of the CPU budget's test, written once."""

from __future__ import annotations

import sys

# argv: topic, rate (messages a second), count (0: until killed), seconds to wait for a
# subscription, node name. Prints "matched" (or "unmatched" once the wait is over), then,
# after the last message, "published N in SECONDS" (SECONDS: the publishing alone).
SCRIPT = r"""
import sys, time, rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Int32
topic, rate, count, wait, name = sys.argv[1:6]
rate, count, wait = float(rate), int(count), float(wait)
rclpy.init()
node = rclpy.create_node(name)
qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
pub = node.create_publisher(Int32, topic, qos)
deadline = time.monotonic() + wait
while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
    time.sleep(0.05)
print("matched" if pub.get_subscription_count() else "unmatched", flush=True)
time.sleep(0.5)  # the subscriber's other matches settle
start, i = time.monotonic(), 0
while count == 0 or i < count:
    pub.publish(Int32(data=i % 2**31))
    i += 1
    time.sleep(max(0.0, start + i / rate - time.monotonic()))
took = time.monotonic() - start
time.sleep(1.0)  # reliable: the last messages reach their subscribers before the node goes
print("published", i, "in", took, flush=True)
"""


def argv(
    topic: str, rate: float, count: int = 0, wait: float = 60.0, name: str = "load"
) -> list[str]:
    """The command of a publisher on ``topic``: ``count`` messages (0: until killed) at
    ``rate`` a second, after waiting at most ``wait`` seconds for a subscription."""
    return [sys.executable, "-c", SCRIPT, topic, str(rate), str(count), str(wait), name]


def publish_seconds(stdout: str) -> float:
    """How long the publishing took, from the publisher's last line (0: it did not say)."""
    for line in reversed(stdout.splitlines()):
        if line.startswith("published "):
            return float(line.split()[-1])
    return 0.0
