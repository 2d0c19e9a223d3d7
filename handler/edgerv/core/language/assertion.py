"""The assertion language: atoms become placeholders p0..pn, the rest is parsed by Spot.

As in the paper (section IV), every atom of an assertion -- a boolean signal, or
a comparison between a signal, a parameter and a literal -- is replaced by a
placeholder proposition ``p<i>``. What remains is LTL/PSL in Spot's infix
syntax, which Spot's own parser reads. PSL's keyword operators, which Spot's
parser does not know, are first rewritten into Spot operators:

=================  =====================================  ==========================
PSL                Spot                                   binding
=================  =====================================  ==========================
``always f``       ``G(f)``                               up to the end of the group
``never f``        ``G!(f)``                              up to the end of the group
``eventually! f``  ``F(f)``                               up to the end of the group
``next f``         ``X f`` (``next!``, ``next[n]`` alike) like ``X``
``next_e[i..j] f`` ``F[i..j] f``                          like ``F``
``next_a[i..j] f`` ``G[i..j] f``                          like ``G``
``a until b``      ``a W b``                              like ``W``
``a until! b``     ``a U b``                              like ``U``
``a until_ b``     ``a W (a & b)``                        like ``W``
``a until!_ b``    ``a U (a & b)``                        like ``U``
``a before b``     ``a R !b``                             like ``R``
``a before! b``    ``a M !b``                             like ``M``
``a before_ b``    ``!b W a``                             like ``W``
``a before!_ b``   ``!b U a``                             like ``U``
=================  =====================================  ==========================

``always``, ``never`` and ``eventually!`` bind more loosely than every other
operator, as in PSL, so ``always a -> b`` means ``always (a -> b)``.
"""

from __future__ import annotations

import itertools
import math
import operator
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from fractions import Fraction
from functools import lru_cache
from typing import Any, Literal, cast

import spot

from edgerv.core.diagnostics import Diagnostic, InputError, did_you_mean
from edgerv.core.documents import MonitorSpec, Value
from edgerv.core.language.bounded import (
    MAX_WINDOW,
    BoundedKind,
    Cut,
    CutKind,
    Delays,
    Obligation,
    as_past,
    cut_formula,
    first_instant,
    substitute,
)
from edgerv.core.language.past import PastError, PastKind, PastOp, compile_boolean
from edgerv.core.language.spot_worker import BudgetExceeded, worker
from edgerv.core.msgtypes import ValueKind

CmpOp = Literal["<", "<=", ">", ">=", "==", "!="]

CMP_FUNCS: dict[str, Callable[[Any, Any], bool]] = {
    "<": operator.lt,
    "<=": operator.le,
    ">": operator.gt,
    ">=": operator.ge,
    "==": operator.eq,
    "!=": operator.ne,
}
_FLIP: dict[str, CmpOp] = {"<": ">", "<=": ">=", ">": "<", ">=": "<=", "==": "==", "!=": "!="}

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
_CMP_TOKENS = {"<", "<=", ">", ">=", "==", "=", "!="}
_BOOL_BINOPS = {*_IMPLIES, "&&", "||", "&", "|", "^", "xor", ";", ":", ","}
_TEMPORAL_BINOPS = {"U", "W", "R", "M"}
_SPOT_WORDS = {"G", "F", "X", "U", "W", "R", "M", "xor", "true", "false"}
_PSL_WORDS = {"always", "never", "eventually", "next", "next_e", "next_a", "until", "before"}
_PAST_UNARY = {"once", "historically", "prev"}
_TIMED_UNTIL = {"U": "U", "until!": "U", "W": "W", "until": "W", "R": "R", "M": "M"}  # timed
_TAKES_BRACKET = {"G", "F", "X", "next", "next!", "next_e", "next_e!", "next_a", "next_a!",
                  "once", "historically", "since"}  # fmt: skip
_NUMBER = re.compile(r"(\d+\.?\d*(?:[eE][+-]?\d+)?|\.\d+(?:[eE][+-]?\d+)?)")
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
# Durations: a number and its unit, written together (500ms, 1.5s, 2min); nanoseconds.
UNITS = {"ns": 1, "us": 1_000, "ms": 1_000_000, "s": 1_000_000_000, "min": 60_000_000_000}
_UNIT_LIST = ", ".join(UNITS)
_TIMED_BOUND = re.compile(r"\d\s*[A-Za-z]")  # an interval bound with a unit: [0..500ms]


MAX_DURATION = 2**63 - 1  # ns (about 292 years): what 64-bit stamps can tell apart


def duration_ns(text: str) -> int | None:
    """The nanoseconds of a duration token (``1.5s``), or None if it is not a whole number
    of nanoseconds up to :data:`MAX_DURATION` or its unit is unknown."""
    m = _NUMBER.match(text)
    if m is None or text[m.end() :] not in UNITS:
        return None
    digits, _, exponent = m.group().lower().partition("e")
    if len(digits) > 40 or len(exponent.lstrip("+-").lstrip("0")) > 2:
        return None  # out of range (1e9999999s would take Fraction seconds to compute)
    ns = Fraction(m.group()) * UNITS[text[m.end() :]]
    return int(ns) if ns.denominator == 1 and ns <= MAX_DURATION else None


# PSL binary keyword operators: Spot text with L and R for the operands.
_TEMPLATE_TOKENS = re.compile(r"\{[LR]\}|[()!&WURM]")
_TEMPLATE_ROLES = {
    "(": "open",
    ")": "close",
    "!": "unary",
    "&": "bbin",
    "W": "tbin",
    "U": "tbin",
    "R": "tbin",
    "M": "tbin",
}
_PSL_BINARY = {  # {L} and {R} stand for the left and right operands
    "until_": "(({L}) W (({L}) & ({R})))",
    "until!_": "(({L}) U (({L}) & ({R})))",
    "before": "(({L}) R !({R}))",
    "before!": "(({L}) M !({R}))",
    "before_": "(!({R}) W ({L}))",
    "before!_": "(!({R}) U ({L}))",
}


@dataclass(frozen=True)
class Token:
    kind: Literal["ident", "number", "duration", "string", "bracket", "op"]
    text: str
    start: int
    end: int


@dataclass(frozen=True)
class Operand:
    """One side of a comparison: a signal (by name), ``age(signal)``, or a constant (a
    duration is a constant in integer nanoseconds)."""

    signal: str | None
    value: Value | None = None
    age: bool = False  # age(signal): the time since the last message on its topic

    def describe(self) -> str:
        if self.signal is not None:
            return f"age({self.signal})" if self.age else self.signal
        return repr(self.value)


@dataclass(frozen=True)
class Atom:
    """A proposition over signal values; ``placeholder`` is its bit in a letter."""

    lhs: Operand
    op: CmpOp
    rhs: Operand
    text: str  # as the user wrote it, for messages

    @property
    def signals(self) -> tuple[str, ...]:
        """The signals whose values it reads (an age atom reads none: it reads the time)."""
        return tuple(
            dict.fromkeys(o.signal for o in (self.lhs, self.rhs) if o.signal and not o.age)
        )

    @property
    def timed(self) -> bool:
        """``age(x) OP duration``: its truth changes as time passes, without a message."""
        return self.lhs.age

    def key(self) -> tuple[Any, ...]:
        def k(o: Operand) -> tuple[Any, ...]:
            if o.signal is not None:
                return ("a" if o.age else "s", o.signal)
            return ("c", type(o.value), o.value)

        return (k(self.lhs), self.op, k(self.rhs))


