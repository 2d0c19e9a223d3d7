"""A JSON Lines trace as a rosbag2 bag: ``python examples/trace_to_bag.py MONITORS TRACE BAG``.

A bag to try ``edgerv check`` on without a robot or the ROS 2 command line (on a robot,
``ros2 bag record -s mcap -o BAG TOPIC...`` makes one). Each event of TRACE is written on
its topic with the message type MONITORS give that topic, logged at its stamp, in stamp
order: what ``edgerv replay`` would publish, as ``ros2 bag record`` would have recorded
it. The messages are made and serialized by rclpy from the venv's ROS 2 (a type of your
own packages is built from its .msg files under ``$EDGERV_MSG_PATH`` at its first use, as
the handler builds it), the bag written by rosbags. ``--storage mcap`` (default: BAG is a
directory holding ``BAG.mcap`` and ``metadata.yaml``, as rosbag2 writes it) or
``--storage sqlite3`` (``BAG/BAG.db3``). BAG must not exist. Exit 0: written; 2: bad input,
said with its place.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from edgerv.core import msgtypes
from edgerv.core.diagnostics import Diagnostic, InputError, Location


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="trace_to_bag.py", description=__doc__.split("\n\n")[0])
    p.add_argument("monitors", help="the monitors whose signals give each topic its type")
    p.add_argument("trace", help="a JSON Lines trace")
    p.add_argument("bag", type=Path, help="the bag to write (a directory; must not exist)")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    args = p.parse_args(argv)
    if args.bag.exists():
        print(f"{args.bag}: error: exists already (rosbag2 writes a new bag)", file=sys.stderr)
        return 2

    from rclpy.serialization import serialize_message
    from rosbags.rosbag2 import StoragePlugin, Writer

    from edgerv.handler.ros.messages import message_class
    from edgerv.handler.ros.replay import fill, read_events

    try:
        read = argparse.Namespace(monitors=args.monitors, trace=args.trace)
        types, events, _end = read_events(read)
    except InputError as exc:
        print(exc, file=sys.stderr)
        return 2
    topics = sorted({e.topic for e in events})
    try:
        classes = {t: message_class(types[t]) for t in topics}
    except ImportError as exc:
        print(f"{args.monitors}: error: {exc}", file=sys.stderr)
        return 2
    for t in topics:
        msgtypes.ensure_type(types[t])  # a type of your own: its .msg files, for the bag
    data = []
    for e in events:  # every message made before the bag is: a bad one leaves no bag
        try:
            data.append(serialize_message(fill(classes[e.topic](), e.msg)))
        except (ValueError, TypeError, AssertionError) as exc:
            where = e.where if e.where.line else Location(args.trace)
            problem = f"cannot make a {types[e.topic]} message: {exc}"
            print(Diagnostic(where, problem).render(), file=sys.stderr)
            return 2
    store = msgtypes.typestore()
    plugin = StoragePlugin.MCAP if args.storage == "mcap" else StoragePlugin.SQLITE3
    writer = Writer(args.bag, version=9, storage_plugin=plugin)
    writer.open()
    try:
        conns = {t: writer.add_connection(t, types[t], typestore=store) for t in topics}
        for e, cdr in zip(events, data, strict=True):
            writer.write(conns[e.topic], e.stamp, cdr)
    finally:
        writer.close()
    print(f"wrote {len(events)} messages of {', '.join(topics)} to {args.bag} ({args.storage})")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
