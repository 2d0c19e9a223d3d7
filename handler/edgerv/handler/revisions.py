"""What changed in a listing since its reader last read it: ``?since=CURSOR`` on ``GET
/v1/monitors`` and ``GET /v1/load`` (docs/protocol.md, "Reading only what changed").

A cloud handler serving a fleet defines an instance of every Monitor for every robot
(20,000 at 100 robots and 200 Monitors), nearly all of them idle there; the operator
reads its listing and its load report every few seconds. Parsed whole each time, those
dominate an operator round and grow with robots x Monitors. With a cursor, a reader
gets only the entries whose report changed since it read (an idle instance's does
not), and the names of those that went; it keeps the rest from its last reading.

Each reading compares every entry with the one last sent (a dict's equality: a few
microseconds each, on the handler's worker thread) rather than trusting every place
that changes a monitor to say so: an entry is resent exactly when what the reader
would see differs. A cursor is ``BOOT.REVISION``: a cursor of another boot of the
handler (it restarted), from the future, or older than the removals it still remembers
gets the whole listing, as a reader without one does."""

from __future__ import annotations

import secrets
import threading
from collections.abc import Mapping
from typing import Any

REMEMBERED = 100_000  # removals remembered; a reader further behind reads everything


class Revisions:
    """One listing's entries by name, each with the revision it last changed at."""

    def __init__(self, remembered: int = REMEMBERED) -> None:
        self.boot = secrets.token_hex(6)  # a restarted handler's cursors are not these
        self.revision = 0
        self.remembered = remembered
        self._kept: dict[str, tuple[int, Any]] = {}  # name -> (revision, entry last sent)
        self._gone: dict[str, int] = {}  # name -> revision it went at, oldest first
        self._floor = 0  # removals up to this revision are forgotten
        self._lock = threading.Lock()  # (readers come on the API's worker threads)

    @property
    def cursor(self) -> str:
        return f"{self.boot}.{self.revision}"

    def read(
        self, entries: Mapping[str, Any], since: str | None
    ) -> tuple[dict[str, Any], list[str] | None, str]:
        """``entries``: the whole listing now, by name. Returns what to send (every entry
        whose value changed after ``since``, or all of them), the names removed after
        ``since`` (None: the answer is the whole listing, ``since`` was not honoured),
        and the cursor to read from next time."""
        with self._lock:
            self._note(entries)
            base = self._base(since)
            if base is None:
                return dict(entries), None, self.cursor
            changed = {n: value for n, (r, value) in self._kept.items() if r > base}
            removed = [n for n, r in self._gone.items() if r > base]
            return changed, removed, self.cursor

    def _note(self, entries: Mapping[str, Any]) -> None:
        rev = self.revision + 1
        kept, gone = self._kept, self._gone
        touched = False
        for name, value in entries.items():
            last = kept.get(name)
            if last is None or last[1] != value:
                kept[name] = (rev, value)
                gone.pop(name, None)  # (back again: its going is no news any more)
                touched = True
        if len(kept) > len(entries):
            for name in [n for n in kept if n not in entries]:
                del kept[name]
                gone[name] = rev
                touched = True
            while len(gone) > self.remembered:
                oldest = next(iter(gone))
                self._floor = max(self._floor, gone.pop(oldest))
        if touched:
            self.revision = rev

    def _base(self, since: str | None) -> int | None:
        """The revision a reader's cursor stands for, if this handler can answer from it."""
        if since is None:
            return None
        boot, _, revision = since.partition(".")
        if boot != self.boot or not (revision.isascii() and revision.isdigit()):
            return None
        base = int(revision)
        return base if self._floor <= base <= self.revision else None