@dataclass(frozen=True)
class ParsedAssertion:
    spec: MonitorSpec
    formula: Any  # spot.formula over p0..p{n-1}
    atoms: tuple[Atom, ...]  # atoms[i] is placeholder p<i>
    spot_text: str  # the text given to Spot's parser
    constraint: Any  # spot.formula: the letters that can occur (see feasible_letters)
    warnings: tuple[Diagnostic, ...]
    past: tuple[PastOp, ...] = ()  # derived placeholders p<len(atoms)>..., inner first

    @property
    def bits(self) -> int:
        """Placeholders in a letter: the atoms', then the past operators'."""
        return len(self.atoms) + len(self.past)


@dataclass
class _Out:
    """An output token for Spot, with the source span it came from."""

    text: str
    start: int
    end: int
    role: str = "other"  # atom, unary, loose, tbin, bbin, pbin, past, future, futbin, open,
    # close, other
    window: tuple[int, int] | None = None  # a timed operator's [lo, hi] in ns


@dataclass
class _Cut:
    """A time-bounded operator taken out of the formula: ``name`` stands for it there;
    ``spans`` its operands' tokens (``[Q]``, or ``[R, Q]`` for U and W)."""

    name: str
    op: _Out
    spans: list[list[_Out]]


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
        m = _NUMBER.match(text, i)
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
                    f"a duration's unit is one of {_UNIT_LIST}, e.g. 500ms",
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


