"""A small safe evaluator for leader-force expressions (Eq. 13, ``ExpressionForce``).

An expression such as ``10*sin(x/8)`` is parsed with :mod:`ast` and compiled
ONCE into a tree of Python closures. Nothing is ever passed to ``eval`` or
``exec``. Only this whitelist is accepted:

- numbers (int or float literals; every number is evaluated as a float, so
  ``9**9**9`` overflows at once instead of building a huge integer; a literal
  that is not a finite float, ``1e999`` or a 400-digit integer, is refused
  when the expression is compiled);
- the names ``x y z vx vy vz t`` (the leader's own state in the mission frame,
  metres, metres per second, seconds of vehicle time) and the constants
  ``pi`` and ``e``;
- ``+ - * / % **``, unary ``+``/``-`` and parentheses;
- calls of the functions in :data:`FUNCTIONS` by plain name, with positional
  arguments only.

Anything else (attributes, subscripts, lambdas, comprehensions, comparisons,
keyword arguments, strings, other names, dunder names) raises
:class:`gcs_swarm.errors.ExpressionError` naming the offending token and its
column. A run-time domain error (``sqrt(-1)``, division by zero, ``x % 0``,
overflow, a negative number to a fractional power, which Python's ``**``
would make complex) and a result that is not finite (``hypot(1e308, 1e308)``)
raise ``ExpressionError`` naming the expression and the variables: evaluation
never returns anything but a finite float, and never takes long (floats only,
``**`` is ``math.pow``).
"""

from __future__ import annotations

import ast
import math
from collections.abc import Callable, Mapping

from gcs_swarm.errors import ExpressionError

__all__ = [
    "CONSTANTS",
    "FUNCTIONS",
    "MAX_DEPTH",
    "MAX_EXPRESSION_CHARS",
    "VARIABLES",
    "CompiledExpression",
    "compile_expression",
    "validate_expression",
]

#: Names of the leader's state and time an expression may read.
VARIABLES: tuple[str, ...] = ("x", "y", "z", "vx", "vy", "vz", "t")
#: Named constants.
CONSTANTS: Mapping[str, float] = {"pi": math.pi, "e": math.e}


def _sign(a: float) -> float:
    return math.copysign(1.0, a) if a != 0.0 else 0.0


def _clip(a: float, lo: float, hi: float) -> float:
    return min(max(a, lo), hi)


# name -> (function, minimum arity, maximum arity or None for any)
_FUNCS: dict[str, tuple[Callable[..., float], int, int | None]] = {
    "sin": (math.sin, 1, 1),
    "cos": (math.cos, 1, 1),
    "tan": (math.tan, 1, 1),
    "asin": (math.asin, 1, 1),
    "acos": (math.acos, 1, 1),
    "atan": (math.atan, 1, 1),
    "atan2": (math.atan2, 2, 2),
    "sinh": (math.sinh, 1, 1),
    "cosh": (math.cosh, 1, 1),
    "tanh": (math.tanh, 1, 1),
    "sqrt": (math.sqrt, 1, 1),
    "exp": (math.exp, 1, 1),
    "log": (math.log, 1, 2),
    "log10": (math.log10, 1, 1),
    "abs": (abs, 1, 1),
    "min": (min, 2, None),
    "max": (max, 2, None),
    "floor": (lambda a: float(math.floor(a)), 1, 1),
    "ceil": (lambda a: float(math.ceil(a)), 1, 1),
    "hypot": (math.hypot, 1, None),
    "sign": (_sign, 1, 1),
    "clip": (_clip, 3, 3),
}
#: Function names an expression may call.
FUNCTIONS: tuple[str, ...] = tuple(sorted(_FUNCS))
#: Longest accepted source text (characters).
MAX_EXPRESSION_CHARS = 1000
#: Deepest accepted nesting of operators and calls (keeps evaluation recursion shallow).
MAX_DEPTH = 100

_BINOPS: dict[type[ast.operator], Callable[[float, float], float]] = {
    ast.Add: lambda a, b: a + b,
    ast.Sub: lambda a, b: a - b,
    ast.Mult: lambda a, b: a * b,
    ast.Div: lambda a, b: a / b,
    ast.Mod: lambda a, b: a % b,
    ast.Pow: math.pow,  # floats only: OverflowError or ValueError, never complex or huge
}

_Node = Callable[[Mapping[str, float]], float]


class CompiledExpression:
    """A compiled expression: call it with a mapping of the variables.

    ``expr({"x": 1.0, "y": 0.0, ..., "t": 0.0}) -> float``. Every name of
    :data:`VARIABLES` that the expression reads (``names``) must be in the
    mapping.
    """

    __slots__ = ("_root", "names", "source")

    def __init__(self, source: str, root: _Node, names: frozenset[str]) -> None:
        self.source = source
        self.names = names
        self._root = root

    def __call__(self, env: Mapping[str, float]) -> float:
        try:
            value = self._root(env)
        except (ArithmeticError, ValueError) as err:
            raise ExpressionError(
                f"expression {self.source!r} cannot be evaluated{self._at(env)}: {err}"
            ) from None
        if not math.isfinite(value):
            raise ExpressionError(
                f"expression {self.source!r} is not finite ({value}){self._at(env)}"
            )
        return value

    def _at(self, env: Mapping[str, float]) -> str:
        """`` at x=1, t=2`` for the variables read (empty when none is)."""
        shown = ", ".join(f"{k}={env[k]:.6g}" for k in sorted(self.names))
        return f" at {shown}" if shown else ""

    def __repr__(self) -> str:
        return f"CompiledExpression({self.source!r})"


