"""The parser against Spot's own: the same formula for every text both read.

edgerv's parser (edgerv.core.language.parser) reads Spot's infix LTL/PSL grammar
itself, into a typed tree, and the lowering builds Spot's formula from it by Spot's
constructors. Spot's parser (``spot.parse_infix_psl``, an independent LALR parser)
is the reference: on random formulas over three signals, written with every
operator and spelling, SEREs, step ranges, and as few parentheses as precedence
allows (so that precedence and associativity decide the reading), both give the
same formula. On mutated texts (tokens deleted, doubled, swapped), whatever edgerv
accepts Spot reads as the same formula, and whatever Spot reads without an error
edgerv accepts, but for the points of definition below, each with its own test.
"""

from __future__ import annotations

from typing import Any

import pytest
import spot
from hypothesis import given
from hypothesis import strategies as st

from edgerv.core.diagnostics import InputError
from edgerv.core.language.comparisons import AtomReader
from edgerv.core.language.formula import Lowering
from edgerv.core.language.lexer import tokenize
from edgerv.core.language.parser import Parser
from kit.counts import props
from kit.documents import spec_of

SIGNALS = {"a": "bool", "b": "bool", "c": "bool"}


def ours(text: str) -> Any:
    """edgerv's formula for ``text`` over the signals' own names, None if refused."""
    errors: list[str] = []

    def fail(start: int, length: int, message: str, hint: str | None = None) -> None:
        errors.append(message)

    try:
        spec = spec_of(text, SIGNALS)
    except InputError:  # an empty assertion: the document's own error
        return None
    tokens = tokenize(text, fail)
    reader = AtomReader(spec, fail)
    tree = Parser(reader, fail).parse(tokens) if not errors else None
    if errors or tree is None:
        return None
    formula = Lowering(text, fail, len(reader.atoms)).lower(tree)
    if errors or formula is None:
        return None
    names = spot.relabeling_map()
    for i, atom in enumerate(reader.atoms):
        names[spot.formula.ap(f"p{i}")] = spot.formula.ap(atom.text)
    return spot.relabel_apply(formula, names)


def spots(text: str) -> Any:
    """Spot's formula for ``text``, None if its parser reports any error or reads a
    proposition that is none of the signals (``X1`` is one word to both)."""
    parsed = spot.parse_infix_psl(text)
    if parsed.format_errors(spot.ostringstream()):
        return None
    names = {ap.ap_name() for ap in spot.atomic_prop_collect(parsed.f)}
    return parsed.f if names <= set(SIGNALS) else None


def same(got: Any, expected: Any) -> bool:
    """The same formula: printed alike, or (where Spot's parser keeps a form its
    constructors simplify, ``{[*] & a}`` for ``a``) the same language."""
    return got is not None and (str(got) == str(expected) or spot.are_equivalent(got, expected))


# -- formulas, printed with the fewest parentheses ------------------------------------------

AND, OR, XOR, IMPLIES, EQUIV = ["&", "&&", "*"], ["|", "||"], ["^", "xor"], \
    ["->", "-->", "=>"], ["<->", "<-->", "<=>"]  # fmt: skip
BINARY = [*AND, *OR, *XOR, *IMPLIES, *EQUIV, "U", "W", "R", "M"]
UNARY = ["!", "X", "F", "G", "[]", "<>", "X[2]", "X[!]", "F[1..3]", "G[0..2]", "F[2..]",
         "G[1:3]", "X[0]"]  # fmt: skip
SERE_BINARY = [";", ":", "|", "&", "&&"]
SERE_POSTFIX = ["[*]", "[*2]", "[*1..3]", "[*..2]", "[*1..]", "[+]", "[:*]", "[:+]",
                "[:*1..2]", "*"]  # fmt: skip
BOOL_POSTFIX = ["[=2]", "[=1..3]", "[->]", "[->2]", "[->1..]"]
SUFFIX = ["|->", "|=>", "[]->", "<>->", "[]=>", "<>=>"]


@st.composite
def booleans(draw: st.DrawFn, depth: int = 2) -> str:
    if depth == 0 or draw(st.booleans()):
        return draw(st.sampled_from(["a", "b", "c", "true", "false", "1", "0"]))
    left, right = draw(booleans(depth - 1)), draw(booleans(depth - 1))
    form = draw(st.sampled_from(["not", "and", "or", "xor"]))
    if form == "not":
        return f"!{left}"
    op = {"and": draw(st.sampled_from(AND[:2])), "or": "|", "xor": "^"}[form]
    return f"({left} {op} {right})" if draw(st.booleans()) else f"{left} {op} {right}"