class _Parser:
    def __init__(self, spec: MonitorSpec) -> None:
        self.spec = spec
        self.text = spec.assertion
        self.diagnostics: list[Diagnostic] = []
        self.atoms: list[Atom] = []
        self.atom_index: dict[tuple[Any, ...], int] = {}
        self.past: list[PastOp] = []
        self.anchored = False  # a time-bounded operator read at the run's first instant
        self.spot_clean = False  # the whole parses in Spot: parts may be parsed here
        self._delays_made: Delays | Literal[False] | None = None  # False: refused

    def fail(self, start: int, length: int, message: str, hint: str | None = None) -> None:
        loc = self.spec.locate_assertion(start, length)
        self.diagnostics.append(Diagnostic(loc, message, hint=hint))

    # -- atoms ---------------------------------------------------------------------------

    def _operand(self, toks: Sequence[Token], i: int) -> tuple[Operand, str, int] | None:
        """An operand starting at toks[i]: (operand, kind, tokens used), or None."""
        t = toks[i] if i < len(toks) else None
        if t is None:
            return None
        sign = 1.0
        used = 0
        if t.kind == "op" and t.text in ("-", "+") and i + 1 < len(toks):
            nxt = toks[i + 1]
            if nxt.kind == "number" and nxt.start == t.end:
                sign = -1.0 if t.text == "-" else 1.0
                t, used = nxt, 1
            elif nxt.kind == "duration" and nxt.start == t.end and t.text == "-":
                self.fail(
                    t.start, nxt.end - t.start, f"a duration cannot be negative: '-{nxt.text}'"
                )
                return Operand(None, 0), "error", 2
        if t.kind == "duration":
            return Operand(None, duration_ns(t.text)), "duration", used + 1
        if t.kind == "ident" and t.text == "age" and _is_call(toks, i):
            return self._age(toks, i)
        if t.kind == "number":
            try:
                number: int | float = int(t.text) if t.text.isdigit() else float(t.text)
            except ValueError:  # Python reads no integer of more than 4,300 digits
                self.fail(t.start, t.end - t.start, "a number too long to read")
                return Operand(None, 0), "error", used + 1
            return Operand(None, -number if sign < 0 else number), "number", used + 1
        if t.kind == "string":
            return Operand(None, t.text[1:-1]), "string", 1
        if t.kind == "ident":
            if t.text in ("true", "false"):
                return Operand(None, t.text == "true"), "bool", 1
            if t.text in self.spec.signals:
                kind = self.spec.signals[t.text].kind
                return Operand(t.text), "number" if kind in ("int", "float") else kind, 1
            if t.text in self.spec.parameters:
                v = self.spec.parameters[t.text]
                k = "bool" if isinstance(v, bool) else "string" if isinstance(v, str) else "number"
                return Operand(None, v), k, 1
        return None

    def _age(self, toks: Sequence[Token], i: int) -> tuple[Operand, str, int]:
        """``age(x)`` at toks[i] (``_is_call`` holds): the operand, or an error reported."""
        arg, close = toks[i + 2], toks[i + 3]
        if arg.kind != "ident" or close.text != ")":
            self.fail(
                toks[i].start, close.end - toks[i].start, "age() takes one signal, e.g. age(scan)"
            )
        elif arg.text in self.spec.signals:
            return Operand(arg.text, age=True), "duration", 4
        else:
            what = "a parameter" if arg.text in self.spec.parameters else "not a signal"
            self.fail(
                arg.start,
                arg.end - arg.start,
                f"age() takes a signal: '{arg.text}' is {what}",
                did_you_mean(arg.text, self.spec.signals) or "declare it under spec.signals",
            )
        return Operand(None, 0), "error", 4

    def _past_window(self, bracket: str, at: int) -> tuple[int, int] | None:
        """``[a..b]`` or ``[a:b]`` of a past operator: durations (a bare 0 is zero)."""
        inner = bracket[1:-1]
        parts = inner.split("..") if ".." in inner else inner.split(":")
        bounds: list[int] = []
        for part in (p.strip() for p in parts):
            ns = 0 if part == "0" else duration_ns(part)
            if ns is None:
                break
            bounds.append(ns)
        if len(parts) != 2 or len(bounds) != 2:
            unitless = all(_NUMBER.fullmatch(p.strip()) for p in parts)
            self.fail(
                at,
                len(bracket),
                "a past operator's interval counts time, not steps"
                if unitless
                else f"bad interval {bracket}: two durations, each with its unit",
                "e.g. once[0..2s] f, historically[100ms:1s] f",
            )
            return None
        if bounds[0] > bounds[1]:
            self.fail(at, len(bracket), f"the interval {bracket} ends before it starts")
            return None
        return bounds[0], bounds[1]

    def derive_past(self, out: list[_Out]) -> list[_Out]:
        """Replace each past operator and its operands by a placeholder of its own, inner
        ones first (module edgerv.core.language.past computes them)."""
        while True:
            found = _innermost_past(out)
            if found is None:
                stuck = next((o for o in out if _is_past(o)), None)
                if stuck is not None:  # each one's operands hold another: no reading
                    self.fail(stuck.start, stuck.end - stuck.start,
                              f"'{stuck.text}' has no operand that can be read here",
                              "put the operands in parentheses, e.g. once (a & b), "
                              "(a) since (b)")  # fmt: skip
                return out
            i, spans = found
            op = out[i]
            if any(out[k].role in _LATE_ROLES for a, b in spans for k in range(a, b)):
                # over a time-bounded operator: read late with it (see pastify_future)
                op.role = "pastcut" if op.role == "past" else "pastcutbin"
                continue
            start, end = spans[0][0] if op.role == "pbin" else i, spans[-1][1]
            operands = []
            for a, b in spans:
                operand = self._past_operand(op, out[a:b])
                if operand is None:
                    return out
                operands.append(operand)
            bit = len(self.atoms) + len(self.past)
            kind: PastKind = cast(PastKind, op.text)
            source = self.text[out[start].start : out[end - 1].end]
            self.past.append(PastOp(kind, bit, tuple(operands), op.window, source))
            out = [*out[:start], _Out(f"p{bit}", out[start].start, out[end - 1].end, "atom"),
                   *out[end:]]  # fmt: skip

    def check_syntax(self, out: list[_Out]) -> None:
        """Does the formula as translated parse in Spot (each past operator read as Spot's
        operator of its shape: ``once`` as F, ``since`` as U)? Asked of Spot's worker:
        :attr:`spot_clean` says. Its errors are reported later, where they were."""
        stand_in = {"prev": "X", "once": "F", "historically": "G"}
        pieces, offsets, pos = [], [], 0
        for o in out:
            text = o.text
            if o.role in ("past",):
                text = stand_in[o.text]
            elif o.role == "pbin":
                text = "U"
            offsets.append((pos, o))
            pieces.append(text)
            pos += len(text) + 1
        text = " ".join(pieces)
        if not text.strip():
            return  # said later: the assertion is empty
        try:
            self.spot_clean = not worker.call(syntax_errors, text)
        except BudgetExceeded as exc:
            message = str(exc)
            if type(exc) is BudgetExceeded:  # not the automaton: the parse itself
                message = f"Spot's parser took more than {exc.seconds:g} s on this assertion"
            self.fail(0, max(1, len(self.text.rstrip())), message,
                      "check its syntax (Spot's error recovery ran away), or split it")  # fmt: skip

    def part(self, text: str) -> Any:
        """The Spot formula of a part of the assertion (an operand), or None if it does
        not parse. In this process where the whole parsed cleanly; else in Spot's worker
        (bad input is where Spot's error recovery can run away)."""
        if not text.strip():
            return None
        if not self.spot_clean:
            try:
                printed = worker.call(_clean_parse, text)
            except BudgetExceeded:
                return None
            return None if printed is None else spot.formula(printed)
        parsed = spot.parse_infix_psl(text)
        return None if parsed.format_errors(spot.ostringstream()) else parsed.f

    def _past_operand(self, op: _Out, tokens: list[_Out]) -> Any:
        parsed = self.part(" ".join(o.text for o in tokens))
        if parsed is None or not parsed.is_boolean():
            self.fail(
                op.start,
                op.end - op.start,
                f"'{op.text}' needs a formula without future operators",
                "past operators look back: their operands are atoms, boolean operators "
                "and other past operators"
                if op.role in ("past", "pbin")
                else "the operands of a time-bounded operator are atoms, boolean operators "
                "and past operators",
            )
            return None
        try:
            return compile_boolean(parsed)
        except PastError as exc:
            self.fail(op.start, op.end - op.start, str(exc))
            return None

    def _timed_interval(self, start: int, length: int) -> None:
        self.fail(
            start,
            length,
            "a time bound here (on a SERE) is not supported yet",
            "time bounds go on F, G, U, W, R and M (F[0..500ms] f, a U[0..1s] b), or write "
            "the deadline with age: always (go -> (age(go) < 500ms until done)); see "
            "docs/semantics.md, 'Time'",
        )

    def cut_future(self, out: list[_Out]) -> tuple[list[_Out], list[_Cut]]:
        """Take each time-bounded operator and its operands out of ``out``: each stands
        as a proposition ``fut<k>`` until :meth:`pastify_future` rewrites the formula.
        Innermost first: an operator nested in another's operand is a ``fut<k>`` there."""
        cuts: list[_Cut] = []
        while (found := _innermost_future(out)) is not None:
            i, lo, hi = found
            o = out[i]
            prefix = o.role in ("future", "pastcut")
            spans = [out[i + 1 : hi]] if prefix else [out[lo:i], out[i + 1 : hi]]
            name = f"fut{len(cuts)}"
            cuts.append(_Cut(name, o, spans))
            out = [*out[:lo], _Out(name, out[lo].start, out[hi - 1].end, "atom"), *out[hi:]]
        return out, cuts

    def pastify_future(self, formula: Any, cuts: list[_Cut]) -> Any:
        """The formula with its time-bounded operators read by past formulas
        (edgerv.core.language.bounded): under a top-level ``always``, ``always (P -> op)`` (alone
        or in a conjunction) as the obligations it opens, reported where a failure
        becomes certain; any other boolean combination of them, nested in one another,
        by reading it with a delay of its horizon; outside ``always`` at the run's
        first instant. Returns the new formula, or None on an error."""
        f = spot.formula
        if formula.kind() == spot.op_And:
            parts = [self.pastify_future(g, cuts) for g in formula]
            return None if any(g is None for g in parts) else f.And(parts)
        used = _futures(formula)
        if not used:
            return formula
        delays = self._delays(cuts)
        if delays is None:
            return None
        if formula.is_boolean():
            return self._at_first_instant(formula, delays, cuts)
        if formula.kind() != spot.op_G:
            return self._late(formula, delays, cuts)
        pieces = []
        for part in _conjuncts(formula[0]):
            names = _futures(part)
            if not names or part.kind() == spot.op_G:  # always (x & always y): y as well
                pieces.append(self.pastify_future(part, cuts) if names else part)
                continue
            shape = _antecedent(part, names[0])
            cut = delays.cuts[names[0]]
            simple = not delays.names(cut_formula(cut)) and cut.kind in ("F", "G", "U", "W")
            if len(names) == 1 and shape is not None and simple:
                pieces.append(self._judged(self._cut_of(cuts, names[0]), shape))
            else:
                pieces.append(self._delayed(part, delays, cuts))
        return None if any(x is None for x in pieces) else f.G(f.And(pieces))

    def _delays(self, cuts: list[_Cut]) -> Delays | None:
        """The time-bounded operators with their operands as Spot formulas (made once a
        parse: the parts of one assertion share their placeholders)."""
        if self._delays_made is None:
            self._delays_made = self._make_delays(cuts)
        return self._delays_made or None

    def _make_delays(self, cuts: list[_Cut]) -> Delays | Literal[False]:
        if len(cuts) > MAX_CUTS:  # each takes a placeholder or more: far past the limit
            op = cuts[MAX_CUTS].op
            self.fail(op.start, op.end - op.start,
                      f"more than {MAX_CUTS} time-bounded operators (and past operators "
                      "over them) in one assertion",
                      "split the assertion into several monitors")  # fmt: skip
            return False
        table: dict[str, Cut] = {}
        for cut in cuts:
            op = cut.op
            operands = []
            for span in cut.spans:
                parsed = self.part(" ".join(o.text for o in span))
                if parsed is None:
                    self.fail(op.start, op.end - op.start, f"'{op.text}' needs an operand")
                    return False
                if not parsed.is_boolean():
                    self.fail(op.start, op.end - op.start,
                              f"an untimed future operator inside the operand of {op.text}",
                              "the operands of a time-bounded operator are atoms, boolean "
                              "operators, past operators and time-bounded operators")  # fmt: skip
                    return False
                operands.append(parsed)
            end = cut.spans[-1][-1].end if cut.spans[-1] else op.end
            begin = cut.spans[0][0].start if cut.spans[0] else op.start
            text = self.text[min(begin, op.start) : end]
            if op.text == "prev":
                self.fail(op.start, op.end - op.start,
                          "prev over a time-bounded operator: not supported (prev counts "
                          "steps, which a late reading does not keep)",
                          "write once[a..b] for a time before now")  # fmt: skip
                return False
            kind = cast(CutKind, op.text)
            window = op.window if op.window is not None else (0, MAX_WINDOW)  # untimed past
            table[cut.name] = Cut(cut.name, kind, window, tuple(operands), text)
        return Delays(table, self._new_past)

    def _new_past(
        self,
        kind: PastKind,
        operands: tuple[Any, ...],
        window: tuple[int, int],
        text: str,
        delay: int,
    ) -> Any:
        bit = len(self.atoms) + len(self.past)
        funcs = tuple(compile_boolean(o) for o in operands)
        self.past.append(PastOp(kind, bit, funcs, window, text, delay))
        return spot.formula.ap(f"p{bit}")

    @staticmethod
    def _cut_of(cuts: list[_Cut], name: str) -> _Cut:
        return next(c for c in cuts if c.name == name)

    def _delayed(self, part: Any, delays: Delays, cuts: list[_Cut]) -> Any:
        """``always (part)``'s piece: ``part`` read its horizon late, from the instant
        the run is that old (no obligation opens before the run)."""
        if not part.is_boolean() and not self._steps_free(part, cuts):
            return None
        horizon = delays.horizon(part)
        try:
            read = delays.at(part, horizon) if part.is_boolean() else delays.ltl(part, horizon)
            return spot.formula.Implies(delays.started(horizon), read)
        except PastError as exc:
            return self._past_error(exc, delays.names(part)[0], cuts)

    def _at_first_instant(self, formula: Any, delays: Delays, cuts: list[_Cut]) -> Any:
        """A boolean combination of time-bounded operators at the top of the assertion,
        each read at the run's first instant: as soon as it is certain when its operands
        hold no other (:func:`bounded.first_instant`), else its horizon late."""

        def read(ap: Any) -> Any:
            name = ap.ap_name()
            if name not in delays.cuts:
                return None
            cut = delays.cuts[name]
            if not delays.names(cut_formula(cut)):
                return first_instant(cut, delays)
            h = delays.horizon(ap)
            ready = delays.started(h)
            late = spot.formula.And([ready, delays.at(ap, h)])
            return spot.formula.U(spot.formula.Not(ready), late)

        self.anchored = True
        try:
            return substitute(formula, read)
        except PastError as exc:
            return self._past_error(exc, delays.names(formula)[0], cuts)

    def _steps_free(self, formula: Any, cuts: list[_Cut]) -> bool:
        """Untimed operators over time-bounded ones range over the instants their
        operands change at, read late: X, a step count (F[1..3]) or a SERE, which count
        steps, have no such reading. Refused at the time-bounded operator; False then."""
        if formula.is_syntactic_stutter_invariant():
            return True
        op = self._cut_of(cuts, _futures(formula)[0]).op
        self.fail(op.start, op.end - op.start,
                  f"a time-bounded {op.text} beside X, a step count or a SERE, which count "
                  "steps: not supported",
                  "bound the step in time instead: X f as F[0..100ms] f, or split the "
                  "assertion into several monitors")  # fmt: skip
        return False

    def _past_error(self, exc: PastError, name: str, cuts: list[_Cut]) -> None:
        op = self._cut_of(cuts, name).op
        self.fail(op.start, op.end - op.start, str(exc))

    def _late(self, formula: Any, delays: Delays, cuts: list[_Cut]) -> Any:
        """An assertion whose untimed temporal operators hold time-bounded ones, not
        under a top-level always: its letters read its horizon H late, from the instant
        the run is H old (so its first step is the run's first instant, read late)."""
        if not self._steps_free(formula, cuts):
            return None
        self.anchored = True
        horizon = delays.horizon(formula)
        try:
            ready = delays.started(horizon)
            late = spot.formula.And([ready, delays.ltl(formula, horizon)])
            return spot.formula.U(spot.formula.Not(ready), late)
        except PastError as exc:
            return self._past_error(exc, delays.names(formula)[0], cuts)

    def _judged(self, cut: _Cut, shape: Any) -> Any:
        """The past formula judging ``always (shape -> cut)``'s obligations."""
        op = cut.op
        operands = [self._past_operand(op, span) for span in cut.spans]
        p = self._past_operand(op, [_Out(str(shape), op.start, op.end, "atom")])
        if any(x is None for x in operands) or p is None or op.window is None:
            return None
        end = cut.spans[-1][-1].end if cut.spans[-1] else op.end
        begin = cut.spans[0][0].start if cut.spans[0] else op.start
        text = self.text[min(begin, op.start) : end]
        *r, q = [self.part(" ".join(o.text for o in span)) for span in cut.spans]
        kind = cast(BoundedKind, op.text)
        ob = Obligation(kind, op.window, shape, q, r[0] if r else None, text)
        try:
            piece, ops = as_past(ob, len(self.atoms) + len(self.past))
        except PastError as exc:  # too many placeholders
            self.fail(op.start, op.end - op.start, str(exc))
            return None
        self.past.extend(ops)
        return piece

    def _add_atom(self, atom: Atom) -> int:
        key = atom.key()
        if key not in self.atom_index:
            self.atom_index[key] = len(self.atoms)
            self.atoms.append(atom)
        return self.atom_index[key]

    def _unknown(self, t: Token) -> None:
        candidates = [*self.spec.signals, *self.spec.parameters]
        self.fail(
            t.start,
            t.end - t.start,
            f"unknown signal or parameter '{t.text}'",
            did_you_mean(t.text, candidates) or "declare it under spec.signals or spec.parameters",
        )

    def _comparison(self, toks: Sequence[Token], i: int) -> tuple[str, int] | None:
        """Parse ``operand CMP operand`` at toks[i]; return (Spot text, tokens used)."""
        j = i + 1
        left = self._operand(toks, i)
        if left is not None:
            j = i + left[2]
        if j >= len(toks) or toks[j].kind != "op" or toks[j].text not in _CMP_TOKENS:
            return None
        cmp_tok = toks[j]
        right = self._operand(toks, j + 1)
        after = toks[j + 1] if j + 1 < len(toks) else None
        if left is None or right is None:  # report one error for the whole comparison
            if left is None and toks[i].kind == "ident":
                self._unknown(toks[i])
            elif left is None:
                return None
            elif after is not None and after.kind == "ident" and after.text not in _SPOT_WORDS:
                self._unknown(after)
            else:
                found = f"'{after.text}'" if after is not None else "nothing"
                self.fail(
                    cmp_tok.start,
                    cmp_tok.end - cmp_tok.start,
                    f"'{cmp_tok.text}' must be followed by a signal, parameter or number, "
                    f"found {found}",
                )
            used = j - i + 1 + (right[2] if right else 1 if after and after.kind != "op" else 0)
            return "p", used
        start = toks[i].start
        end = toks[j + right[2]].end
        source = self.text[start:end]
        (lo, lkind, _), (ro, rkind, _) = left, right
        op: CmpOp = "==" if cmp_tok.text == "=" else cast(CmpOp, cmp_tok.text)
        used = j + right[2] - i + 1
        if "error" in (lkind, rkind):  # reported where it is
            return "p", used
        if (lo.age and ro.age) or (lkind == rkind == "duration" and not (lo.age or ro.age)):
            self.fail(
                start,
                end - start,
                f"'{source}' must compare one age(x) with a duration",
                "e.g. age(scan) < 200ms",
            )
            return "p", used
        if lo.signal is None and ro.signal is None:
            self.fail(
                start,
                end - start,
                f"'{source}' compares two constants",
                "a comparison needs a signal on at least one side",
            )
            return "p", j + right[2] + 1 - i
        if lkind != rkind:
            self.fail(
                start,
                end - start,
                f"type mismatch in '{source}': {lo.describe()} is {_kind_name(lkind)}, "
                f"{ro.describe()} is {_kind_name(rkind)}",
                "a duration compares only with age(x), and takes a unit: age(scan) < 200ms"
                if "duration" in (lkind, rkind)
                else None,
            )
            return "p", j + right[2] + 1 - i
        if lkind in ("bool", "string") and op not in ("==", "!="):
            self.fail(
                cmp_tok.start,
                cmp_tok.end - cmp_tok.start,
                f"'{cmp_tok.text}' does not apply to {lkind}s, in '{source}'",
                "only == and != compare bools and strings",
            )
            return "p", j + right[2] + 1 - i
        if lo.signal is None:  # constant on the left: put the signal first
            lo, ro, op = ro, lo, _FLIP[op]
        negate = False
        if op == "!=":  # a != b is !(a == b), also for NaN: one placeholder serves both
            op, negate = "==", True
        if lkind == "bool" and ro.signal is None:  # running == false is !running
            if ro.value is False:
                negate = not negate
            ro = Operand(None, True)
        index = self._add_atom(Atom(lo, op, ro, source))
        return ("!" if negate else "") + f"p{index}", used

    # -- the whole assertion ---------------------------------------------------------------

    def check_brackets(self, toks: Sequence[Token]) -> None:
        """Unbalanced ( ) and { } are reported at the user's own bracket."""
        stack: list[Token] = []
        pairs = {")": "(", "}": "{"}
        for t in toks:
            if t.kind != "op":
                continue
            if t.text in "({":
                stack.append(t)
            elif t.text in ")}":
                if not stack or stack[-1].text != pairs[t.text]:
                    self.fail(
                        t.start,
                        1,
                        f"'{t.text}' closes nothing",
                        "remove it or add the opening bracket",
                    )
                    return
                stack.pop()
        if stack:
            t = stack[-1]
            self.fail(
                t.start,
                1,
                f"'{t.text}' is never closed",
                f"add '{')' if t.text == '(' else '}'}' where the group ends",
            )

    def translate(self, toks: Sequence[Token]) -> list[_Out]:
        self.check_brackets(toks)
        out: list[_Out] = []
        i = 0
        while i < len(toks):
            t = toks[i]
            cmp_ = self._comparison(toks, i)
            if cmp_ is not None:
                text, used = cmp_
                out.append(_Out(text, t.start, toks[i + used - 1].end, "atom"))
                i += used
                continue
            if t.kind == "op" and t.text in _CMP_TOKENS:
                self.fail(
                    t.start,
                    t.end - t.start,
                    f"'{t.text}' needs a signal, parameter or number on its left",
                )
            elif t.kind == "ident":
                i += self._word(t, toks[i + 1] if i + 1 < len(toks) else None, out) - 1
            elif t.kind == "number":
                if t.text in ("0", "1"):
                    out.append(_Out(t.text, t.start, t.end, "atom"))
                else:
                    self.fail(
                        t.start,
                        t.end - t.start,
                        f"number {t.text} outside a comparison",
                        "compare it with a signal, e.g. speed < 100",
                    )
            elif t.kind == "string":
                self.fail(t.start, t.end - t.start, f"string {t.text} outside a comparison")
            elif t.kind == "bracket":
                if _TIMED_BOUND.search(t.text):
                    self._timed_interval(t.start, t.end - t.start)
                out.append(_Out(t.text, t.start, t.end, "unary" if t.text == "[]" else "other"))
            elif t.kind == "duration":
                self.fail(
                    t.start,
                    t.end - t.start,
                    f"duration {t.text} outside a comparison",
                    "compare it with age(x), e.g. age(scan) < 200ms",
                )
            else:
                role = (
                    "open"
                    if t.text in "({"
                    else "close"
                    if t.text in ")}"
                    else "bbin"
                    if t.text in _BOOL_BINOPS
                    else "unary"
                    if t.text in ("!", "<>")
                    else "other"
                )
                out.append(_Out(t.text, t.start, t.end, role))
            i += 1
        return out

    def _word(self, t: Token, nxt: Token | None, out: list[_Out]) -> int:
        """Translate a word (and the bracket right after it, for X[..], next_e[..]).

        Returns how many tokens were used.
        """
        w, s, e = t.text, t.start, t.end
        bracket = nxt.text if nxt is not None and nxt.kind == "bracket" and nxt.start == e else None
        takes_bracket = w in _TAKES_BRACKET and w not in self.spec.signals
        used = 2 if bracket is not None and takes_bracket else 1
        if w in ("once", "historically", "since", "prev") and w not in self.spec.signals:
            window = None
            if bracket is not None and w != "prev":
                window = self._past_window(bracket, e)
            end = e + (len(bracket) if bracket is not None and takes_bracket else 0)
            out.append(_Out(w, s, end, "pbin" if w == "since" else "past", window))
            return used
        if bracket is not None and takes_bracket and _TIMED_BOUND.search(bracket):
            end = e + len(bracket)
            if w in ("X", "next", "next!"):
                self.fail(s, end - s, f"'{w}' counts steps: it takes no duration",
                          "for a time bound use F[0..500ms] f or G[0..2s] f")  # fmt: skip
            else:  # F, G and PSL's next_e, next_a with a time bound: see pastify_future
                window = self._past_window(bracket, e)
                op = "F" if w == "F" or w.startswith("next_e") else "G"
                out.append(_Out(op, s, end, "future", window))
            return used
        timed = bracket is not None and _TIMED_BOUND.search(bracket)
        if bracket is not None and not timed and w in _TIMED_UNTIL and w not in self.spec.signals:
            self.fail(e, len(bracket), f"'{w}' takes a time bound, not steps",
                      f"give the bounds units, e.g. a {w}[0..500ms] b")  # fmt: skip
            return 2
        if timed and w in _TIMED_UNTIL and w not in self.spec.signals:
            assert bracket is not None
            window = self._past_window(bracket, e)
            op = _TIMED_UNTIL[w]
            out.append(_Out(op, s, e + len(bracket), "futbin", window))
            return 2
        if w == "age" and nxt is not None and nxt.text == "(":
            self.fail(
                s,
                e - s,
                "age(x) is a duration, not a proposition",
                "compare it with a duration, e.g. age(scan) < 200ms",
            )
            return 4  # age ( x )
        if w in self.spec.signals:
            sig = self.spec.signals[w]
            if sig.kind != "bool":
                self.fail(
                    s,
                    e - s,
                    f"'{w}' is a {sig.kind} signal, not a proposition",
                    f"compare it, e.g. {w} > 0",
                )
                return used
            index = self._add_atom(Atom(Operand(w), "==", Operand(None, True), w))
            out.append(_Out(f"p{index}", s, e, "atom"))
        elif w in self.spec.parameters:
            self.fail(
                s,
                e - s,
                f"parameter '{w}' used as a proposition",
                "parameters are constants: compare a signal with it, e.g. speed < " + w,
            )
        elif w in ("G", "F", "X"):
            if bracket is not None:
                out.append(_Out(w + bracket, s, e + len(bracket), "unary"))
            else:
                out.append(_Out(w, s, e, "unary"))
        elif w in _TEMPORAL_BINOPS:
            out.append(_Out(w, s, e, "tbin"))
        elif w == "xor":
            out.append(_Out(w, s, e, "bbin"))
        elif w in ("true", "false"):
            out.append(_Out(w, s, e, "atom"))
        elif w in ("always", "never", "eventually!"):
            spot_op = {"always": "G", "never": "G!", "eventually!": "F"}[w]
            out.append(_Out(spot_op, s, e, "loose"))
        elif w in ("next", "next!"):
            out.append(_Out("X" + (bracket or ""), s, e + len(bracket or ""), "unary"))
        elif w in ("next_e", "next_e!", "next_a", "next_a!"):
            if bracket is None:
                self.fail(s, e - s, f"'{w}' needs a range", f"write e.g. {w}[1..3] f")
                return used
            op = "F" if w.startswith("next_e") else "G"
            out.append(_Out(op + bracket.replace(" to ", ".."), s, e + len(bracket), "unary"))
        elif w == "until":
            out.append(_Out("W", s, e, "tbin"))
        elif w == "until!":
            out.append(_Out("U", s, e, "tbin"))
        elif w in _PSL_BINARY:
            out.append(_Out(w, s, e, "pbin"))
        elif w == "eventually":
            self.fail(
                s, e - s, "PSL's 'eventually' is written 'eventually!'", "or use the LTL operator F"
            )
        elif (m := re.fullmatch(r"([GFX]+)([A-Za-z_]\w*)?", w)) and (
            m.group(2) is None or m.group(2) in self.spec.signals
        ):
            # Spot's compact spelling: GFp is G F p, XF( is X F ( (Spot prints formulas so)
            for k, op in enumerate(m.group(1)):
                out.append(_Out(op, s + k, s + k + 1, "unary"))
            if m.group(2) is not None:
                rest = len(m.group(1))
                self._word(Token("ident", m.group(2), s + rest, e), None, out)
        else:
            self._unknown(t)
        return used


