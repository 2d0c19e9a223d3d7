"""The verdict storm (issue 38): 5,000 monitors whose every message violates, 1,000
msg/s for 10 s, on one live handler (--memory-budget 2GiB, --quiet-violations); its
peak resident memory, verdicts reached and logged a second, what it coalesced, took,
lost and dropped, and how long SIGTERM took. Prints one result row (JSON)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

from ros_env import ros_env

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from kit import int32_publisher

MONITORS = int(os.environ.get("STORM_MONITORS", 5000))
SECONDS = 10
RATE = 1000
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


def metrics(port: int) -> dict[str, float]:
    req = urllib.request.Request(f"http://127.0.0.1:{port}/metrics")
    text = urllib.request.urlopen(req, timeout=30).read().decode()
    out: dict[str, float] = {}
    for line in text.splitlines():
        if line.startswith("#"):
            continue
        key, _, value = line.rpartition(" ")
        name = key.split("{")[0]
        out[name] = out.get(name, 0.0) + float(value)
    return out


def main() -> None:
    tmp = Path(tempfile.mkdtemp(prefix="edgerv-storm-"))
    monitors, log = tmp / "storm.yaml", tmp / "verdicts.jsonl"
    monitors.write_text("---\n".join(DOC.format(i=i) for i in range(MONITORS)))
    env = ros_env("77")
    port = 18470
    handler = subprocess.Popen(
        [sys.executable, "-m", "edgerv", "handler", "--name", "storm", "--monitors",
         str(monitors), "--listen", f"127.0.0.1:{port}", "--verdict-log", str(log),
         "--memory-budget", "2GiB", "--quiet-violations"],
        env=env, stdout=subprocess.DEVNULL, stderr=(tmp / "stderr.log").open("w"),
    )  # fmt: skip
    while " ready: " not in (tmp / "stderr.log").read_text():
        assert handler.poll() is None, (tmp / "stderr.log").read_text()
        time.sleep(0.2)
    peak = [0]
    done = threading.Event()

    def sample() -> None:
        while not done.is_set() and handler.poll() is None:
            peak[0] = max(peak[0], rss(handler.pid))
            time.sleep(0.1)

    threading.Thread(target=sample, daemon=True).start()
    started = time.monotonic()
    pub = subprocess.run(
        int32_publisher.argv("/storm", RATE, RATE * SECONDS, wait=3600, name="storm_publisher"),
        env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    time.sleep(2.0)  # the handler catches up with what it took
    m = metrics(port)
    elapsed = time.monotonic() - started
    stopping = time.monotonic()
    handler.send_signal(signal.SIGTERM)
    rc = handler.wait(timeout=120)
    stop = time.monotonic() - stopping
    done.set()
    logged = sum(1 for _ in log.open())
    print(
        json.dumps(
            {
                "monitors": MONITORS,
                "published": RATE * SECONDS,
                "publish_seconds": int32_publisher.publish_seconds(pub.stdout),
                "taken": m.get("edgerv_messages_total", 0),
                "lost": m.get("edgerv_messages_lost_total", 0),
                "verdicts_reached": m.get("edgerv_verdicts_total", 0),
                "verdicts_per_second": m.get("edgerv_verdicts_total", 0) / elapsed,
                "events_dropped": m.get("edgerv_events_dropped_total", 0),
                "coalesced": m.get("edgerv_verdicts_coalesced_total", 0),
                "logged": logged,
                "peak_rss_mib": peak[0] >> 20,
                "stop_seconds": round(stop, 2),
                "exit": rc,
            }
        )
    )


if __name__ == "__main__":
    main()
