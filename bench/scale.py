"""Scale: 10,000 monitors in one handler (the paper ran 200).

100 topics (std_msgs/Float64). On each topic one *probe* monitor,
`always (x < 0)`, is violated by every message, and the rest are idle
(`always (x < 1e300)`, never decided, but buffered and stepped). A paced
publisher sends 1,000 messages/s round-robin over the topics; this process
listens on /edgerv/verdicts and measures, for every probe verdict, the time
from the message's publication (its stamp) to the verdict's arrival.

Side by side in one run: a handler with only the 100 probes (baseline), then one
with 10,000 monitors. Memory per idle monitor = the difference in resident
memory divided by the 9,900 extra monitors.
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
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ros_env import ros_env

TOPICS = 100
MONITORS = 10_000
RATE = 1000.0
SECONDS = 10.0
DOMAIN = "94"
TOPIC_NAMES = ",".join(f"/s{i}" for i in range(TOPICS))

# A paced publisher of std_msgs/Float64: RATE messages/s for SECONDS round-robin over the
# topics named (comma-separated), once each has a subscriber; prints how many it sent.
PUBLISHER = r"""
import sys, time, rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64
topics, rate, seconds = sys.argv[1].split(","), float(sys.argv[2]), float(sys.argv[3])
rclpy.init(); node = rclpy.create_node("scale_publisher")
qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
pubs = [node.create_publisher(Float64, t, qos) for t in topics]
deadline = time.monotonic() + 60
while any(p.get_subscription_count() == 0 for p in pubs) and time.monotonic() < deadline:
    time.sleep(0.1)
time.sleep(1.0)
n = int(rate * seconds)
start = time.perf_counter()
for i in range(n):
    ahead = start + i / rate - time.perf_counter()
    if ahead > 0:
        time.sleep(ahead)
    pubs[i % len(pubs)].publish(Float64(data=float(i)))
time.sleep(2)
print(n, flush=True)
"""


def env() -> dict[str, str]:
    return ros_env(DOMAIN)


def monitors(total: int) -> str:
    docs = []
    per_topic = total // TOPICS
    for t in range(TOPICS):
        for k in range(per_topic):
            probe = k == 0
            docs.append(
                "apiVersion: edgerv.io/v1alpha1\nkind: Monitor\n"
                f"metadata: {{name: {'probe' if probe else 'idle'}-{t}-{k}}}\n"
                f'spec:\n  assertion: "always (x < {0 if probe else "1e300"})"\n'
                f"  signals:\n    x: {{topic: /s{t}, type: std_msgs/msg/Float64, "
                "qos: {reliability: reliable}}\n"
            )
    return "---\n".join(docs)


def resident_bytes(port: int) -> float:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=30) as resp:
        for line in resp.read().decode().splitlines():
            if line.startswith("edgerv_process_resident_memory_bytes"):
                return float(line.split()[-1])
    raise RuntimeError("no resident memory metric")


def wait_until_serving(
    proc: subprocess.Popen[Any], port: int, started: float, limit: float
) -> float:
    """Seconds from ``started`` (perf_counter) until the handler ``proc`` answers on
    ``port``; RuntimeError if it exits or ``limit`` seconds pass first."""
    while True:
        try:
            resident_bytes(port)
            return time.perf_counter() - started
        except OSError:
            if proc.poll() is not None or time.perf_counter() - started > limit:
                raise RuntimeError("the handler did not start") from None
            time.sleep(0.5)


class VerdictListener:
    """The probe monitors' verdicts on /edgerv/verdicts (in ROS domain ``domain``; a probe:
    a monitor whose name ``probe`` accepts): publish-to-arrival in ms, and who spoke."""

    def __init__(
        self,
        domain: str = DOMAIN,
        probe: Callable[[str], bool] = lambda name: name.startswith("probe"),
    ) -> None:
        import rclpy
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_msgs.msg import String

        os.environ.update(ros_env(domain))
        rclpy.init()
        self.rclpy = rclpy
        self.probe = probe
        self.node = rclpy.create_node("scale_listener")
        self.latencies: list[float] = []
        self.heard: set[str] = set()  # the probes whose verdicts came
        self.node.create_subscription(
            String,
            "/edgerv/verdicts",
            self._on,
            QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE),
        )
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _on(self, msg: Any) -> None:
        now = time.time_ns()
        verdict = json.loads(msg.data)
        if self.probe(verdict["monitor"]):
            self.latencies.append((now - verdict["stamp"]) / 1e6)
            self.heard.add(verdict["monitor"])

    def _spin(self) -> None:
        while not self.stop.is_set():
            self.rclpy.spin_once(self.node, timeout_sec=0.1)

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.node.destroy_node()
        self.rclpy.try_shutdown()


def run(total: int, listener: VerdictListener) -> dict[str, float]:
    port = 19000 + os.getpid() % 1000
    with tempfile.TemporaryDirectory() as tmp:
        doc = Path(tmp) / "monitors.yaml"
        doc.write_text(monitors(total))
        started = time.perf_counter()
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "edgerv",
                "handler",
                "--name",
                "scale",
                "--monitors",
                str(doc),
                "--listen",
                f"127.0.0.1:{port}",
                "--log-level",
                "warning",
            ],
            env=env(),
        )
        try:
            load_seconds = wait_until_serving(proc, port, started, 600)
            time.sleep(2)
            rss = resident_bytes(port)
            listener.latencies.clear()
            pub = subprocess.run(
                [sys.executable, "-c", PUBLISHER, TOPIC_NAMES, str(RATE), str(SECONDS)],
                env=env(),
                capture_output=True,
                text=True,
                timeout=300,
            )
            sent = int(pub.stdout.split()[0])
            time.sleep(1)
            lat = sorted(listener.latencies)
        finally:
            proc.terminate()
            proc.wait(timeout=60)
    return {
        "rss": rss,
        "load": load_seconds,
        "sent": sent,
        "verdicts": len(lat),
        "p50": statistics.median(lat) if lat else float("nan"),
        "p99": lat[int(len(lat) * 0.99) - 1] if lat else float("nan"),
    }


def main() -> list[dict[str, Any]]:
    listener = VerdictListener()
    try:
        base = run(TOPICS, listener)
        full = run(MONITORS, listener)
    finally:
        listener.close()
    per_monitor = (full["rss"] - base["rss"]) / (MONITORS - TOPICS)
    return [
        {
            "name": "scale: memory per idle monitor",
            "detail": f"{MONITORS:,} monitors on {TOPICS} topics; loaded in {full['load']:.0f} s "
            f"(100 monitors: {base['load']:.1f} s)",
            "baseline": f"{TOPICS} monitors: {base['rss'] / 2**20:,.0f} MiB resident",
            "measured": f"{MONITORS:,} monitors: {full['rss'] / 2**20:,.0f} MiB resident",
            "ratio": f"{per_monitor / 1024:.1f} KiB per idle monitor",
        },
        {
            "name": "scale: publish-to-verdict latency at 1,000 msg/s",
            "detail": f"{full['sent']:,} messages, each offered to {MONITORS // TOPICS} monitors; "
            f"verdicts received {full['verdicts']:,} (baseline {base['verdicts']:,})",
            "baseline": f"{TOPICS} monitors: p50 {base['p50']:.1f} ms, p99 {base['p99']:.1f} ms",
            "measured": f"{MONITORS:,} monitors: p50 {full['p50']:.1f} ms, "
            f"p99 {full['p99']:.1f} ms",
            "ratio": f"p99 {full['p99'] / base['p99']:.1f}x the baseline's",
        },
    ]


if __name__ == "__main__":
    print(json.dumps(main(), indent=1))