def _futures(formula: Any) -> list[str]:
    """The time-bounded operators' propositions (``fut<k>``) in ``formula``."""
    names = (ap.ap_name() for ap in spot.atomic_prop_collect(formula))
    return sorted(n for n in names if n.startswith("fut"))


def _conjuncts(body: Any) -> list[Any]:
    """``body`` as a conjunction's parts, ``P -> (A & B)`` as ``P -> A`` and ``P -> B``."""
    if body.kind() == spot.op_And:
        return [part for g in body for part in _conjuncts(g)]
    if body.kind() == spot.op_Implies and body[1].kind() == spot.op_And:
        return [part for g in body[1] for part in _conjuncts(spot.formula.Implies(body[0], g))]
    return [body]


def _antecedent(part: Any, name: str) -> Any:
    """P when ``part`` is ``P -> fut``, ``fut`` (P true) or ``!P | fut``; else None."""
    fut = spot.formula.ap(name)
    if part == fut:
        return spot.formula.tt()
    if part.kind() == spot.op_Implies and part[1] == fut:
        return part[0]
    if part.kind() == spot.op_Or and fut in list(part):
        return spot.formula.Not(spot.formula.Or([g for g in part if g != fut]))
    return None


def _kind_name(kind: str) -> str:
    names = {"number": "a number", "bool": "a boolean", "string": "a string"}
    return names.get(kind, f"a {kind}")  # a duration


