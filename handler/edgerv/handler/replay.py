"""``edgerv replay``: publish a JSON Lines trace as real ROS 2 messages.

Each event is published on its topic with the message type the monitors give
that topic, in timestamp order (ties in file order), ``--interval`` apart. A
stand-in for the robot when trying monitors or a handler without one.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from edgerv.core.diagnostics import Diagnostic, InputError, Location
from edgerv.core.documents import load_monitors
from edgerv.core.traces import Trace


def fill(msg: Any, data: dict[str, Any], where: str = "msg") -> Any:
    """Set the fields of an rclpy message from nested dicts (numbers widened to float)."""
    for key, value in data.items():
        if not hasattr(msg, key):
            raise ValueError(f"{where} has no field '{key}'")
        current = getattr(msg, key)
        if isinstance(value, dict):
            fill(current, value, f"{where}.{key}")
        elif isinstance(current, float) and isinstance(value, int) and not isinstance(value, bool):
            setattr(msg, key, float(value))
        else:
            setattr(msg, key, value)
    return msg


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("trace", help="a JSON Lines trace")
    p.add_argument(
        "--monitors",
        required=True,
        metavar="FILE_OR_DIR",
        help="the monitors whose signals give each topic its message type",
    )
    p.add_argument(
        "--interval",
        type=float,
        default=0.002,
        metavar="SECONDS",
        help="pause between two messages (default 0.002)",
    )
    p.add_argument(
        "--wait",
        type=float,
        default=10.0,
        metavar="SECONDS",
        help="wait this long for a subscriber on every topic (default 10)",
    )


def run(args: argparse.Namespace) -> int:
    try:
        specs = load_monitors(args.monitors)
        types = {s.topic: s.msg_type for spec in specs for s in spec.signals.values()}
        trace = Trace(Path(args.trace))
        try:
            trace.inspect(types)
            events = sorted(trace.events(types), key=lambda e: e.stamp)
        finally:
            trace.close()
    except InputError as exc:
        print(exc, file=sys.stderr)
        return 2
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rclpy.utilities import try_shutdown

    from edgerv.handler.ros_node import message_class

    rclpy.init()
    node = rclpy.create_node("edgerv_replay")
    try:
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        classes = {t: message_class(m) for t, m in types.items()}
        pubs = {t: node.create_publisher(classes[t], t, qos) for t in types}
        deadline = time.monotonic() + args.wait
        while any(p.get_subscription_count() == 0 for p in pubs.values()):
            if time.monotonic() > deadline:
                missing = [t for t, p in pubs.items() if p.get_subscription_count() == 0]
                print(
                    f"edgerv replay: no subscriber on {', '.join(missing)} after "
                    f"{args.wait:g} s; publishing anyway",
                    file=sys.stderr,
                )
                break
            time.sleep(0.05)
        time.sleep(0.3)  # let discovery settle on both sides
        for event in events:
            try:
                msg = fill(classes[event.topic](), event.msg)
            except (ValueError, TypeError, AssertionError) as exc:
                diag = Diagnostic(
                    event.where if event.where.line else Location(args.trace),
                    f"cannot make a {types[event.topic]} message: {exc}",
                )
                print(diag.render(), file=sys.stderr)
                return 2
            pubs[event.topic].publish(msg)
            time.sleep(args.interval)
        time.sleep(0.5)  # reliable delivery of the last messages before the node goes
        print(f"edgerv replay: published {len(events)} messages", file=sys.stderr)
        return 0
    finally:
        node.destroy_node()
        try_shutdown()
