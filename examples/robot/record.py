"""Record topics into a rosbag2 MCAP bag: ``python record.py BAG TOPIC=TYPE ...``.

The demo's recorder (no rosbag2 is installable from PyPI, so it writes the bag
with ``rosbags``, a rosbag2 writer that ``ros2 bag info``/``play`` and MCAP
tools read). It takes every message as the bytes the publisher sent and logs
it at its publication instant (the DDS source timestamp), the instant the
monitor handler uses for a message without a header, so a live run and
``edgerv check`` on its bag time every message alike. (``ros2 bag record`` logs
the reception instant instead.) Subscriptions are reliable with a deep queue:
nothing the publishers sent to it is dropped. It prints ``ready`` once
subscribed, and on SIGINT/SIGTERM takes what is left, closes the bag and prints
the message count per topic as JSON.
"""

from __future__ import annotations

import importlib
import json
import signal
import sys
import time
from pathlib import Path
from typing import Any

import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore


def message_class(msg_type: str) -> Any:
    pkg, _, name = msg_type.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def main(argv: list[str]) -> int:
    bag, specs = Path(argv[0]), [a.split("=", 1) for a in argv[1:]]
    stopping: list[int] = []
    signal.signal(signal.SIGTERM, lambda s, _f: stopping.append(s))
    signal.signal(signal.SIGINT, lambda s, _f: stopping.append(s))
    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node("edgerv_demo_recorder")
    qos = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE)
    store = get_typestore(Stores.ROS2_JAZZY)
    writer = Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    subs = []
    counts: dict[str, int] = {}
    for topic, msg_type in specs:
        cls = message_class(msg_type)
        sub = node.create_subscription(cls, topic, lambda _m: None, qos, raw=True)
        conn = writer.add_connection(topic, msg_type, typestore=store)
        subs.append((sub, cls, conn, topic))
        counts[topic] = 0
    print("ready", flush=True)

    def drain() -> int:
        taken = 0
        for sub, cls, conn, topic in subs:
            with sub.handle:
                while (got := sub.handle.take_message(cls, True)) is not None:
                    raw, info = got
                    writer.write(conn, int(info["source_timestamp"]), raw)
                    counts[topic] += 1
                    taken += 1
        return taken

    while not stopping:
        if not drain():
            time.sleep(0.005)
    time.sleep(0.2)
    drain()
    writer.close()
    node.destroy_node()
    rclpy.try_shutdown()
    print(json.dumps({"recorded": counts}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