def _is_past(o: _Out) -> bool:
    return o.role == "past" or (o.role == "pbin" and o.text == "since")


def _prefix_operand_end(out: list[_Out], j: int) -> int:
    """One past the operand starting at out[j] of a prefix operator: the unary operators
    before it, then a bracketed group or one token."""
    while j < len(out) and out[j].role in ("unary", "past", "future", "pastcut"):
        j += 1
    if j < len(out) and out[j].role == "open":
        depth = 0
        for k in range(j, len(out)):
            depth += {"open": 1, "close": -1}.get(out[k].role, 0)
            if depth == 0:
                return k + 1
        return len(out)
    return min(j + 1, len(out))


def _innermost_future(out: list[_Out]) -> tuple[int, int, int] | None:
    """A time-bounded operator whose operands hold no other: its index and the span
    ``[lo, hi)`` it and its operands take."""
    for i in reversed(range(len(out))):
        role = out[i].role
        if role in ("future", "pastcut"):
            lo, hi = i, _prefix_operand_end(out, i + 1)
        elif role in ("futbin", "pastcutbin"):
            lo, hi = _operand_end(out, i, -1) + 1, _operand_end(out, i, +1)
        else:
            continue
        if not any(out[k].role in _LATE_ROLES for k in range(lo, hi) if k != i):
            return i, lo, hi
    return None


