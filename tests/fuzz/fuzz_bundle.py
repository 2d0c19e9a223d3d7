"""Coverage-guided fuzzing (atheris, libFuzzer) of the handoff's wire form.

A receiver takes a snapshot bundle (``ERVB``: one deflate stream of ``ERV3``
frames) in ``POST /v1/handoff/adopt``, and ``edgerv migrate`` checks the one a
sender released (docs/protocol.md, "Wire form"). Whatever the bytes:
``unbundle``, ``frame_sizes``, ``decode`` and ``restore`` return, or raise
``HandoffError``; and a snapshot that restores runs on (events, the sort,
evaluation, clock steps) without any error. The first byte of an input picks the
entry (0: a bundle, read as ``edgerv migrate`` reads it and as a receiver does,
:func:`~edgerv.core.handoff.read_bundle`; 1: one frame as it is; 2: a frame deflated
into a bundle here, so that mutations of the frame are not lost in the deflate stream,
its runs of letters swollen by the second byte's high bits (:data:`SWELL`: valid
snapshots, huge once decoded, which a receiver reads within its budget or refuses); 3:
a header and a body, framed here, see :func:`framed`), the second the monitor definition
the snapshot is restored into (``bundle.dict``: the header's JSON words)::

    python tests/fuzz/fuzz_bundle.py WORK_CORPUS tests/fuzz/corpus/bundle \
        -dict=tests/fuzz/bundle.dict -max_total_time=60

``make fuzz`` runs it (``FUZZ_SECONDS``); ``tests/unit/test_fuzz_targets.py`` runs
it for a few thousand inputs and replays every input in
``tests/fuzz/crashes/bundle/`` through :func:`fuzz_one_input`.
"""

from __future__ import annotations

import contextlib
import importlib
import random
import sys
from typing import Any

ASSERTIONS = [
    "always (a -> x < 5)",
    "always (a -> age(x) < 4ns)",
    "always (historically[1ns..6ns] (x < 8) | a)",
    "always ((once a) -> x > 1)",
]
DOCUMENT = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {{name: m}}
spec:
  assertion: "{}"
  signals:
    a: {{topic: /a, type: std_msgs/msg/Bool}}
    x: {{topic: /x, type: std_msgs/msg/Float64}}
  sortThreshold: 8
"""
LIMIT = 1 << 20  # inflated bytes (the API allows 1 GiB: not for a fuzzer's memory)
MAX_LETTERS = 1 << 16  # letters a snapshot may carry here (the default 16 Mi is slow to run)

_monitors: list[Any] = []


def events(
    seed: int, n: int, start: int, only: int | None = None
) -> list[tuple[int, int, list[tuple[int, Any]]]]:
    """A run of ``n`` events on the two signals (``only``: on that one) from ``start``."""
    rng, stamp, out = random.Random(seed), start, []
    for seq in range(n):
        stamp += rng.choice([0, 1, 3])
        signal = (rng.random() < 0.5) if only is None else only == 0
        out.append((stamp, seq, [(0, rng.random() < 0.6)] if signal else [(1, rng.uniform(0, 9))]))
    return out


def held(at: int) -> list[tuple[int, int, list[tuple[int, Any]]]]:
    """What a receiver held when it adopts, from just before the cut ``at``: a batch that is
    compressed column-wise, of one signal only (the other goes on from its snapshot value)."""
    return events(1, 150, at - 6, only=0)


def run_on(rt: Any, at: int) -> None:
    """What a restored monitor goes through: events one by one, evaluation, clock steps.
    ``at``: about the cut (64-bit stamps)."""
    rt.evaluate()
    for stamp, seq, updates in events(2, 20, at + 1000):
        if rt.offer(stamp, seq, updates):
            rt.evaluate()
    rt.holding = False
    rt.flush()
    rt.advance(at + 10**4)
    rt.evaluate()


def framed(data: bytes) -> bytes:
    """A frame of a header and a body given apart (``data``: the header's length, 2 bytes
    big-endian, the header, the body), its lengths right: a mutation inside the header
    reaches the checks behind the frame's."""
    size = int.from_bytes(data[:2], "big")
    header, body = data[2 : 2 + size], data[2 + size :]
    return b"ERV3" + len(header).to_bytes(4, "big") + len(body).to_bytes(4, "big") + header + body


