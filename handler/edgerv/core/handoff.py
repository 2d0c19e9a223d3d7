"""What a monitor's handoff moves between handlers, where the cut falls, and its wire form.

The protocol (the paper's section V, Fig. 3; docs/protocol.md) hands a monitor
from H1 to H2. This module is its data side:

* While the handoff runs, both handlers *hold* the monitor: they buffer its
  events and evaluate none (``MonitorRuntime.holding``). H1 still compresses
  each on arrival, ahead (``MonitorRuntime.ahead``): at the cut, the letters up
  to it are ready (:meth:`MonitorRuntime.cover`).
* **The cut.** H2 reports, per topic of the monitor, the stamp of the first
  event it received. The cut ``T`` is the largest of them (:func:`cut_point`).
  H1 covers every event stamped ``<= T``; H2 drops its own events stamped
  ``<= T`` and covers the rest. With per-topic in-order delivery, every event
  is covered exactly once: an event stamped ``<= T`` was received by H1, which
  was subscribed throughout; one stamped ``> T`` came on its topic after H2's
  first event there, which H2 received. H1 stops holding only once every topic
  brought it an event stamped after ``T`` (or a grace period ran out since it
  learned ``T``): each topic is its own channel, and an event stamped ``<= T`` on
  one may reach H1 after a later one on another. (The paper's cut,
  the oldest event H2 holds, loses the events of a topic on which H2 has not yet
  received anything.)
* **The snapshot** (``MonitorRuntime.snapshot``): H1 compresses its held events
  ``<= T`` and sends the automaton state (one integer), the step counter, the
  signal values as of the cut (the next letter needs the last value of every
  signal), and the letters not yet evaluated. The paper's compression drops the
  timestamps; edgerv keeps one only where a verdict can be reported (a verdict
  names the stamp of its deciding event): H1 walks the letters through the
  table from the current state, reporting nothing, and keeps the stamps of the
  steps that reach a verdict state.
* ``MonitorRuntime.restored`` builds H2's runtime: the snapshot's letters first, then H2's
  own events ``> T``. It ignores every later event stamped ``<= T`` too: H2 may
  not have taken all of its own events ``<= T`` yet when it adopts. H1 uses it
  as well, on its own snapshot, to resume when the handoff is undone after it
  released (docs/protocol.md).

:func:`encode` and :func:`decode` give a snapshot's frame (``ERV3``): a JSON
header, then the letters run-length encoded (each run's letter as 16 bits, then
each run's length as 32 bits) and the kept stamps as varint (index gap, stamp
delta) pairs. :func:`bundle` deflates a batch's frames as one stream (``ERVB``),
:func:`unbundle` splits it again. A trace whose letters change every few dozen
events costs well under a bit an event. :func:`decode` and :func:`unbundle`
check everything and raise :class:`HandoffError`.
"""

from __future__ import annotations

import json
import struct
import zlib
from array import array
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from edgerv.core.pipeline import letter_typecode
from edgerv.core.snapshot import HandoffError as HandoffError
from edgerv.core.snapshot import Snapshot as Snapshot
from edgerv.core.snapshot import runs_of

WIRE_VERSION = 3
_FRAME = struct.Struct("!4sII")  # magic, header length, body length
_MAGIC = b"ERV3"
_BUNDLE = struct.Struct("!4sI")  # magic, length of the frames once inflated
_BUNDLE_MAGIC = b"ERVB"
MAX_BUNDLE = 256 << 20  # what a bundle may take, inflated and decoded (bytes)
MAX_LETTERS = 1 << 24  # letters one snapshot may carry
INFLATE_STEP = 1 << 20  # bytes inflated at a time (the cap is checked after each)
INFLATE_FEED = 1 << 16  # deflated bytes given to zlib at a time
# What decoding takes beyond the frame's own bytes, measured with tracemalloc
# (tests/unit/test_bundle_budget.py): its header's JSON as Python objects (at most ~20
# times its text: ``[{},{},...]``), each letter about twice (NumPy's repeat, then the
# array; 3 here), each run, each kept stamp in a dict and the list of varints it is read
# from.
HEADER_FACTOR = 32
LETTER_FACTOR = 3
STAMP_BYTES = 240
RUN_BYTES = 10  # each run: its letter widened, its length as NumPy's repeat takes it (intp)
FRAME_BYTES = 256  # a frame's view and its place in the list of frames


