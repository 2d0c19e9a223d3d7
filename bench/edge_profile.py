"""Where the edge's CPU goes, without ROS: the case study's 200 monitors fed what the take
loop would hand them at the robot's rates (bench/edge_cost.py's publisher), in process.

Each message is serialized as the robot publishes it (rclpy's serializer), read from its
CDR bytes by the topic's reader (what the take loop does), passed through the reorder
window, ingested (Engine.ingest) and evaluated by a scheduler round after each batch;
Engine.tick runs every 50 ms of simulated time, as the scheduler does. The clock is
simulated: ``SECONDS`` of robot time run as fast as the CPU allows.

``python bench/edge_profile.py [--seconds 20] [--cprofile] [--monitors FILE] [--held]``:
the CPU seconds of each stage per second of robot time (i.e. the fraction of a core it
would take live), and with --cprofile the top functions. ``--monitors``: another set of
monitors over the same topics (``make demo``'s 450: its ``demo-output/monitors.yaml``);
``--held``: every monitor held by a handoff's sender from the start (what the edge pays
while it moves them away; run it for about 1.5 s of robot time, the buffers' capacity).
``--diagnostics``: and the /diagnostics thread's looks (:class:`Diagnostics`), a stage.
"""

from __future__ import annotations

import argparse
import cProfile
import math
import pstats
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
CASE_STUDY = ROOT / "examples" / "robot" / "case-study.yaml"


class SimulatedClock:
    def __init__(self) -> None:
        self.ns = 1_700_000_000_000_000_000

    def monotonic(self) -> float:
        return self.ns / 1e9

    def wall_ns(self) -> int:
        return self.ns


