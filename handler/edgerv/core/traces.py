"""Recorded runs: JSON Lines traces and rosbag2 bags (MCAP or sqlite3), streamed.

A JSON Lines trace holds one event per line::

    {"topic": "/speed", "stamp": 1700000000023000000, "msg": {"data": 17.3}}

``stamp`` is integer nanoseconds; it may be left out when ``msg.header.stamp``
is present, which takes precedence either way (the same rule as the live
handler: a message's own header stamp, else when it was published).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from edgerv.core.diagnostics import Diagnostic, InputError, Location
from edgerv.core.msgtypes import typestore
from edgerv.core.pipeline import header_stamp

Progress = Callable[[int], None]  # advance by n units (bytes or messages)
STAMPS = range(-(2**63), 2**63)  # a stamp is signed 64-bit nanoseconds, as ROS time is


@dataclass(frozen=True)
class TraceEvent:
    topic: str
    stamp: int
    msg: Any
    where: Location  # the line of a JSON trace, or the message's index in a bag


class Trace:
    """A recorded run opened for streaming."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.is_bag = path.is_dir() or path.suffix in (".mcap", ".db3", ".bag")
        self.msgtypes: dict[str, str] = {}  # topic -> message type, for bags
        # The latest time the trace shows as passed: the largest stamp of any of its
        # events, read or not (a bag: also its last message's log time). Monitors with
        # timed atoms take their clock steps up to it at the end of a check.
        self.end: int | None = None

    def _saw(self, stamp: int) -> None:
        if self.end is None or stamp > self.end:
            self.end = stamp

    def events(
        self, topics: Collection[str], progress: Progress | None = None
    ) -> Iterator[TraceEvent]:
        if self.is_bag:
            return self._bag_events(topics, progress)
        return self._jsonl_events(topics, progress)

    # -- JSON Lines --------------------------------------------------------------------------

    def _jsonl_events(
        self, topics: Collection[str], progress: Progress | None
    ) -> Iterator[TraceEvent]:
        path = str(self.path)
        try:
            handle = self.path.open("rb")
        except OSError as exc:
            raise InputError(
                [Diagnostic(Location(path), f"cannot read trace: {exc.strerror}")]
            ) from None
        with handle:
            for lineno, raw in enumerate(handle, start=1):
                if progress:
                    progress(len(raw))
                if not raw.strip():
                    continue
                event = _jsonl_event(path, lineno, raw, topics, self._saw)
                if event is not None:
                    yield event

    # -- rosbag2 -----------------------------------------------------------------------------

    def _bag_events(
        self, topics: Collection[str], progress: Progress | None
    ) -> Iterator[TraceEvent]:
        from rosbags.highlevel import AnyReader

        path = str(self.path)
        try:
            reader = AnyReader([self._bag_target()], default_typestore=typestore())
            reader.open()
        except Exception as exc:  # rosbags raises several error types for unreadable bags
            raise InputError(
                [
                    Diagnostic(
                        Location(path),
                        f"cannot read bag: {exc}",
                        hint="give a rosbag2 directory, .mcap or .db3 file",
                    )
                ]
            ) from None
        try:
            self._saw(reader.end_time - 1)  # rosbags: the instant after the last message
            conns = [c for c in reader.connections if c.topic in topics]
            index = 0
            messages = reader.messages(connections=conns)
            while True:
                try:
                    conn, log_time, raw = next(messages)
                    msg = reader.deserialize(raw, conn.msgtype)
                except StopIteration:
                    break
                except Exception as exc:
                    where = Location(path, index + 1) if index else Location(path)
                    raise InputError(
                        [
                            Diagnostic(
                                where,
                                f"bag is damaged after message {index}: {exc}",
                                hint="verdicts above cover the messages before it",
                            )
                        ]
                    ) from None
                index += 1
                if progress:
                    progress(1)
                stamp = log_time if (stamp := header_stamp(msg)) is None else stamp
                if stamp not in STAMPS:
                    raise InputError(
                        [
                            Diagnostic(
                                Location(path, index),
                                f"message {index} on {conn.topic} is stamped {stamp} ns, "
                                "out of the range of 64-bit nanoseconds",
                            )
                        ]
                    )
                self._saw(stamp)
                yield TraceEvent(conn.topic, stamp, msg, Location(path, index))
        finally:
            reader.close()

    def inspect(self, topics: Collection[str]) -> int:
        """Read a bag's index (its topics' types into ``msgtypes``); return the progress total:
        bytes for a JSON trace, monitored messages for a bag."""
        if not self.path.exists():
            raise InputError([Diagnostic(Location(str(self.path)), "no such file or directory")])
        if not self.is_bag:
            return self.path.stat().st_size
        from rosbags.highlevel import AnyReader

        try:
            with AnyReader([self._bag_target()], default_typestore=typestore()) as reader:
                self.msgtypes = {c.topic: c.msgtype for c in reader.connections}
                total: int = sum(c.msgcount for c in reader.connections if c.topic in topics)
        except Exception as exc:  # rosbags raises several error types for unreadable bags
            raise InputError(
                [
                    Diagnostic(
                        Location(str(self.path)),
                        f"cannot read bag: {exc}",
                        hint="give a rosbag2 directory, or its .mcap or .db3 file",
                    )
                ]
            ) from None
        return total

    def _bag_target(self) -> Path:
        if self.path.suffix == ".db3" and (self.path.parent / "metadata.yaml").exists():
            return self.path.parent  # a sqlite3 bag is read through its directory
        return self.path


def _jsonl_event(
    path: str, lineno: int, raw: bytes, topics: Collection[str], saw: Callable[[int], None]
) -> TraceEvent | None:
    text = raw.decode("utf-8", errors="replace").rstrip("\r\n")

    def fail(message: str, col: int | None = None) -> InputError:
        loc = Location(path, lineno, col, 1, text if col else None)
        return InputError([Diagnostic(loc, message)])

    try:
        record = json.loads(text)
    except json.JSONDecodeError as exc:
        raise fail(f"invalid JSON: {exc.msg}", exc.pos + 1) from None
    except ValueError:  # Python reads no integer of more than 4,300 digits
        raise fail("invalid JSON: a number too long to read") from None
    except RecursionError:  # Python's parser recurses per level: thousands are too many
        raise fail("nested too deep to read (a message has a few levels)") from None
    if not isinstance(record, dict):
        raise fail("each line must be a JSON object with topic, stamp and msg")
    topic = record.get("topic")
    if not isinstance(topic, str):
        raise fail("missing 'topic' (a string such as \"/speed\")")
    if topic not in topics:  # not read, but it shows that time passed
        other = record.get("msg")
        shown = header_stamp(other) if isinstance(other, dict) else None
        shown = record.get("stamp") if shown is None else shown
        if isinstance(shown, int) and not isinstance(shown, bool) and shown in STAMPS:
            saw(shown)
        return None
    msg = record.get("msg")
    if not isinstance(msg, dict):
        raise fail("missing 'msg' (the message as a JSON object, e.g. {\"data\": 1.5})")
    stamp = header_stamp(msg)
    if stamp is None:
        stamp = record.get("stamp")
        if isinstance(stamp, bool) or not isinstance(stamp, int):
            raise fail("missing 'stamp' (integer nanoseconds) and msg has no header.stamp")
    if stamp not in STAMPS:
        raise fail(f"stamp {stamp} is out of the range of 64-bit nanoseconds")
    saw(stamp)
    return TraceEvent(topic, stamp, msg, Location(path, lineno))