class BundleTooLarge(HandoffError):
    """A bundle that announces, inflates or would decode to more than its budget."""


def cut_point(first_stamps: Mapping[str, int], topics: Iterable[str]) -> int | None:
    """The cut once H2 has an event on every topic of the monitor, else None (wait)."""
    firsts = []
    for topic in topics:
        if topic not in first_stamps:
            return None
        firsts.append(first_stamps[topic])
    return max(firsts) if firsts else None


# -- wire form -------------------------------------------------------------------------------


def _varints(numbers: Iterable[int]) -> bytearray:
    out = bytearray()
    for d in numbers:
        z = (d << 1) ^ (d >> 63)  # zigzag: small negative numbers stay small
        while True:
            byte = z & 0x7F
            z >>= 7
            out.append(byte | (0x80 if z else 0))
            if not z:
                break
    return out


def _from_varints(data: bytes | memoryview, n: int, what: str) -> list[int]:
    out, i = [], 0
    for _ in range(n):
        z = shift = 0
        while True:
            if i >= len(data) or shift > 63:
                raise HandoffError(f"{what} are truncated")
            byte = data[i]
            i += 1
            z |= (byte & 0x7F) << shift
            shift += 7
            if not byte & 0x80:
                break
        out.append((z >> 1) ^ -(z & 1))
    if i != len(data):
        raise HandoffError(f"{what} have trailing bytes")
    return out


def encode(snap: Snapshot) -> bytes:
    """One snapshot's frame (uncompressed: :func:`bundle` deflates frames together)."""
    _, run_letters, run_lengths = snap.runs if snap.runs is not None else runs_of(snap.letters)
    letters: bytes = run_letters.astype("<u2").tobytes() + run_lengths.astype("<u4").tobytes()
    pairs: list[int] = []
    last_i = last_s = 0
    for i in sorted(snap.stamps):
        pairs += (i - last_i, snap.stamps[i] - last_s)
        last_i, last_s = i, snap.stamps[i]
    header = json.dumps(
        {
            "v": WIRE_VERSION,
            "monitor": snap.monitor,
            "epoch": snap.epoch,
            "cut": snap.cut,
            "state": snap.state,
            "step": snap.step,
            "halted": snap.halted,
            "values": list(snap.values),
            "valuation": snap.valuation,
            "lastReleased": snap.last_released,
            "late": snap.late_events,
            "bits": snap.bits,
            "n": len(snap.letters),
            "runs": len(run_lengths),
            "stamps": len(snap.stamps),
            "clock": None if snap.clock is None else [snap.clock[0], list(snap.clock[1])],
            "past": snap.past,
            **({"wide": snap.wide} if snap.wide else {}),  # (a wide letter's valuation)
        },
        separators=(",", ":"),
    ).encode()
    body = letters + _varints(pairs)
    return _FRAME.pack(_MAGIC, len(header), len(body)) + header + body


def decode_frames(frames: Sequence[bytes]) -> list[Snapshot]:
    """Each frame's snapshot (:func:`decode`); a bad one is named by its place."""
    snaps = []
    for i, data in enumerate(frames, 1):
        try:
            snaps.append(decode(data))
        except HandoffError as exc:
            raise HandoffError(f"snapshot {i} of {len(frames)}: {exc}") from None
    return snaps


def bundle(frames: Iterable[bytes]) -> bytes:
    """Snapshot frames as they cross the wire: one deflate stream over all of them.

    Deflating the batch at once shares what monitors have in common (their header
    keys, similar letters): a monitor's header costs a few dozen bytes, not ~250.
    """
    raw = b"".join(frames)
    return _BUNDLE.pack(_BUNDLE_MAGIC, len(raw)) + zlib.compress(raw, 6)


def bundled_size(data: bytes | bytearray | memoryview) -> int:
    """The inflated size a bundle announces, from its first 8 bytes (raises
    :class:`HandoffError` if they are not a bundle's)."""
    if len(data) < _BUNDLE.size or bytes(data[:4]) != _BUNDLE_MAGIC:
        raise HandoffError("not an edgerv snapshot bundle (or one of another wire version)")
    return int(_BUNDLE.unpack_from(data)[1])


