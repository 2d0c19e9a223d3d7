"""Several recorded runs checked as one: bags and JSON Lines traces merged in stamp order.

``edgerv check monitors.yaml a.mcap b/ c.jsonl`` and ``edgerv check monitors.yaml
recordings/`` (a directory of bags) check one run made of every event of every trace:
each trace's events keep their order, and between traces the event with the smallest
timestamp comes first (equal timestamps: the trace named first). Two bags recorded side
by side (one per robot subsystem) are thus checked as if one recorder had taken both,
and consecutive recordings one after the other. A trace whose events are not in
timestamp order is merged as it is (its own order kept), as the sort window of each
monitor would see it live. One trace is read exactly as :class:`Trace` reads it.
"""

from __future__ import annotations

import heapq
from collections import Counter
from collections.abc import Collection, Iterator, Mapping, Sequence
from operator import attrgetter
from pathlib import Path

from edgerv.core.bags import STORAGE_SUFFIXES
from edgerv.core.diagnostics import Diagnostic, InputError, Location
from edgerv.core.traces import Progress, Trace, TraceEvent, TraceEvents, chunks_of

_STAMP = attrgetter("stamp")


def expand(paths: Sequence[Path]) -> list[Path]:
    """The traces named: each path as it is, except a directory that is not a bag itself
    (no metadata.yaml, no .mcap or .db3 file in it: those make one bag, rosbag2's split
    files): its bags (the subdirectories that are) and its .jsonl traces and compressed
    storage files (.mcap.zstd, .db3.zstd), by name. A directory holding none is an error
    naming it, as is one that cannot be read."""
    try:
        return _expand(paths)
    except OSError as exc:
        where = str(exc.filename) if exc.filename else str(paths[0])
        raise InputError(
            [Diagnostic(Location(where), f"cannot read it: {exc.strerror or exc}")]
        ) from None


def _expand(paths: Sequence[Path]) -> list[Path]:
    out: list[Path] = []
    for path in paths:
        if not path.is_dir() or _is_bag_directory(path):
            out.append(path)
            continue
        found = sorted(
            p
            for p in path.iterdir()
            if (p.is_dir() and _is_bag_directory(p))
            or (p.is_file() and p.name.endswith((".jsonl", ".mcap.zstd", ".db3.zstd")))
        )
        if not found:
            raise InputError(
                [
                    Diagnostic(
                        Location(str(path)),
                        "a directory without metadata.yaml, storage files (.mcap, .db3), "
                        "bags or .jsonl traces in it",
                        hint="give a rosbag2 bag (its directory, or its .mcap or .db3 file), "
                        "a .jsonl trace, or a directory of them",
                    )
                ]
            )
        out += found
    seen: set[Path] = set()
    for path in out:
        if path.resolve() in seen:
            raise InputError(
                [
                    Diagnostic(
                        Location(str(path)), "this trace is named twice: it would be checked twice"
                    )
                ]
            )
        seen.add(path.resolve())
    return out


def _is_bag_directory(path: Path) -> bool:
    return (path / "metadata.yaml").exists() or any(
        p.suffix in STORAGE_SUFFIXES for p in path.iterdir()
    )


class TraceSet:
    """The traces of one check, with :class:`Trace`'s face: one is read as it is, several
    merged in stamp order (their messages then decoded whole, a trace at a time)."""

    def __init__(self, paths: Sequence[Path]) -> None:
        self.traces = [Trace(p) for p in paths]
        shown = ", ".join(map(str, paths[:3]))
        self.name = shown if len(paths) <= 3 else f"{shown} and {len(paths) - 3} more"

    @property
    def ends_needed(self) -> bool:
        """Whether the end of the traces' time is read from topics no monitor reads."""
        return all(t.ends_needed for t in self.traces)

    @ends_needed.setter
    def ends_needed(self, needed: bool) -> None:
        for trace in self.traces:
            trace.ends_needed = needed

    @property
    def counts(self) -> Counter[str]:
        total: Counter[str] = Counter()
        for trace in self.traces:
            total.update(trace.counts)
        return total

    @property
    def warnings(self) -> list[Diagnostic]:
        """What the traces' reading found to warn about (a stamp's unit)."""
        return [w for trace in self.traces for w in trace.warnings]

    @property
    def end(self) -> int | None:
        ends = [t.end for t in self.traces if t.end is not None]
        return max(ends) if ends else None

    @property
    def msgtypes(self) -> dict[str, str]:
        """Each bag topic's message type; a topic that two bags record as different types
        is an error naming both."""
        types: dict[str, str] = {}
        where: dict[str, Trace] = {}
        errors = []
        for trace in self.traces:
            for topic, msgtype in trace.msgtypes.items():
                if types.setdefault(topic, msgtype) != msgtype:
                    errors.append(
                        Diagnostic(
                            Location(str(trace.path)),
                            f"{topic} is recorded as {msgtype} here and as {types[topic]} "
                            f"in {where[topic].path}",
                            hint="check these traces separately",
                        )
                    )
                where.setdefault(topic, trace)
        if errors:
            raise InputError(errors)
        return types

    def open(self) -> None:
        for trace in self.traces:
            trace.open()

    def close(self) -> None:
        for trace in self.traces:
            trace.close()

    def inspect(self, topics: Collection[str]) -> int:
        return sum(trace.inspect(topics) for trace in self.traces)

    def events(
        self,
        topics: Collection[str],
        progress: Progress | None = None,
        fields: Mapping[str, Sequence[str]] | None = None,
    ) -> TraceEvents:
        if len(self.traces) == 1:
            return self.traces[0].events(topics, progress, fields)
        streams = [iter(t.events(topics, progress)) for t in self.traces]
        return TraceEvents(chunks_of(_merged(streams)))

    def unread(self, readers: Mapping[str, Collection[str]]) -> list[Diagnostic]:
        """A warning for each monitored topic of which no trace gave an event, saying what
        the first trace that has other topics has instead."""
        if len(self.traces) == 1:
            return self.traces[0].unread(readers)
        counts = self.counts
        out = []
        for topic in sorted(t for t in readers if not counts[t]):
            hints = [(t.path, t.instead(topic)) for t in self.traces]
            path, hint = next(
                ((p, h) for p, h in hints if not h.startswith("the trace holds no")), hints[0]
            )
            out.append(
                Diagnostic(
                    Location(self.name),
                    f"no message on {topic} was read from any of the {len(self.traces)} "
                    f"traces (monitors reading it: {', '.join(sorted(readers[topic]))})",
                    severity="warning",
                    hint=f"{path}: {hint}",
                )
            )
        return out


def _merged(streams: list[Iterator[TraceEvent]]) -> Iterator[TraceEvent]:
    """The streams' events by stamp, each stream's order kept, ties to the first stream."""
    return heapq.merge(*streams, key=_STAMP)