def _fail(source: str, node: ast.AST, what: str) -> ExpressionError:
    col = getattr(node, "col_offset", None)
    where = f" at column {col + 1}" if col is not None else ""
    allowed = "allowed names: " + ", ".join((*VARIABLES, *CONSTANTS))
    return ExpressionError(
        f"expression {source!r}{where}: {what} ({allowed}; functions: {', '.join(FUNCTIONS)})"
    )


def _compile(source: str, node: ast.AST, names: set[str], depth: int = 0) -> _Node:
    if depth > MAX_DEPTH:
        raise _fail(source, node, f"nested more than {MAX_DEPTH} levels deep")
    depth += 1
    if isinstance(node, ast.Constant):
        value = node.value
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise _fail(source, node, f"literal {value!r} is not a number")
        try:
            const = float(value)
        except OverflowError:
            const = math.inf
        if not math.isfinite(const):
            shown = str(value) if isinstance(value, float) else f"a {len(str(value))}-digit integer"
            raise _fail(source, node, f"literal {shown} is not a finite number")
        return lambda env: const
    if isinstance(node, ast.Name):
        name = node.id
        if name in CONSTANTS:
            const = CONSTANTS[name]
            return lambda env: const
        if name in VARIABLES:
            names.add(name)
            return lambda env: env[name]
        if name in _FUNCS:
            raise _fail(source, node, f"function {name!r} used without a call")
        raise _fail(source, node, f"unknown name {name!r}")
    if isinstance(node, ast.BinOp):
        op = _BINOPS.get(type(node.op))
        if op is None:
            raise _fail(source, node, f"operator {type(node.op).__name__} is not allowed")
        left = _compile(source, node.left, names, depth)
        right = _compile(source, node.right, names, depth)
        return lambda env: op(left(env), right(env))
    if isinstance(node, ast.UnaryOp):
        operand = _compile(source, node.operand, names, depth)
        if isinstance(node.op, ast.USub):
            return lambda env: -operand(env)
        if isinstance(node.op, ast.UAdd):
            return operand
        raise _fail(source, node, f"operator {type(node.op).__name__} is not allowed")
    if isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name):
            raise _fail(source, node, "only plain function names may be called")
        fname = node.func.id
        entry = _FUNCS.get(fname)
        if entry is None:
            raise _fail(source, node, f"unknown function {fname!r}")
        if node.keywords:
            raise _fail(source, node, f"{fname}() takes no keyword arguments")
        if any(isinstance(a, ast.Starred) for a in node.args):
            raise _fail(source, node, f"{fname}() takes no *arguments")
        func, lo, hi = entry
        n = len(node.args)
        if n < lo or (hi is not None and n > hi):
            want = f"{lo}" if hi == lo else (f"{lo}..{hi}" if hi is not None else f"{lo} or more")
            raise _fail(source, node, f"{fname}() takes {want} arguments, got {n}")
        args = tuple(_compile(source, a, names, depth) for a in node.args)
        if n == 1:
            (a0,) = args
            return lambda env: float(func(a0(env)))
        return lambda env: float(func(*(a(env) for a in args)))
    token = type(node).__name__
    if isinstance(node, ast.Attribute):
        return_what = f"attribute access '.{node.attr}' is not allowed"
    elif isinstance(node, ast.Lambda):
        return_what = "lambda is not allowed"
    else:
        return_what = f"{token} is not allowed"
    raise _fail(source, node, return_what)


def compile_expression(source: str) -> CompiledExpression:
    """Parse and compile ``source`` once; raise ``ExpressionError`` if it is not allowed."""
    if not isinstance(source, str):
        raise ExpressionError(f"expression must be a string, got {type(source).__name__}")
    text = source.strip()
    if not text:
        raise ExpressionError("expression is empty")
    if len(text) > MAX_EXPRESSION_CHARS:
        raise ExpressionError(
            f"expression is {len(text)} characters long, at most {MAX_EXPRESSION_CHARS} allowed"
        )
    try:
        tree = ast.parse(text, mode="eval")
    except SyntaxError as err:
        col = f" at column {err.offset}" if err.offset else ""
        raise ExpressionError(f"expression {text!r}{col}: syntax error: {err.msg}") from None
    except (ValueError, RecursionError, MemoryError) as err:
        raise ExpressionError(f"expression {text!r} cannot be parsed: {err}") from None
    names: set[str] = set()
    try:
        root = _compile(text, tree.body, names)
    except RecursionError:
        raise ExpressionError(f"expression {text!r} is nested too deeply") from None
    return CompiledExpression(text, root, frozenset(names))


def validate_expression(source: str) -> None:
    """Raise ``ExpressionError`` if ``source`` is not an allowed expression.

    For the mission loader: checks syntax, names and arity without evaluating.
    """
    compile_expression(source)
