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
        lines = [f"{self.location}: {self.severity}: {self.message}"]
        loc = self.location
        if loc.source_line is not None and loc.col is not None:
            text = loc.source_line.rstrip("\n")
            lines.append(f"    {text}")
            lines.append("    " + " " * (loc.col - 1) + "^" * max(1, loc.length))
        if self.hint:
            lines.append(f"  hint: {self.hint}")
        return "\n".join(lines)


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
