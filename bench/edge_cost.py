"""The edge's cost (issue 35): the case study's 200 monitors at a robot's rates, beside a
bare rclpy receiver of the same topics, on one core each, from one publisher on the other.

One publisher process (pinned to core PUB_CORE) publishes the case study's topics at the
simulated robot's rates (examples/robot/robot.py): /imu 200 Hz, /odom 50 Hz, /scan 20 Hz
(360 ranges), /camera/image 8 Hz (160 x 120 mono), /cmd_vel 8 Hz, /battery and /bumper
1 Hz, and one /goal (a mission) two seconds in; reliable, as the robot's. The values move
as a robot driving loops in its room does, so the monitors step, and some are violated.

Measured, each pinned to core RX_CORE, one after the other in one run, each for SECONDS
of publishing:

* ``edgerv handler`` with examples/robot/case-study.yaml (200 monitors), default flags
  (diagnostics, typed and JSON verdicts, a verdict log);
* a bare rclpy node that subscribes to the same topics (the same types and QoS) with
  the stock executor and callbacks that do nothing: what any Python monitor node pays
  before it checks anything;
* the floor (``TAKE_ONLY``): a node that takes the same subscriptions' messages as
  bytes with a wait set, as the handler's take loop does, and reads nothing: what
  receiving alone costs in rclpy, below which no Python monitor node can go;
* the same handler with no traffic (idle), and the bare node idle;
* 10,000 idle monitors (bench/scale.py's: 100 topics, no publisher), unless --no-10k;
* each idle handler twice: SETTLE seconds after it is ready, and again LATER seconds
  after (its /diagnostics statuses change by time alone at 10 s, stale, and at 1 min:
  the second window is an idle handler's steady state, until the next step at 10 min).

CPU is the process's utime + stime from /proc/<pid>/stat (its threads, and any child it
forked) over the window, in percent of one core. The publisher records what it published
as JSON Lines; the handler's verdict log is compared with ``edgerv check`` of that
recording (verdicts with a stamp before the publisher's last message less
COMPARE_MARGIN: the live run's end, where time passes without messages until SIGTERM,
is not in the recording).

``python bench/edge_cost.py [--seconds 20] [--rounds 1] [--no-10k] [--profile DIR]
[--before DIR]``; ``--before DIR`` measures the handler of that package tree too, in turn
with this one (``git archive HEAD handler | tar -x -C DIR``: DIR/handler);
``--profile DIR`` also records each handler window with py-spy (if installed) into DIR
(sampling from the other core, --nonblocking: it costs the handler nothing measurable,
but the numbers of a profiled run are not the bench's).
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from ros_env import ros_env

ROOT = Path(__file__).resolve().parents[1]
CASE_STUDY = ROOT / "examples" / "robot" / "case-study.yaml"
THREAD_NAMES = Path(__file__).resolve().parent / "thread_names"  # (a sitecustomize)
DOMAIN = "95"
RX_CORE, PUB_CORE = "0", "1"
SETTLE = 3.0  # seconds after a receiver is ready (and matched) before the window
LATER = 75.0  # seconds after idle monitors are ready: their second window
POLL_SECONDS = 0.5  # make demo's `edgerv orchestrate --interval`: a load report twice a second
API_PORT = 19500 + os.getpid() % 400  # each handler's API (on loopback)
TOKEN = ros_env(DOMAIN)["EDGERV_TOKEN"]  # its bearer token (bench/ros_env.py's)
COMPARE_MARGIN_NS = 2_000_000_000
TICK = os.sysconf("SC_CLK_TCK")

PUBLISHER = r"""
import json, math, sys, time
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, TwistStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import BatteryState, Image, Imu, LaserScan
from std_msgs.msg import Bool

