"""``hild ctl pub``'s values: numbers and expressions of ``t``, evaluated without ``eval`` and refused clearly."""

from __future__ import annotations

import math
import re
import time

import pytest

from hild.api.expressions import MAX_LENGTH, ExpressionError, parse, parse_all, values_at


@pytest.mark.parametrize(
    ("text", "t", "value"),
    [
        ("0.3", 5.0, 0.3),
        ("-1.5e-2", 0.0, -0.015),
        ("  2  ", 0.0, 2.0),
        ("0.3*sin(2*pi*0.5*t)", 0.5, 0.3),
        ("0.3*sin(2*pi*0.5*t)", 1.0, 0.3 * math.sin(math.pi)),
        ("cos(tau*t) + e - e", 0.0, 1.0),
        ("0.2 if 1 < t < 2 else 0", 1.5, 0.2),
        ("0.2 if 1 < t < 2 else 0", 2.5, 0.0),
        ("(t > 1) * 0.2", 3.0, 0.2),
        ("t % 2 - 1", 3.5, 0.5),
        ("2 ** 0.5", 0.0, math.sqrt(2)),
        ("max(min(t, 0.5), -0.5)", 9.0, 0.5),
        ("abs(-t) + sign(-2)", 2.0, 1.0),
        ("atan2(1, 1)", 0.0, math.pi / 4),
    ],
)
def test_numbers_and_expressions_of_t(text: str, t: float, value: float) -> None:
    assert parse(text).at(t) == pytest.approx(value, abs=1e-12)


def test_a_number_is_constant_and_an_expression_of_t_is_not() -> None:
    assert parse("0.5 * pi").constant
    assert not parse("0.5 * t").constant
    assert values_at(parse_all(["1", "t", "2*t"]), 3.0) == [1.0, 3.0, 6.0]


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("__import__('os')", "unknown function '__import__'"),
        ("os.system('ls')", "unknown function 'os.system'"),
        ("().__class__.__bases__", "attribute access not allowed"),
        ("t.real", "attribute access not allowed"),
        ("sin.__globals__", "attribute access not allowed"),
        ("[1][0]", "subscripts not allowed"),
        ("[1, 2]", "List not allowed"),
        ("'a' * 3", "is not a number"),
        ("True", "is not a number"),
        ("1j", "is not a number"),
        ("lambda: 1", "lambda not allowed"),
        ("(x := 1)", "assignment not allowed"),
        ("sin(x=1)", "keyword arguments not allowed"),
        ("t == 1", "operator Eq not allowed"),
        ("1 << 100000", "operator LShift not allowed"),
        ("f'{t}'", "JoinedStr not allowed"),
        ("import os", "is not an expression"),
        ("x = 1", "is not an expression"),
        ("1; 2", "is not an expression"),
        ("", "is not an expression"),
        ("x + 1", "unknown name 'x'"),
        ("sin", "sin is a function"),
        ("nope(t)", "unknown function 'nope'"),
    ],
)
def test_anything_but_arithmetic_is_refused(text: str, reason: str) -> None:
    with pytest.raises(ExpressionError, match=re.escape(reason)):
        parse(text)


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("9**9**9", "overflows a float"),
        ("999999 ** 999999", "overflows a float"),
        ("10 ** 400", "overflows a float"),
        ("exp(1000)", "overflows a float"),
        ("1" * 400, "overflows a float"),
        ("1e308 * 10", "'inf', not a finite number"),
        ("1e308 * 10 - 1e308 * 10", "'nan', not a finite number"),
        ("sqrt(-1)", "math domain error"),
        ("(-8) ** (1/3)", "math domain error"),
        ("1 / t", "at t=0: float division by zero"),
    ],
)
def test_huge_and_non_finite_values_are_refused_at_once(text: str, reason: str) -> None:
    started = time.monotonic()
    with pytest.raises(ExpressionError, match=reason):
        parse(text)
    assert time.monotonic() - started < 1.0  # refused, not computed: a big-integer 9**9**9 would take minutes


def test_a_long_expression_is_refused_before_it_is_parsed() -> None:
    with pytest.raises(ExpressionError, match=f"at most {MAX_LENGTH}"):
        parse("t+" * MAX_LENGTH + "t")


def test_a_value_that_fails_later_says_when() -> None:
    expression = parse("1 / (t - 2)")
    assert expression.at(0.0) == -0.5
    with pytest.raises(ExpressionError, match="at t=2: float division by zero"):
        expression.at(2.0)


def test_parse_all_names_the_bad_value() -> None:
    with pytest.raises(ExpressionError, match=r"value 2: 'x': unknown name 'x'"):
        parse_all(["0.1", "x", "0.3"])