def _inflated(data: bytes | bytearray | memoryview, limit: int) -> bytearray:
    size = bundled_size(data)
    if size > limit:
        raise BundleTooLarge(f"a bundle of {size} bytes is over the limit of {limit}")
    try:
        return _inflate(memoryview(data)[_BUNDLE.size :], size)
    except zlib.error as exc:
        raise HandoffError(f"a bundle does not inflate: {exc}") from None


def _split(raw: bytes | bytearray | memoryview, budget: int) -> list[memoryview]:
    """A bundle's inflated bytes -> its frames (views, not copies). What the frames and
    their headers will take (:data:`FRAME_BYTES`, :data:`HEADER_FACTOR`) is counted as
    they are found, against ``budget`` with the bytes themselves."""
    view = memoryview(raw)
    frames: list[memoryview] = []
    i, cost = 0, _held(len(view))
    while i < len(view):
        if len(view) - i < _FRAME.size:
            raise HandoffError("a bundle ends inside a frame")
        magic, hlen, blen = _FRAME.unpack_from(view, i)
        if magic != _MAGIC:
            raise HandoffError("not an edgerv snapshot (or one of another wire version)")
        end = i + _FRAME.size + hlen + blen
        if end > len(view):
            raise HandoffError("a bundle ends inside a frame")
        cost += FRAME_BYTES + HEADER_FACTOR * hlen
        if cost > budget:
            raise BundleTooLarge(
                f"a bundle's first {len(frames) + 1} snapshots would take more than the "
                f"limit of {budget} bytes read"
            )
        frames.append(view[i:end])
        i = end
    return frames


def unbundle(data: bytes, limit: int = MAX_BUNDLE) -> list[bytes]:
    """A bundle -> its snapshot frames, each to check with :func:`decode` (a receiver
    reads one with :func:`read_bundle`, which checks what it costs first)."""
    return [bytes(frame) for frame in _split(_inflated(data, limit), limit)]


def decoded_cost(header: Mapping[str, Any], hlen: int) -> int:
    """Bytes a frame's header and decoding take beyond the frame itself, from its header
    alone (its counts checked already: :func:`_header`)."""
    letter = array(letter_typecode(int(header["bits"]))).itemsize
    return (
        HEADER_FACTOR * hlen
        + LETTER_FACTOR * letter * int(header["n"])
        + RUN_BYTES * int(header["runs"])
        + STAMP_BYTES * int(header["stamps"])
    )


def read_bundle(
    data: bytes | bytearray | memoryview,
    budget: int = MAX_BUNDLE,
    admit: Callable[[str, int], None] | None = None,
    max_letters: int = MAX_LETTERS,
) -> list[Snapshot]:
    """A receiver's reading of a bundle: its snapshots, each checked (:func:`decode`), or
    :class:`HandoffError` naming the snapshot (:class:`BundleTooLarge` past ``budget``).

    In order, each step before the next costs anything: the announced size against the
    budget; the inflation, capped at that size as it goes; every frame's header, and
    ``admit(monitor, epoch)`` for it (it raises :class:`HandoffError` for a snapshot the
    receiver does not take: a monitor it is not receiving); the inflated bytes and what
    decoding the frames will take (:func:`decoded_cost`) against the budget; only then the
    letters and stamps of each frame."""
    raw = _inflated(data, budget)
    frames = _split(raw, budget)  # counts the headers' cost before any is parsed
    headers, cost = [], _held(len(raw)) + FRAME_BYTES * len(frames)
    for i, frame in enumerate(frames, 1):
        try:
            h, hlen, blen = _header(frame, max_letters)
            if admit is not None:
                admit(h["monitor"], h["epoch"])
        except HandoffError as exc:
            raise type(exc)(f"snapshot {i} of {len(frames)}: {exc}") from None
        headers.append((h, hlen, blen))
        cost += decoded_cost(h, hlen)
    if cost > budget:
        raise BundleTooLarge(
            f"a bundle of {len(frames)} snapshots would take {cost} bytes decoded, over the "
            f"limit of {budget}"
        )
    snaps = []
    for i, (frame, (h, hlen, blen)) in enumerate(zip(frames, headers, strict=True), 1):
        try:
            snaps.append(_decode(frame, h, hlen, blen))
        except HandoffError as exc:
            raise HandoffError(f"snapshot {i} of {len(frames)}: {exc}") from None
    return snaps