seconds, record = float(sys.argv[1]), sys.argv[2]
rclpy.init(); node = rclpy.create_node("edge_cost_robot")
DEEP = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
SHALLOW = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
pubs = {
    "/imu": node.create_publisher(Imu, "/imu", DEEP),
    "/odom": node.create_publisher(Odometry, "/odom", DEEP),
    "/scan": node.create_publisher(LaserScan, "/scan", DEEP),
    "/camera/image": node.create_publisher(Image, "/camera/image", SHALLOW),
    "/cmd_vel": node.create_publisher(TwistStamped, "/cmd_vel", DEEP),
    "/battery": node.create_publisher(BatteryState, "/battery", DEEP),
    "/bumper": node.create_publisher(Bool, "/bumper", DEEP),
    "/goal": node.create_publisher(PoseStamped, "/goal", SHALLOW),
}
wait_until = time.monotonic() + 60
while any(p.get_subscription_count() == 0 for p in pubs.values()) and time.monotonic() < wait_until:
    time.sleep(0.05)
time.sleep(1.0)

def stamp(ns):
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

out = open(record, "w")
def rec(topic, ns, msg):
    out.write(json.dumps({"topic": topic, "stamp": ns, "msg": msg}) + "\n")

image = Image(height=120, width=160, step=160, encoding="mono8", data=bytes(160 * 120))
image.header.frame_id = "camera"
counts = dict.fromkeys(pubs, 0)
print("start", time.time_ns(), flush=True)
start = time.perf_counter()
k = 0
goal_at = 400  # ticks: two seconds in
n = int(seconds * 200)
while k < n:
    ahead = start + k * 0.005 - time.perf_counter()
    if ahead > 0:
        time.sleep(ahead)
    t = k * 0.005
    # a robot driving loops in its 6 m x 5 m room, a little faster in places
    x = 2.0 + 2.6 * math.cos(0.25 * t)
    y = 1.5 + 2.2 * math.sin(0.25 * t)
    v = 0.45 + 0.2 * math.sin(0.7 * t)
    w = 0.25 + 0.5 * math.sin(0.3 * t) + (3.5 if k // 200 % 7 == 3 else 0.0)
    ns = time.time_ns()
    m = Imu(); m.header.stamp = stamp(ns); m.header.frame_id = "imu"
    ax, ay, az = 0.4 * math.sin(3 * t), 0.3 * math.cos(2 * t), 9.81 + 0.2 * math.sin(5 * t)
    m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = ax, ay, az
    m.angular_velocity.z = w
    pubs["/imu"].publish(m); counts["/imu"] += 1
    rec("/imu", ns, {"linear_acceleration": {"x": ax, "y": ay, "z": az},
                     "angular_velocity": {"z": w}})
    if k % 4 == 0:
        ns = time.time_ns()
        m = Odometry(); m.header.stamp = stamp(ns); m.header.frame_id = "odom"
        m.pose.pose.position.x, m.pose.pose.position.y = x, y
        m.twist.twist.linear.x, m.twist.twist.angular.z = v, w
        pubs["/odom"].publish(m); counts["/odom"] += 1
        rec("/odom", ns, {"pose": {"pose": {"position": {"x": x, "y": y}}},
                          "twist": {"twist": {"linear": {"x": v}, "angular": {"z": w}}}})
    if k % 10 == 0:
        ns = time.time_ns()
        m = LaserScan(); m.header.stamp = stamp(ns); m.header.frame_id = "laser"
        m.angle_min, m.angle_max, m.range_max = -math.pi, math.pi, 12.0
        m.angle_increment = 2 * math.pi / 360
        ranges = [0.25 + 2.5 * abs(math.sin(i * 0.0175 + 0.25 * t)) for i in range(360)]
        m.ranges = ranges
        pubs["/scan"].publish(m); counts["/scan"] += 1
        rec("/scan", ns, {"ranges": ranges})
    if k % 25 == 0:
        ns = time.time_ns()
        image.header.stamp = stamp(ns)
        pubs["/camera/image"].publish(image); counts["/camera/image"] += 1
        rec("/camera/image", ns, {"height": 120})
        ns = time.time_ns()
        m = TwistStamped(); m.header.stamp = stamp(ns)
        m.twist.linear.x, m.twist.angular.z = v, w
        pubs["/cmd_vel"].publish(m); counts["/cmd_vel"] += 1
        rec("/cmd_vel", ns, {"twist": {"linear": {"x": v}, "angular": {"z": w}}})
    if k % 200 == 0:
        ns = time.time_ns()
        pct = 0.9 - 0.001 * t
        m = BatteryState(); m.header.stamp = stamp(ns); m.percentage = pct
        pubs["/battery"].publish(m); counts["/battery"] += 1
        rec("/battery", ns, {"percentage": pct})
        ns = time.time_ns()
        pubs["/bumper"].publish(Bool(data=False)); counts["/bumper"] += 1
        rec("/bumper", ns, {"data": False})
    if k == goal_at:
        ns = time.time_ns()
        m = PoseStamped(); m.header.stamp = stamp(ns)
        m.pose.position.x, m.pose.position.y = 0.0, 3.0
        pubs["/goal"].publish(m); counts["/goal"] += 1
        rec("/goal", ns, {"pose": {"position": {"x": 0.0, "y": 3.0}}})
    k += 1
out.close()
print("end", time.time_ns(), json.dumps(counts), flush=True)
time.sleep(1.0)
"""

BARE = r"""
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from geometry_msgs.msg import PoseStamped, TwistStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import BatteryState, Image, Imu, LaserScan
from std_msgs.msg import Bool
rclpy.init(); node = rclpy.create_node("edge_cost_bare")
qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)  # the handler's default
for topic, cls in (("/imu", Imu), ("/odom", Odometry), ("/scan", LaserScan),
                   ("/camera/image", Image), ("/cmd_vel", TwistStamped),
                   ("/battery", BatteryState), ("/bumper", Bool), ("/goal", PoseStamped)):
    node.create_subscription(cls, topic, lambda msg: None, qos)
