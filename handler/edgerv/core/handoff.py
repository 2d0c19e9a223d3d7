"""What a monitor's handoff moves between handlers, where the cut falls, and its wire form.

The protocol (the paper's section V, Fig. 3; the network side belongs to the
migration work) hands a monitor from H1 to H2. This module is its data side:

* While the handoff runs, both handlers *hold* the monitor: they buffer its raw
  events without compressing or evaluating them (``MonitorRuntime.holding``).
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
* **The snapshot** (:func:`export_snapshot`): H1 compresses its held events
  ``<= T`` and sends the automaton state (one integer), the step counter, the
  signal values as of the cut (the next letter needs the last value of every
  signal), and the letters not yet evaluated, bit-packed.
* :func:`restore` builds H2's runtime: the snapshot's letters first, then H2's
  own events ``> T``. It ignores every later event stamped ``<= T`` too: H2 may
  not have taken all of its own events ``<= T`` yet when it adopts.

:func:`encode` and :func:`decode` give the snapshot's wire form: a JSON header,
the letters packed at ``bits`` bits each and the stamps delta-encoded, both
deflated. :func:`decode` checks everything and raises :class:`HandoffError`.
"""

from __future__ import annotations

import json
import struct
import zlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from edgerv.core.monitor import CompiledMonitor
from edgerv.core.pipeline import _UNSET, MonitorRuntime, Update

WIRE_VERSION = 1
_FRAME = struct.Struct("!4sII")  # magic, header length, body length
_MAGIC = b"ERV1"


class HandoffError(Exception):
    """A snapshot that cannot be used: what is wrong with it."""


@dataclass(frozen=True)
class Snapshot:
    monitor: str
    epoch: int  # fences stale handoffs: a handler ignores an epoch it has seen
    cut: int
    state: int
    step: int
    halted: bool
    values: tuple[Any, ...]  # per signal, None for "no value yet"
    valuation: int
    last_released: int | None
    late_events: int
    bits: int
    letters: tuple[int, ...]
    stamps: tuple[int, ...]


def cut_point(first_stamps: Mapping[str, int], topics: Iterable[str]) -> int | None:
    """The cut once H2 has an event on every topic of the monitor, else None (wait)."""
    firsts = []
    for topic in topics:
        if topic not in first_stamps:
            return None
        firsts.append(first_stamps[topic])
    return max(firsts) if firsts else None


def export_snapshot(rt: MonitorRuntime, cut: int, epoch: int) -> Snapshot:
    """H1's side: compress the held events up to the cut, drop the rest, take the state.

    Afterwards ``rt`` must not run any more: the monitor belongs to H2.
    """
    covered = [e for e in rt.events if e[0] <= cut]
    rt.events = covered
    rt.holding = False
    if covered:
        rt.flush()
    return Snapshot(
        monitor=rt.name,
        epoch=epoch,
        cut=cut,
        state=rt.state,
        step=rt.step,
        halted=rt.halted,
        values=tuple(None if v is _UNSET else v for v in rt.values),
        valuation=rt.valuation,
        last_released=rt.last_released,
        late_events=rt.late_events,
        bits=rt.monitor.table.bits,
        letters=tuple(rt.letters),
        stamps=tuple(rt.stamps),
    )


def restore(
    monitor: CompiledMonitor, snap: Snapshot, held: Sequence[tuple[int, int, Sequence[Update]]]
) -> MonitorRuntime:
    """H2's side: the monitor as H1 left it, then H2's own held events after the cut."""
    if snap.monitor != monitor.name:
        raise HandoffError(f"snapshot of '{snap.monitor}' given for '{monitor.name}'")
    table = monitor.table
    if snap.bits != table.bits or len(snap.values) != len(monitor.signal_names):
        raise HandoffError(
            f"snapshot of '{snap.monitor}' does not fit this definition "
            "(placeholders or signals differ): the handlers disagree on it"
        )
    if not 0 <= snap.state < table.states:
        raise HandoffError(f"automaton state {snap.state} out of range")
    rt = MonitorRuntime(monitor)
    rt.state, rt.step, rt.halted = snap.state, snap.step, snap.halted
    rt.values = [_UNSET if v is None else v for v in snap.values]
    rt.missing = sum(v is None for v in snap.values)
    rt.valuation = snap.valuation
    rt.last_released, rt.late_events = snap.last_released, snap.late_events
    rt.letters.extend(snap.letters)
    rt.stamps.extend(snap.stamps)
    # Events up to the cut are H1's, also those H2 has not taken yet (still in its queues)
    rt.floor = snap.cut
    rt.events = [e for e in held if e[0] > snap.cut]
    if len(rt.events) >= rt.threshold:
        rt.flush()
    return rt


