"""The brackets after operators: time bounds, step ranges and SERE repetitions.

A bracket is one token (``[0..500ms]``, ``[1..3]``, ``[*2..]``, ``[->]``); the
operator before it says which kind it must be. Each reader gives its values, or
None (False for :func:`repeat`) after reporting the error at the bracket.
"""

from __future__ import annotations

import re
from typing import Literal

from edgerv.core.language.lexer import NUMBER, TIMED_BOUND, Fail, Token, duration_ns
from edgerv.core.language.tree import UNBOUNDED, RepeatOp

MAX_REPEAT = 254  # Spot's largest step count or repetition
_STEP_RANGE = re.compile(
    r"\[\s*(\d*)\s*(?:(\.\.|:|,|\bto\b)\s*(\d+|\$|inf)?\s*)?(!)?\s*\]"
)  # [n], [n..m], [n:], [n..$], [!], [n!]
_REPEAT = re.compile(r"\[\s*(\*|:\*|\+|:\+|=|->)\s*(.*?)\s*\]", re.S)


def is_time_bound(bracket: Token) -> bool:
    """A bound with a unit (``[0..500ms]``), not a step range."""
    return TIMED_BOUND.search(bracket.text) is not None


def window(bracket: Token, fail: Fail) -> tuple[int, int] | None:
    """A time bound ``[a..b]`` or ``[a:b]``: durations (a bare 0 is zero), in ns."""
    text = bracket.text
    inner = text[1:-1]
    parts = inner.split("..") if ".." in inner else inner.split(":")
    bounds: list[int] = []
    for part in (p.strip() for p in parts):
        ns = 0 if part == "0" else duration_ns(part)
        if ns is None:
            break
        bounds.append(ns)
    if len(parts) != 2 or len(bounds) != 2:
        unitless = all(NUMBER.fullmatch(p.strip()) for p in parts)
        fail(bracket.start, len(text),
             "a past operator's interval counts time, not steps" if unitless
             else f"bad interval {text}: two durations, each with its unit",
             "e.g. once[0..2s] f, historically[100ms:1s] f")  # fmt: skip
        return None
    if bounds[0] > bounds[1]:
        fail(bracket.start, len(text), f"the interval {text} ends before it starts")
        return None
    return bounds[0], bounds[1]


def steps(bracket: Token, op: str, fail: Fail) -> tuple[int, int, bool] | None:
    """A step range: ``X[n]``, ``X[!]``, ``F[i..j]``, ``G[i..]`` (lo, hi, strong)."""
    m = _STEP_RANGE.fullmatch(bracket.text)
    hint = f"e.g. {op}[2] f" if op == "X" else f"e.g. {op}[1..3] f, {op}[2..] f"
    if m is None:
        _at_token(fail, bracket, f"bad step range {bracket.text} for {op}", hint)
        return None
    lo_s, sep, hi_s, bang = m.groups()
    if op == "X":
        if sep or (not lo_s and not bang):
            _at_token(fail, bracket, f"{op} takes one step count: {op}[n] or {op}[!]", hint)
            return None
        n = _count(bracket, lo_s or "1", fail)
        return None if n is None else (n, n, bool(bang))
    if not lo_s or not sep:
        _at_token(fail, bracket, f"{op}[..] takes two bounds", hint)
        return None
    lo = _count(bracket, lo_s, fail)
    hi = UNBOUNDED if hi_s in (None, "$", "inf") else _count(bracket, hi_s, fail)
    if lo is None or hi is None:
        return None
    if hi != UNBOUNDED and hi < lo:
        _at_token(fail, bracket, f"the range {bracket.text} ends before it starts")
        return None
    return lo, hi, bool(bang)


def repeat(t: Token, fail: Fail) -> tuple[RepeatOp, int, int] | Literal[False] | None:
    """A SERE repetition ``[*i..j]``, ``[+]``, ``[:*]``, ``[:+]``, ``[=i..j]``,
    ``[->i..j]`` (None if the bracket is not one; False after an error, if it is a bad one)."""
    m = _REPEAT.fullmatch(t.text)
    if m is None:
        return None
    kind, args = m.groups()
    if kind in ("+", ":+"):
        if args:
            _at_token(fail, t, f"[{kind}] takes no count", "write [*2..] for two or more")
            return "[*", 0, 0
        return ("[*" if kind == "+" else "[:*"), 1, UNBOUNDED
    op: RepeatOp = {"*": "[*", ":*": "[:*", "=": "[=", "->": "[->"}[kind]  # type: ignore[assignment]
    default_lo = 1 if op == "[->" else 0
    if not args:
        return (op, 1, 1) if op == "[->" else (op, 0, UNBOUNDED)
    rng = re.fullmatch(r"(\d*)\s*(?:(\.\.|:|,|\bto\b)\s*(\d+|\$|inf)?)?", args)
    if rng is None:
        _at_token(fail, t, f"bad repetition {t.text}", "e.g. a[*2..3], a[=2], a[->1..]")
        return False
    lo_s, sep, hi_s = rng.groups()
    lo = _count(t, lo_s, fail) if lo_s else default_lo
    hi = lo if not sep else UNBOUNDED if hi_s in (None, "$", "inf") else _count(t, hi_s, fail)
    if lo is None or hi is None:
        return False
    if hi != UNBOUNDED and hi < lo:
        _at_token(fail, t, f"the range {t.text} ends before it starts")
        return False
    return op, lo, hi


def _count(t: Token, digits: str, fail: Fail) -> int | None:
    n = int(digits) if len(digits) < 10 else MAX_REPEAT + 1
    if n > MAX_REPEAT:
        _at_token(fail, t, f"{digits} steps: more than the {MAX_REPEAT} Spot can count",
                  "for longer stretches bound them in time: F[0..2s] f")  # fmt: skip
        return None
    return n


def time_bound_on_a_sere(t: Token, fail: Fail) -> None:
    _at_token(
        fail,
        t,
        "a time bound here (on a SERE) is not supported yet",
        "time bounds go on F, G, U, W, R and M (F[0..500ms] f, a U[0..1s] b), or write "
        "the deadline with age: always (go -> (age(go) < 500ms until done)); see "
        "docs/semantics.md, 'Time'",
    )


def _at_token(fail: Fail, t: Token, message: str, hint: str | None = None) -> None:
    fail(t.start, max(1, t.end - t.start), message, hint)