print("ready", flush=True)
try:
    rclpy.spin(node)
except KeyboardInterrupt:
    pass
"""

# The floor: what the handler's take loop pays before it reads anything. The same
# subscriptions, waited on with a wait set and taken as the bytes the publisher sent
# (take_message(..., raw=True)), each message then let go: no field read, no monitor.
TAKE_ONLY = r"""
import contextlib
import rclpy
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from geometry_msgs.msg import PoseStamped, TwistStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import BatteryState, Image, Imu, LaserScan
from std_msgs.msg import Bool
rclpy.init(); node = rclpy.create_node("edge_cost_take_only")
qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)  # the handler's default
subs = [(node.create_subscription(cls, topic, lambda msg: None, qos), cls)
        for topic, cls in (("/imu", Imu), ("/odom", Odometry), ("/scan", LaserScan),
                           ("/camera/image", Image), ("/cmd_vel", TwistStamped),
                           ("/battery", BatteryState), ("/bumper", Bool), ("/goal", PoseStamped))]
with contextlib.ExitStack() as stack:
    for sub, _ in subs:
        stack.enter_context(sub.handle)
    stack.enter_context(node.context.handle)
    wait_set = _rclpy.WaitSet(len(subs), 0, 0, 0, 0, 0, node.context.handle)
    print("ready", flush=True)
    try:
        while True:
            wait_set.clear_entities()
            for sub, _ in subs:
                wait_set.add_subscription(sub.handle)
            wait_set.wait(1_000_000_000)
            for sub, cls in subs:
                take = sub.handle.take_message
                while take(cls, True) is not None:
                    pass
    except KeyboardInterrupt:
        pass
