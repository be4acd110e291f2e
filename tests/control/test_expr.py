"""The safe leader-force expression evaluator (no eval, whitelist only)."""

from __future__ import annotations

import math

import pytest

from gcs_swarm.control import validate_expression
from gcs_swarm.control.expr import FUNCTIONS, compile_expression
from gcs_swarm.errors import ExpressionError

ENV = {"x": 8.0, "y": -2.0, "z": 0.5, "vx": 1.0, "vy": 0.0, "vz": -0.25, "t": 3.0}


@pytest.mark.parametrize(
    ("src", "expected"),
    [
        ("10", 10.0),
        ("10*sin(x/8)", 10.0 * math.sin(1.0)),
        ("2", 2.0),
        ("-x + +y", -10.0),
        ("x**2 % 7", 64.0 % 7.0),
        ("atan2(y, x) + pi - e", math.atan2(-2.0, 8.0) + math.pi - math.e),
        ("min(x, y, z) + max(vx, vy)", -1.0),
        ("sqrt(abs(y)) * exp(-t) / log(x)", math.sqrt(2.0) * math.exp(-3.0) / math.log(8.0)),
        (
            "tanh(vz) + cos(t) - tan(z) + asin(z) + acos(z) + atan(z)",
            math.tanh(-0.25)
            + math.cos(3.0)
            - math.tan(0.5)
            + math.asin(0.5)
            + math.acos(0.5)
            + math.atan(0.5),
        ),
        ("hypot(x, y) + log(x, 2) + sign(y) + clip(t, 0, 1)", math.hypot(8, -2) + 3.0 - 1 + 1),
        ("1e3 * 2.5e-3", 2.5),
    ],
)
def test_whitelist_evaluates(src: str, expected: float) -> None:
    validate_expression(src)
    assert compile_expression(src)(ENV) == pytest.approx(expected, rel=1e-12)


def test_every_listed_function_is_callable() -> None:
    for name in FUNCTIONS:
        arity = {"atan2": 2, "min": 2, "max": 2, "clip": 3}.get(name, 1)
        args = ", ".join(["0.5"] * arity)
        assert math.isfinite(compile_expression(f"{name}({args})")(ENV))


@pytest.mark.parametrize(
    ("src", "needle"),
    [
        ("__import__('os')", "'__import__'"),
        ("x.__class__", "attribute"),
        ("(1).real", "attribute"),
        ("lambda: 1", "lambda"),
        ("foo(x)", "unknown function 'foo'"),
        ("open('f')", "unknown function 'open'"),
        ("eval('1')", "unknown function 'eval'"),
        ("q + 1", "unknown name 'q'"),
        ("__builtins__", "unknown name '__builtins__'"),
        ("[x for x in y]", "ListComp"),
        ("x if y else z", "IfExp"),
        ("x < y", "Compare"),
        ("'a'", "not a number"),
        ("True", "not a number"),
        ("1j", "not a number"),
        ("sin(x=1)", "keyword"),
        ("sin(*x)", "*arguments"),
        ("sin(1, 2)", "takes 1 arguments, got 2"),
        ("atan2(1)", "takes 2 arguments, got 1"),
        ("sin", "without a call"),
        ("x[0]", "Subscript"),
        ("x // 2", "FloorDiv"),
        ("~1", "Invert"),
        ("not x", "Not"),
        ("(x := 1)", "NamedExpr"),
        ("sin(x))", "syntax error"),
        ("", "empty"),
        ("x" * 2000, "at most"),
        ("math.sin(x)", "only plain function names"),
    ],
)
def test_rejected_with_a_clear_message(src: str, needle: str) -> None:
    with pytest.raises(ExpressionError, match=None) as info:
        validate_expression(src)
    assert needle in str(info.value), str(info.value)


def test_runtime_domain_errors_raise_expression_error() -> None:
    for src in ("sqrt(-1 - x*0)", "1/(x-8)", "log(x-8)", "exp(1000*x)", "10**10**10"):
        f = compile_expression(src)
        with pytest.raises(ExpressionError, match=r"cannot be evaluated|not finite"):
            f(ENV)


def test_deep_nesting_is_rejected_not_a_crash() -> None:
    with pytest.raises(ExpressionError):
        validate_expression("(" * 400 + "x" + ")" * 400)
    with pytest.raises(ExpressionError):
        validate_expression("-" * 900 + "x")


def test_compiled_once_reports_its_variables() -> None:
    f = compile_expression("10*sin(x/8) + t")
    assert f.names == frozenset({"x", "t"})
    assert f({"x": 0.0, "t": 1.5}) == 1.5
