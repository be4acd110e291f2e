"""Leaf fields of the mission format: numbers (``Num`` and its shorthands
``Int``, ``Pos``, ``NonNeg``), ``Bool``, ``Str``, ``Enum``, ``Const`` and
``Vec3`` (three numbers). Each validates a scalar node by the YAML 1.2 core
schema and describes itself as JSON Schema (``declarations`` has the base
and the containers).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import yaml

from gcs_swarm.mission.bounds import POSITION_LIMIT_M
from gcs_swarm.mission.context import TAG as _TAG
from gcs_swarm.mission.context import Context, did_you_mean
from gcs_swarm.mission.declarations import INVALID, Field, ListOf

__all__ = ["Bool", "Const", "Enum", "Int", "NonNeg", "Num", "Pos", "Str", "Vec3"]

#: YAML 1.2 core-schema numbers (``source.YAML12Loader`` resolves plain
#: scalars with the same forms; an explicit ``!!int``/``!!float`` must match them too).
_INT_RE = re.compile(r"[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+")
_FLOAT_RE = re.compile(
    r"[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?|([-+]?)\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN)"
)
#: YAML 1.1's base-60 numbers (``1:30`` = 90): strings in YAML 1.2.
_SEXAGESIMAL_RE = re.compile(r"[-+]?[0-9][0-9_]*(?::[0-5]?[0-9])+(?:\.[0-9_]*)?")
#: Longest integer literal read (a float holds at most about 309 digits).
_MAX_INT_DIGITS = 400


def _num_text(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else repr(x)


class _NotANumber(ValueError):
    """A scalar that looks like a number but is refused; ``str()`` says why."""


def _number(node: yaml.Node) -> float | None:
    """The finite-or-not number a scalar node holds by the YAML 1.2 core
    schema, or None if it is not one. ``_NotANumber`` for a literal too large
    for a float, an ambiguous leading zero (``010`` is octal 8 in YAML 1.1,
    10 in YAML 1.2) or a YAML 1.1 sexagesimal (``1:30``)."""
    if not isinstance(node, yaml.ScalarNode):
        return None
    text = str(node.value)
    if node.tag == _TAG + "int":
        if not _INT_RE.fullmatch(text):
            return None
        digits = text.lstrip("+-")
        if len(digits) > _MAX_INT_DIGITS:
            raise _NotANumber(f"a {len(digits)}-digit integer is too large for a number")
        if digits.startswith("0x"):
            value = int(digits[2:], 16)
        elif digits.startswith("0o"):
            value = int(digits[2:], 8)
        elif len(digits) > 1 and digits.startswith("0"):
            sign, plain = text[: len(text) - len(digits)], digits.lstrip("0") or "0"
            raise _NotANumber(
                f"a leading zero is ambiguous: YAML 1.1 reads {text} as octal;"
                f" write {sign}{plain} or 0o{plain}"
            )
        else:
            value = int(digits)
        try:
            return float(-value if text.startswith("-") else value)
        except OverflowError:
            raise _NotANumber(f"a {len(digits)}-digit integer is too large for a number") from None
    if node.tag == _TAG + "float":
        m = _FLOAT_RE.fullmatch(text)
        if m is None:
            return None
        if "inf" in text.lower():
            return -math.inf if m[1] == "-" else math.inf
        return math.nan if "nan" in text.lower() else float(text)
    if node.tag == _TAG + "str" and node.style is None and _SEXAGESIMAL_RE.fullmatch(text):
        raise _NotANumber(f"YAML 1.2 reads {text} as a string, not a base-60 number")
    return None


@dataclass
class Num(Field):
    """A finite number (int or float in YAML) within optional bounds."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    nullable: bool = False
    integer: bool = False
    note: str = ""

    def expected(self) -> str:
        return self._range() + (f" ({self.note})" if self.note else "")

    def _range(self) -> str:
        kind = "an integer" if self.integer else "a number"
        if self.lo is not None and self.hi is not None and not (self.lo_open or self.hi_open):
            text = f"{kind} {_num_text(self.lo)}..{_num_text(self.hi)}"
        else:
            parts = []
            if self.lo is not None:
                parts.append(f"{'>' if self.lo_open else '>='} {_num_text(self.lo)}")
            if self.hi is not None:
                parts.append(f"{'<' if self.hi_open else '<='} {_num_text(self.hi)}")
            text = f"{kind} {' and '.join(parts)}" if parts else kind
        return text + (" or null" if self.nullable else "")

    def _parse(self, node: yaml.Node, path: str, ctx: Context) -> Any:
        if self.nullable and isinstance(node, yaml.ScalarNode) and node.tag == _TAG + "null":
            return None
        try:
            x = _number(node)
        except _NotANumber as why:
            return self._bad(node, path, ctx, f" ({why})")
        if x is None:
            return self._bad(node, path, ctx)
        if not math.isfinite(x):
            return self._bad(node, path, ctx, " (not finite)")
        if self.integer and (node.tag != _TAG + "int" or not x.is_integer()):
            return self._bad(node, path, ctx)
        if self.lo is not None and (x < self.lo or (self.lo_open and x == self.lo)):
            return self._bad(node, path, ctx)
        if self.hi is not None and (x > self.hi or (self.hi_open and x == self.hi)):
            return self._bad(node, path, ctx)
        return int(x) if self.integer else x

    def schema(self) -> dict[str, Any]:
        out: dict[str, Any] = {"type": "integer" if self.integer else "number"}
        if self.lo is not None:
            out["exclusiveMinimum" if self.lo_open else "minimum"] = self.lo
        if self.hi is not None:
            out["exclusiveMaximum" if self.hi_open else "maximum"] = self.hi
        if self.nullable:
            out["type"] = [out["type"], "null"]
        return out


