"""Field definitions of the mission format: each one both validates a YAML
node (with its line) and describes itself as JSON Schema, so the validator and
``gcs-swarm schema`` are generated from the same declarations and cannot drift.

Nodes come from ``yaml.compose`` with the safe loader (no Python tags are ever
constructed). A field's ``parse`` returns the Python value, or ``INVALID``
after recording one problem line per mistake in the ``Context``.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import yaml

from gcs_swarm.mission.bounds import POSITION_LIMIT_M
from gcs_swarm.mission.context import TAG as _TAG
from gcs_swarm.mission.context import Context, describe_node, did_you_mean

__all__ = [
    "INVALID",
    "REQUIRED",
    "Bool",
    "ByKind",
    "Const",
    "Enum",
    "Field",
    "Int",
    "Key",
    "ListOf",
    "NonNeg",
    "Num",
    "Obj",
    "Pos",
    "Str",
    "Vec3",
]


class _Marker:
    def __init__(self, name: str) -> None:
        self._name = name

    def __repr__(self) -> str:
        return self._name


#: A value that failed validation (its problems are already recorded).
INVALID: Any = _Marker("INVALID")
#: Default of a key that must be present.
REQUIRED: Any = _Marker("REQUIRED")

_SCALAR_TAGS = {_TAG + t for t in ("str", "int", "float", "bool", "null", "timestamp")}
#: YAML 1.2 core-schema numbers (``source.YAML12Loader`` resolves plain
#: scalars with the same forms; an explicit ``!!int``/``!!float`` must match them too).
_INT_RE = re.compile(r"[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+")
_FLOAT_RE = re.compile(
    r"[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?|([-+]?)\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN)"
)
#: YAML 1.1's base-60 numbers (``1:30`` = 90): strings in YAML 1.2.
_SEXAGESIMAL_RE = re.compile(r"[-+]?[0-9][0-9_]*(?::[0-5]?[0-9])+(?:\.[0-9_]*)?")
#: A key shown as is in a key path; any other is shown quoted (a space, a colon, nothing).
_KEY_NAME_RE = re.compile(r"[A-Za-z0-9_<>-]+")
#: Longest integer literal read (a float holds at most about 309 digits).
_MAX_INT_DIGITS = 400
#: Nodes one file may expand to (aliases can make a small file huge).
MAX_NODES = 100_000


def _num_text(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else repr(x)


class Field:
    """Base of every field: tag and size checks, then ``_parse``."""

    doc: str = ""

    def parse(self, node: yaml.Node, path: str, ctx: Context) -> Any:
        """Validate ``node`` at key path ``path``; the value or ``INVALID``."""
        ctx.nodes_seen += 1
        if ctx.nodes_seen > MAX_NODES:
            if not ctx.too_big:
                ctx.too_big = True
                ctx.add(node, path, f"the file expands to more than {MAX_NODES} nodes (aliases?)")
            return INVALID
        ctx.lines.setdefault(path, node.start_mark.line + 1)
        if not _standard_tag(node):
            tag = str(node.tag).replace(_TAG, "!!")
            ctx.add(node, path, f"unsupported YAML tag {tag}: mission files are plain YAML")
            return INVALID
        return self._parse(node, path, ctx)

    def _parse(self, node: yaml.Node, path: str, ctx: Context) -> Any:
        raise NotImplementedError

    def expected(self) -> str:
        """What this field wants, e.g. ``an integer 1..255``."""
        raise NotImplementedError

    def schema(self) -> dict[str, Any]:
        """JSON Schema (draft 2020-12) of this field."""
        raise NotImplementedError

    def _bad(self, node: yaml.Node, path: str, ctx: Context, note: str = "") -> Any:
        ctx.add(node, path, f"expected {self.expected()}, got {describe_node(node)}{note}")
        return INVALID


def _standard_tag(node: yaml.Node) -> bool:
    if isinstance(node, yaml.MappingNode):
        return bool(node.tag == _TAG + "map")
    if isinstance(node, yaml.SequenceNode):
        return bool(node.tag == _TAG + "seq")
    return node.tag in _SCALAR_TAGS


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


@dataclass
class ListOf(Field):
    """A list whose items all follow ``item``; the value is a tuple."""

    item: Field = field(default_factory=Field)
    min_items: int = 0
    max_items: int | None = None
    what: str = ""

    def expected(self) -> str:
        if self.what:
            return self.what
        if self.max_items is not None and self.max_items == self.min_items:
            return f"a list of {self.min_items} items"
        return f"a list of at least {self.min_items} item(s)" if self.min_items else "a list"

    def _parse(self, node: yaml.Node, path: str, ctx: Context) -> Any:
        if not isinstance(node, yaml.SequenceNode):
            return self._bad(node, path, ctx)
        n = len(node.value)
        if n < self.min_items or (self.max_items is not None and n > self.max_items):
            return self._bad(node, path, ctx)
        values = [self.item.parse(child, f"{path}[{i}]", ctx) for i, child in enumerate(node.value)]
        if any(v is INVALID for v in values):
            return INVALID
        return tuple(values)

    def schema(self) -> dict[str, Any]:
        out: dict[str, Any] = {"type": "array", "items": self.item.schema()}
        if self.min_items:
            out["minItems"] = self.min_items
        if self.max_items is not None:
            out["maxItems"] = self.max_items
        return out


def Vec3(
    what: str = "[x, y, z]", positive: bool = False, limit: float = POSITION_LIMIT_M
) -> ListOf:
    """Three finite numbers (``positive``: each > 0), e.g. a position [m];
    each within +-``limit`` (default: the position bound of ``bounds``)."""
    num = Num(lo=0.0, lo_open=True, hi=limit) if positive else Num(lo=-limit, hi=limit)
    kind = "numbers > 0" if positive else "numbers"
    return ListOf(item=num, min_items=3, max_items=3, what=f"a list of 3 {kind} {what}")


@dataclass
class Key:
    """One key of a mapping: its YAML ``name``, field, ``default`` (or
    ``REQUIRED``), one-line ``doc`` with the unit, and the dataclass field it
    fills (``target``; None when a custom build places it)."""

    name: str
    spec: Field
    default: Any = None
    doc: str = ""
    target: str | None = ""

    def __post_init__(self) -> None:
        if self.target == "":
            self.target = self.name


@dataclass
class Obj(Field):
    """A mapping with known keys, built into ``cls`` (or by ``build``).

    ``build(values, ctx, node, path)`` receives the values by YAML key name,
    defaults filled. ``partial``: return that dict even when some values are
    ``INVALID`` (the top level, so sections that parsed can still be checked).
    ``extra_fields`` names the dataclass fields a custom
    build fills from keys whose ``target`` is None (checked by a test).
    """

    name: str = ""
    keys: tuple[Key, ...] = ()
    cls: type | None = None
    build: Callable[[dict[str, Any], Context, yaml.Node, str], Any] | None = None
    extra_fields: tuple[str, ...] = ()
    what: str = ""
    partial: bool = False

    def key(self, name: str) -> Key:
        """The key called ``name``."""
        for k in self.keys:
            if k.name == name:
                return k
        raise KeyError(name)

    def expected(self) -> str:
        return self.what or f"a mapping with keys {', '.join(k.name for k in self.keys)}"

    def _parse(self, node: yaml.Node, path: str, ctx: Context) -> Any:
        if not isinstance(node, yaml.MappingNode):
            return self._bad(node, path, ctx)
        names = [k.name for k in self.keys]
        known = {k.name: k for k in self.keys}
        found: dict[str, yaml.Node] = {}
        ok = True
        for key_node, value_node in node.value:
            if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == _TAG + "merge":
                ctx.add(
                    key_node,
                    path or "(top level)",
                    "merge keys (<<) and complex keys are not supported",
                )
                ok = False
                continue
            name = str(key_node.value)
            shown = name if _KEY_NAME_RE.fullmatch(name) else json.dumps(name)  # "a b", ""
            sub = f"{path}.{shown}" if path else shown
            if name not in known:
                hint = did_you_mean(name, names)
                ctx.add(
                    key_node,
                    sub,
                    f"unknown key{hint}"
                    if hint
                    else f"unknown key; expected one of {', '.join(names)}",
                )
                ok = False
            elif name in found:
                first = found[name].start_mark.line + 1
                ctx.add(key_node, sub, f"duplicate key (first given at line {first})")
                ok = False
            else:
                found[name] = value_node
                ctx.lines[sub] = key_node.start_mark.line + 1
        values: dict[str, Any] = {}
        for k in self.keys:
            sub = f"{path}.{k.name}" if path else k.name
            if k.name in found:
                values[k.name] = k.spec.parse(found[k.name], sub, ctx)
                ok = ok and values[k.name] is not INVALID
            elif k.default is REQUIRED:
                ctx.add(node, path or "(top level)", f'missing required key "{k.name}"')
                ok = False
            else:
                values[k.name] = k.default() if callable(k.default) else k.default
        if self.partial:
            return values
        if not ok:
            return INVALID
        if self.build is not None:
            return self.build(values, ctx, node, path)
        if self.cls is None:
            return values
        return self.cls(**{k.target: values[k.name] for k in self.keys if k.target})

    def schema(self) -> dict[str, Any]:
        props: dict[str, Any] = {}
        for k in self.keys:
            sub = dict(k.spec.schema())
            if k.doc:
                sub["description"] = k.doc
            if k.default is not REQUIRED and not callable(k.default) and k.default is not None:
                sub["default"] = _jsonable(k.default)
            props[k.name] = sub
        out: dict[str, Any] = {"type": "object", "properties": props, "additionalProperties": False}
        required = [k.name for k in self.keys if k.default is REQUIRED]
        if required:
            out["required"] = required
        return out


def _jsonable(x: Any) -> Any:
    if isinstance(x, tuple | list):
        return [_jsonable(v) for v in x]
    if hasattr(x, "__dataclass_fields__"):
        return {name: _jsonable(getattr(x, name)) for name in x.__dataclass_fields__}
    return x


@dataclass
class ByKind(Field):
    """One of several shapes told apart by the node kind: a scalar, a
    mapping or a list (e.g. ``origin: first-vehicle`` or ``{lat, lon, alt}``)."""

    scalar: Field | None = None
    mapping: Field | None = None
    sequence: Field | None = None
    what: str = ""

    def expected(self) -> str:
        return self.what

    def _parse(self, node: yaml.Node, path: str, ctx: Context) -> Any:
        if isinstance(node, yaml.MappingNode):
            chosen = self.mapping
        elif isinstance(node, yaml.SequenceNode):
            chosen = self.sequence
        else:
            chosen = self.scalar
        if chosen is None:
            return self._bad(node, path, ctx)
        return chosen._parse(node, path, ctx)

    def schema(self) -> dict[str, Any]:
        alts = [f.schema() for f in (self.scalar, self.mapping, self.sequence) if f is not None]
        return {"oneOf": alts}
