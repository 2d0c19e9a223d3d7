"""The parser: an assertion's tokens to its typed syntax tree (edgerv.core.language.tree).

Spot's infix LTL/PSL grammar (the same operators, precedences and associativity as
Spot's own parser, checked against it by tests/unit/test_parser.py) with edgerv's
additions: atoms are comparisons over signals (edgerv.core.language.comparisons),
PSL's keyword operators (``always``, ``until_``, ``before!``, ...), past operators
(``once``, ``historically``, ``prev``, ``since``) and time bounds in durations on
``F``, ``G``, ``U``, ``W``, ``R``, ``M``, ``once``, ``historically`` and ``since``.

Binding, loosest first: ``always``/``never``/``eventually!`` and a SERE's ``|->``
(to the end of their group); SERE ``;``, then ``:``; ``->`` ``<->`` (right);
``|``; ``xor``; ``&``; Wring's ``*``; ``U W R M`` and their PSL spellings and
``since`` (right); the prefix operators, ``!`` tightest. SERE repetitions (``[*]``,
``[=n]``, ``[->]``...) bind tighter than everything but ``!``.

An operator-precedence parser over two explicit stacks: nesting costs no Python
recursion (the lexer's limits bound it for Spot's sake). The first syntax error
stops it, named at its token; errors in atoms (an unknown name, a type mismatch)
are all collected.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Literal

from edgerv.core.language import brackets
from edgerv.core.language.atoms import Atom, Operand
from edgerv.core.language.comparisons import AtomReader
from edgerv.core.language.lexer import CMP_TOKENS, Fail, Token
from edgerv.core.language.tree import (
    UNBOUNDED,
    Binary,
    BoolOp,
    Closure,
    Const,
    FirstMatch,
    Node,
    Not,
    Past,
    Prop,
    Repeat,
    RepeatOp,
    Sere,
    SereOp,
    Span,
    Steps,
    Suffix,
    Timed,
    Until,
    UntilOp,
)

Mode = Literal["ltl", "sere"]

LOOSE, UNARY, NEXT, REPEAT, NOT, TIGHT = 0, 90, 100, 110, 120, 130  # prefix and postfix

# Binary operators: (precedence, right-associative, what they build)
_IMPLIES = {"->", "-->", "=>", "==>"}
_EQUIV = {"<->", "<-->", "<=>", "<==>"}
_LTL_BOOL: dict[str, tuple[int, BoolOp]] = {
    **{t: (30, "->") for t in _IMPLIES},
    **{t: (30, "<->") for t in _EQUIV},
    "|": (40, "|"), "||": (40, "|"), "^": (50, "^"), "xor": (50, "^"),
    "&": (60, "&"), "&&": (60, "&"), "*": (70, "&"),
}  # fmt: skip
_SERE_OPS: dict[str, tuple[int, SereOp]] = {
    ";": (10, ";"), ":": (20, ":"),
    **{t: (30, "->") for t in _IMPLIES},
    **{t: (30, "<->") for t in _EQUIV},
    "|": (40, "|"), "||": (40, "|"), "^": (50, "^"), "xor": (50, "^"),
    "&": (60, "&"), "&&": (60, "&&"),
}  # fmt: skip
_UNTIL_PREC = 80
_UNTIL_WORDS: dict[str, UntilOp] = {"U": "U", "W": "W", "R": "R", "M": "M",
                                   "until": "W", "until!": "U"}  # fmt: skip
_PSL_BINARY = {"until_", "until!_", "before", "before!", "before_", "before!_"}
_STEP_WORDS = {"G", "F", "X", "next", "next!", "next_e", "next_e!", "next_a", "next_a!"}
_PAST_WORDS = {"once", "historically", "prev", "since"}
_COMPACT = re.compile(r"([GFX]+)([A-Za-z_]\w*)?")  # Spot's GFp: G F p
_NAMES = {
    "U": "until operator", "W": "weak until operator", "R": "release operator",
    "M": "strong release operator", "until": "until operator", "until!": "until operator",
    "until_": "until operator", "until!_": "until operator", "before": "before operator",
    "before!": "before operator", "before_": "before operator", "before!_": "before operator",
    "since": "since operator", "&": "and operator", "&&": "and operator", "*": "and operator",
    "|": "or operator", "||": "or operator", "^": "xor operator", "xor": "xor operator",
    ";": "concat operator", ":": "fusion operator", ")": "closing parenthesis",
    "}": "closing brace", "|->": "SERE implication", "|=>": "SERE implication",
    ",": "comma",
    **{t: "implication operator" for t in _IMPLIES},
    **{t: "equivalence operator" for t in _EQUIV},
}  # fmt: skip


@dataclass
class _Op:
    """An operator waiting on the stack for its operands (or an open group)."""

    kind: Literal["prefix", "binary", "group"]
    prec: int
    token: Token
    build: Callable[[list[Node], Span], Node] | None = None  # operands, span: the node
    mode: Mode = "ltl"  # a group's mode
    right: bool = False  # binary: right-associative


class Parser:
    """Tokens to a tree: :meth:`parse`; errors go to ``fail``, ``reader.atoms`` holds
    the atoms in placeholder order."""

    def __init__(self, reader: AtomReader, fail: Fail) -> None:
        self.reader = reader
        self.spec = reader.spec
        self.fail = fail
        self.vals: list[Node] = []
        self.ops: list[_Op] = []
        self.stopped = False  # a syntax error: the rest is not read

    # -- the main loop -------------------------------------------------------------------

    def parse(self, toks: Sequence[Token]) -> Node | None:
        if not self._balanced(toks):
            self._atoms_only(toks)  # its atoms' errors too: all fixed in one pass
            return None
        self.toks = toks
        i, expect_operand = 0, True
        while i < len(toks) and not self.stopped:
            if expect_operand:
                i, expect_operand = self._operand(i)
            else:
                i, expect_operand = self._operator(i)
        if self.stopped:
            return None
        if expect_operand:
            if not toks:
                self.fail(0, max(1, len(self.reader.text)), "the assertion is empty", None)
            else:
                last = toks[-1]
                self._syntax(last, f"'{last.text}' needs a formula after it")
            return None
        self._reduce_group()
        return self.vals[-1] if len(self.vals) == 1 and not self.ops else None

    def _mode(self) -> Mode:
        return next((op.mode for op in reversed(self.ops) if op.kind == "group"), "ltl")

    def _syntax(self, t: Token, message: str, hint: str | None = None) -> None:
        self._stop(t.start, max(1, t.end - t.start), message, hint)

    def _stop(self, start: int, length: int, message: str, hint: str | None = None) -> None:
        """A syntax error: reported, and the rest is not read."""
        self.fail(start, length, message, hint)
        self.stopped = True

    def _unexpected(self, t: Token, after_formula: bool) -> None:
        name = _NAMES.get(t.text)
        what = f"{name} '{t.text}'" if name else f"'{t.text}'"
        if not after_formula and t.text in (")", "}") and self.ops and self.ops[-1].kind != "group":
            op = self.ops[-1].token.text
            self._syntax(t, f"'{op}' needs a formula after it",
                         f"write its operand before '{t.text}'")  # fmt: skip
            return
        if after_formula:
            self._syntax(t, f"syntax error, unexpected {what} after a formula",
                         "join formulas with an operator: &, |, ->, U, ...")  # fmt: skip
        else:
            self._syntax(t, f"syntax error, unexpected {what}",
                         "a formula (an atom, or an operator and its operands) goes "
                         "here")  # fmt: skip

    # -- where a formula is expected -----------------------------------------------------

    def _operand(self, i: int) -> tuple[int, bool]:
        """Read at toks[i] where an operand is expected: a leaf (then an operator is
        expected), or a prefix operator or an opening bracket (an operand still is)."""
        toks, t = self.toks, self.toks[i]
        found = self.reader.comparison(toks, i)
        if found is not None:
            index, negate, used = found
            span = (t.start, toks[i + used - 1].end)
            self._leaf(index, negate, span)
            return i + used, False
        if t.kind == "op":
            return self._operand_op(i, t)
        if t.kind == "ident":
            return self._word(i, t)
        if t.kind == "number":
            if t.text in ("0", "1"):
                self.vals.append(Const((t.start, t.end), (t.start, t.end), t.text == "1"))
            else:
                self.fail(t.start, t.end - t.start, f"number {t.text} outside a comparison",
                          "compare it with a signal, e.g. speed < 100")  # fmt: skip
                self._leaf(None, False, (t.start, t.end))
            return i + 1, False
        if t.kind == "string":
            self.fail(t.start, t.end - t.start, f"string {t.text} outside a comparison", None)
            self._leaf(None, False, (t.start, t.end))
            return i + 1, False
        if t.kind == "duration":
            self.fail(t.start, t.end - t.start, f"duration {t.text} outside a comparison",
                      "compare it with age(x), e.g. age(scan) < 200ms")  # fmt: skip
            self._leaf(None, False, (t.start, t.end))
            return i + 1, False
        return self._operand_bracket(i, t)

    def _leaf(self, index: int | None, negate: bool, span: Span) -> None:
        """An atom's placeholder (None: its error is reported; a stand-in goes on)."""
        node: Node = Const(span, span, False) if index is None else Prop(span, span, index)
        self.vals.append(Not(span, span, node) if negate else node)

    def _operand_op(self, i: int, t: Token) -> tuple[int, bool]:
        if t.text in ("(", "{"):
            mode: Mode = "sere" if t.text == "{" else self._mode()
            self.ops.append(_Op("group", -1, t, mode=mode))
        elif t.text == "!":
            self._prefix(t, NOT, lambda v, s: Not(s, _at(t), v[0]))
        elif t.text == "<>":
            self._temporal_prefix(t, UNARY, lambda v, s: Steps(s, _at(t), "F", v[0]))
        elif t.text in CMP_TOKENS:
            self._syntax(t, f"'{t.text}' needs a signal, parameter or number on its left")
        else:
            self._unexpected(t, after_formula=False)
        return i + 1, True

    def _operand_bracket(self, i: int, t: Token) -> tuple[int, bool]:
        if t.text.replace(" ", "") == "[]":
            self._temporal_prefix(t, UNARY, lambda v, s: Steps(s, _at(t), "G", v[0]))
            return i + 1, True
        rep = brackets.repeat(t, self._stop) if self._mode() == "sere" else None
        if rep is False:  # reported
            return i + 1, False
        if rep is not None and rep[0] == "[*":  # a lone [*] or [+] repeats true
            op, lo, hi = rep
            self.vals.append(Repeat(_at(t), _at(t), op, None, lo, hi))
            return i + 1, False
        if brackets.is_time_bound(t):
            brackets.time_bound_on_a_sere(t, self._stop)
        else:
            self._unexpected(t, after_formula=False)
        return i + 1, False

    def _prefix(self, t: Token, prec: int, build: Callable[[list[Node], Span], Node]) -> None:
        self.ops.append(_Op("prefix", prec, t, build))

    def _temporal_prefix(
        self, t: Token, prec: int, build: Callable[[list[Node], Span], Node]
    ) -> None:
        """A temporal operator: not inside a SERE, whose steps are booleans."""
        if self._mode() == "sere":
            self._syntax(t, f"'{t.text}' inside a SERE: a SERE's steps are booleans",
                         "put the temporal operator outside the braces: "
                         "{a ; b} |-> F c")  # fmt: skip
            return
        self._prefix(t, prec, build)

    # -- words -----------------------------------------------------------------------------

    def _word(self, i: int, t: Token) -> tuple[int, bool]:
        w = t.text
        nxt = self.toks[i + 1] if i + 1 < len(self.toks) else None
        bracket = self._bracket_after(i)
        if w in self.spec.signals:
            return self._signal(i, t)
        if w in _PAST_WORDS:
            return self._past_word(i, t, bracket)
        if w in _STEP_WORDS:
            return self._step_word(i, t, bracket)
        if w == "age" and nxt is not None and nxt.text == "(":
            self.fail(t.start, t.end - t.start, "age(x) is a duration, not a proposition",
                      "compare it with a duration, e.g. age(scan) < 200ms")  # fmt: skip
            self._leaf(None, False, _at(t))
            return i + 4, False  # age ( x )
        if w in self.spec.parameters:
            self.fail(t.start, t.end - t.start, f"parameter '{w}' used as a proposition",
                      "parameters are constants: compare a signal with it, e.g. speed < "
                      + w)  # fmt: skip
            self._leaf(None, False, _at(t))
            return i + 1, False
        if w in ("true", "false"):
            self.vals.append(Const(_at(t), _at(t), w == "true"))
            return i + 1, False
        if w in ("always", "never", "eventually!"):
            op = {"always": "G", "never": "G", "eventually!": "F"}[w]
            neg = w == "never"

            def loose(v: list[Node], s: Span) -> Node:
                operand = Not(v[0].span, _at(t), v[0]) if neg else v[0]
                return Steps(s, _at(t), op, operand)  # type: ignore[arg-type]

            self._temporal_prefix(t, LOOSE, loose)
            return i + 1, True
        if w == "first_match" and nxt is not None and nxt.text == "(":
            self._prefix(t, TIGHT, lambda v, s: FirstMatch(s, _at(t), v[0]))
            return i + 1, True
        if w == "eventually":
            self._syntax(t, "PSL's 'eventually' is written 'eventually!'",
                         "or use the LTL operator F")  # fmt: skip
            return i + 1, True
        if (m := _COMPACT.fullmatch(w)) and m.group(2) in (
            None,
            "true",
            "false",
            *self.spec.signals,
        ):
            letters = m.group(1)
            for k, letter in enumerate(letters):  # Spot's GFp is G F p; XX[2] is X X[2]
                tk = Token("ident", letter, t.start + k, t.start + k + 1)
                last = k == len(letters) - 1 and m.group(2) is None
                if last:
                    return self._step_word(i, tk, bracket)
                self._step_word(i, tk, None)
            rest = Token("ident", m.group(2), t.start + len(m.group(1)), t.end)
            if rest.text in ("true", "false"):
                self.vals.append(Const(_at(rest), _at(rest), rest.text == "true"))
                return i + 1, False
            return self._signal(i, rest)
        if w in _UNTIL_WORDS or w in _PSL_BINARY or w == "xor":
            self._unexpected(t, after_formula=False)
            return i + 1, True
        self.reader.unknown(t)
        self._leaf(None, False, _at(t))
        return i + 1, False

    def _bracket_after(self, i: int) -> Token | None:
        """The bracket after the operator at toks[i], its bound or range (``[]`` is G)."""
        nxt = self.toks[i + 1] if i + 1 < len(self.toks) else None
        if nxt is None or nxt.kind != "bracket" or nxt.text.replace(" ", "") == "[]":
            return None
        return nxt

    def _signal(self, i: int, t: Token) -> tuple[int, bool]:
        sig = self.spec.signals[t.text]
        if sig.kind != "bool":
            self.fail(t.start, t.end - t.start,
                      f"'{t.text}' is a {sig.kind} signal, not a proposition",
                      f"compare it, e.g. {t.text} > 0")  # fmt: skip
            self._leaf(None, False, _at(t))
        else:
            index = self.reader.add_atom(Atom(Operand(t.text), "==", Operand(None, True), t.text))
            self._leaf(index, False, _at(t))
        return i + 1, False

    def _past_word(self, i: int, t: Token, bracket: Token | None) -> tuple[int, bool]:
        w = t.text
        if w == "since":
            self._unexpected(t, after_formula=False)
            return i + 1, True
        window = None
        used = 1
        if bracket is not None and w != "prev":
            window = brackets.window(bracket, self._stop)
            used = 2
            if window is None:
                return i + used, True
        at = (t.start, bracket.end if used == 2 and bracket else t.end)
        name = w

        def build(v: list[Node], s: Span) -> Node:
            return Past(s, at, name, window, (v[0],))  # type: ignore[arg-type]

        self._prefix(t, UNARY, build)
        return i + used, True

    def _step_word(self, i: int, t: Token, bracket: Token | None) -> tuple[int, bool]:
        """G, F, X and PSL's next forms, with a step range or a time bound or neither."""
        w = t.text
        at_ = _at(t) if bracket is None else (t.start, bracket.end)
        used = 1 if bracket is None else 2
        op: Literal["X", "F", "G"] = (
            "X" if w in ("X", "next", "next!") else "F" if w in ("F", "next_e", "next_e!")
            else "G"
        )  # fmt: skip
        if bracket is not None and brackets.is_time_bound(bracket):
            if op == "X":
                self._syntax(t, f"'{w}' counts steps: it takes no duration",
                             "for a time bound use F[0..500ms] f or G[0..2s] f")  # fmt: skip
                return i + used, True
            window = brackets.window(bracket, self._stop)
            if window is None:
                return i + used, True
            timed = op

            def build_timed(v: list[Node], s: Span) -> Node:
                return Timed(s, at_, timed, window, (v[0],))

            self._temporal_prefix(t, UNARY, build_timed)
            return i + used, True
        if w.startswith(("next_e", "next_a")) and bracket is None:
            self._syntax(t, f"'{w}' needs a range", f"write e.g. {w}[1..3] f")
            return i + 1, True
        lo = hi = None
        strong = False
        if bracket is not None:
            steps = brackets.steps(bracket, op, self._stop)
            if steps is None:
                return i + used, True
            lo, hi, strong = steps

        def build(v: list[Node], s: Span) -> Node:
            return Steps(s, at_, op, v[0], lo, hi, strong)

        self._temporal_prefix(t, NEXT if op == "X" else UNARY, build)
        return i + used, True

    # -- where an operator is expected ---------------------------------------------------

    def _operator(self, i: int) -> tuple[int, bool]:
        t = self.toks[i]
        mode = self._mode()
        if t.kind == "op" and t.text in (")", "}"):
            return self._close(i, t)
        if t.kind == "op" and mode == "sere" and t.text == "*":
            self._postfix(t, "[*", 0, UNBOUNDED)
            return i + 1, False
        if t.kind == "bracket":
            rep = brackets.repeat(t, self._stop) if mode == "sere" else None
            if rep is False:  # reported
                return i + 1, False
            if rep is not None:
                self._postfix(t, *rep)
            elif brackets.is_time_bound(t):
                brackets.time_bound_on_a_sere(t, self._stop)
            else:
                self._unexpected(t, after_formula=True)
            return i + 1, False
        text = t.text
        if t.kind == "op" and mode == "sere" and text in _SERE_OPS:
            prec, sop = _SERE_OPS[text]
            self._binary(t, prec, sop in ("->", "<->"), _sere(sop, t))
            return i + 1, True
        if t.kind == "op" and mode == "ltl" and text in _LTL_BOOL:
            prec, bop = _LTL_BOOL[text]
            self._binary(t, prec, bop in ("->", "<->"), _bool(bop, t))
            return i + 1, True
        if t.kind == "ident" and text == "xor":
            if mode == "sere":
                self._binary(t, 50, False, _sere("^", t))
            else:
                self._binary(t, 50, False, _bool("^", t))
            return i + 1, True
        if t.kind == "ident" and (text in _UNTIL_WORDS or text in _PSL_BINARY or text == "since"):
            return self._until_word(i, t)
        if t.kind == "op" and text in (";", ":"):
            self._syntax(t, f"'{text}' joins the steps of a SERE, inside braces",
                         "e.g. {a ; b[*]} |-> c")  # fmt: skip
            return i + 1, True
        self._unexpected(t, after_formula=True)
        return i + 1, True

    def _until_word(self, i: int, t: Token) -> tuple[int, bool]:
        w = t.text
        bracket = self._bracket_after(i)
        at_ = _at(t) if bracket is None else (t.start, bracket.end)
        used = 1 if bracket is None else 2
        if w != "since" and self._mode() == "sere":
            self._syntax(t, f"'{w}' inside a SERE: a SERE's steps are booleans",
                         "put the temporal operator outside the braces")  # fmt: skip
            return i + used, True
        if w == "since":
            window = brackets.window(bracket, self._stop) if bracket is not None else None
            if bracket is not None and window is None:
                return i + used, True

            def since(v: list[Node], s: Span) -> Node:
                return Past(s, at_, "since", window, (v[0], v[1]))

            self._binary(t, _UNTIL_PREC, True, since)
            return i + used, True
        if bracket is not None:
            if w not in _UNTIL_WORDS or not brackets.is_time_bound(bracket):
                self._syntax(bracket, f"'{w}' takes a time bound, not steps"
                             if w in _UNTIL_WORDS else f"'{w}' takes no bound",
                             f"give the bounds units, e.g. a {w}[0..500ms] b"
                             if w in _UNTIL_WORDS else None)  # fmt: skip
                return i + used, True
            window = brackets.window(bracket, self._stop)
            if window is None:
                return i + used, True
            top = _UNTIL_WORDS[w]

            def timed(v: list[Node], s: Span) -> Node:
                return Timed(s, at_, top, window, (v[0], v[1]))

            self._binary(t, _UNTIL_PREC, True, timed)
            return i + used, True
        self._binary(t, _UNTIL_PREC, True, _psl_binary(w, at_))
        return i + 1, True

    def _binary(
        self, t: Token, prec: int, right: bool, build: Callable[[list[Node], Span], Node]
    ) -> None:
        self._reduce_while(lambda op: op.prec > prec or (op.prec == prec and not right))
        self.ops.append(_Op("binary", prec, t, build, right=right))

    def _postfix(self, t: Token, op: RepeatOp, lo: int, hi: int) -> None:
        self._reduce_while(lambda o: o.prec > REPEAT)
        operand = self.vals.pop()
        self.vals.append(Repeat((operand.span[0], t.end), _at(t), op, operand, lo, hi))

    def _close(self, i: int, t: Token) -> tuple[int, bool]:
        self._reduce_group()
        group = self.ops.pop()
        value = self.vals.pop()
        self.vals.append(replace(value, span=(group.token.start, t.end)))
        if t.text == ")" or self._mode() == "sere":
            return i + 1, False  # a parenthesis, or braces inside a SERE: a group
        return self._braced(i + 1, group.token, t)

    def _braced(self, i: int, open_: Token, close: Token) -> tuple[int, bool]:
        """A braced SERE where a formula is: ``{r}``, ``{r}!``, ``{r} |-> f``, ``{r}(f)``."""
        sere = self.vals.pop()
        toks = self.toks
        t = toks[i] if i < len(toks) else None
        u = toks[i + 1] if i + 1 < len(toks) else None
        arrow = None
        if t is not None and t.text in ("|->", "|=>"):
            arrow, used = t.text, 1
        elif t is not None and u is not None and t.text in ("[]", "<>") and u.text in ("->", "=>"):
            arrow, used = t.text + u.text, 2
        if arrow is not None:
            universal = arrow[0] in "|["
            if arrow.endswith("=>"):  # non-overlapping: {r;1}
                one = Const(_at(close), _at(close), True)
                sere = Sere(sere.span, _at(close), ";", sere, one)
            start = open_.start
            at_ = (toks[i].start, toks[i + used - 1].end)
            body = sere

            def suffix(v: list[Node], s: Span) -> Node:
                return Suffix((start, s[1]), at_, universal, body, v[0])

            self._prefix(toks[i], LOOSE, suffix)
            return i + used, True
        if t is not None and t.text == "(" and t.kind == "op":
            body2 = sere

            def uconcat(v: list[Node], s: Span) -> Node:
                return Suffix((open_.start, s[1]), _at(close), True, body2, v[0])

            self._prefix(close, TIGHT, uconcat)
            return i, True
        if t is not None and t.text == "!" and t.kind == "op":
            self.vals.append(Closure((open_.start, t.end), _at(close), sere, True))
            return i + 1, False
        if t is not None and t.kind == "bracket" and brackets.is_time_bound(t):
            brackets.time_bound_on_a_sere(t, self._stop)
            return i + 1, False
        self.vals.append(Closure((open_.start, close.end), _at(close), sere, False))
        return i, False

    # -- the stacks ------------------------------------------------------------------------

    def _reduce_while(self, cond: Callable[[_Op], bool]) -> None:
        while self.ops and self.ops[-1].kind != "group" and cond(self.ops[-1]):
            self._reduce_one()

    def _reduce_group(self) -> None:
        """Reduce every operator down to the innermost open group (all, outside one)."""
        while self.ops and self.ops[-1].kind != "group":
            self._reduce_one()

    def _reduce_one(self) -> None:
        op = self.ops.pop()
        assert op.build is not None
        if op.kind == "prefix":
            operand = self.vals.pop()
            span = (min(op.token.start, operand.span[0]), operand.span[1])
            self.vals.append(op.build([operand], span))
        else:
            right = self.vals.pop()
            left = self.vals.pop()
            self.vals.append(op.build([left, right], (left.span[0], right.span[1])))

    # -- brackets --------------------------------------------------------------------------

    def _atoms_only(self, toks: Sequence[Token]) -> None:
        """Where the brackets do not balance, no tree: report what is wrong in the atoms
        (a comparison, an unknown name) as the parse would have."""
        i = 0
        while i < len(toks):
            found = self.reader.comparison(toks, i)
            if found is not None:
                i += found[2]
                continue
            t = toks[i]
            if t.kind == "ident" and not (
                t.text in self.spec.signals or t.text in self.spec.parameters or _is_word(t.text)
            ):
                self.reader.unknown(t)
            i += 1

    def _balanced(self, toks: Sequence[Token]) -> bool:
        """Unbalanced ( ) and { } are reported at the user's own bracket."""
        stack: list[Token] = []
        pairs = {")": "(", "}": "{"}
        for t in toks:
            if t.kind != "op":
                continue
            if t.text in ("(", "{"):
                stack.append(t)
            elif t.text in (")", "}"):
                if not stack or stack[-1].text != pairs[t.text]:
                    self.fail(t.start, 1, f"'{t.text}' closes nothing",
                              "remove it or add the opening bracket")  # fmt: skip
                    return False
                stack.pop()
        if stack:
            t = stack[-1]
            close = ")" if t.text == "(" else "}"
            self.fail(t.start, 1, f"'{t.text}' is never closed",
                      f"add '{close}' where the group ends")  # fmt: skip
            return False
        return True


