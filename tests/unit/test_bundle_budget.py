"""A receiver's reading of a snapshot bundle within its budget (issue #38,
:func:`edgerv.core.handoff.read_bundle`): what decoding takes is known from the headers,
before anything is decoded, and is never less than what it takes (tracemalloc); a bundle
that announces, inflates or would decode past its budget is refused before the work; a
bundle within it is read as before.
"""

from __future__ import annotations

import gc
import json
import sys
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from edgerv.core import handoff
from edgerv.core.handoff import (
    BundleTooLarge,
    HandoffError,
    bundle,
    decoded_cost,
    encode,
    read_bundle,
    unbundle,
)
from edgerv.core.pipeline import MonitorRuntime
from kit.documents import compiled

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "fuzz"))
import fuzz_bundle  # tests/fuzz: real events, and swollen snapshots

MONITOR = compiled("always (a -> x < 5)", {"a": "bool", "x": "float"})


def real_frame(epoch: int = 7, n: int = 60) -> bytes:
    rt = MonitorRuntime(MONITOR)
    rt.holding = True
    for stamp, seq, updates in fuzz_bundle.events(4, n, 100):
        rt.offer(stamp, seq, updates)
    return encode(rt.snapshot(cut=100 + n, epoch=epoch))


def framed(header: dict[str, Any], body: bytes) -> bytes:
    text = json.dumps(header).encode()
    return b"ERV3" + len(text).to_bytes(4, "big") + len(body).to_bytes(4, "big") + text + body


def header_of(frame: bytes) -> dict[str, Any]:
    return dict(json.loads(frame[12 : 12 + int.from_bytes(frame[4:8], "big")]))


def every_letter_a_run(n: int, kept: int, bits: int = 4, past: Any = None) -> bytes:
    """A frame whose ``n`` letters each make a run, ``kept`` of them with a stamp."""
    letters = (np.arange(n) % 2).astype("<u2").tobytes() + np.ones(n, "<u4").tobytes()
    pairs = []
    for i in range(kept):
        pairs += [1 if i else 0, 10**12 if i == 0 else 1000]
    header = header_of(real_frame()) | {"bits": bits, "n": n, "runs": n, "stamps": kept,
                                        "values": [None, None], "valuation": 0, "past": past,
                                        "clock": None}  # fmt: skip
    return framed(header, letters + handoff._varints(pairs))


def measured(wire: bytes, budget: int) -> tuple[list[Any], int]:
    gc.collect()
    tracemalloc.start()
    try:
        snaps = read_bundle(wire, budget)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return snaps, peak


@pytest.mark.parametrize(
    "frame",
    [
        every_letter_a_run(100_000, 100_000),  # stamps: a dict entry each
        every_letter_a_run(100_000, 0, bits=12),  # letters of two bytes
        fuzz_bundle.swollen(real_frame(), 50_000),  # 16-bit runs: millions of letters
        every_letter_a_run(1, 0, past=[{}] * 100_000),  # a header of objects
        every_letter_a_run(1, 0, past=[[]] * 100_000),
        every_letter_a_run(1, 0, past=["s"] * 100_000),
        every_letter_a_run(1, 0, past=[0.5] * 100_000),
    ],
    ids=["stamps", "wide letters", "long runs", "dicts", "lists", "strings", "floats"],
)
def test_what_decoding_takes_is_never_more_than_the_headers_say(frame: bytes) -> None:
    """The estimate the budget is checked against, against what decoding took."""
    hlen = int.from_bytes(frame[4:8], "big")
    h, _, _ = handoff._header(frame, handoff.MAX_LETTERS)
    estimate = handoff._held(len(frame)) + handoff.FRAME_BYTES + decoded_cost(h, hlen)
    (snap,), peak = measured(bundle([frame]), 1 << 30)
    assert len(snap.letters) == h["n"]
    assert peak <= estimate, (peak, estimate)


def test_a_few_kib_of_valid_snapshots_that_decode_to_gib_are_refused_undecoded(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The issue's bundle: 40 valid snapshots whose letters come in runs of millions (16 Mi
    letters each: 640 Mi letters), a few KiB on the wire; 2.5 GiB and 12 s before."""
    monkeypatch.setattr(handoff, "_decode", lambda *a: pytest.fail("a snapshot was decoded"))
    frame = real_frame()
    wire = bundle([fuzz_bundle.swollen(frame, handoff.MAX_LETTERS // header_of(frame)["n"])] * 40)
    assert len(wire) < 32 << 10
    gc.collect()
    tracemalloc.start()
    try:
        with pytest.raises(BundleTooLarge, match="a bundle of 40 snapshots would take"):
            read_bundle(wire)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 8 << 20, peak


@pytest.mark.parametrize("announced", [1 << 30, 16 << 20])
def test_a_deflate_bomb_is_refused_by_its_announced_size_or_as_it_inflates(
    announced: int,
) -> None:
    """A MiB of deflate that inflates to 1 GiB: refused at its first 8 bytes when it
    announces more than the budget, else a step past what it announced."""
    stream = fuzz_bundle.deflate_bomb(1 << 30)
    wire = b"ERVB" + announced.to_bytes(4, "big") + stream
    gc.collect()
    tracemalloc.start()
    try:
        with pytest.raises(HandoffError) as refused:
            read_bundle(wire, 32 << 20)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    if announced > 32 << 20:
        assert isinstance(refused.value, BundleTooLarge) and peak < 1 << 20
    else:
        assert "does not inflate to its announced size: it goes on past it" in str(refused.value)
        assert peak <= handoff._held(announced) + handoff.INFLATE_STEP, peak


def test_frames_past_the_budget_are_refused_before_their_headers_are_read() -> None:
    """Many empty frames, each a header and a list place: counted as they are found."""
    tiny = framed({"v": 3}, b"")
    with pytest.raises(BundleTooLarge, match=r"first \d+ snapshots would take more than"):
        read_bundle(bundle([tiny] * 20_000), 4 << 20)


def test_admit_sees_every_header_before_any_snapshot_is_decoded(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    seen: list[tuple[str, int]] = []

    def admit(name: str, epoch: int) -> None:
        seen.append((name, epoch))
        if len(seen) == 3:
            raise HandoffError("not this one")

    monkeypatch.setattr(handoff, "_decode", lambda *a: pytest.fail("a snapshot was decoded"))
    with pytest.raises(HandoffError, match="snapshot 3 of 3: not this one"):
        read_bundle(bundle([real_frame(7), real_frame(8), real_frame(9)]), admit=admit)
    assert seen == [("m", 7), ("m", 8), ("m", 9)]


def test_a_bundle_within_its_budget_reads_as_before() -> None:
    frames = [real_frame(7, n) for n in (10, 200, 3000)]
    wire = bundle(frames)
    snaps = read_bundle(wire, 1 << 20)
    assert snaps == [handoff.decode(f) for f in unbundle(wire)]
    assert [len(s.letters) for s in snaps] == [len(handoff.decode(f).letters) for f in frames]
