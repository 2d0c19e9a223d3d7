"""A verdict storm on a live handler (real rclpy): thousands of monitors, every message
violating each of them. The handler keeps taking messages (those it could not take are
counted lost), its resident memory stays within --memory-budget, the verdict log holds
every verdict reached of what was taken (each monitor's steps 1..n, n its events), and
SIGTERM ends it within its stop time whatever is queued."""

from __future__ import annotations

import signal
import subprocess
import threading
import time
from pathlib import Path

from kit import int32_publisher
from kit.ros import HandlerProcess, ros_env, wait_for

MONITORS = 2000
MESSAGES = 6000  # at 1,000 a second: 12 million verdicts reached, at most
BUDGET = 1 << 30
STOP_DEADLINE = 15.0  # the chart's grace period with --drain 0 (docs/handler.md, "Stopping")

DOC = """apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {{name: storm-{i}}}
spec:
  assertion: "always (x < 0)"
  signals:
    x: {{topic: /storm, type: std_msgs/msg/Int32, field: data}}
  bufferCapacity: 64
  sortThreshold: 1
"""


def rss(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    return 0


def test_a_verdict_storm_stays_in_budget_counts_what_it_lost_and_stops_in_time(
    tmp_path: Path, domain: int
) -> None:
    monitors = tmp_path / "storm.yaml"
    monitors.write_text("---\n".join(DOC.format(i=i) for i in range(MONITORS)))
    handler = HandlerProcess(
        tmp_path, monitors, domain, "--memory-budget", str(BUDGET), "--quiet-violations"
    )
    peak = [0]
    sampling = threading.Event()

    def sample() -> None:
        while not sampling.is_set() and handler.proc.poll() is None:
            try:
                peak[0] = max(peak[0], rss(handler.proc.pid))
            except OSError:
                return
            time.sleep(0.1)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    try:
        pub = subprocess.run(
            int32_publisher.argv("/storm", 1000, MESSAGES, wait=30, name="storm_publisher"),
            env=ros_env(domain),
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert "published" in pub.stdout, pub.stderr

        def accounted() -> bool:
            taken = handler.metric("edgerv_messages_total", topic="/storm") or 0
            lost = handler.metric("edgerv_messages_lost_total", topic="/storm") or 0
            return taken + lost >= MESSAGES

        # every message published was taken or counted lost (behaviour: within a minute)
        assert wait_for(accounted, timeout=60, interval=1.0), handler.stderr[-3000:]
        taken = handler.metric("edgerv_messages_total", topic="/storm") or 0
        lost = handler.metric("edgerv_messages_lost_total", topic="/storm") or 0
        assert taken + lost == MESSAGES
        _, text = handler.request("GET", "/metrics")
        events: dict[str, float] = {}
        dropped: dict[str, float] = {}
        for line in str(text).splitlines():
            for name, into in (
                ("edgerv_events_total", events),
                ("edgerv_events_dropped_total", dropped),
            ):
                if line.startswith(name + '{monitor="'):
                    monitor = line.split('"')[1]
                    into[monitor] = float(line.rpartition(" ")[2])
        assert len(events) == MONITORS
        for m in events:  # each message taken was its monitors' event or counted dropped
            assert events[m] + dropped.get(m, 0) == taken
        coalesced = sum(
            float(line.rpartition(" ")[2])
            for line in str(text).splitlines()
            if line.startswith("edgerv_verdicts_coalesced_total{")
        )
        # the storm: a verdict per monitor per message taken (a sink fell behind)
        assert sum(events.values()) > 100_000
        stopping = time.monotonic()
        rc = handler.stop(signal.SIGTERM, timeout=60)
        took = time.monotonic() - stopping
    finally:
        sampling.set()
        if handler.proc.poll() is None:
            handler.proc.kill()
    assert rc == 0, handler.stderr[-3000:]
    assert took < STOP_DEADLINE, f"SIGTERM took {took:.1f} s"
    assert peak[0] <= BUDGET, f"RSS peaked at {peak[0] >> 20} MiB"
    # the verdict log: every verdict reached of what each monitor took, in order, none twice
    steps: dict[str, list[int]] = {}
    for v in handler.verdicts():
        assert v["verdict"] == "violated"
        steps.setdefault(v["monitor"], []).append(v["step"])
    not_evaluated = "not evaluated within the stop time" in handler.stderr
    for m, n in events.items():
        got = steps.get(m, [])
        assert got == list(range(1, len(got) + 1))
        if not not_evaluated:
            assert len(got) == n, (m, len(got), n)
    print(
        f"storm: {MONITORS} monitors, {MESSAGES} messages, taken {taken:.0f}, lost {lost:.0f}, "
        f"events {sum(events.values()):.0f}, dropped {sum(dropped.values()):.0f}, "
        f"logged {sum(map(len, steps.values()))}, coalesced {coalesced:.0f}, "
        f"peak RSS {peak[0] >> 20} MiB, stop {took:.1f} s"
    )
