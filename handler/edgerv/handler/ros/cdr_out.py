"""The messages the handler publishes most, serialized to CDR here: what rclpy's serializer
gives (tests/integration/test_ros_outputs.py, test_typed_verdicts.py), at a fraction of
its cost (rclpy builds a Python object per field, then converts each to C). Pure: no ROS.

``diagnostic_msgs/msg/DiagnosticArray`` (/diagnostics) and edgerv_msgs' ``Verdict`` and
``VerdictArray`` (/edgerv/verdict, /edgerv/last_verdicts), little endian.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence

from edgerv.handler.health import Status, breathing

_U32 = struct.Struct("<I").pack
_STAMP = struct.Struct("<iI").pack
_NULS = tuple(bytes(n) for n in range(5))


def _cdr_string(text: str) -> bytes:
    """A CDR string, padded after it to a multiple of 4 bytes (what the next string or
    count needs): its length with the NUL, its bytes, the NUL, the padding."""
    data = text.encode()
    size = len(data) + 1
    return _U32(size) + data + _NULS[1 + -size % 4]


def encode_diagnostic_array(
    statuses: Sequence[Status], stamp_ns: int, breathe: Callable[[], None] | None = None
) -> bytes:
    """``diagnostic_msgs/msg/DiagnosticArray`` as CDR (little endian): the message rclpy's
    own serializer gives (tests/integration/test_ros_outputs.py), at a fraction of its
    cost (rclpy builds a Python object per KeyValue, then converts each to C).

    Strings and counts are 4-byte aligned; only a status's level (one byte) is not, so
    every string is written with the padding after it that the next one needs, except a
    status's last, after which the next status's level follows at once. ``breathe``:
    called every BREATH_EVERY statuses (health.Breather: the work spread in time)."""
    seconds, nanoseconds = divmod(stamp_ns, 1_000_000_000)
    parts = [
        b"\x00\x01\x00\x00",  # the encapsulation: CDR, little endian
        _STAMP(seconds, nanoseconds),  # header.stamp
        _cdr_string(""),  # header.frame_id
        _U32(len(statuses)),
    ]
    append = parts.append
    known: dict[str, bytes] = {}  # keys, and values such as "0", repeat across statuses
    end = 0  # the offset after the last part, modulo 4
    for status in breathing(statuses, breathe):
        append(bytes((int(status.level),)) + _NULS[-(end + 1) % 4])
        for text in (status.name, status.message, status.hardware_id):
            append(known.get(text) or known.setdefault(text, _cdr_string(text)))
        values = status.values
        append(_U32(len(values)))
        end = 0
        for key, value in values:
            append(known.get(key) or known.setdefault(key, _cdr_string(key)))
            append(known.get(value) or known.setdefault(value, _cdr_string(value)))
        if values:  # the last string without its padding
            size = len(value.encode()) + 1
            parts[-1] = parts[-1][: len(parts[-1]) - -size % 4]
            end = size % 4
    return b"".join(parts)


def restamp_diagnostic_array(data: bytes, stamp_ns: int) -> bytes:
    """``data`` (:func:`encode_diagnostic_array`'s) with ``stamp_ns`` as its header.stamp."""
    seconds, nanoseconds = divmod(stamp_ns, 1_000_000_000)
    return data[:4] + _STAMP(seconds, nanoseconds) + data[12:]


# -- edgerv_msgs: Verdict, VerdictArray ----------------------------------------------------

_U64 = struct.Struct("<Q").pack
CDR_LE = b"\x00\x01\x00\x00"  # the encapsulation: CDR, little endian
_U64_MAX = 2**64 - 1
# an edgerv_msgs/msg/Verdict's fields: monitor, verdict, stamp (ns), step, handler,
# assertion, epoch
VerdictFields = tuple[str, str, int, int, str, str, int]


def encode_verdict(
    monitor: str,
    verdict: str,
    stamp_ns: int,
    step: int,
    handler: str,
    assertion: str,
    epoch: int,
    at: int = 0,
) -> bytes:
    """One ``edgerv_msgs/msg/Verdict`` as CDR (little endian), without the encapsulation,
    at offset ``at`` (0 or 4 modulo 8) of the message it is in: its two uint64 (step,
    epoch) align to 8 from the message's start. It ends 8-aligned (with epoch), so in a
    VerdictArray every verdict after the first starts at 0 modulo 8: the bytes encoded for
    /edgerv/verdict are kept and joined as they are (:func:`encode_verdict_array`).
    The same bytes as rclpy's serializer (tests/integration/test_typed_verdicts.py)."""
    seconds, nanoseconds = divmod(stamp_ns, 1_000_000_000)
    head = _cdr_string(monitor) + _cdr_string(verdict) + _STAMP(seconds, nanoseconds)
    tail = _cdr_string(handler) + _cdr_string(assertion)
    to_step = -(at + len(head)) % 8  # 0 or 4: every part is 4-aligned
    to_epoch = -(at + len(head) + to_step + 8 + len(tail)) % 8
    return b"".join(
        (
            head,
            _NULS[to_step],
            _U64(min(max(step, 0), _U64_MAX)),
            tail,
            _NULS[to_epoch],
            _U64(min(max(epoch, 0), _U64_MAX)),  # (an epoch is any integer a driver sent)
        )
    )


def encode_verdict_message(fields: VerdictFields) -> bytes:
    """A whole ``edgerv_msgs/msg/Verdict`` message (what rclpy's serialize_message gives)."""
    return CDR_LE + encode_verdict(*fields)


def encode_verdict_array(
    stamp_ns: int,
    handler: str,
    verdicts: Sequence[VerdictFields],
    encoded: Sequence[bytes] | None = None,
) -> bytes:
    """``edgerv_msgs/msg/VerdictArray`` as CDR (little endian). ``encoded``: each verdict's
    :func:`encode_verdict` at offset 0, where kept; only the first is encoded again, when
    it starts at 4 modulo 8 (after the stamp, the handler's name and the count)."""
    seconds, nanoseconds = divmod(stamp_ns, 1_000_000_000)
    head = _STAMP(seconds, nanoseconds) + _cdr_string(handler) + _U32(len(verdicts))
    parts = [CDR_LE, head]
    parts += encoded if encoded is not None else [encode_verdict(*f) for f in verdicts]
    if verdicts and len(head) % 8:
        parts[2] = encode_verdict(*verdicts[0], at=len(head))
    return b"".join(parts)