def swollen(frame: bytes, factor: int) -> bytes:
    """The same snapshot with each run of letters ``factor`` times as long (at most 2^32 - 1
    a run): as valid, as small on the wire (a run's length is 4 bytes, deflated to about
    nothing), and ``factor`` times the letters once decoded."""
    import json

    import numpy as np

    hlen = int.from_bytes(frame[4:8], "big")
    header, body = json.loads(frame[12 : 12 + hlen]), frame[12 + hlen :]
    runs = header["runs"]
    lengths = np.frombuffer(body, "<u4", count=runs, offset=2 * runs).astype(np.uint64)
    lengths = np.minimum(lengths * factor, 2**32 - 1)
    header["n"] = int(lengths.sum())
    grown = body[: 2 * runs] + lengths.astype("<u4").tobytes() + body[6 * runs :]
    return framed(len(json.dumps(header)).to_bytes(2, "big") + json.dumps(header).encode() + grown)


def deflate_bomb(inflated: int) -> bytes:
    """A zlib stream of ``inflated`` zero bytes, about a thousandth of that: one deflate
    block of a MiB of zeros, repeated (made in a moment; its checksum is not the stream's,
    as a reader that stops past its limit never learns)."""
    import zlib

    raw = zlib.compressobj(9, zlib.DEFLATED, -15)  # raw deflate: blocks without a header
    block = raw.compress(bytes(1 << 20)) + raw.flush(zlib.Z_FULL_FLUSH)
    end = raw.flush(zlib.Z_FINISH)
    return b"\x78\xda" + block * (inflated >> 20) + end + bytes(4)


def load() -> None:
    from edgerv.core.documents import load_monitors_text
    from edgerv.core.monitor import compile_monitor

    for assertion in ASSERTIONS:
        _monitors.append(compile_monitor(load_monitors_text("m", DOCUMENT.format(assertion))[0]))


def swell(frame: bytes, factor: int) -> bytes:
    """:func:`swollen`, for a frame whose header reads (else the frame as it is)."""
    if factor == 1:
        return frame
    try:
        return swollen(frame, factor)
    except (ValueError, KeyError, TypeError, IndexError, OverflowError, RecursionError):
        return frame


SWELL = [1, 1, 1, 1, 7, 1000, 10**5, 2**20]  # by data[1] // 4: valid, and huge decoded


def fuzz_one_input(data: bytes) -> None:
    from edgerv.core.handoff import (
        BundleTooLarge,
        HandoffError,
        bundle,
        decode,
        frame_sizes,
        read_bundle,
        unbundle,
    )
    from edgerv.core.pipeline import MonitorRuntime

    if not _monitors:
        load()
    if len(data) < 2:
        return
    mode, monitor, rest = data[0] % 4, _monitors[data[1] % len(_monitors)], data[2:]
    try:
        if mode == 0:
            frames = unbundle(rest, LIMIT)
            with contextlib.suppress(HandoffError):  # the receiver's reading: the same
                read_bundle(rest, LIMIT, max_letters=MAX_LETTERS)
        elif mode == 1:
            frames = [rest]
        elif mode == 2:  # swollen, maybe: a receiver reads it within its budget, or refuses
            wire = bundle([swell(rest, SWELL[data[1] // 4 % len(SWELL)])])
            try:
                snaps = read_bundle(wire, LIMIT, max_letters=MAX_LETTERS)
            except BundleTooLarge:
                return
            frames = unbundle(wire, LIMIT)
            assert len(frames) == len(snaps)
        else:
            frames = [framed(rest)]
        for frame in frames:
            frame_sizes(frame)
            snap = decode(frame, MAX_LETTERS)
            # the receiver's own events around the cut, then later ones (real stamps: 64 bits)
            at = max(-(2**62), min(snap.cut, 2**62))
            run_on(MonitorRuntime.restored(monitor, snap, held(at)), at)
    except HandoffError:
        pass


def main() -> None:
    import atheris

    with atheris.instrument_imports(include=["edgerv"]):
        for module in ("edgerv.core.handoff", "edgerv.core.pipeline", "edgerv.core.language.past"):
            importlib.import_module(module)
        load()
    atheris.Setup(sys.argv, fuzz_one_input)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
