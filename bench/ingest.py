"""Ingestion: the stock rclpy executor against the edgerv handler, on the same publisher.

A paced publisher process sends std_msgs/Float64 messages (reliable, keep last
1000) for SECONDS a trial, either to a stock-executor subscriber (a Python
callback per message that reads msg.data) or to a real `edgerv handler` running
one monitor on the topic; every trial starts a fresh receiver. Each receiver's
result is the highest rate at which every message arrived, found by search, and
its CPU time per message there. The publisher and the receiver share this
machine's two cores.

The search, per side:

* Growth: from a low start (STOCK_START, HANDLER_START), the rate grows by
  GROWTH (x1.5) until a rate loses messages.
* Bisection: between the last lossless and the first lossy rate, at their
  geometric mean, until the two are within RESOLUTION (6 %, so ~5 %) of each
  other. The result is the last lossless rate.
* Repetition, best of 2: a rate counts as lossy only when it loses messages in 2
  of 2 tries; a first try that loses nothing decides at once, so only lossy (or
  publisher-limited) first tries cost a second. A loss can come from the setup
  rather than the receiver (a burst of load elsewhere on two shared cores stalls
  the receiver), while a clean trial shows directly that the receiver took every
  message at that rate; one burst of load thus cannot lower a result. Both sides
  follow the same rule, so the bias (slightly towards the best case) cancels in
  the ratio.
* The publisher's limit: the publisher prints the rate it achieved. A trial
  whose publisher fell below REACHED (97 %) of the rate tested the setup, not
  the receiver. If no try of a rate reached it and one lost nothing, the search
  ends there and the result is reported as "≥ the achieved rate: the
  publisher's own limit", never as the receiver's rate. Reported rates are the
  rates the publisher achieved (at most the rate asked), not the rates asked.
* Budget: a side starts no new rate after MAX_TRIALS trials (a second try of a
  started rate still runs), and a search stopped there while still growing is a
  bound ("≥") too. The two searches interleave trial by trial, so load elsewhere
  hits both alike. A trial takes SECONDS plus ~4.5 s (stock) or ~6.5 s (handler,
  whose start-up is slower) of process start-up, discovery and draining, so
  ~8.5 s and ~10.5 s at 4 s. A search needs 6-12 trials (4-5 growing, 1-2 for
  the first lossy rate, 3-6 bisecting), ~3 minutes for both; the cap (13 + 1 a
  side, which fits a whole search from the starts above) bounds the module at
  about 4.5 minutes.

Received means: the stock callback's count; for the handler, the events offered
to the monitor less any its buffer dropped. CPU is the receiving process's CPU
time over the trial (idle time around the burst included) divided by that count.
EDGERV_BENCH_INGEST_SECONDS and EDGERV_BENCH_INGEST_TRIALS override SECONDS and
MAX_TRIALS (for a quick smoke run).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ros_env import ros_env

SECONDS = float(os.environ.get("EDGERV_BENCH_INGEST_SECONDS", "4"))
MAX_TRIALS = int(os.environ.get("EDGERV_BENCH_INGEST_TRIALS", "13"))  # a side
STOCK_START = 3000.0
HANDLER_START = 20000.0
GROWTH = 1.5
RESOLUTION = 1.06  # bisect until the first lossy rate is within 6 % of the last lossless
TRIES = 2  # best of 2: a rate is lossy only if every one of its tries loses messages
REACHED = 0.97  # the publisher reached a rate when it achieved at least 97 % of it
DOMAIN = "93"
ROOT = Path(__file__).resolve().parents[1]

PUBLISHER = r"""
import sys, time, rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64
n, rate = int(sys.argv[1]), float(sys.argv[2])
rclpy.init(); node = rclpy.create_node("bench_publisher")
qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
pub = node.create_publisher(Float64, "/bench", qos)
deadline = time.monotonic() + 20
while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
    time.sleep(0.05)
time.sleep(1.0)
raws = [serialize_message(Float64(data=float(i))) for i in range(1000)]
start = time.perf_counter()
for i in range(n):
    ahead = start + i / rate - time.perf_counter()  # paced: message i leaves at i / rate
    if ahead > 0.001:
        time.sleep(ahead)
    pub.publish(raws[i % 1000])
print(n / (time.perf_counter() - start), flush=True)
time.sleep(2)
"""

STOCK = r"""
import sys, time, rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64
rclpy.init(); node = rclpy.create_node("bench_stock")
state = {"n": 0, "last": None, "sum": 0.0}
def callback(msg):
    state["last"] = time.perf_counter()
    state["n"] += 1
    state["sum"] += msg.data
qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
node.create_subscription(Float64, "/bench", callback, qos)
print("ready", flush=True)
cpu0, began = time.process_time(), time.perf_counter()
while (  # until 2 s after the last message; 60 s without any: the publisher never came
    time.perf_counter() - began < 60 if state["last"] is None
    else time.perf_counter() - state["last"] < 2
):
    rclpy.spin_once(node, timeout_sec=0.1)
