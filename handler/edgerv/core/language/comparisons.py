"""Reading atoms from the assertion's tokens: operands, ``age()``, comparisons, typed.

:class:`AtomReader` is the parser's reader of leaves: at a token, a comparison
``operand CMP operand`` (its operands' kinds checked against the signals' and the
parameters'), each distinct atom given its placeholder in the order atoms first
appear. Comparisons that mean the same (``speed < 100``, ``100 > speed``) are one
atom; ``x != c`` is ``!(x == c)``; ``running == false`` is ``!running``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, cast

from edgerv.core.diagnostics import did_you_mean
from edgerv.core.documents import MonitorSpec
from edgerv.core.language.atoms import FLIP, Atom, CmpOp, Operand
from edgerv.core.language.lexer import CMP_TOKENS, SPOT_WORDS, Fail, Token, duration_ns


class AtomReader:
    def __init__(self, spec: MonitorSpec, fail: Fail) -> None:
        self.spec = spec
        self.text = spec.assertion
        self.fail = fail
        self.atoms: list[Atom] = []
        self.atom_index: dict[tuple[Any, ...], int] = {}

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

    def add_atom(self, atom: Atom) -> int:
        key = atom.key()
        if key not in self.atom_index:
            self.atom_index[key] = len(self.atoms)
            self.atoms.append(atom)
        return self.atom_index[key]

    def unknown(self, t: Token) -> None:
        candidates = [*self.spec.signals, *self.spec.parameters]
        self.fail(
            t.start,
            t.end - t.start,
            f"unknown signal or parameter '{t.text}'",
            did_you_mean(t.text, candidates) or "declare it under spec.signals or spec.parameters",
        )

    def comparison(self, toks: Sequence[Token], i: int) -> tuple[int | None, bool, int] | None:
        """``operand CMP operand`` at toks[i]: (its atom's placeholder, negated, tokens
        used), the placeholder None where an error was reported; None if there is no
        comparison at toks[i]."""
        j = i + 1
        left = self._operand(toks, i)
        if left is not None:
            j = i + left[2]
        if j >= len(toks) or toks[j].kind != "op" or toks[j].text not in CMP_TOKENS:
            return None
        cmp_tok = toks[j]
        right = self._operand(toks, j + 1)
        after = toks[j + 1] if j + 1 < len(toks) else None
        if left is None or right is None:  # report one error for the whole comparison
            if left is None and toks[i].kind == "ident":
                self.unknown(toks[i])
            elif left is None:
                return None
            elif after is not None and after.kind == "ident" and after.text not in SPOT_WORDS:
                self.unknown(after)
            else:
                found = f"'{after.text}'" if after is not None else "nothing"
                self.fail(
                    cmp_tok.start,
                    cmp_tok.end - cmp_tok.start,
                    f"'{cmp_tok.text}' must be followed by a signal, parameter or number, "
                    f"found {found}",
                )
            used = j - i + 1 + (right[2] if right else 1 if after and after.kind != "op" else 0)
            return None, False, used
        start = toks[i].start
        end = toks[j + right[2]].end
        source = self.text[start:end]
        (lo, lkind, _), (ro, rkind, _) = left, right
        op: CmpOp = "==" if cmp_tok.text == "=" else cast(CmpOp, cmp_tok.text)
        used = j + right[2] - i + 1
        if "error" in (lkind, rkind):  # reported where it is
            return None, False, used
        if (lo.age and ro.age) or (lkind == rkind == "duration" and not (lo.age or ro.age)):
            self.fail(
                start,
                end - start,
                f"'{source}' must compare one age(x) with a duration",
                "e.g. age(scan) < 200ms",
            )
            return None, False, used
        if lo.signal is None and ro.signal is None:
            self.fail(
                start,
                end - start,
                f"'{source}' compares two constants",
                "a comparison needs a signal on at least one side",
            )
            return None, False, j + right[2] + 1 - i
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
            return None, False, j + right[2] + 1 - i
        if lkind in ("bool", "string") and op not in ("==", "!="):
            self.fail(
                cmp_tok.start,
                cmp_tok.end - cmp_tok.start,
                f"'{cmp_tok.text}' does not apply to {lkind}s, in '{source}'",
                "only == and != compare bools and strings",
            )
            return None, False, j + right[2] + 1 - i
        if lo.signal is None:  # constant on the left: put the signal first
            lo, ro, op = ro, lo, FLIP[op]
        negate = False
        if op == "!=":  # a != b is !(a == b), also for NaN: one placeholder serves both
            op, negate = "==", True
        if lkind == "bool" and ro.signal is None:  # running == false is !running
            if ro.value is False:
                negate = not negate
            ro = Operand(None, True)
        return self.add_atom(Atom(lo, op, ro, source)), negate, used

    # -- the whole assertion ---------------------------------------------------------------


def _kind_name(kind: str) -> str:
    names = {"number": "a number", "bool": "a boolean", "string": "a string"}
    return names.get(kind, f"a {kind}")  # a duration


def _is_call(toks: Sequence[Token], i: int) -> bool:
    """``name ( ... )`` at toks[i], the parenthesis right after the name."""
    return (
        i + 3 < len(toks)
        and toks[i + 1].text == "("
        and toks[i + 1].start == toks[i].end
        and toks[i + 1].kind == "op"
    )