def frame_sizes(frame: bytes) -> tuple[int, int]:
    """A snapshot's constant part (frame and header, in bytes, before the bundle's
    compression) and its letter count, read from its header alone."""
    try:
        hlen = int(_FRAME.unpack_from(frame)[1])
        header = json.loads(frame[_FRAME.size : _FRAME.size + hlen])
        return _FRAME.size + hlen, int(header["n"])
    except (struct.error, ValueError, KeyError, TypeError, OverflowError, RecursionError) as exc:
        raise HandoffError(f"malformed snapshot header: {exc}"[:300]) from None


def _inflate(data: bytes | bytearray | memoryview, size: int) -> bytearray:
    """Decompress exactly ``size`` bytes, at most :data:`INFLATE_STEP` at a time, fed
    :data:`INFLATE_FEED` bytes at a time: a hostile stream stops one step past ``size``,
    whatever it would inflate to, having taken that and what :func:`_held` counts."""
    d = zlib.decompressobj()
    out = bytearray()
    view = memoryview(data)
    at = 0
    pending: bytes | memoryview = b""
    while True:
        if not pending and at < len(view):
            pending, at = view[at : at + INFLATE_FEED], at + INFLATE_FEED
        chunk = d.decompress(pending, min(INFLATE_STEP, size + 1 - len(out)))
        out += chunk
        if len(out) > size:
            raise HandoffError(
                "a bundle does not inflate to its announced size: it goes on past it"
            )
        pending = d.unconsumed_tail
        if d.eof or not (chunk or pending or at < len(view)):
            break
    if len(out) != size or not d.eof or d.unused_data or at < len(view):
        raise HandoffError("a bundle does not inflate to its announced size")
    return out


def _held(inflated: int) -> int:
    """What inflating ``inflated`` bytes took at most: the bytes, a bytearray's growth (an
    eighth), a step's output and its input."""
    return inflated + inflated // 8 + min(inflated, INFLATE_STEP) + INFLATE_FEED


def _stamp(t: Any) -> bool:
    """Signed 64-bit integer nanoseconds (what the runtime's stamp arrays hold)."""
    return isinstance(t, int) and not isinstance(t, bool) and -(2**63) <= t < 2**63


def _stamp_or_none(t: Any) -> bool:
    return t is None or _stamp(t)


def _header(
    data: bytes | bytearray | memoryview, max_letters: int
) -> tuple[dict[str, Any], int, int]:
    """A frame's header, parsed, and its counts checked (letters, runs, stamps against the
    frame's bytes); its header and body lengths."""
    if len(data) < _FRAME.size:
        raise HandoffError("too short for a snapshot")
    magic, hlen, blen = _FRAME.unpack_from(data)
    if magic != _MAGIC:
        raise HandoffError("not an edgerv snapshot (or one of another wire version)")
    if len(data) != _FRAME.size + hlen + blen:
        raise HandoffError("length does not match its frame")
    try:
        h = json.loads(bytes(data[_FRAME.size : _FRAME.size + hlen]))
        if not isinstance(h, dict):
            raise HandoffError("a snapshot's header is not a JSON object")
        if h.get("v") != WIRE_VERSION:
            raise HandoffError(f"wire version {_shown(h.get('v'))} is not {WIRE_VERSION}")
        n, bits = int(h["n"]), int(h["bits"])
        runs, kept = int(h["runs"]), int(h["stamps"])
        if not (0 <= n <= max_letters and 0 <= bits <= 16):
            raise HandoffError("letter count or width out of range")
        # each run takes 6 bytes, each kept stamp at least 2 (two varints)
        if not (0 <= runs <= n and 0 <= kept <= n and 6 * runs + 2 * kept <= blen):
            raise HandoffError("run or stamp count out of range")
        if not isinstance(h.get("monitor"), str):
            raise HandoffError("a snapshot's monitor is not a name")
        if not _stamp(h.get("epoch")):
            raise HandoffError("a snapshot's epoch is not a 64-bit integer")
        h["n"], h["bits"], h["runs"], h["stamps"] = n, bits, runs, kept
        return h, hlen, blen
    except HandoffError:
        raise
    except (ValueError, KeyError, TypeError, OverflowError, UnicodeDecodeError) as exc:
        raise HandoffError(f"malformed snapshot: {exc}"[:300]) from None
    except RecursionError:  # Python's JSON parser recurses per level
        raise HandoffError("malformed snapshot: its header is nested too deep") from None


