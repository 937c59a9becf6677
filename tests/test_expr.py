"""The expression language: what parses, what is refused (and where), what it computes."""

from __future__ import annotations

import pytest

from hmi.errors import SourcePos
from hmi.logic.expr import (
    ExprError,
    Literal,
    NotMonomial,
    compile_bool,
    max_depth,
    monomial_literals,
    parse_expr,
)

POS = SourcePos("f.yaml", 3, 10)
SLOTS = {"a": 0, "b": 1, "c": 2}


def ev(text: str, now: list, *history: list) -> bool:
    return compile_bool(parse_expr(text, POS), SLOTS)(now, list(history))


@pytest.mark.parametrize("text,now,expected", [
    ("a and b", [1, 1, 0], True),
    ("a and b", [1, 0, 0], False),
    ("a or b", [0, 1, 0], True),
    ("not a", [0, 0, 0], True),
    ("not a and b", [0, 1, 0], True),  # not binds tighter than and, as in the papers
    ("not (a and b)", [1, 1, 0], False),
    ("a and b or c", [0, 0, 1], True),
    ("a and (b or c)", [1, 0, 1], True),
    ("True", [0, 0, 0], True),
    ("False or a", [1, 0, 0], True),
    ("1 and a", [1, 0, 0], True),
    ("a and b and c", [1, 1, 1], True),
    ("a and b and c", [1, 1, 0], False),
    ("a or b or c", [0, 0, 0], False),
])
def test_boolean_semantics(text, now, expected):
    assert ev(text, [bool(x) for x in now], [False] * 3) is expected


def test_prev_reads_the_previous_scan():
    now, before = [True, False, False], [False, True, False]
    assert ev("prev(a)", now, before) is False
    assert ev("prev(b)", now, before) is True


def test_prev_at_depth_n_reads_n_scans_back():
    h1, h2, h3 = [False] * 3, [True, False, False], [False, True, False]
    now = [False] * 3
    assert ev("prev(a, 2)", now, h1, h2, h3) is True
    assert ev("prev(a, 3)", now, h1, h2, h3) is False
    assert ev("prev(b, 3)", now, h1, h2, h3) is True
    assert max_depth(parse_expr("prev(a, 3) and prev(b)", POS)) == 3


@pytest.mark.parametrize("prev_a,a,rise,fall", [
    (False, True, True, False), (True, False, False, True),
    (True, True, False, False), (False, False, False, False)])
def test_edges(prev_a, a, rise, fall):
    now, before = [a, False, False], [prev_a, False, False]
    assert ev("rise(a)", now, before) is rise
    assert ev("fall(a)", now, before) is fall


def test_step_time_comparison_uses_microseconds():
    expr = parse_expr("X3.t >= 2s and a", POS)
    fn = compile_bool(expr, {"a": 0, "X3": 1}, {"X3": 2})
    assert fn([True, True, 1_999_999], []) is False
    assert fn([True, True, 2_000_000], []) is True
    fn2 = compile_bool(parse_expr("X3.t < 500ms", POS), {"X3": 1}, {"X3": 2})
    assert fn2([False, True, 499_999], []) is True


@pytest.mark.parametrize("text,col,fragment", [
    ("a and and b", 6, "syntax error"),
    ("a + b", 0, "arithmetic operator '+'"),
    ("max(a)", 0, "function 'max' is not allowed"),
    ("prev(a, b)", 8, "depth of prev() must be a whole number"),
    ("prev(a, 0)", 8, "out of range"),
    ("rise(a and b)", 5, "applies to a variable name"),
    ("rise(a, 2)", 0, "given 2 arguments"),
    ("a.x", 0, "attribute .x"),
    ("a >= b", 0, "only times can be compared"),
    ("X1.t >= 1s >= 2s", 0, "chained comparisons"),
    ("a[0]", 0, "indexing"),
    ("2", 0, "the constant 2"),
    ("'text'", 0, "the constant 'text'"),
    ("X1.t", 0, "a time value alone"),
    ("a if b else c", 0, "if/else"),
    ("lambda: a", 0, "lambda"),
    ("__import__('os')", 0, "function '__import__'"),
])
def test_refused_constructs_point_at_the_offending_column(text, col, fragment):
    with pytest.raises(ExprError) as info:
        parse_expr(text, POS)
    assert fragment in info.value.message
    assert info.value.pos == SourcePos("f.yaml", 3, 10 + col)


def test_durations_inside_expressions_keep_columns():
    # "2s" is rewritten internally; an error after it must still point at the right column.
    with pytest.raises(ExprError) as info:
        parse_expr("X1.t >= 2s and a + b", POS)
    assert info.value.pos.col == 10 + 15


def test_monomial_literals_of_constraints():
    lits = monomial_literals(parse_expr("rise(C) and not fso", POS))
    assert lits == (Literal("C", 0, True), Literal("C", 1, False), Literal("fso", 0, False))
    lits = monomial_literals(parse_expr("prev(C) and not C and not fsc", POS))
    assert lits == (Literal("C", 1, True), Literal("C", 0, False), Literal("fsc", 0, False))


def test_monomial_never_true_and_non_monomials():
    assert monomial_literals(parse_expr("a and not a", POS)) is None
    assert monomial_literals(parse_expr("a and False", POS)) is None
    for text in ("a or b", "not (a and b)", "a and (b or c)", "X1.t > 1s and a",
                 "not rise(a)"):
        with pytest.raises(NotMonomial):
            monomial_literals(parse_expr(text, POS))


def test_no_python_evaluation_ever(monkeypatch):
    import builtins

    def forbidden(*args, **kwargs):
        raise AssertionError("eval/exec must never be called")
    monkeypatch.setattr(builtins, "eval", forbidden)
    monkeypatch.setattr(builtins, "exec", forbidden)
    assert ev("a and not prev(b)", [True, False, False], [False, False, False]) is True