"""


def env(source: Path | None = None) -> dict[str, str]:
    """The ROS environment; ``source``: a handler package tree to run instead of this one
    (``--before``: the code before a change, e.g. ``git archive HEAD handler``)."""
    out = ros_env(DOMAIN)
    paths = [str(THREAD_NAMES), out.get("PYTHONPATH")]
    if source is not None:
        paths.insert(0, str(source))
    out["PYTHONPATH"] = os.pathsep.join(filter(None, paths))
    return out


def cpu_seconds(pid: int) -> float:
    """utime + stime of ``pid`` and its live descendants (seconds)."""
    total = 0.0
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        me, parent = int(entry.name), int(fields[1])
        if me == pid or _descends(parent, pid):
            total += (int(fields[11]) + int(fields[12])) / TICK
    return total


def thread_cpu(pid: int) -> dict[str, float]:
    """CPU seconds of each thread of ``pid``, by "name/tid" (the OS's thread name: Python's
    threads are all "python", the middleware's have names of their own)."""
    out: dict[str, float] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            stat = (task / "stat").read_text()
        except OSError:
            continue
        name = stat[stat.index("(") + 1 : stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2 :].split()
        out[f"{name}/{task.name}"] = (int(fields[11]) + int(fields[12])) / TICK
    return out


def thread_split(
    before: dict[str, float], after: dict[str, float], wall: float
) -> dict[str, float]:
    """Percent of a core of each thread over a window, summed by thread name, busiest first."""
    by_name: dict[str, float] = {}
    for key, cpu in after.items():
        name = key.rsplit("/", 1)[0]
        by_name[name] = by_name.get(name, 0.0) + cpu - before.get(key, 0.0)
    return {
        k: round(100 * v / wall, 3)
        for k, v in sorted(by_name.items(), key=lambda kv: -kv[1])
        if v > 0
    }


def _descends(ppid: int, root: int) -> bool:
    seen = 0
    while ppid > 1 and seen < 32:
        if ppid == root:
            return True
        try:
            stat = Path(f"/proc/{ppid}/stat").read_text()
        except OSError:
            return False
        ppid = int(stat[stat.rindex(")") + 2 :].split()[1])
        seen += 1
    return False


def pinned(core: str, argv: list[str]) -> list[str]:
    return ["taskset", "-c", core, *argv]


class Receiver:
    """A receiving process pinned to RX_CORE, ready once its output says ``ready``."""

    def __init__(self, argv: list[str], ready: str, out: Path, source: Path | None = None) -> None:
        self.out = out
        self.handler = "handler" in argv  # stopped by SIGTERM (a bare node by SIGINT)
        with out.open("w") as sink:
            self.proc = subprocess.Popen(
                pinned(RX_CORE, argv), env=env(source), stdout=sink, stderr=subprocess.STDOUT
            )
        started = time.monotonic()
        while ready not in out.read_text():
            if self.proc.poll() is not None or time.monotonic() - started > 600:
                raise RuntimeError(f"the receiver did not start: {out.read_text()[-2000:]}")
            time.sleep(0.2)
        self.ready_at = time.monotonic()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGTERM if self.handler else signal.SIGINT)
        try:
            self.proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def handler_argv(monitors: Path, verdict_log: Path | None) -> list[str]:
    argv = [
        sys.executable,
        "-m",
        "edgerv",
        "handler",
        "--name",
        "edge",
        "--monitors",
        str(monitors),
        "--listen",
        f"127.0.0.1:{API_PORT}",
        "--log-level",
        "info",
    ]
    if verdict_log is not None:
        argv += ["--verdict-log", str(verdict_log)]
    return argv