# -- wire form -------------------------------------------------------------------------------


def _pack_letters(letters: Sequence[int], bits: int) -> bytes:
    acc = 0
    for i, letter in enumerate(letters):
        acc |= letter << (i * bits)
    return acc.to_bytes((len(letters) * bits + 7) // 8, "little")


def _unpack_letters(data: bytes, n: int, bits: int) -> list[int]:
    acc = int.from_bytes(data, "little")
    mask = (1 << bits) - 1
    return [(acc >> (i * bits)) & mask for i in range(n)]


def _varints(deltas: Iterable[int]) -> bytes:
    out = bytearray()
    for d in deltas:
        z = (d << 1) ^ (d >> 63)  # zigzag: small negative deltas stay small
        while True:
            byte = z & 0x7F
            z >>= 7
            out.append(byte | (0x80 if z else 0))
            if not z:
                break
    return bytes(out)


def _from_varints(data: bytes, n: int) -> list[int]:
    out, i, prev = [], 0, 0
    for _ in range(n):
        z = shift = 0
        while True:
            if i >= len(data):
                raise HandoffError("stamps are truncated")
            byte = data[i]
            i += 1
            z |= (byte & 0x7F) << shift
            shift += 7
            if not byte & 0x80:
                break
        prev += (z >> 1) ^ -(z & 1)
        out.append(prev)
    if i != len(data):
        raise HandoffError("stamps have trailing bytes")
    return out


def encode(snap: Snapshot) -> bytes:
    letters = zlib.compress(_pack_letters(snap.letters, snap.bits), 9)
    first = snap.stamps[0] if snap.stamps else 0
    deltas = [first] + [b - a for a, b in zip(snap.stamps, snap.stamps[1:], strict=False)]
    stamps = zlib.compress(_varints(deltas if snap.stamps else []), 9)
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
            "lettersLen": len(letters),
        },
        separators=(",", ":"),
    ).encode()
    body = letters + stamps
    return _FRAME.pack(_MAGIC, len(header), len(body)) + header + body


def _inflate(data: bytes, limit: int) -> bytes:
    """Decompress at most ``limit`` bytes: a hostile message cannot blow up memory."""
    d = zlib.decompressobj()
    out = d.decompress(data, limit + 1)
    if len(out) > limit or d.unconsumed_tail:
        raise HandoffError("a section inflates beyond its announced size")
    return out


def decode(data: bytes, max_letters: int = 1 << 24) -> Snapshot:
    """Parse and check a snapshot from the wire; raise :class:`HandoffError` if it is bad."""
    if len(data) < _FRAME.size:
        raise HandoffError("too short for a snapshot")
    magic, hlen, blen = _FRAME.unpack_from(data)
    if magic != _MAGIC:
        raise HandoffError("not an edgerv snapshot")
    if len(data) != _FRAME.size + hlen + blen:
        raise HandoffError("length does not match its frame")
    try:
        h = json.loads(data[_FRAME.size : _FRAME.size + hlen])
        if h.get("v") != WIRE_VERSION:
            raise HandoffError(f"wire version {h.get('v')} is not {WIRE_VERSION}")
        n, bits, llen = int(h["n"]), int(h["bits"]), int(h["lettersLen"])
        if not 0 <= n <= max_letters or not 0 <= bits <= 16 or not 0 <= llen <= blen:
            raise HandoffError("letter count, width or length out of range")
        body = data[_FRAME.size + hlen :]
        packed = _inflate(body[:llen], (n * bits + 7) // 8)
        if len(packed) != (n * bits + 7) // 8:
            raise HandoffError("letters do not have the announced size")
        letters = _unpack_letters(packed, n, bits)
        stamps = _from_varints(_inflate(body[llen:], 10 * n), n) if n else []
        values = tuple(h["values"])
        if not all(v is None or isinstance(v, bool | int | float | str) for v in values):
            raise HandoffError("a signal value is not a plain value")
        return Snapshot(
            monitor=str(h["monitor"]),
            epoch=int(h["epoch"]),
            cut=int(h["cut"]),
            state=int(h["state"]),
            step=int(h["step"]),
            halted=bool(h["halted"]),
            values=values,
            valuation=int(h["valuation"]),
            last_released=None if h["lastReleased"] is None else int(h["lastReleased"]),
            late_events=int(h["late"]),
            bits=bits,
            letters=tuple(letters),
            stamps=tuple(stamps),
        )
    except HandoffError:
        raise
    except (ValueError, KeyError, TypeError, zlib.error) as exc:
        raise HandoffError(f"malformed snapshot: {exc}") from None