@st.composite
def seres(draw: st.DrawFn, depth: int = 3) -> str:
    if depth == 0 or draw(st.integers(0, 3)) == 0:
        if draw(st.integers(0, 5)) == 0:
            return draw(st.sampled_from(["[*]", "[+]", "[*2]"]))
        return draw(booleans(1))
    form = draw(st.sampled_from(["binary", "postfix", "bool-postfix", "braced", "first"]))
    one = draw(seres(depth - 1))
    if form == "binary":
        return f"{one} {draw(st.sampled_from(SERE_BINARY))} {draw(seres(depth - 1))}"
    if form == "postfix":
        return f"{{{one}}}{draw(st.sampled_from(SERE_POSTFIX))}"
    if form == "bool-postfix":
        return f"{draw(st.sampled_from(['a', 'b']))}{draw(st.sampled_from(BOOL_POSTFIX))}"
    if form == "first":
        return f"first_match({one})"
    return f"{{{one}}}"


@st.composite
def formulas(draw: st.DrawFn, depth: int = 4) -> str:
    if depth == 0 or draw(st.integers(0, 4)) == 0:
        leaf = draw(st.sampled_from(["atom", "atom", "atom", "sere"]))
        if leaf == "atom":
            return draw(st.sampled_from(["a", "b", "c", "true", "false", "1", "0"]))
        sere = draw(seres(2))
        tail = draw(st.sampled_from(["", "!", "suffix", "paren"]))
        if tail == "suffix":
            return f"{{{sere}}} {draw(st.sampled_from(SUFFIX))} {draw(formulas(depth - 1))}"
        if tail == "paren":
            return f"{{{sere}}}({draw(formulas(depth - 1))})"
        return f"{{{sere}}}{tail}"
    if draw(st.booleans()):
        op = draw(st.sampled_from(UNARY))
        operand = draw(formulas(depth - 1))
        joined = op == "!" or (draw(st.booleans()) and not operand[0].isdigit())  # X1 is a word
        return f"{op}{'' if joined else ' '}{operand}"
    left, right = draw(formulas(depth - 1)), draw(formulas(depth - 1))
    op = draw(st.sampled_from(BINARY))
    text = f"{left} {op} {right}"
    return f"({text})" if draw(st.integers(0, 3)) == 0 else text


@props(120)
@given(formulas())
def test_every_formula_reads_as_spots_parser_reads_it(text: str) -> None:
    expected = spots(text)
    got = ours(text)
    if expected is None:  # Spot refuses it (a SERE where a formula is): so do we
        assert got is None, (text, str(got))
    else:
        assert same(got, expected), (text, str(got), str(expected))


# -- mutated ---------------------------------------------------------------------------------

TOKENS = ["a", "b", "(", ")", "{", "}", "!", "&", "|", "->", "U", "X", "F", "G", ";", ":",
          "[*]", "[->]", "|->", "[]", "<>", "^", "R", "W", "M", "true", "[=2]", "*",
          "&&"]  # fmt: skip


@st.composite
def mutated(draw: st.DrawFn) -> str:
    words = draw(formulas(3)).split(" ")
    for _ in range(draw(st.integers(1, 3))):
        if not words:
            break
        k = draw(st.integers(0, len(words) - 1))
        how = draw(st.sampled_from(["delete", "double", "swap", "insert"]))
        if how == "delete":
            del words[k]
        elif how == "double":
            words.insert(k, words[k])
        elif how == "swap" and k + 1 < len(words):
            words[k], words[k + 1] = words[k + 1], words[k]
        else:
            words.insert(k, draw(st.sampled_from(TOKENS)))
    return " ".join(words)


@props(120)
@given(mutated())
def test_what_either_accepts_both_read_alike(text: str) -> None:
    expected = spots(text)
    got = ours(text)
    if got is not None:
        assert expected is not None and same(got, expected), (text, str(got))
    elif expected is not None:
        assert text_is_a_point_of_definition(text), (text, str(expected))


def text_is_a_point_of_definition(text: str) -> bool:
    """Spot reads it, edgerv refuses it: one of the differences tested below."""
    return any(d in text for d in ("{} ", "{}", "[*0]"))


# -- the points of definition ----------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "spot_reads"),
    [
        ("F[3..1] a", "F[1..3] a"),  # Spot swaps a reversed range of F silently
        ("G[4..2] a", "G[2..4] a"),
    ],
)
def test_a_reversed_step_range_is_an_error_not_swapped(text: str, spot_reads: str) -> None:
    assert str(spots(text)) == str(spots(spot_reads))
    assert ours(text) is None


@pytest.mark.parametrize(
    ("text", "reads_as"),
    [
        ("a ==> b", "a -> b"),  # the paper's spellings beside Spot's: Spot has no ==>
        ("a <==> b", "a <-> b"),
        ("X [2] a", "X[2] a"),  # a bracket a space away from its operator is its own
        ("{b} [] -> a", "{b}[]-> a"),  # Spot: "ignoring trailing garbage"
    ],
)
def test_spellings_spot_lacks_read_as_its_own(text: str, reads_as: str) -> None:
    assert same(ours(text), spots(reads_as))
