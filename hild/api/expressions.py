"""Values of ``hild ctl pub``: a number, or an arithmetic expression of ``t`` such as ``0.3*sin(2*pi*0.5*t)``.

Evaluated by simpleeval (a well-kept AST walker, never ``eval``), narrowed further: only numbers, ``t``, the
constants and math functions below, arithmetic, comparisons and ``a if cond else b`` (for steps). No strings,
attributes, subscripts, keywords or statements. Every number becomes a float before any operation, so nothing grows
without bound (``9**9**9`` overflows a float at once instead of building a huge integer), and the text is at most
``MAX_LENGTH`` characters, so neither does the tree: one evaluation costs microseconds whatever is typed.
"""

from __future__ import annotations

import ast
import math
import operator
from collections.abc import Callable, Sequence
from typing import Any

import simpleeval

MAX_LENGTH = 500  # characters: an expression is one line typed in a shell


class ExpressionError(ValueError):
    """An expression that cannot be used; the message names the expression and why."""


def _power(a: float, b: float) -> float:
    return math.pow(a, b)  # floats only: overflow raises OverflowError, a negative base ** fraction ValueError


OPERATORS: dict[type[ast.AST], Callable[..., Any]] = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.FloorDiv: operator.floordiv,
    ast.Mod: operator.mod,
    ast.Pow: _power,
    ast.USub: operator.neg,
    ast.UAdd: operator.pos,
    ast.Lt: operator.lt,
    ast.LtE: operator.le,
    ast.Gt: operator.gt,
    ast.GtE: operator.ge,
}
FUNCTIONS: dict[str, Callable[..., float]] = {
    **{
        name: getattr(math, name)
        for name in (
            "sin",
            "cos",
            "tan",
            "asin",
            "acos",
            "atan",
            "atan2",
            "sinh",
            "cosh",
            "tanh",
            "exp",
            "log",
            "log10",
            "log2",
            "sqrt",
            "hypot",
            "floor",
            "ceil",
            "fmod",
            "copysign",
            "degrees",
            "radians",
        )
    },
    "abs": math.fabs,
    "min": min,
    "max": max,
    "sign": lambda x: math.copysign(1.0, x) if x else 0.0,
}
CONSTANTS = {"pi": math.pi, "tau": math.tau, "e": math.e}


class _Evaluator(simpleeval.SimpleEval):
    """simpleeval with only the nodes a formula needs; every literal a float."""

    ALLOWED = (ast.Expression, ast.Name, ast.Constant, ast.UnaryOp, ast.BinOp, ast.Compare, ast.IfExp, ast.Call)

    def __init__(self) -> None:
        super().__init__(operators=dict(OPERATORS), functions=dict(FUNCTIONS), names={})
        self.nodes = {kind: handler for kind, handler in self.nodes.items() if kind in self.ALLOWED}
        self.nodes[ast.Expression] = lambda node: self._eval(node.body)
        self.nodes[ast.Constant] = self._number

    @staticmethod
    def _number(node: ast.Constant) -> float:
        if isinstance(node.value, bool) or not isinstance(node.value, int | float):
            raise simpleeval.FeatureNotAvailable(f"only numbers are allowed, not {node.value!r}")
        return float(node.value)  # an int literal too large for a float raises OverflowError here


class Expression:
    """One parsed value: :meth:`at` gives it at time ``t`` (s). Not thread-safe: one evaluator, reused."""

    def __init__(self, text: str, tree: ast.Expression) -> None:
        self.text = text
        self.tree = tree
        self.constant = not any(isinstance(n, ast.Name) and n.id == "t" for n in ast.walk(tree))
        self._evaluator = _Evaluator()
        self._value: float | None = None  # a constant's value, once known

    def at(self, t: float) -> float:
        """The value at ``t``; ExpressionError if it fails or is not a finite number there."""
        if self._value is not None:
            return self._value
        self._evaluator.names = {**CONSTANTS, "t": float(t)}
        try:
            value = self._evaluator.eval(self.text, previously_parsed=self.tree)
        except simpleeval.InvalidExpression as exc:  # _check refuses these first; simpleeval is the second wall
            raise ExpressionError(f"{_clip(self.text)}: {exc}") from None
        except OverflowError:
            raise ExpressionError(f"{_clip(self.text)} at t={t:g} overflows a float") from None
        except (ArithmeticError, ValueError, TypeError, RecursionError) as exc:
            raise ExpressionError(f"{_clip(self.text)} at t={t:g}: {exc or type(exc).__name__}") from None
        if isinstance(value, bool):
            value = float(value)
        if not isinstance(value, float | int) or not math.isfinite(value):
            raise ExpressionError(f"{_clip(self.text)} at t={t:g} is {_clip(repr(value))}, not a finite number")
        if self.constant:
            self._value = float(value)
        return float(value)