def Int(lo: float | None = None, hi: float | None = None) -> Num:
    """An integer within optional closed bounds."""
    return Num(lo=lo, hi=hi, integer=True)


def Pos(nullable: bool = False, hi: float | None = None) -> Num:
    """A number > 0 (optionally null, optionally at most ``hi``)."""
    return Num(lo=0.0, lo_open=True, hi=hi, nullable=nullable)


def NonNeg(hi: float | None = None) -> Num:
    """A number >= 0 (optionally at most ``hi``)."""
    return Num(lo=0.0, hi=hi)


@dataclass
class Bool(Field):
    """``true`` or ``false`` only: YAML 1.1's yes/no/on/off are refused, since
    YAML 1.2 tools (and the JSON Schema) read them as strings. ``nullable``:
    ``null`` is accepted too (a default decided from the rest of the mission)."""

    nullable: bool = False

    def expected(self) -> str:
        return "true or false" + (" or null" if self.nullable else "")

    def _parse(self, node: yaml.Node, path: str, ctx: Context) -> Any:
        if self.nullable and isinstance(node, yaml.ScalarNode) and node.tag == _TAG + "null":
            return None
        if isinstance(node, yaml.ScalarNode) and node.tag == _TAG + "bool":
            if node.value.lower() in ("true", "false"):
                return node.value.lower() == "true"
        return self._bad(node, path, ctx)

    def schema(self) -> dict[str, Any]:
        return {"type": ["boolean", "null"] if self.nullable else "boolean"}


@dataclass
class Str(Field):
    """A non-empty string; plain scalars are taken as written (``name: 2024``).
    ``check`` returns an error text for a malformed value, or None; without
    one, the whole string must match ``pattern`` (which the schema states)."""

    what: str = "a non-empty string"
    pattern: str | None = None
    check: Callable[[str], str | None] | None = None

    def expected(self) -> str:
        return self.what

    def _parse(self, node: yaml.Node, path: str, ctx: Context) -> Any:
        if not isinstance(node, yaml.ScalarNode) or node.tag == _TAG + "null":
            return self._bad(node, path, ctx)
        text = str(node.value)
        if not text.strip():
            return self._bad(node, path, ctx)
        if self.check is not None:
            problem = self.check(text)
            if problem is not None:
                ctx.add(node, path, problem)
                return INVALID
        elif self.pattern is not None and re.fullmatch(self.pattern, text) is None:
            return self._bad(node, path, ctx)
        return text

    def schema(self) -> dict[str, Any]:
        out: dict[str, Any] = {"type": "string", "minLength": 1}
        if self.pattern is not None:
            out["pattern"] = self.pattern
        return out


@dataclass
class Enum(Field):
    """One of a fixed set of words."""

    choices: tuple[str, ...] = ()

    def expected(self) -> str:
        return "one of " + ", ".join(self.choices)

    def _parse(self, node: yaml.Node, path: str, ctx: Context) -> Any:
        if isinstance(node, yaml.ScalarNode) and node.value in self.choices:
            return node.value
        hint = ""
        if isinstance(node, yaml.ScalarNode):
            hint = did_you_mean(str(node.value), self.choices)
        return self._bad(node, path, ctx, hint)

    def schema(self) -> dict[str, Any]:
        return {"enum": list(self.choices)}


@dataclass
class Const(Field):
    """Exactly one word, e.g. ``first-vehicle``."""

    value: str = ""

    def expected(self) -> str:
        return json.dumps(self.value)

    def _parse(self, node: yaml.Node, path: str, ctx: Context) -> Any:
        if isinstance(node, yaml.ScalarNode) and node.value == self.value:
            return self.value
        return self._bad(node, path, ctx)

    def schema(self) -> dict[str, Any]:
        return {"const": self.value}


def Vec3(
    what: str = "[x, y, z]", positive: bool = False, limit: float = POSITION_LIMIT_M
) -> ListOf:
    """Three finite numbers (``positive``: each > 0), e.g. a position [m];
    each within +-``limit`` (default: the position bound of ``bounds``)."""
    num = Num(lo=0.0, lo_open=True, hi=limit) if positive else Num(lo=-limit, hi=limit)
    kind = "numbers > 0" if positive else "numbers"
    return ListOf(item=num, min_items=3, max_items=3, what=f"a list of 3 {kind} {what}")
