"""The assertion language: placeholders, PSL keywords, paper spellings, precise errors."""

from __future__ import annotations

import pytest
import spot

from edgerv.core.diagnostics import InputError
from edgerv.core.language.assertion import parse_assertion
from kit.documents import spec_of

SIGNALS = {"a": "bool", "b": "bool", "c": "bool", "speed": "float", "n": "int", "mode": "string"}


def parsed(assertion: str, **spec):  # type: ignore[no-untyped-def]
    return parse_assertion(spec_of(assertion, SIGNALS, **spec))


def error_of(assertion: str, **spec) -> str:  # type: ignore[no-untyped-def]
    with pytest.raises(InputError) as info:
        parsed(assertion, **spec)
    return str(info.value)


# Each PSL or paper spelling, and the LTL it must mean (placeholders in order of first use).
EQUIVALENT = [
    ("always (a -> (b until c))", "G(p0 -> (p1 W p2))"),
    ("always a -> b", "G(p0 -> p1)"),  # PSL: always binds looser than ->
    ("always(a && b || !c)", "G((p0 & p1) | !p2)"),
    ("never a", "G !p0"),
    ("eventually! a", "F p0"),
    ("next a", "X p0"),
    ("next! a", "X p0"),
    ("next[2] a", "X X p0"),
    ("next_e[1..3] a", "X(p0 | X(p0 | X p0))"),
    ("next_a[1..2] a", "X(p0 & X p0)"),
    ("a until! b", "p0 U p1"),
    ("a until_ b", "p0 W (p0 & p1)"),
    ("a until!_ b", "p0 U (p0 & p1)"),
    ("a before b", "!p1 W (p0 & !p1)"),  # the textbook definition of PSL's before
    ("a before! b", "!p1 U (p0 & !p1)"),
    ("a before_ b", "!p1 W p0"),
    ("a before!_ b", "!p1 U p0"),
    ("always a before b", "G(!p1 W (p0 & !p1))"),
    ("a & b before c | a", "p0 | (p0 & (!p2 W (p1 & !p2)))"),
    ("GFa", "G F p0"),
    ("G(a -> Fb)", "G(p0 -> F p1)"),
    ("a xor b", "p0 xor p1"),
    ("a <-> b", "p0 <-> p1"),
    ("a M b", "p0 M p1"),
    ("a R b", "p0 R p1"),
    ("{a;b[*]} |-> c", "{p0;p1[*]} |-> p2"),
    ("always (a -> eventually! b)", "G(p0 -> F p1)"),
    ("true U a", "F p0"),
]


@pytest.mark.parametrize(("psl", "ltl"), EQUIVALENT)
def test_keywords_mean_the_ltl_operators(psl: str, ltl: str) -> None:
    assert spot.are_equivalent(parsed(psl).formula, spot.formula(ltl)), parsed(psl).spot_text


def test_the_papers_running_example_gets_three_placeholders() -> None:
    p = parse_assertion(
        spec_of(
            "always (running -> (speed < limit until stop))",
            {"running": "bool", "speed": "float", "stop": "bool"},
            parameters={"limit": 100},
        )
    )
    assert [a.text for a in p.atoms] == ["running", "speed < limit", "stop"]
    assert spot.are_equivalent(p.formula, spot.formula("G(p0 -> (p1 W p2))"))


def test_the_same_atom_written_twice_is_one_placeholder() -> None:
    p = parsed("speed < 100 & 100 > speed & n = 3 & n == 3 & !(n != 3)")
    assert [a.text for a in p.atoms] == ["speed < 100", "n = 3"]


def test_bool_comparisons_fold_into_the_signal_placeholder() -> None:
    p = parsed("(a == true) & (b = false) & (c != false)")
    assert len(p.atoms) == 3
    assert spot.are_equivalent(p.formula, spot.formula("p0 & !p1 & p2"))


def test_parameters_negative_numbers_and_strings() -> None:
    p = parsed('speed >= -2.5 & n < lim & mode == "AUTO"', parameters={"lim": 7})
    assert [(a.op, a.rhs.value) for a in p.atoms] == [(">=", -2.5), ("<", 7), ("==", "AUTO")]


def test_signal_on_both_sides() -> None:
    p = parse_assertion(spec_of("x < y", {"x": "float", "y": "int"}))
    assert p.atoms[0].signals == ("x", "y")


@pytest.mark.parametrize(
    ("assertion", "col", "message"),
    [
        ("always (a -> (sped < 100 until c))", 28, "unknown signal or parameter 'sped'"),
        ("speed < lim", 22, "unknown signal or parameter 'lim'"),
        ("a < 3", 14, "type mismatch in 'a < 3': a is a boolean, 3 is a number"),
        ('mode < "x"', 19, "'<' does not apply to strings"),
        ("speed", 14, "'speed' is a float signal, not a proposition"),
        ("always (a -> (b U c)", 21, "'(' is never closed"),
        ("a -> b)", 20, "')' closes nothing"),
        ("a U U b", 18, "syntax error, unexpected until operator"),
        ("3 < 4", 14, "'3 < 4' compares two constants"),
        ("a & 42", 18, "number 42 outside a comparison"),
        ("eventually a", 14, "PSL's 'eventually' is written 'eventually!'"),
        ("speed <", 20, "'<' must be followed by a signal, parameter or number, found nothing"),
        ("a $ b", 16, "unexpected character '$'"),
    ],
)
def test_errors_point_at_the_offending_token(assertion: str, col: int, message: str) -> None:
    text = error_of(assertion)
    first = text.splitlines()[0]
    assert first.startswith(f"test.yaml:6:{col}: error: ")
    assert message in first


def test_unknown_name_suggests_the_close_one() -> None:
    assert "did you mean 'speed'?" in error_of("sped < 3")


def test_error_positions_inside_a_quoted_multiline_document() -> None:
    from edgerv.core.documents import load_monitors_text

    text = (
        "apiVersion: edgerv.io/v1alpha1\nkind: Monitor\nmetadata: {name: m}\nspec:\n"
        "  signals: {a: {topic: /a, type: std_msgs/msg/Bool}}\n"
        '  assertion: "always (a ->\n    nope)"\n'
    )
    spec = load_monitors_text("doc.yaml", text)[0]
    with pytest.raises(InputError) as info:
        parse_assertion(spec)
    assert str(info.value).startswith("doc.yaml:7:5: error: unknown signal or parameter 'nope'")


def test_block_scalar_positions() -> None:
    from edgerv.core.documents import load_monitors_text

    text = (
        "apiVersion: edgerv.io/v1alpha1\nkind: Monitor\nmetadata: {name: m}\nspec:\n"
        "  signals: {a: {topic: /a, type: std_msgs/msg/Bool}}\n"
        "  assertion: |\n    always (a ->\n        a & b)\n"
    )
    spec = load_monitors_text("doc.yaml", text)[0]
    with pytest.raises(InputError) as info:
        parse_assertion(spec)
    assert str(info.value).startswith("doc.yaml:8:13: error: unknown signal or parameter 'b'")


def test_unsatisfiable_and_valid_assertions_are_warned() -> None:
    assert "can never hold" in parsed("a & !a").warnings[0].message
    assert "always holds" in parsed("G(a | !a)").warnings[0].message
    # valid only because an int cannot be both < 3 and >= 3 -- the placeholders alone are not
    assert "always holds" in parsed("G(n < 3 | n >= 3)").warnings[0].message
    # a float may be NaN, for which both comparisons are false: not valid
    assert parsed("G(speed < 3 | speed >= 3)").warnings == ()
    assert parsed("G(a -> F b)").warnings == ()
