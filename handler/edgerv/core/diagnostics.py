"""Diagnostics that name the place: ``FILE:LINE:COL: error: ...`` plus a caret line.

Every bad input (an assertion, a Monitor document, a trace) is reported as a
:class:`Diagnostic`. Code that finds problems collects them and raises
:class:`InputError` with all of them at once, so a user fixes a file in one pass.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Literal

Severity = Literal["error", "warning"]


@dataclass(frozen=True)
class Location:
    """A place in a file: 1-based line and column; ``length`` characters are marked."""

    path: str
    line: int | None = None
    col: int | None = None
    length: int = 1
    source_line: str | None = None  # the text of that line, for the caret display

    def __str__(self) -> str:
        if self.line is None:
            return self.path
        if self.col is None:
            return f"{self.path}:{self.line}"
        return f"{self.path}:{self.line}:{self.col}"


@dataclass(frozen=True)
class Diagnostic:
    location: Location
    message: str
    severity: Severity = "error"
    hint: str | None = None

    def render(self) -> str:
        """The diagnostic as a terminal shows it: what it quotes of the input shortened
        (:data:`MAX_QUOTED` characters of the line around the place) and its control
        characters escaped, so a bad line of megabytes or escape sequences prints as a
        line of text."""
        message = printable(self.message, MAX_MESSAGE)
        lines = [f"{printable(str(self.location), MAX_MESSAGE)}: {self.severity}: {message}"]
        loc = self.location
        if loc.source_line is not None and loc.col is not None:
            text, caret, marked = _excerpt(loc.source_line.rstrip("\n"), loc.col - 1, loc.length)
            lines.append(f"    {text}")
            lines.append("    " + " " * caret + "^" * max(1, marked))
        if self.hint:
            lines.append(f"  hint: {printable(self.hint, MAX_MESSAGE)}")
        return "\n".join(lines)


MAX_QUOTED = 200  # characters of a source line shown around the place
MAX_MESSAGE = 1_000  # characters of a message or hint


def _escaped(ch: str) -> str:
    code = ord(ch)
    if code < 0x20 or 0x7F <= code < 0xA0 or code in (0x2028, 0x2029):
        return (
            "\\t"
            if ch == "\t"
            else "\\n"
            if ch == "\n"
            else f"\\x{code:02x}"
            if code < 0x100
            else f"\\u{code:04x}"
        )
    return ch


def printable(text: str, limit: int) -> str:
    """``text`` with control characters escaped (``\\x1b``), cut at ``limit``
    characters with a note of how much was left out."""
    cut = text[:limit]
    shown = "".join(map(_escaped, cut)) if not cut.isprintable() else cut
    return shown if len(text) <= limit else f"{shown}... ({len(text) - limit:,} more characters)"


def _excerpt(line: str, at: int, length: int) -> tuple[str, int, int]:
    """At most :data:`MAX_QUOTED` characters of ``line`` around offset ``at``, escaped:
    the text, the caret's column in it and how many characters it marks."""
    at = max(0, min(at, len(line)))
    start = max(0, min(at - MAX_QUOTED // 2, len(line) - MAX_QUOTED))
    end = min(len(line), start + MAX_QUOTED)
    stop = min(end, at + max(1, length))
    before, marked, after = (
        "".join(map(_escaped, part)) for part in (line[start:at], line[at:stop], line[stop:end])
    )
    head = "..." if start > 0 else ""
    tail = "..." if end < len(line) else ""
    return head + before + marked + after + tail, len(head) + len(before), max(1, len(marked))


class InputError(Exception):
    """Bad input: one or more error diagnostics (and possibly warnings)."""

    def __init__(self, diagnostics: Sequence[Diagnostic]) -> None:
        self.diagnostics = list(diagnostics)
        super().__init__("\n".join(d.render() for d in self.diagnostics))

    @property
    def errors(self) -> list[Diagnostic]:
        return [d for d in self.diagnostics if d.severity == "error"]


def did_you_mean(name: str, candidates: Iterable[str]) -> str | None:
    """A hint naming the closest candidates, or listing them when nothing is close."""
    names = sorted(set(candidates))
    if not names:
        return None
    close = difflib.get_close_matches(name, names, n=2, cutoff=0.6)
    if close:
        return "did you mean " + " or ".join(f"'{c}'" for c in close) + "?"
    return "known names: " + ", ".join(names)