# A time-bounded operator, and a past one over one (read late with it: a cut too)
_LATE_ROLES = ("future", "futbin", "pastcut", "pastcutbin")


def _innermost_past(out: list[_Out]) -> tuple[int, list[tuple[int, int]]] | None:
    """A past operator whose operands hold no other: its index and operand spans."""
    for i in reversed(range(len(out))):
        if not _is_past(out[i]):
            continue
        if out[i].role == "past":
            spans = [(i + 1, _prefix_operand_end(out, i + 1))]
        else:
            spans = [(_operand_end(out, i, -1) + 1, i), (i + 1, _operand_end(out, i, +1))]
        if not any(_is_past(out[k]) for a, b in spans for k in range(a, b)):
            return i, spans
    return None


def _is_call(toks: Sequence[Token], i: int) -> bool:
    """``name ( ... )`` at toks[i], the parenthesis right after the name."""
    return (
        i + 3 < len(toks)
        and toks[i + 1].text == "("
        and toks[i + 1].start == toks[i].end
        and toks[i + 1].kind == "op"
    )


def _operand_end(out: list[_Out], i: int, step: int) -> int:
    """Index one past the operand of out[i] in direction step (+1 right, -1 left)."""
    depth = 0
    j = i + step
    while 0 <= j < len(out):
        role = out[j].role
        opens, closes = ("open", "close") if step > 0 else ("close", "open")
        if role == opens:
            depth += 1
        elif role == closes:
            if depth == 0:
                break
            depth -= 1
        elif depth == 0 and (
            role in ("bbin", "pbin", "pastcutbin")
            or (step < 0 and role in ("tbin", "futbin", "loose"))
        ):
            break
        j += step
    return j