def _shown(value: Any) -> str:
    """A header's value as JSON writes it, shortened (never a Python repr)."""
    try:
        text = json.dumps(value)
    except (TypeError, ValueError, RecursionError):
        text = f"a {type(value).__name__}"
    return text if len(text) <= 40 else text[:37] + "..."


def decode(data: bytes | bytearray | memoryview, max_letters: int = MAX_LETTERS) -> Snapshot:
    """Parse and check a snapshot frame; raise :class:`HandoffError` if it is bad."""
    return _decode(data, *_header(data, max_letters))


def _decode(
    data: bytes | bytearray | memoryview, h: dict[str, Any], hlen: int, blen: int
) -> Snapshot:
    """A frame whose header :func:`_header` read: its letters, stamps and fields checked."""
    n, bits, runs, kept = h["n"], h["bits"], h["runs"], h["stamps"]
    try:
        body = memoryview(data)[_FRAME.size + hlen :]
        run_letters = np.frombuffer(body, dtype="<u2", count=runs)
        run_lengths = np.frombuffer(body, dtype="<u4", offset=2 * runs, count=runs)
        if runs and (int(run_letters.max()) >= 1 << bits or int(run_lengths.min()) < 1):
            raise HandoffError("a letter or run length is out of range")
        if int(run_lengths.sum(dtype=np.int64)) != n:
            raise HandoffError("letters do not have the announced count")
        letters = array(letter_typecode(bits))
        repeated = np.repeat(run_letters.astype(letters.typecode), run_lengths)
        letters.frombytes(repeated.data.cast("B"))  # (no copy to bytes first)
        del repeated
        pairs = _from_varints(body[6 * runs :], 2 * kept, "stamps")
        stamps: dict[int, int] = {}
        i = stamp = 0
        for gap, delta in zip(pairs[::2], pairs[1::2], strict=True):
            i, stamp = i + gap, stamp + delta
            if not 0 <= i < n or (stamps and gap < 1):
                raise HandoffError("a stamp's index is out of range")
            if not _stamp(stamp):
                raise HandoffError("a stamp is not 64-bit integer nanoseconds")
            stamps[i] = stamp
        del pairs
        values = tuple(h["values"])
        if not all(v is None or isinstance(v, bool | int | float | str) for v in values):
            raise HandoffError("a signal value is not a plain value")
        clock = h.get("clock")
        if clock is not None:
            now, last = clock
            if not all(_stamp_or_none(t) for t in (now, *last)):
                raise HandoffError("a clock time is not integer nanoseconds")
            clock = (now, tuple(last))
        cut, last_released, valuation = h["cut"], h["lastReleased"], h["valuation"]
        if not _stamp(cut) or not _stamp_or_none(last_released):
            raise HandoffError("the cut or the last release is not 64-bit integer nanoseconds")
        wide = h.get("wide", 0)
        if not (isinstance(wide, int) and (wide == 0 or bits < wide <= 63)):
            raise HandoffError(f"letter width {_shown(wide)} out of range")
        if not (isinstance(valuation, int) and 0 <= valuation < 1 << (wide or bits)):
            raise HandoffError(
                f"valuation {_shown(valuation)} does not fit {wide or bits} placeholder bits"
            )
        return Snapshot(
            monitor=str(h["monitor"]),
            epoch=int(h["epoch"]),
            cut=cut,
            state=int(h["state"]),
            step=int(h["step"]),
            halted=bool(h["halted"]),
            values=values,
            valuation=valuation,
            last_released=last_released,
            late_events=int(h["late"]),
            bits=bits,
            letters=letters,
            stamps=stamps,
            clock=clock,
            past=h.get("past"),
            wide=wide,
        )
    except HandoffError:
        raise
    except (ValueError, KeyError, TypeError, OverflowError) as exc:  # Overflow: int(inf)
        raise HandoffError(f"malformed snapshot: {exc}"[:300]) from None
    except RecursionError:
        raise HandoffError("malformed snapshot: its header is nested too deep") from None
