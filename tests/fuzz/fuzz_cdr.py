"""Coverage-guided fuzzing (atheris, libFuzzer) of the CDR field readers.

The handler reads each monitored field straight from the bytes a publisher sent
(``edgerv.core.cdr``: a reader generated per message type and field set). Any
bytes can arrive on a topic; a reader must return values, or raise one of
``cdr.MALFORMED`` (the take loop counts the message as malformed and goes on),
and do it quickly. The first byte of an input picks the reader, the rest is the
payload (its encapsulation header included: ``00 01`` little-endian, ``00 00``
big-endian, which falls back to rosbags). The generated readers are instrumented
too, so the fuzzer is guided through them::

    python tests/fuzz/fuzz_cdr.py WORK_CORPUS tests/fuzz/corpus/cdr -max_total_time=60

``make fuzz`` runs it (``FUZZ_SECONDS``); ``tests/unit/test_fuzz_targets.py`` runs
it for a few thousand inputs and replays every input in ``tests/fuzz/crashes/cdr/``
through :func:`fuzz_one_input`.
"""

from __future__ import annotations

import contextlib
import sys
import types
from collections.abc import Callable
from typing import Any

# (message type, fields a monitor reads): sequences of primitives, of strings and of
# messages, fixed arrays, strings, fields behind them
READERS: list[tuple[str, list[str]]] = [
    ("sensor_msgs/msg/LaserScan", ["header.stamp.sec", "ranges[0]", "intensities[3]"]),
    ("sensor_msgs/msg/LaserScan", ["header.frame_id", "range_max"]),
    ("nav_msgs/msg/Odometry", ["twist.twist.linear.x", "pose.covariance[35]"]),
    ("nav_msgs/msg/Odometry", ["child_frame_id", "header.frame_id"]),
    ("std_msgs/msg/String", ["data"]),
    ("geometry_msgs/msg/PolygonInstance", ["id"]),
    ("geometry_msgs/msg/PolygonInstance", ["polygon.points[1].y"]),
    ("sensor_msgs/msg/JointState", ["name[1]", "effort[2]"]),
    ("diagnostic_msgs/msg/DiagnosticArray", ["status[0].values[1].value"]),
]

_readers: list[Callable[[bytes], Any]] = []
_malformed: tuple[type[Exception], ...] = ()
_stamp: Callable[[bytes], int] | None = None


def load(instrument: Callable[[Any], Any] | None = None) -> None:
    """Compile the readers (``instrument``: atheris' instrument_func, for their code)."""
    global _malformed, _stamp
    from edgerv.core import cdr

    _malformed, _stamp = cdr.MALFORMED, cdr.header_stamp_ns
    for msg_type, paths in READERS:
        read = cdr.compile_reader(msg_type, paths)
        if instrument is not None:  # the generated functions, and the helpers they call
            space = read.__globals__
            for name, value in list(space.items()):
                if isinstance(value, types.FunctionType) and value.__code__.co_filename.startswith(
                    "<cdr reader"
                ):
                    space[name] = instrument(value)
            read = space["read"]
        _readers.append(read)


def fuzz_one_input(data: bytes) -> None:
    if not _readers:
        load()
    if not data:
        return
    payload = data[1:]
    with contextlib.suppress(_malformed):
        _readers[data[0] % len(_readers)](payload)
    assert _stamp is not None
    with contextlib.suppress(ValueError):
        _stamp(payload)


def main() -> None:
    import atheris

    with atheris.instrument_imports(include=["edgerv"]):
        load(atheris.instrument_func)
    atheris.Setup(sys.argv, fuzz_one_input)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
