"""The assertion's words: tokens with their place, durations, and the size limits.

A token is one word, number, duration (``500ms``: a number and its unit, written
together), string, bracket (``[0..1s]``, ``[*2]``: one token, read by whoever takes
it) or operator (the longest that matches). :func:`check_size` refuses, at its
place, an assertion nested or chained deeper than the rest can take.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from fractions import Fraction
from typing import Literal, Protocol


class Fail(Protocol):
    """Reports an error at ``length`` characters from ``start`` in the assertion."""

    def __call__(
        self, start: int, length: int, message: str, hint: str | None = None, /
    ) -> None: ...


# Implication and equivalence in all of Spot's spellings, and the SERE implications.
_IMPLIES = ["<==>", "<-->", "<=>", "<->", "==>", "-->", "|->", "|=>", "->", "=>"]
# Longest first: the lexer takes the longest operator that matches.
_OPERATORS = sorted(
    [
        *_IMPLIES,
        "<>",
        "<=",
        ">=",
        "==",
        "!=",
        "&&",
        "||",
        "<",
        ">",
        "=",
        "&",
        "|",
        "!",
        "^",
        ";",
        ":",
        "(",
        ")",
        "{",
        "}",
        "-",
        "+",
        "*",
        ",",
    ],
    key=len,
    reverse=True,
)
CMP_TOKENS = {"<", "<=", ">", ">=", "==", "=", "!="}
SPOT_WORDS = {"G", "F", "X", "U", "W", "R", "M", "xor", "true", "false"}
_PSL_WORDS = {"always", "never", "eventually", "next", "next_e", "next_a", "until", "before"}
_PAST_UNARY = {"once", "historically", "prev"}
NUMBER = re.compile(r"(\d+\.?\d*(?:[eE][+-]?\d+)?|\.\d+(?:[eE][+-]?\d+)?)")
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
# Durations: a number and its unit, written together (500ms, 1.5s, 2min); nanoseconds.
UNITS = {"ns": 1, "us": 1_000, "ms": 1_000_000, "s": 1_000_000_000, "min": 60_000_000_000}
UNIT_LIST = ", ".join(UNITS)
TIMED_BOUND = re.compile(r"\d\s*(?!to\b)[A-Za-z]")  # an interval bound with a unit: [0..500ms]


MAX_DURATION = 2**63 - 1  # ns (about 292 years): what 64-bit stamps can tell apart


def duration_ns(text: str) -> int | None:
    """The nanoseconds of a duration token (``1.5s``), or None if it is not a whole number
    of nanoseconds up to :data:`MAX_DURATION` or its unit is unknown."""
    m = NUMBER.match(text)
    if m is None or text[m.end() :] not in UNITS:
        return None
    digits, _, exponent = m.group().lower().partition("e")
    if len(digits) > 40 or len(exponent.lstrip("+-").lstrip("0")) > 2:
        return None  # out of range (1e9999999s would take Fraction seconds to compute)
    ns = Fraction(m.group()) * UNITS[text[m.end() :]]
    return int(ns) if ns.denominator == 1 and ns <= MAX_DURATION else None


@dataclass(frozen=True)
class Token:
    kind: Literal["ident", "number", "duration", "string", "bracket", "op"]
    text: str
    start: int
    end: int


def tokenize(text: str, fail: Callable[[int, int, str, str | None], None]) -> list[Token]:
    tokens: list[Token] = []
    i, n = 0, len(text)
    while i < n:
        ch = text[i]
        if ch.isspace():
            i += 1
            continue
        if ch == '"':
            j = text.find('"', i + 1)
            if j < 0:
                fail(i, n - i, "unterminated string", 'close it with "')
                return tokens
            tokens.append(Token("string", text[i : j + 1], i, j + 1))
            i = j + 1
            continue
        if ch == "[":
            j = text.find("]", i + 1)
            if j < 0:
                fail(i, 1, "unclosed '['", "close it with ']'")
                return tokens
            tokens.append(Token("bracket", text[i : j + 1], i, j + 1))
            i = j + 1
            continue
        m = NUMBER.match(text, i)
        if m and (ch.isdigit() or ch == "."):
            unit = _IDENT.match(text, m.end())
            if unit is None:
                tokens.append(Token("number", m.group(), i, m.end()))
                i = m.end()
                continue
            whole = text[i : unit.end()]
            if unit.group() not in UNITS:
                fail(
                    unit.start(),
                    unit.end() - unit.start(),
                    f"unknown unit '{unit.group()}' in '{whole}'",
                    f"a duration's unit is one of {UNIT_LIST}, e.g. 500ms",
                )
            elif duration_ns(whole) is None:
                fail(
                    i,
                    len(whole),
                    f"'{whole}' is not a whole number of nanoseconds"
                    " (up to 2^63 - 1 ns, about 292 years)",
                    None,
                )
            tokens.append(Token("duration", whole, i, unit.end()))  # also when bad: one error
            i = unit.end()
            continue
        m = _IDENT.match(text, i)
        if m:
            j = m.end()
            word = m.group()
            if word in _PSL_WORDS and j < n and text[j] == "!":
                j += 1
                if word in ("until", "before") and j < n and text[j] == "_":
                    j += 1
            elif word in ("until", "before") and j < n and text[j] == "_":
                j += 1
            tokens.append(Token("ident", text[i:j], i, j))
            i = j
            continue
        for op in _OPERATORS:
            if text.startswith(op, i):
                tokens.append(Token("op", op, i, i + len(op)))
                i += len(op)
                break
        else:
            fail(i, 1, f"unexpected character '{ch}'", None)
            i += 1
    return tokens


MAX_NESTING = 1_000  # brackets in brackets
MAX_OPERATORS = 4_000  # operators in all: a chain of them (! ! a, a U b U c) nests too

_OPERATOR_WORDS = {*SPOT_WORDS, *_PSL_WORDS, *_PAST_UNARY, "since", "until!", "until_",
                   "until!_", "before!", "before_", "before!_", "next!", "next_e!",
                   "next_a!", "eventually!"}  # fmt: skip


def check_size(tokens: Sequence[Token], fail: Fail) -> None:
    """Refuse, at its place, an assertion nested or chained deeper than Spot's recursion
    can take (its process dies, or this one, from 10,000 levels on)."""
    depth = operators = 0
    for t in tokens:
        if t.kind == "op" and t.text in "({":
            depth += 1
            if depth > MAX_NESTING:
                fail(t.start, 1, f"brackets nested more than {MAX_NESTING:,} deep",
                     "split the assertion into several monitors")  # fmt: skip
                return
        elif t.kind == "op" and t.text in ")}":
            depth -= 1
        elif t.kind == "op" or (t.kind == "ident" and t.text in _OPERATOR_WORDS):
            operators += 1
            if operators > MAX_OPERATORS:
                fail(t.start, t.end - t.start,
                     f"more than {MAX_OPERATORS:,} operators in one assertion",
                     "split the assertion into several monitors")  # fmt: skip
                return