MAX_REWRITTEN = 10_000  # tokens, once PSL's keywords are rewritten


class _Grown(Exception):
    """PSL keywords that repeat an operand, nested so that the text grows past
    :data:`MAX_REWRITTEN` (each ``until_`` on the left doubles it)."""

    def __init__(self, keyword: _Out) -> None:
        self.keyword = keyword


def _rewrite_psl_binary(out: list[_Out]) -> list[_Out]:
    """Rewrite until_/before* into Spot operators, rightmost first (they are right-associative)."""
    while True:
        idx = [i for i, o in enumerate(out) if o.role == "pbin"]
        if not idx:
            return out
        i = idx[-1]
        kw = out[i]
        if len(out) > MAX_REWRITTEN:
            raise _Grown(kw)
        lo = _operand_end(out, i, -1) + 1
        hi = _operand_end(out, i, +1)
        left, right = out[lo:i], out[i + 1 : hi]
        pieces: list[_Out] = []
        for part in _TEMPLATE_TOKENS.findall(_PSL_BINARY[kw.text]):
            if part in ("{L}", "{R}"):
                operand = left if part == "{L}" else right
                pieces += [_Out(o.text, o.start, o.end, o.role) for o in operand]
            else:
                pieces.append(_Out(part, kw.start, kw.end, _TEMPLATE_ROLES[part]))
        out = out[:lo] + pieces + out[hi:]


def _wrap_loose(out: list[_Out]) -> list[_Out]:
    """``always f`` becomes ``G(f)`` with f running to the end of the enclosing group."""
    for i in range(len(out) - 1, -1, -1):
        if out[i].role != "loose":
            continue
        kw = out[i]
        end = _group_end(out, i)
        out = [
            *out[:i],
            _Out(kw.text, kw.start, kw.end, "unary"),
            _Out("(", kw.start, kw.end, "open"),
            *out[i + 1 : end],
            _Out(")", kw.start, kw.end, "close"),
            *out[end:],
        ]
    return out


def _group_end(out: list[_Out], i: int) -> int:
    depth = 0
    for j in range(i + 1, len(out)):
        if out[j].role == "open":
            depth += 1
        elif out[j].role == "close":
            if depth == 0:
                return j
            depth -= 1
    return len(out)


def syntax_errors(text: str) -> str:
    """Spot's error listing for ``text`` ("" if it parses). Spot's worker runs it
    (:func:`_spot_errors`): its parser's error recovery can take seconds and gigabytes
    on a few characters (``F F F []``), which the worker's budget and memory bound."""
    stream = spot.ostringstream()
    spot.parse_infix_psl(text).format_errors(stream)
    return str(stream.str())


def _clean_parse(text: str) -> str | None:
    """Spot's printing of ``text``'s formula, None if it does not parse (in the worker)."""
    parsed = spot.parse_infix_psl(text)
    return None if parsed.format_errors(spot.ostringstream()) else str(parsed.f)


def _spot_errors(text: str, offsets: list[tuple[int, _Out]]) -> list[tuple[_Out, str]]:
    """Parse Spot's error listing and map each caret back to an output token."""
    listing = worker.call(syntax_errors, text)
    if not listing:
        return []
    found: list[tuple[_Out, str]] = []
    blocks = [b for b in listing.split("\n\n") if b.strip()]
    for block in blocks:
        lines = block.split("\n")
        caret = next((ln for ln in lines if ln.strip().startswith("^")), None)
        message = lines[-1].strip()
        if found:
            break  # Spot's first error is the one to fix; the rest often follow from it
        col = (caret.index("^") - 4) if caret else 0
        token = offsets[-1][1]
        for off, tok in offsets:
            if off <= col:
                token = tok
        found.append((token, message))
    return found


MAX_NESTING = 1_000  # brackets in brackets
MAX_CUTS = 64  # time-bounded operators, and past ones over them: Delays nests a call each
MAX_OPERATORS = 4_000  # operators in all: a chain of them (! ! a, a U b U c) nests too


def _check_size(tokens: Sequence[Token], fail: Callable[[int, int, str, str | None], None]) -> None:
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


_OPERATOR_WORDS = {*_SPOT_WORDS, *_PSL_WORDS, *_PAST_UNARY, "since", "until!", "until_",
                   "until!_", "before!", "before_", "before!_", "next!", "next_e!",
                   "next_a!", "eventually!"}  # fmt: skip


def parse_assertion(spec: MonitorSpec) -> ParsedAssertion:
    """Replace atoms by placeholders and parse the formula with Spot; raise InputError."""
    p = _Parser(spec)
    tokens = tokenize(spec.assertion, p.fail)
    _check_size(tokens, p.fail)
    if p.diagnostics:
        raise InputError(p.diagnostics)
    out = p.translate(tokens)
    if p.diagnostics:
        raise InputError(p.diagnostics)
    p.check_syntax(out)  # before anything parses a part of it in this process
    if p.diagnostics:
        raise InputError(p.diagnostics)
    out = p.derive_past(out)
    if p.diagnostics:
        raise InputError(p.diagnostics)
    try:
        rewritten = _rewrite_psl_binary(out)
    except _Grown as grown:
        kw = grown.keyword
        p.fail(
            kw.start,
            kw.end - kw.start,
            f"'{kw.text}' repeats its left operand: nested so, the assertion grows past "
            f"{MAX_REWRITTEN:,} tokens",
            "write it with W and U (a until_ b is a W (a & b)), or split the assertion",
        )
        raise InputError(p.diagnostics) from None
    out, cuts = p.cut_future(_wrap_loose(rewritten))
    if p.diagnostics:
        raise InputError(p.diagnostics)
    pieces, offsets, pos = [], [], 0
    for o in out:
        offsets.append((pos, o))
        pieces.append(o.text)
        pos += len(o.text) + 1
    text = " ".join(pieces)
    if not text.strip():
        p.fail(0, max(1, len(spec.assertion)), "the assertion is empty")
        raise InputError(p.diagnostics)
    try:
        errors = _spot_errors(text, offsets)
    except BudgetExceeded as exc:
        p.fail(0, max(1, len(spec.assertion.rstrip())), str(exc), exc.hint)
        raise InputError(p.diagnostics) from None
    for tok, message in errors:
        p.fail(tok.start, max(1, tok.end - tok.start), message)
    if p.diagnostics:
        raise InputError(p.diagnostics)
    formula = spot.parse_infix_psl(text).f
    if cuts:
        formula = p.pastify_future(formula, cuts)
        if p.diagnostics:
            raise InputError(p.diagnostics)
        text = str(formula)
    atoms = tuple(p.atoms)
    constraint = feasible_letters(spec, atoms)
    warnings = _vacuity_warnings(spec, formula, constraint)  # past placeholders range free
    if p.anchored and spec.on_verdict == "reset":
        warnings.append(
            Diagnostic(
                spec.locate_assertion(0, len(spec.assertion.rstrip())),
                "this assertion is read at the run's first instant (a time-bounded operator "
                "outside always): after its verdict, reset reads it again at each step, "
                "its window long past",
                "warning",
                "write onVerdict: halt for its one verdict, or put it under always",
            )
        )
    return ParsedAssertion(spec, formula, atoms, text, constraint, tuple(warnings), tuple(p.past))