def profile(pid: int, seconds: float, out: Path | None) -> subprocess.Popen[bytes] | None:
    spy = shutil.which("py-spy") or str(Path(sys.executable).parent / "py-spy")
    if out is None or not Path(spy).exists():
        return None
    return subprocess.Popen(
        pinned(
            PUB_CORE,
            [
                spy,
                "record",
                "--nonblocking",
                "--threads",
                "--idle",
                "--format",
                "raw",
                "--rate",
                "200",
                "--duration",
                str(int(seconds)),
                "--pid",
                str(pid),
                "--output",
                str(out),
            ],
        ),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def traffic_window(rx: Receiver, seconds: float, record: Path, spy: Path | None) -> dict[str, Any]:
    """The receiver's CPU while the publisher publishes for ``seconds``."""
    time.sleep(SETTLE)
    pub = subprocess.Popen(
        pinned(PUB_CORE, [sys.executable, "-c", PUBLISHER, str(seconds), str(record)]),
        env=env(),
        stdout=subprocess.PIPE,
        text=True,
    )
    assert pub.stdout is not None
    line = pub.stdout.readline()  # "start": matched, publishing
    if not line.startswith("start"):
        raise RuntimeError("the publisher did not start")
    cpu0, t0, th0 = cpu_seconds(rx.pid), time.monotonic(), thread_cpu(rx.pid)
    sampler = profile(rx.pid, seconds, spy)
    line = pub.stdout.readline()  # "end ..."
    cpu1, t1, th1 = cpu_seconds(rx.pid), time.monotonic(), thread_cpu(rx.pid)
    pub.wait(timeout=60)
    if sampler is not None:
        sampler.wait(timeout=120)
    _, end_ns, counts = line.split(" ", 2)
    return {
        "cpu": cpu1 - cpu0,
        "wall": t1 - t0,
        "pct": 100 * (cpu1 - cpu0) / (t1 - t0),
        "end_ns": int(end_ns),
        "threads": thread_split(th0, th1, t1 - t0),
        "counts": json.loads(counts),
    }


def idle_window(
    rx: Receiver, seconds: float, spy: Path | None, settle: float = SETTLE, poll: float = 0.0
) -> dict[str, Any]:
    """``seconds`` of ``rx`` idle, from ``settle`` seconds after it was ready; given
    ``poll``, its load report read every ``poll`` seconds meanwhile (from the other core,
    as an orchestrator polls it: ``GET /v1/load``)."""
    time.sleep(max(0.0, rx.ready_at + settle - time.monotonic()))
    cpu0, t0, th0 = cpu_seconds(rx.pid), time.monotonic(), thread_cpu(rx.pid)
    sampler = profile(rx.pid, seconds, spy)
    polls = 0
    if poll > 0:
        cores = os.sched_getaffinity(0)
        os.sched_setaffinity(0, {int(PUB_CORE)})  # (polled from the publisher's core)
        # one connection kept alive, as the orchestrator's client keeps it
        conn = http.client.HTTPConnection("127.0.0.1", API_PORT, timeout=10)
        try:
            while time.monotonic() < t0 + seconds:
                conn.request("GET", "/v1/load", headers={"Authorization": f"Bearer {TOKEN}"})
                if b'"monitors"' not in conn.getresponse().read():
                    raise RuntimeError("GET /v1/load answered no load report")
                polls += 1
                time.sleep(max(0.0, t0 + polls * poll - time.monotonic()))
        finally:
            conn.close()
            os.sched_setaffinity(0, cores)
    else:
        time.sleep(seconds)
    cpu1, t1, th1 = cpu_seconds(rx.pid), time.monotonic(), thread_cpu(rx.pid)
    if sampler is not None:
        sampler.wait(timeout=120)
    return {
        "cpu": cpu1 - cpu0,
        "wall": t1 - t0,
        "pct": 100 * (cpu1 - cpu0) / (t1 - t0),
        "threads": thread_split(th0, th1, t1 - t0),
        "polls": polls,
    }


def compare_verdicts(log: Path, record: Path, end_ns: int) -> dict[str, Any]:
    """The handler's verdicts against `edgerv check` of what was published (stamps before
    end_ns - COMPARE_MARGIN_NS)."""
    cut = end_ns - COMPARE_MARGIN_NS
    live = sorted(
        (r["monitor"], r["verdict"], r["step"], r["stamp"])
        for r in map(json.loads, log.read_text().splitlines())
        if r["stamp"] < cut
    )
    out = subprocess.run(
        [sys.executable, "-m", "edgerv", "check", str(CASE_STUDY), str(record), "--json"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    doc = json.loads(out.stdout)
    offline = sorted(
        (m["name"], v["verdict"], v["step"], v["stamp"])
        for m in doc["monitors"]
        for v in m["verdicts"]
        if v["stamp"] < cut
    )
    # /bumper has no header: its stamp live is the DDS source timestamp, in the recording
    # the publisher's clock just before publish (microseconds apart): compare without
    # stamps too
    same = live == offline
    same_steps = [x[:3] for x in live] == [x[:3] for x in offline]
    monitors = len({x[0] for x in live} | {x[0] for x in offline})
    return {
        "live": len(live),
        "offline": len(offline),
        "equal": same,
        "equal_steps": same_steps,
        "monitors": monitors,
        "differ": sorted(set(live) ^ set(offline))[:5],
    }


def run(
    seconds: float, rounds: int, ten_k: bool, spy_dir: Path | None, before: Path | None
) -> dict[str, Any]:
    """Each round: the handler (and, given ``before``, the handler of that tree) and the
    bare receiver with traffic, in turn; then each idle."""
    sides: list[tuple[str, Path | None]] = [("handler", None)]
    if before is not None:
        sides.insert(0, ("before", before))
    results: dict[str, Any] = {"bare": [], "verdicts": {}}
    with tempfile.TemporaryDirectory() as tmp_:
        tmp = Path(tmp_)
        for r in range(rounds):
            for side, source in sides:
                log, record = tmp / f"{side}-verdicts-{r}.jsonl", tmp / f"published-{r}.jsonl"
                out = tmp / f"{side}.out"
                rx = Receiver(handler_argv(CASE_STUDY, log), " ready: ", out, source)
                try:
                    spy = spy_dir / f"{side}-traffic-{r}.txt" if spy_dir else None
                    h = traffic_window(rx, seconds, record, spy)
                finally:
                    rx.stop()
                results.setdefault(side, []).append(h)
                results["verdicts"].setdefault(side, []).append(
                    compare_verdicts(log, record, h["end_ns"])
                )
            rx = Receiver([sys.executable, "-c", BARE], "ready", tmp / "bare.out")
            try:
                results["bare"].append(traffic_window(rx, seconds, tmp / "bare.jsonl", None))
            finally:
                rx.stop()
            rx = Receiver([sys.executable, "-c", TAKE_ONLY], "ready", tmp / "take-only.out")
            try:
                window = traffic_window(rx, seconds, tmp / "take-only.jsonl", None)
                results.setdefault("take_only", []).append(window)
            finally:
                rx.stop()
        for side, source in sides:
            rx = Receiver(handler_argv(CASE_STUDY, None), " ready: ", tmp / "idle.out", source)
            try:
                spy = spy_dir / f"{side}-idle.txt" if spy_dir else None
                results[f"{side}_idle"] = idle_window(rx, seconds, spy)
                spy = spy_dir / f"{side}-idle-later.txt" if spy_dir else None
                results[f"{side}_idle_later"] = idle_window(rx, seconds, spy, LATER)
                spy = spy_dir / f"{side}-idle-polled.txt" if spy_dir else None
                after = LATER + seconds  # right after the window above
                results[f"{side}_idle_polled"] = idle_window(rx, seconds, spy, after, POLL_SECONDS)
            finally:
                rx.stop()
        rx = Receiver([sys.executable, "-c", BARE], "ready", tmp / "bare.out")
        try:
            results["bare_idle"] = idle_window(rx, seconds, None)
        finally:
            rx.stop()
        if ten_k:
            sys.path.insert(0, str(Path(__file__).resolve().parent))
            from scale import monitors

            doc = tmp / "ten-k.yaml"
            doc.write_text(monitors(10_000))
            for side, source in sides:
                rx = Receiver(handler_argv(doc, None), " ready: ", tmp / "10k.out", source)
                try:
                    spy = spy_dir / f"{side}-idle-10k.txt" if spy_dir else None
                    results[f"{side}_idle_10k"] = idle_window(rx, seconds, spy)
                    # and later, the same handler: past the statuses' steps at 10 s
                    # (stale) and 1 min since they started, when an idle handler's
                    # diagnostics read its monitors anew (the next: 10 min)
                    spy = spy_dir / f"{side}-idle-10k-later.txt" if spy_dir else None
                    results[f"{side}_idle_10k_later"] = idle_window(rx, seconds, spy, LATER)
                finally:
                    rx.stop()
    return results


def cpu_model() -> str:
    try:
        for line in subprocess.run(["lscpu"], capture_output=True, text=True).stdout.splitlines():
            if line.startswith("Model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown CPU"


def rows(res: dict[str, Any], seconds: float) -> list[dict[str, str]]:
    def mean(side: str) -> tuple[float, str]:
        xs = [w["pct"] for w in res[side]]
        return sum(xs) / len(xs), ", ".join(f"{x:.2f}" for x in xs)

    bm, bs = mean("bare")
    counts = res["handler"][0]["counts"]
    has_before = "before" in res

    def verdicts(side: str) -> str:
        v = res["verdicts"][side]
        agree = all(x["equal_steps"] for x in v)
        return (
            f"live {v[0]['live']:,}, `edgerv check` of the recording {v[0]['offline']:,}: "
            + ("identical (monitor, verdict, step)" if agree else f"DIFFER: {v[0]['differ']}")
            + ("; stamps identical" if all(x["equal"] for x in v) else "")
        )

    hm, hs = mean("handler")
    detail = (
        f"{seconds:g} s a window, {len(res['bare'])} window(s) a side, in turn, each "
        f"receiver pinned to core {RX_CORE} and the publisher to core {PUB_CORE}; published "
        + ", ".join(f"{t} {n}" for t, n in counts.items())
        + "; CPU: utime+stime of /proc/<pid>/stat over the window; verdicts with a stamp "
        "before the last message's less 2 s, "
        + (f"before: {verdicts('before')}; after: " if has_before else "")
        + verdicts("handler")
    )
    measured = f"edgerv handler {hm:.2f}% of a core ({hs})"
    ratio = f"{hm / bm:.3f}x the bare receiver's CPU"
    if has_before:
        pm, ps = mean("before")
        measured = f"before: {pm:.2f}% ({ps}); after: {hm:.2f}% of a core ({hs})"
        ratio = f"before {pm / bm:.3f}x, after {hm / bm:.3f}x the bare receiver's CPU"
    fm, fs = mean("take_only")
    ratio += f"; {hm / fm:.2f}x the take-only floor's"
    out = [
        {
            "name": "the edge's cost: the case study's 200 monitors at a robot's rates "
            "(target <= 0.1x the bare receiver)",
            "detail": detail,
            "baseline": f"bare rclpy receiver (stock executor, empty callbacks) "
            f"{bm:.2f}% of a core ({bs})",
            "measured": measured,
            "ratio": ratio,
        },
        {
            "name": "the edge's cost: the floor of a receiver in rclpy (what the target "
            "0.1x the bare receiver is measured against)",
            "detail": "the same traffic, in turn with the two above, pinned alike: a node "
            "that only takes each message's bytes from the same subscriptions with a wait "
            "set (the handler's take loop: take_message raw), and reads nothing; its "
            "middleware's own receive thread included, as in every side's CPU",
            "baseline": f"bare rclpy receiver {bm:.2f}% of a core ({bs}); the target, 0.1x "
            f"of it: {bm / 10:.2f}%",
            "measured": f"take-only receiver {fm:.2f}% of a core ({fs})",
            "ratio": f"{fm / bm:.3f}x the bare receiver's CPU: the floor is "
            f"{fm / (bm / 10):.1f}x the target",
        },
    ]

    def idle_row(key: str, name: str, detail: str, baseline: str, target: float) -> None:
        """The row of the idle window ``key`` (handler_KEY, and before_KEY if measured)."""
        idle = res[f"handler_{key}"]["pct"]
        measured = f"edgerv handler idle {idle:.2f}% of a core"
        if has_before:
            before = res[f"before_{key}"]["pct"]
            measured = f"before: {before:.2f}%; after: {idle:.2f}% of a core"
        out.append(
            {
                "name": name,
                "detail": detail,
                "baseline": baseline,
                "measured": measured,
                "ratio": f"after: {idle / target:.2f}x the target",
            }
        )

    later = f"{seconds:g} s from {LATER:g} s after the handler was ready, past its statuses' "
    idle_row(
        "idle",
        "the edge's cost, idle: 200 monitors, no traffic (target <= 0.3% of a core)",
        f"{seconds:g} s, pinned to core {RX_CORE}; the same bare receiver idle in turn with it",
        f"bare rclpy receiver idle {res['bare_idle']['pct']:.2f}% of a core",
        0.3,
    )
    idle_row(
        "idle_later",
        "the edge's cost, idle: the same 200 monitors later (target <= 0.3% of a core)",
        later + f"steps at 10 s (stale) and 1 min (the next at 10 min); pinned to core {RX_CORE}",
        "target 0.3% of a core",
        0.3,
    )

    def per_report(side: str) -> float:
        """CPU seconds a load report cost ``side``'s handler: its polled window's CPU less
        its unpolled window's (scaled to the same length), over the reads."""
        polled, quiet = res[f"{side}_idle_polled"], res[f"{side}_idle_later"]
        return float(polled["cpu"] - quiet["cpu"] * polled["wall"] / quiet["wall"]) / max(
            1, polled["polls"]
        )

    polled, quiet = res["handler_idle_polled"], res["handler_idle_later"]
    measured = (
        f"idle and polled {polled['pct']:.2f}% of a core: {per_report('handler') * 1000:.2f} "
        "ms of CPU a load report"
    )
    ratio = f"the polls {(polled['pct'] - quiet['pct']):.2f}% of a core"
    if has_before:
        measured = (
            f"before: {res['before_idle_polled']['pct']:.2f}% "
            f"({per_report('before') * 1000:.2f} ms a report); after: {polled['pct']:.2f}% of "
            f"a core ({per_report('handler') * 1000:.2f} ms a report)"
        )
        ratio = f"a report costs {per_report('handler') / per_report('before'):.2f}x before's; "
        ratio += f"the polls {(polled['pct'] - quiet['pct']):.2f}% of a core"
    tick = 1000 / TICK / max(1, polled["polls"])  # ms a report, one clock tick over the reads
    out.append(
        {
            "name": "the edge's cost, idle and polled: the same 200 monitors, their load "
            f"report read every {POLL_SECONDS:g} s (make demo's edgerv orchestrate --interval)",
            "detail": f"{seconds:g} s right after the window above, {polled['polls']} "
            f"reads of GET /v1/load from core {PUB_CORE} on one kept-alive connection (as "
            "the orchestrator's client); a report's cost: the window's CPU less the idle "
            f"window's, over the reads (known to a clock tick: {tick:.2f} ms a report)",
            "baseline": f"the same handler unpolled {quiet['pct']:.2f}% of a core",
            "measured": measured,
            "ratio": ratio,
        }
    )
    if "handler_idle_10k" in res:
        idle_row(
            "idle_10k",
            "the edge's cost, idle: 10,000 monitors on 100 topics, no traffic "
            "(target <= 1% of a core)",
            f"{seconds:g} s, pinned to core {RX_CORE}, bench/scale.py's monitors",
            "target 1% of a core",
            1.0,
        )
        idle_row(
            "idle_10k_later",
            "the edge's cost, idle: the same 10,000 monitors later (target <= 1% of a core)",
            later + "steps at 10 s (stale) and 1 min, when the diagnostics read every monitor "
            f"anew (the next at 10 min); pinned to core {RX_CORE}",
            "target 1% of a core",
            1.0,
        )
    return out


def main(argv: list[str] | None = None) -> list[dict[str, str]]:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--no-10k", action="store_true")
    ap.add_argument("--profile", type=Path, default=None, metavar="DIR")
    ap.add_argument(
        "--before",
        type=Path,
        default=None,
        metavar="DIR",
        help="also measure the handler of this package tree (the code before a change)",
    )
    args = ap.parse_args(argv or [])
    if args.profile is not None:
        args.profile.mkdir(parents=True, exist_ok=True)
    res = run(args.seconds, args.rounds, not args.no_10k, args.profile, args.before)
    out = rows(res, args.seconds)
    print(json.dumps({"cpu": cpu_model(), "raw": res}, indent=1), file=sys.stderr)
    return out


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1:]), indent=1))