def _is_word(w: str) -> bool:
    """An operator or constant of the language (``G``, ``until!_``, ``GF``, ``true``)."""
    return (
        w in _UNTIL_WORDS or w in _PSL_BINARY or w in _STEP_WORDS or w in _PAST_WORDS
        or w in ("true", "false", "xor", "age", "always", "never", "eventually!",
                 "eventually", "first_match")
        or _COMPACT.fullmatch(w) is not None
    )  # fmt: skip


def _at(t: Token) -> Span:
    return (t.start, t.end)


def _bool(op: BoolOp, t: Token) -> Callable[[list[Node], Span], Node]:
    return lambda v, s: Binary(s, _at(t), op, v[0], v[1])


def _sere(op: SereOp, t: Token) -> Callable[[list[Node], Span], Node]:
    return lambda v, s: Sere(s, _at(t), op, v[0], v[1])


def _psl_binary(w: str, at: Span) -> Callable[[list[Node], Span], Node]:
    """``a until b`` and PSL's other keywords as Spot's operators (docs/semantics.md's
    table): ``until_`` repeats its left operand, shared in the tree, not copied."""

    def build(v: list[Node], s: Span) -> Node:
        left, right = v
        if w in _UNTIL_WORDS:
            return Until(s, at, _UNTIL_WORDS[w], left, right)
        if w in ("until_", "until!_"):
            both = Binary(s, at, "&", left, right)
            return Until(s, at, "W" if w == "until_" else "U", left, both)
        not_right = Not(right.span, at, right)
        if w in ("before", "before!"):
            return Until(s, at, "R" if w == "before" else "M", left, not_right)
        return Until(s, at, "W" if w == "before_" else "U", not_right, left)

    return build
