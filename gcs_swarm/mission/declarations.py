"""Field declarations of the mission format: each one both validates a YAML
node (with its line) and describes itself as JSON Schema, so the validator and
``gcs-swarm schema`` are generated from the same declarations and cannot drift.

Nodes come from ``yaml.compose`` with the safe loader (no Python tags are ever
constructed). A field's ``parse`` returns the Python value, or ``INVALID``
after recording one problem line per mistake in the ``Context``.

This module holds the base ``Field`` (tag and size checks) and the
containers (``ListOf``, ``Key``, ``Obj``, ``ByKind``); the leaf values
(numbers, booleans, strings, choices, ``Vec3``) are in ``scalars``. (The
potential fields of the law are ``gcs_swarm.control.fields``.)
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import yaml

from gcs_swarm.mission.context import TAG as _TAG
from gcs_swarm.mission.context import Context, describe_node, did_you_mean

__all__ = [
    "INVALID",
    "MAX_NODES",
    "REQUIRED",
    "ByKind",
    "Field",
    "Key",
    "ListOf",
    "Obj",
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
#: A key shown as is in a key path; any other is shown quoted (a space, a colon, nothing).
_KEY_NAME_RE = re.compile(r"[A-Za-z0-9_<>-]+")
#: Nodes one file may expand to (aliases can make a small file huge).
MAX_NODES = 100_000


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