@lru_cache(maxsize=4096)
def _vacuity(formula_text: str, constraint_text: str) -> str | None:
    """'unsatisfiable', 'valid' or None for a formula over the letters that can occur."""
    f, g = spot.formula(formula_text), spot.formula.G(spot.formula(constraint_text))
    if spot.translate(spot.formula.And([g, f])).is_empty():
        return "unsatisfiable"
    if spot.translate(spot.formula.And([g, spot.formula.Not(f)])).is_empty():
        return "valid"
    return None


def _vacuity_warnings(spec: MonitorSpec, formula: Any, constraint: Any) -> list[Diagnostic]:
    loc = spec.locate_assertion(0, len(spec.assertion.rstrip()))
    try:
        kind = worker.call(_vacuity, str(formula), str(constraint))
    except BudgetExceeded as exc:
        raise InputError([Diagnostic(loc, str(exc), hint=exc.hint)]) from None
    if kind == "unsatisfiable":
        return [
            Diagnostic(
                loc,
                "the assertion can never hold: every run violates it at step 1",
                "warning",
                "check the comparisons and the temporal operators",
            )
        ]
    if kind == "valid":
        return [
            Diagnostic(
                loc,
                "the assertion always holds: no run can violate it",
                "warning",
                "a monitor that cannot fail checks nothing; check the formula",
            )
        ]
    return []


def _samples(kind: ValueKind, constants: list[Value]) -> list[Value]:
    """Values covering every region that comparisons with ``constants`` can tell apart."""
    if kind == "bool":
        return [False, True]
    if kind == "string":
        strs = [c for c in constants if isinstance(c, str)]
        return [*strs, "\x00" + "".join(strs)]
    numbers = [c for c in constants if isinstance(c, int | float) and not isinstance(c, bool)]
    if kind == "int":  # exact: an integer constant may be beyond a float's range
        points: set[Value] = {0}
        for c in numbers:
            if isinstance(c, int):
                points |= {c - 1, c, c + 1}
            elif math.isfinite(c):  # an infinite or NaN one compares alike with every int
                points |= {math.floor(c) - 1, math.floor(c), math.ceil(c), math.ceil(c) + 1}
        return sorted(points)
    nums = sorted({f for f in map(_nearest_float, numbers) if not math.isnan(f)})
    points_f: set[float] = {0.0, -math.inf, math.inf}
    for a, b in itertools.pairwise(nums):
        middle = (a + b) / 2
        if not math.isfinite(middle):  # a + b overflowed, or an infinity is a bound
            middle = a / 2 + b / 2
        if math.isfinite(middle):
            points_f.add(middle)
    for c in nums:  # each side of it, also where adding 1.0 changes nothing
        points_f |= {c, c - 1.0, c + 1.0, math.nextafter(c, -math.inf), math.nextafter(c, math.inf)}
    return [*sorted(points_f), math.nan]


def _nearest_float(c: int | float) -> float:
    """``c`` as a float; an integer beyond a float's range as the infinity of its sign."""
    try:
        return float(c)
    except OverflowError:
        return math.inf if c > 0 else -math.inf


def feasible_letters(spec: MonitorSpec, atoms: Sequence[Atom]) -> Any:
    """A boolean formula over the placeholders true of exactly the letters that can occur.

    Atoms that read the same single signal are not independent (``speed < 50`` and
    ``speed > 100`` are never both true). Monitoring over the letters that can occur
    gives the exact verdicts of the assertion over signal values: a prefix is bad
    when no continuation of *possible* letters satisfies the formula.
    """
    by_signal: dict[tuple[str, bool], list[int]] = {}
    for i, a in enumerate(atoms):
        if a.rhs.signal is None and a.lhs.signal is not None:
            by_signal.setdefault((a.lhs.signal, a.lhs.age), []).append(i)
    parts = []
    for (name, age), idxs in by_signal.items():
        if len(idxs) < 2 and (age or spec.signals[name].kind != "float"):
            continue
        consts = [atoms[i].rhs.value for i in idxs if atoms[i].rhs.value is not None]
        if age:  # nanoseconds, never negative; infinite before the topic's first message
            ints = _samples("int", consts)  # type: ignore[arg-type]
            samples: list[Any] = [v for v in ints if isinstance(v, int) and v >= 0] + [math.inf]
        else:
            samples = _samples(spec.signals[name].kind, consts)  # type: ignore[arg-type]
        rows = set()
        for v in samples:
            rows.add(tuple(_compare(v, atoms[i].op, atoms[i].rhs.value) for i in idxs))
        if len(rows) == 2 ** len(idxs):
            continue
        disjuncts = [
            spot.formula.And(
                [
                    spot.formula.ap(f"p{i}") if bit else spot.formula.Not(spot.formula.ap(f"p{i}"))
                    for i, bit in zip(idxs, row, strict=True)
                ]
            )
            for row in sorted(rows)
        ]
        parts.append(spot.formula.Or(disjuncts))
    return spot.formula.And(parts) if parts else spot.formula.tt()


def _compare(value: Any, op: str, const: Any) -> bool:
    try:
        return bool(CMP_FUNCS[op](value, const))
    except TypeError:
        return False


def compile_atom_columns(atom: Atom, index_of: dict[str, int]) -> Callable[[list[Any]], Any]:
    """The atom over columns of values (one array per signal): an array of truth values.

    The same comparison as :func:`compile_atom`, applied elementwise (the columns are
    NumPy object arrays, so each element is compared as the Python values it holds).
    """
    func = CMP_FUNCS[atom.op]
    if atom.lhs.signal is None or atom.timed:  # timed atoms are the clock's (pipeline.Clock)
        raise ValueError(atom)
    li = index_of[atom.lhs.signal]
    if atom.rhs.signal is not None:
        ri = index_of[atom.rhs.signal]
        return lambda cols: func(cols[li], cols[ri])
    const = atom.rhs.value
    return lambda cols: func(cols[li], const)


def compile_atom(atom: Atom, index_of: dict[str, int]) -> Callable[[list[Any]], bool]:
    """A function from the signal values (by index) to the atom's truth value."""
    func = CMP_FUNCS[atom.op]
    if atom.lhs.signal is None or atom.timed:  # never: constants go right; timed: the clock's
        raise ValueError(atom)
    li = index_of[atom.lhs.signal]
    if atom.rhs.signal is not None:
        ri = index_of[atom.rhs.signal]
        return lambda values: bool(func(values[li], values[ri]))
    const = atom.rhs.value
    return lambda values: bool(func(values[li], const))
