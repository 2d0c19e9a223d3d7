"""Where verdicts go besides ROS: a JSON Lines log, one verdict per line."""

from __future__ import annotations

import json
import threading
from collections.abc import Sequence
from pathlib import Path

from edgerv.core.pipeline import Verdict


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

    def write(self, handler: str, verdicts: Sequence[Verdict]) -> None:
        text = "".join(json.dumps(verdict_record(handler, v)) + "\n" for v in verdicts)
        with self._lock:
            self._file.write(text)
            self._file.flush()

    def close(self) -> None:
        with self._lock:
            self._file.flush()
            self._file.close()