WHAT = {
    ast.Attribute: "attribute access",
    ast.Subscript: "subscripts",
    ast.keyword: "keyword arguments",
    ast.Starred: "unpacking",
    ast.BoolOp: "and/or",
    ast.Lambda: "lambda",
    ast.NamedExpr: "assignment",
}
ALLOWED_WORDS = "numbers, t, pi, tau, e, + - * / // % **, < <= > >=, 'a if cond else b' and math functions"


def _check(text: str, tree: ast.Expression) -> None:
    """Refuse anything but the allowed nodes, operators, names and functions, before it is evaluated."""
    called = {id(node.func) for node in ast.walk(tree) if isinstance(node, ast.Call)}
    for node in ast.walk(tree):
        if isinstance(node, ast.Load) or type(node) in OPERATORS:
            continue
        if type(node) not in _Evaluator.ALLOWED:
            what = WHAT.get(type(node)) or (
                f"operator {type(node).__name__}"
                if isinstance(node, ast.operator | ast.cmpop | ast.unaryop)
                else type(node).__name__
            )
            raise ExpressionError(f"{_clip(text)}: {what} not allowed (only {ALLOWED_WORDS})")
        if isinstance(node, ast.Constant) and (isinstance(node.value, bool) or not isinstance(node.value, int | float)):
            raise ExpressionError(f"{_clip(text)}: {_clip(repr(node.value))} is not a number (only {ALLOWED_WORDS})")
        if isinstance(node, ast.Call) and not (isinstance(node.func, ast.Name) and node.func.id in FUNCTIONS):
            name = node.func.id if isinstance(node.func, ast.Name) else ast.unparse(node.func)
            raise ExpressionError(f"{_clip(text)}: unknown function {_clip(name)} (functions: {', '.join(FUNCTIONS)})")
        if isinstance(node, ast.Name) and node.id in FUNCTIONS and id(node) not in called:
            raise ExpressionError(f"{_clip(text)}: {node.id} is a function: call it, as in {node.id}(t)")
        if isinstance(node, ast.Name) and node.id != "t" and node.id not in CONSTANTS and node.id not in FUNCTIONS:
            raise ExpressionError(f"{_clip(text)}: unknown name {node.id!r} (names: t, {', '.join(CONSTANTS)})")


def _clip(text: str, limit: int = 60) -> str:
    return repr(text if len(text) <= limit else f"{text[: limit - 1]}…")


def parse(text: str) -> Expression:
    """Parse one value and evaluate it once at ``t = 0``, so a bad one is refused before anything is sent."""
    if len(text) > MAX_LENGTH:
        raise ExpressionError(f"expression of {len(text)} characters; at most {MAX_LENGTH}")
    try:
        tree = ast.parse(text.strip(), mode="eval")  # one expression: statements are a syntax error here
    except (SyntaxError, ValueError, RecursionError, MemoryError) as exc:
        raise ExpressionError(f"{_clip(text)} is not an expression ({getattr(exc, 'msg', None) or exc})") from None
    _check(text, tree)
    expression = Expression(text, tree)
    expression.at(0.0)
    return expression


def parse_all(texts: Sequence[str]) -> list[Expression]:
    """Parse every value; the first bad one is refused with its position (1-based)."""
    expressions = []
    for i, text in enumerate(texts, start=1):
        try:
            expressions.append(parse(text))
        except ExpressionError as exc:
            raise ExpressionError(f"value {i}: {exc}") from None
    return expressions


def values_at(expressions: Sequence[Expression], t: float) -> list[float]:
    return [e.at(t) for e in expressions]