print(state["n"], time.process_time() - cpu0, flush=True)
"""

MONITOR = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: bench}
spec:
  assertion: "always (x < 1e300)"
  signals:
    x: {topic: /bench, type: std_msgs/msg/Float64, qos: {reliability: reliable, depth: 1000}}
"""


def env() -> dict[str, str]:
    return ros_env(DOMAIN)


def publish(n: int, rate: float) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-c", PUBLISHER, str(n), str(rate)],
        env=env(),
        stdout=subprocess.PIPE,
        text=True,
    )


def achieved(pub: subprocess.Popen[str]) -> float:
    """The rate the publisher reports it reached (it prints it when done)."""
    return float(pub.communicate(timeout=300)[0].split()[-1])


@dataclass
class Trial:
    rate: float  # the rate asked of the publisher
    sent: int
    received: float
    cpu: float  # the receiver's CPU seconds
    achieved: float  # the rate the publisher reached

    @property
    def lossless(self) -> bool:
        return self.received >= self.sent

    @property
    def reached(self) -> bool:
        return self.achieved >= REACHED * self.rate

    @property
    def offered(self) -> float:
        return min(self.rate, self.achieved)

    @property
    def cpu_per_msg(self) -> float:
        return self.cpu / self.received if self.received else float("nan")

    def received_pct(self) -> str:
        # a loss never rounds up to 100 %
        text = "100%" if self.lossless else f"{min(99.9, 100 * self.received / self.sent):.1f}%"
        if not self.reached:
            text += f" (pub {k(self.achieved)})"
        return text


def k(rate: float) -> str:
    return f"{rate / 1000:.3g}k" if rate < 999500 else f"{rate / 1e6:.3g}M"


def stock_run(rate: float) -> Trial:
    """One paced run into a fresh stock-executor subscriber."""
    n = int(rate * SECONDS)
    sub = subprocess.Popen(
        [sys.executable, "-c", STOCK], env=env(), stdout=subprocess.PIPE, text=True
    )
    assert sub.stdout is not None
    sub.stdout.readline()
    reached = achieved(publish(n, rate))
    received, cpu = (float(x) for x in sub.communicate(timeout=300)[0].split())
    return Trial(rate, n, received, cpu, reached)


def metrics(port: int) -> dict[str, float]:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10) as resp:
        text = resp.read().decode()
    out = {}
    for line in text.splitlines():
        if line.startswith(
            (
                "edgerv_events_total",
                "edgerv_events_dropped_total",
                "edgerv_process_cpu_seconds_total",
            )
        ):
            key, _, value = line.rpartition(" ")
            out[key.split("{")[0]] = float(value)
    return out


class HandlerProcess:
    def __init__(self, tmp: str) -> None:
        self.port = 18000 + os.getpid() % 1000
        doc = Path(tmp) / "bench.yaml"
        doc.write_text(MONITOR)
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "edgerv",
                "handler",
                "--name",
                "bench",
                "--monitors",
                str(doc),
                "--listen",
                f"127.0.0.1:{self.port}",
                "--log-level",
                "warning",
            ],
            env=env(),
        )
        deadline = time.monotonic() + 30
        while True:
            try:
                metrics(self.port)
                return
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)

    def run(self, rate: float) -> Trial:
        n = int(rate * SECONDS)
        before = metrics(self.port)
        reached = achieved(publish(n, rate))
        time.sleep(1.0)
        after = metrics(self.port)

        def delta(key: str) -> float:
            return after.get(key, 0.0) - before.get(key, 0.0)

        received = delta("edgerv_events_total") - delta("edgerv_events_dropped_total")
        return Trial(rate, n, received, delta("edgerv_process_cpu_seconds_total"), reached)

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(timeout=30)


def handler_run(tmp: str, rate: float) -> Trial:
    """One paced run into a fresh handler."""
    handler = HandlerProcess(tmp)
    try:
        return handler.run(rate)
    finally:
        handler.stop()


