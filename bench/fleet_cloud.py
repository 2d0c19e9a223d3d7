"""A fleet's cloud handler (issue 36): one handler holding 100 robots' instances of the
same 200 Monitors, each robot's graph a ROS namespace of its own.

Each Monitor's instance for a robot is made as the operator makes it
(:func:`edgerv.core.robots.instance_spec`, :func:`~edgerv.core.robots.instance_name`, the
robot's label): its topics in the robot's namespace (``/speed`` becomes ``/amr_7/speed``).
Of a robot's 200, one *probe* instance, ``always (speed < 0)``, is violated by every
message; the others, ``always (speed < 1e300)``, are stepped by every message and never
decided. The handler runs every instance (the cloud has all of them: in a fleet the
operator defines each robot's instances there and activates those moved up; here all
are, the worst case). A paced publisher sends 1,000 messages/s round-robin over the
robots' /speed topics (each robot 1,000 / robots messages/s); this process listens on
/edgerv/verdicts and measures, for every probe verdict, the time from the message's
stamp to the verdict's arrival.

Side by side in one run, the same traffic: the handler holding each robot's probe alone
(baseline: 100 instances), then every robot's 200 (20,000). Memory per instance = the
difference in resident memory divided by the extra instances.

``python bench/fleet_cloud.py [--robots 100]``
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

import yaml

from edgerv.core.documents import API_VERSION, KIND
from edgerv.core.robots import ROBOT_LABEL, in_namespace, instance_name, instance_spec
from ros_env import ros_env
from scale import PUBLISHER, VerdictListener, resident_bytes, wait_until_serving

ROBOTS = 100
MONITORS = 200  # a robot's, the paper's count
RATE = 1000.0
SECONDS = 10.0
DOMAIN = "93"
NAMESPACE = "fleet"  # the Monitors' Kubernetes namespace: instance NAMESPACE.NAME.ROBOT


def robot(i: int) -> str:
    return f"amr-{i}"


def base_specs() -> list[tuple[str, dict[str, Any]]]:
    """The 200 Monitors every robot runs an instance of: (name, spec)."""
    out = []
    for k in range(MONITORS):
        probe = k == 0
        out.append(
            (
                "probe" if probe else f"idle-{k}",
                {
                    "assertion": f"always (speed < {0 if probe else '1e300'})",
                    "signals": {
                        "speed": {
                            "topic": "/speed",
                            "type": "std_msgs/msg/Float64",
                            "qos": {"reliability": "reliable"},
                        }
                    },
                },
            )
        )
    return out


def instances(robot_name: str, monitors: int = MONITORS) -> str:
    """A robot's instances of the first ``monitors`` Monitors (the probe first), as the
    operator gives them to a handler."""
    docs = []
    for name, spec in base_specs()[:monitors]:
        docs.append(
            {
                "apiVersion": API_VERSION,
                "kind": KIND,
                "metadata": {
                    "name": instance_name(f"{NAMESPACE}.{name}", robot_name),
                    "labels": {ROBOT_LABEL: robot_name},
                },
                "spec": instance_spec(spec, robot_name),
            }
        )
    return yaml.safe_dump_all(docs, sort_keys=False)


def running(port: int) -> int:
    """How many monitors run on the handler (its /metrics)."""
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=60) as resp:
        lines = resp.read().decode().splitlines()
    return sum(1 for x in lines if x.startswith("edgerv_monitor_active{") and x.endswith(" 1.0"))


def run(robots: int, monitors: int, listener: VerdictListener) -> dict[str, Any]:
    """The handler holding ``monitors`` instances of each of ``robots`` robots."""
    port = 19400 + os.getpid() % 500
    topics = [in_namespace("/speed", robot(i)) for i in range(robots)]
    total = robots * monitors
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(robots):  # a file a robot (a Monitor file holds at most 4 MiB)
            (Path(tmp) / f"{robot(i)}.yaml").write_text(instances(robot(i), monitors))
        started = time.perf_counter()
        proc = subprocess.Popen(
            [sys.executable, "-m", "edgerv", "handler", "--name", "cloud", "--monitors",
             tmp, "--max-monitors", str(max(total, 10_000)), "--listen",
             f"127.0.0.1:{port}", "--log-level", "warning"],
            env=ros_env(DOMAIN),
        )  # fmt: skip
        try:
            load_seconds = wait_until_serving(proc, port, started, 900)
            loaded = running(port)
            if loaded != total:  # never a number measured on fewer than it says
                raise RuntimeError(f"the handler runs {loaded} of the {total} instances")
            time.sleep(2)
            rss = resident_bytes(port)
            listener.latencies.clear()
            listener.heard.clear()
            pub = subprocess.run(
                [sys.executable, "-c", PUBLISHER, ",".join(topics), str(RATE), str(SECONDS)],
                env=ros_env(DOMAIN),
                capture_output=True,
                text=True,
                timeout=600,
            )
            sent = int(pub.stdout.split()[0])
            time.sleep(1)
            lat = sorted(listener.latencies)
            heard = len({name.rsplit(".", 1)[1] for name in listener.heard})  # NS.NAME.ROBOT
            if heard != robots:
                raise RuntimeError(f"probe verdicts came from {heard} of the {robots} robots")
        finally:
            proc.terminate()
            proc.wait(timeout=120)
    return {
        "rss": rss,
        "load": load_seconds,
        "sent": sent,
        "verdicts": len(lat),
        "robots": heard,
        "p50": statistics.median(lat) if lat else float("nan"),
        "p99": lat[int(len(lat) * 0.99) - 1] if lat else float("nan"),
    }


def main(argv: list[str] | None = None) -> list[dict[str, Any]]:
    """The two rows (bench/run_all.py calls it with no arguments: the defaults)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=ROBOTS)
    args = ap.parse_args([] if argv is None else argv)
    listener = VerdictListener(DOMAIN, lambda name: name.startswith(f"{NAMESPACE}.probe."))
    try:
        probes = run(args.robots, 1, listener)
        fleet = run(args.robots, MONITORS, listener)
    finally:
        listener.close()
    total = args.robots * MONITORS
    per_instance = (fleet["rss"] - probes["rss"]) / (total - args.robots)
    return [
        {
            "name": f"a fleet's cloud handler: memory holding {args.robots} robots' instances",
            "detail": f"{MONITORS} Monitors a robot, each robot's instances in its ROS namespace "
            f"(/amr_N/speed), as the operator makes them; {total:,} instances running "
            f"(--max-monitors raised: the default is 10,000); loaded in {fleet['load']:.0f} s "
            f"(the probes alone: {probes['load']:.1f} s)",
            "baseline": f"{args.robots} robots, their probe alone ({args.robots} instances): "
            f"{probes['rss'] / 2**20:,.0f} MiB resident",
            "measured": f"{args.robots} robots x {MONITORS}, {total:,} instances: "
            f"{fleet['rss'] / 2**20:,.0f} MiB resident",
            "ratio": f"{per_instance / 1024:.1f} KiB per instance",
        },
        {
            "name": f"a fleet's cloud handler: publish-to-verdict latency, {args.robots} robots",
            "detail": f"{fleet['sent']:,} messages at {RATE:,.0f}/s round-robin over the robots' "
            f"/speed ({RATE / args.robots:g}/s a robot), each offered to its robot's "
            f"{MONITORS} instances; probe verdicts received {fleet['verdicts']:,} from "
            f"{fleet['robots']} robots (baseline {probes['verdicts']:,}); several topics: "
            "each message waits in the reorder window (20 ms) on both sides",
            "baseline": f"the probes alone: p50 {probes['p50']:.1f} ms, p99 {probes['p99']:.1f} ms",
            "measured": f"{total:,} instances: p50 {fleet['p50']:.1f} ms, "
            f"p99 {fleet['p99']:.1f} ms",
            "ratio": f"p99 {fleet['p99'] / probes['p99']:.1f}x the baseline's",
        },
    ]


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1:]), indent=1))