def messages(seconds: float) -> list[tuple[int, str, bytes]]:
    """(stamp ns, topic, CDR bytes) in publication order, as bench/edge_cost.py publishes."""
    from builtin_interfaces.msg import Time
    from geometry_msgs.msg import PoseStamped, TwistStamped
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import BatteryState, Image, Imu, LaserScan
    from std_msgs.msg import Bool

    def stamp(ns: int) -> Any:
        return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

    image = Image(height=120, width=160, step=160, encoding="mono8", data=bytes(160 * 120))
    out: list[tuple[int, str, bytes]] = []
    base = 1_700_000_000_000_000_000
    for k in range(int(seconds * 200)):
        t = k * 0.005
        ns = base + k * 5_000_000
        x, y = 2.0 + 2.6 * math.cos(0.25 * t), 1.5 + 2.2 * math.sin(0.25 * t)
        v = 0.45 + 0.2 * math.sin(0.7 * t)
        w = 0.25 + 0.5 * math.sin(0.3 * t) + (3.5 if k // 200 % 7 == 3 else 0.0)
        m: Any = Imu()
        m.header.stamp = stamp(ns)
        m.linear_acceleration.x = 0.4 * math.sin(3 * t)
        m.linear_acceleration.y = 0.3 * math.cos(2 * t)
        m.linear_acceleration.z = 9.81 + 0.2 * math.sin(5 * t)
        m.angular_velocity.z = w
        out.append((ns, "/imu", serialize_message(m)))
        if k % 4 == 0:
            m = Odometry()
            m.header.stamp = stamp(ns + 1000)
            m.pose.pose.position.x, m.pose.pose.position.y = x, y
            m.twist.twist.linear.x, m.twist.twist.angular.z = v, w
            out.append((ns + 1000, "/odom", serialize_message(m)))
        if k % 10 == 0:
            m = LaserScan()
            m.header.stamp = stamp(ns + 2000)
            m.ranges = [0.25 + 2.5 * abs(math.sin(i * 0.0175 + 0.25 * t)) for i in range(360)]
            out.append((ns + 2000, "/scan", serialize_message(m)))
        if k % 25 == 0:
            image.header.stamp = stamp(ns + 3000)
            out.append((ns + 3000, "/camera/image", serialize_message(image)))
            m = TwistStamped()
            m.header.stamp = stamp(ns + 4000)
            m.twist.linear.x, m.twist.angular.z = v, w
            out.append((ns + 4000, "/cmd_vel", serialize_message(m)))
        if k % 200 == 0:
            m = BatteryState()
            m.header.stamp = stamp(ns + 5000)
            m.percentage = 0.9 - 0.001 * t
            out.append((ns + 5000, "/battery", serialize_message(m)))
            out.append((ns + 6000, "/bumper", serialize_message(Bool(data=False))))
        if k == 400:
            m = PoseStamped()
            m.header.stamp = stamp(ns + 7000)
            m.pose.position.x, m.pose.position.y = 0.0, 3.0
            out.append((ns + 7000, "/goal", serialize_message(m)))
    return out


class Diagnostics:
    """The diagnostics thread's looks (edgerv.handler.ros.diagnostics.Diagnostics._loop)
    on the simulated clock, without ROS: woken by a violation (Health.write, a verdict
    sink) or at the instant its Pacer asks, each a Health.due and the array's CDR bytes
    (what it publishes). The CPU pacing is the Pacer's; the Breather's sleeps are not
    taken (they cost no CPU)."""

    def __init__(self, engine: Any, clock: SimulatedClock) -> None:
        from edgerv.handler.health import Health, Pacer

        self.engine, self.clock = engine, clock
        self.health = Health("edge", clock=clock)
        engine.sinks.append(self.health)
        self.pacer = Pacer(self.health.config.period, start=clock.monotonic())
        self.next_look = clock.monotonic()
        self.looks = self.updates = self.published = 0

    def due(self) -> bool:
        return self.health.changed.is_set() or self.clock.monotonic() >= self.next_look

    def read(self, fingerprint: object, names: Any = None) -> Any:
        from edgerv.handler.health import read_engine

        some = {} if names is None else {"names": names}  # (the code before took none)
        return read_engine(self.engine, fingerprint=fingerprint, **some)

    def look(self) -> None:
        from edgerv.handler import health as health_module
        from edgerv.handler.ros.cdr_out import encode_diagnostic_array

        health, pacer, now = self.health, self.pacer, self.clock.monotonic()
        if now < pacer.not_before:  # the CPU budget comes first, a violation or not
            self.next_look = pacer.not_before
            return
        health.changed.clear()
        started = time.thread_time()
        update = pacer.update_due(now)
        counts = getattr(health_module, "alarm_counts", None)  # (the code before had none)
        alarms = None if counts is None else counts(self.engine, health.stale_topics())
        statuses = health.due(self.read, None, now, update, *(() if counts is None else (alarms,)))
        if statuses is not None:
            encode_diagnostic_array(statuses, self.clock.ns)
            health.published(statuses)
            self.published += 1
        self.looks += 1
        self.updates += update
        pacer.worked(now, time.thread_time() - started, update)
        self.next_look = now + pacer.wait(now, health.next_change(now))


def run(
    seconds: float,
    profiler: cProfile.Profile | None,
    monitors: Path = CASE_STUDY,
    held: bool = False,
    diagnostics: bool = False,
) -> dict[str, float]:
    from edgerv.core.cdr import compile_reader
    from edgerv.core.documents import load_monitors
    from edgerv.handler.engine import Engine
    from edgerv.handler.reorder import ReorderWindow

    clock = SimulatedClock()
    engine = Engine("edge", flush_after=0.5, clock=clock)
    diagnosing = Diagnostics(engine, clock) if diagnostics else None
    for spec in load_monitors(monitors):
        engine.put(engine.compile(spec), active=True)
        if held:
            engine.handoffs.hold(spec.name, 1)
    routes = engine.routes()
    readers = {t: compile_reader(r.msg_type, r.fields) for t, r in routes.items()}
    msgs = messages(seconds)
    reorder: ReorderWindow[Any] = ReorderWindow(0.02)
    stages = ("read", "reorder", "ingest", "evaluate", "tick")
    spent = dict.fromkeys(stages + (("diagnostics",) if diagnostics else ()), 0.0)
    verdicts = 0
    next_tick = clock.ns
    pc = time.process_time
    if profiler is not None:
        profiler.enable()
    for ns, topic, raw in msgs:
        clock.ns = ns
        t0 = pc()
        values, stamp = readers[topic](raw)
        t1 = pc()
        batch = reorder.add([(stamp or ns, topic, values)], ns / 1e9)
        batch += reorder.due(ns / 1e9)
        t2 = pc()
        engine.ingest(batch)
        engine.drained_at = ns
        t3 = pc()
        reached = engine.evaluate()
        if diagnosing is not None:
            engine.emit(reached)
        verdicts += len(reached)
        t4 = pc()
        if ns >= next_tick:
            ticked = engine.tick()
            engine.emit(ticked)  # (the verdict sinks: the diagnostics' Health among them)
            verdicts += len(ticked)
            next_tick = ns + 50_000_000
        t5 = pc()
        if diagnosing is not None and diagnosing.due():
            diagnosing.look()
            spent["diagnostics"] += pc() - t5
        spent["read"] += t1 - t0
        spent["reorder"] += t2 - t1
        spent["ingest"] += t3 - t2
        spent["evaluate"] += t4 - t3
        spent["tick"] += t5 - t4
    if profiler is not None:
        profiler.disable()
    out = {k: 100 * v / seconds for k, v in spent.items()}  # % of a core
    out["messages"] = len(msgs)
    out["verdicts"] = verdicts
    if diagnosing is not None:
        out["looks"], out["updates"] = diagnosing.looks, diagnosing.updates
    return out


def commit_cost(monitors: Path) -> dict[str, float]:
    """ms to let go of every monitor after a handoff released them all: committed one
    at a time (each commit its own call) and as a batch (Engine.handoffs.settle, one call)."""
    from edgerv.core.documents import load_monitors
    from edgerv.handler.engine import Engine

    specs = load_monitors(monitors)
    out = {}
    for way in ("one at a time", "at once"):
        engine = Engine("edge", flush_after=0.5, clock=SimulatedClock())
        for spec in specs:
            engine.put(engine.compile(spec), active=True)
            engine.handoffs.hold(spec.name, 1)
        for spec in specs:
            assert engine.handoffs.release(spec.name, 1, cut=0, grace=0.0) is not None
        names = [spec.name for spec in specs]
        t = time.perf_counter()
        if way == "at once":
            engine.handoffs.settle("commit", 1, names)
        else:
            for name in names:
                engine.handoffs.settle("commit", 1, [name])
        out[way] = (time.perf_counter() - t) * 1e3
    return out


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--cprofile", action="store_true")
    ap.add_argument("--monitors", type=Path, default=CASE_STUDY)
    ap.add_argument("--held", action="store_true")
    ap.add_argument(
        "--diagnostics", action="store_true", help="and the /diagnostics thread's looks"
    )
    ap.add_argument("--commit", action="store_true", help="time the commit of all instead")
    args = ap.parse_args(argv)
    if args.commit:
        took = commit_cost(args.monitors)
        print("commit of all, ms: " + ", ".join(f"{k} {v:.1f}" for k, v in took.items()))
        return
    profiler = cProfile.Profile() if args.cprofile else None
    res = run(args.seconds, profiler, args.monitors, args.held, args.diagnostics)
    counts = ("messages", "verdicts", "looks", "updates")
    total = sum(v for k, v in res.items() if k not in counts)
    print(
        f"{res['messages']} messages, {res['verdicts']} verdicts in {args.seconds:g} s of robot "
        f"time; % of a core: "
        + ", ".join(f"{k} {v:.2f}" for k, v in res.items() if k not in counts)
        + f"; total {total:.2f}"
        + (f"; {res['looks']} looks, {res['updates']} updates" if args.diagnostics else "")
    )
    if profiler is not None:
        pstats.Stats(profiler, stream=sys.stdout).sort_stats("tottime").print_stats(25)


if __name__ == "__main__":
    main(sys.argv[1:])