class Search:
    """One side's search for its highest lossless rate (see the module's docstring)."""

    def __init__(self, start: float) -> None:
        self.start = start
        self.trials: dict[float, list[Trial]] = {}  # rate -> its tries, in search order
        self.lo: Trial | None = None  # a lossless try at the highest lossless rate
        self.hi: float | None = None  # the lowest lossy rate
        self.limit: Trial | None = None  # a lossless try the publisher could not pace
        self.pending: float | None = None  # a rate whose tries are not done
        self.count = 0
        self.end = ""  # "resolved", "publisher" or "cap" once the search is over

    def next_rate(self) -> float | None:
        if self.pending is not None:
            return self.pending
        if self.end:
            return None
        if self.lo is not None and self.hi is not None and self.hi / self.lo.rate <= RESOLUTION:
            self.end = "resolved"
            return None
        if self.count >= MAX_TRIALS:
            self.end = "cap"
            return None
        if self.lo is None:
            rate = self.start if self.hi is None else self.hi / GROWTH
        elif self.hi is None:
            rate = self.lo.rate * GROWTH
        else:
            rate = math.sqrt(self.lo.rate * self.hi)
        self.pending = float(f"{rate:.3g}")
        return self.pending

    def record(self, trial: Trial) -> None:
        self.count += 1
        tries = self.trials.setdefault(trial.rate, [])
        tries.append(trial)
        clean = [t for t in tries if t.lossless and t.reached]
        if clean:
            self.lo, self.pending = clean[0], None
            return
        if len(tries) < TRIES:
            return  # lossy or short once: try the rate again
        self.pending = None
        short_clean = [t for t in tries if t.lossless]  # lossless, but the publisher was slow
        if short_clean and not any(t.reached for t in tries):
            self.limit, self.end = max(short_clean, key=lambda t: t.achieved), "publisher"
        else:
            self.hi = trial.rate

    def best(self) -> Trial | None:
        if self.limit is not None and (self.lo is None or self.limit.offered > self.lo.offered):
            return self.limit
        return self.lo

    def bound(self) -> bool:
        """True when the result is only a lower bound on the receiver's rate."""
        return self.end == "publisher" or (self.end == "cap" and self.hi is None)

    def rate_text(self) -> str:
        best = self.best()
        if best is None:
            return f"no lossless rate down to {self.hi or 0:,.0f} msg/s"
        if self.end == "publisher":
            return f"≥ {best.offered:,.0f} msg/s (the publisher's own limit)"
        if self.bound():
            return f"≥ {best.offered:,.0f} msg/s (no loss yet; trial cap)"
        return f"{best.offered:,.0f} msg/s (loses at {self.hi:,.0f})"

    def trials_text(self) -> str:
        return " ".join(
            f"{k(rate)} " + "/".join(t.received_pct() for t in tries)
            for rate, tries in self.trials.items()
        )


def main() -> list[dict[str, Any]]:
    stock, handler = Search(STOCK_START), Search(HANDLER_START)
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        while True:
            ran = False
            for name, search, run in (
                ("stock", stock, stock_run),
                ("handler", handler, lambda r: handler_run(tmp, r)),
            ):
                rate = search.next_rate()
                if rate is None:
                    continue
                trial = run(rate)
                search.record(trial)
                ran = True
                print(
                    f"  ingest {name} {k(rate)}: {trial.received_pct()} "
                    f"({time.monotonic() - t0:.0f} s)",
                    file=sys.stderr,
                    flush=True,
                )
            if not ran:
                break
    took = time.monotonic() - t0
    s, h = stock.best(), handler.best()
    if s is not None and h is not None and not (stock.bound() and handler.bound()):
        mark = "≥ " if handler.bound() else "≤ " if stock.bound() else ""
        rates = f"{mark}{h.offered / s.offered:.1f}x"
        cpu = f"{s.cpu_per_msg / h.cpu_per_msg:.1f}x less CPU"
    else:
        rates = cpu = "n/a"
    s_cpu = f"{s.cpu_per_msg * 1e6:,.0f} us" if s else "n/a"
    h_cpu = f"{h.cpu_per_msg * 1e6:,.0f} us" if h else "n/a"
    return [
        {
            "name": "ingestion without loss (target >= 8x the stock executor)",
            "detail": f"paced std_msgs/Float64 publisher, reliable, keep last 1000, "
            f"{SECONDS:g} s a trial; each side's highest lossless rate by search: "
            f"x{GROWTH:g} from {k(STOCK_START)} (stock) / {k(HANDLER_START)} (handler) "
            f"until a loss, then bisection to ~5 %; a rate is lossy only if 2 of 2 "
            f"tries lose messages; a rate the publisher cannot reach ends the search "
            f"(≥); trials (rate asked, received): stock {stock.trials_text()}; "
            f"handler {handler.trials_text()}; {took:.0f} s",
            "baseline": f"stock executor {stock.rate_text()}, {s_cpu} CPU a message",
            "measured": f"handler {handler.rate_text()}, {h_cpu} CPU a message",
            "ratio": f"{rates} ({cpu} a message)",
        },
        {
            "name": "ingestion cost per message at the highest lossless rate",
            "detail": "CPU time of the receiving process per message, in the trial at "
            "each side's highest lossless rate (the rates above)",
            "baseline": f"stock executor {s_cpu}" + (f" at {s.offered:,.0f} msg/s" if s else ""),
            "measured": f"handler {h_cpu}" + (f" at {h.offered:,.0f} msg/s" if h else ""),
            "ratio": cpu,
        },
    ]


if __name__ == "__main__":
    print(json.dumps(main(), indent=1, ensure_ascii=False))
