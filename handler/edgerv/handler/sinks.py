"""Where verdicts go besides ROS: a JSON Lines log, one verdict per line; a line on the
console (and /rosout) per violation, at most one a second per monitor."""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from edgerv.core.pipeline import Verdict
from edgerv.handler.outbox import Burst

violations_log = logging.getLogger("edgerv.handler.violations")
LINE_SECONDS = 1.0  # at most one violation line per monitor this often


def verdict_record(handler: str, v: Verdict) -> dict[str, object]:
    """The one shape of a verdict outside the handler (log line, ROS message, API)."""
    return {
        "monitor": v.monitor,
        "verdict": v.verdict,
        "stamp": v.stamp,
        "step": v.step,
        "handler": handler,
    }


class VerdictLog:
    """Appends ``{"monitor", "verdict", "stamp", "step", "handler"}`` lines, flushed per batch."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("a", encoding="utf-8")
        self._lock = threading.Lock()
        self._names: dict[str, str] = {}  # monitor -> its name as JSON

    def write(self, handler: str, verdicts: Sequence[Verdict]) -> None:
        # json.dumps(verdict_record(...)) byte for byte, each name escaped once (a verdict
        # storm writes hundreds of thousands a second: the log is its exact sink)
        names, h = self._names, json.dumps(handler)
        if len(names) > 100_000:
            names.clear()
        parts = []
        for v in verdicts:
            m = names.get(v.monitor)
            if m is None:
                m = names[v.monitor] = json.dumps(v.monitor)
            parts.append(
                f'{{"monitor": {m}, "verdict": "{v.verdict}", "stamp": {v.stamp}, '
                f'"step": {v.step}, "handler": {h}}}\n'
            )
        text = "".join(parts)
        with self._lock:
            self._file.write(text)
            self._file.flush()

    def close(self) -> None:
        with self._lock:
            self._file.flush()
            self._file.close()


@dataclass
class _Held:
    last: float  # when the monitor's last line was written (monotonic s)
    suppressed: int = 0  # its violations since, not written


class PerKeyLimit:
    """At most one line per key (a monitor) every ``period`` seconds; the ones held back
    are counted, and the count goes with the key's next line. Pure: the caller says the
    time."""

    def __init__(self, period: float = LINE_SECONDS) -> None:
        self.period = period
        self._held: dict[str, _Held] = {}

    def admit(self, key: str, now: float) -> int | None:
        """None: hold this one back (counted); else write it, after this many held back."""
        held = self._held.get(key)
        if held is None:
            self._held[key] = _Held(now)
            return 0
        if now - held.last < self.period:
            held.suppressed += 1
            return None
        suppressed, held.last, held.suppressed = held.suppressed, now, 0
        return suppressed

    def hold_back(self, key: str, n: int) -> None:
        """Count ``n`` more held back for ``key`` (a burst's violations between its ends)."""
        held = self._held.get(key)
        if held is not None:
            held.suppressed += n

    def pending(self) -> dict[str, int]:
        """The keys with lines held back since their last one, and how many."""
        return {k: h.suppressed for k, h in self._held.items() if h.suppressed}

    def forget(self, now: float) -> None:
        """Drop the keys that wrote nothing for a period and hold nothing back (a monitor
        removed, or quiet: its next line is written at once all the same)."""
        stale = [
            k for k, h in self._held.items() if not h.suppressed and now - h.last >= self.period
        ]
        for k in stale:
            del self._held[k]


def stamp_text(ns: int) -> str:
    """A stamp as seconds.nanoseconds."""
    sec, nanosec = divmod(ns, 1_000_000_000)
    return f"{sec}.{nanosec:09d}"


def violation_line(v: Verdict, topics: Sequence[str], suppressed: int = 0) -> str:
    """``monitor speed-limit violated at step 12 (stamp 1700000001.250000000) on /odom,
    /stop``, and the violations held back since the monitor's last line."""
    on = f" on {', '.join(topics)}" if topics else ""
    line = f"monitor {v.monitor} {v.verdict} at step {v.step} (stamp {stamp_text(v.stamp)}){on}"
    if suppressed:
        line += f" ({suppressed} more violation{'s' if suppressed > 1 else ''} since its last line)"
    return line


class ViolationLines:
    """A verdict sink: a WARNING line per violation (``edgerv.handler.violations``: the
    handler's stderr, and /rosout through the node's logger), at most one per monitor a
    second (:class:`PerKeyLimit`); the violations held back are counted in the
    monitor's next line, and those never followed by one are said at :meth:`close`.
    ``topics``: the topics of a monitor, by name (none for one removed since)."""

    def __init__(
        self,
        topics: Callable[[str], Sequence[str]],
        period: float = LINE_SECONDS,
        clock: Callable[[], float] = time.monotonic,
        log: logging.Logger = violations_log,
    ) -> None:
        self.topics = topics
        self.limit = PerKeyLimit(period)
        self.clock = clock
        self.log = log
        self._lock = threading.Lock()  # (the scheduler writes; close() comes at shutdown)
        self._forgot = 0.0

    def write(self, handler: str, verdicts: Sequence[Verdict]) -> None:
        lines = []
        with self._lock:
            now = self.clock()
            for v in verdicts:
                if v.verdict != "violated":
                    continue
                suppressed = self.limit.admit(v.monitor, now)
                if suppressed is not None:
                    lines.append(violation_line(v, self.topics(v.monitor), suppressed))
            if now - self._forgot >= 60 * self.limit.period:  # the dict stays small
                self._forgot = now
                self.limit.forget(now)
        for line in lines:
            self.log.warning("%s", line)

    def write_bursts(self, handler: str, bursts: Sequence[Burst[Verdict]]) -> None:
        """Bursts its lane coalesced: the first and last violation of each, as verdicts,
        and those between counted as held back (said in the monitor's next line)."""
        for b in bursts:
            self.write(handler, [b.first])
            if b.between and b.first.verdict == "violated":
                with self._lock:
                    self.limit.hold_back(b.monitor, b.between)
            if b.count > 1:
                self.write(handler, [b.last])

    def close(self) -> None:
        """Say the violations held back that no line followed."""
        with self._lock:
            pending = self.limit.pending()
            self.limit = PerKeyLimit(self.limit.period)
        for monitor, n in sorted(pending.items()):
            self.log.warning(
                "monitor %s: %d more violation%s since its last line",
                monitor,
                n,
                "s" if n > 1 else "",
            )
