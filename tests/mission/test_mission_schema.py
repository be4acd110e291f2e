"""The JSON Schema is in step with the dataclasses and accepts every shipped
mission; the docs mention every key.

jsonschema is not a dependency, so a minimal draft 2020-12 validator (the
keywords the generated schema uses) is written here.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path
from typing import Any

import pytest
import yaml

from gcs_swarm.control.params import LawConfig
from gcs_swarm.mission import Mission, schema
from gcs_swarm.mission.declarations import ByKind, Field, ListOf, Obj
from gcs_swarm.mission.format import LAW_SOURCES, MISSION

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = sorted((ROOT / "config" / "missions").glob("*.yaml"))
BAD = Path(__file__).parent / "fixtures" / "bad"

_USED = {
    "$schema", "$id", "title", "description", "default", "type", "properties",
    "additionalProperties", "required", "items", "minItems", "maxItems", "enum",
    "const", "minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum",
    "minLength", "pattern", "oneOf",
}  # fmt: skip


def _type_ok(value: Any, kind: str) -> bool:
    if kind == "object":
        return isinstance(value, dict)
    if kind == "array":
        return isinstance(value, list)
    if kind == "string":
        return isinstance(value, str)
    if kind == "boolean":
        return isinstance(value, bool)
    if kind == "null":
        return value is None
    if kind == "integer":
        return isinstance(value, int) and not isinstance(value, bool)
    if kind == "number":
        return isinstance(value, int | float) and not isinstance(value, bool)
    raise AssertionError(f"unknown type {kind}")


def validate(value: Any, s: dict[str, Any], path: str = "$") -> list[str]:
    """Errors of ``value`` against schema ``s`` (empty list: valid)."""
    unknown = set(s) - _USED
    assert not unknown, f"validator does not know {unknown}"
    errs: list[str] = []
    if "type" in s:
        kinds = s["type"] if isinstance(s["type"], list) else [s["type"]]
        if not any(_type_ok(value, k) for k in kinds):
            return [f"{path}: not {kinds}"]
    if "enum" in s and value not in s["enum"]:
        errs.append(f"{path}: not in {s['enum']}")
    if "const" in s and value != s["const"]:
        errs.append(f"{path}: not {s['const']!r}")
    if isinstance(value, int | float) and not isinstance(value, bool):
        if not math.isfinite(value):
            errs.append(f"{path}: not finite")
        if "minimum" in s and value < s["minimum"]:
            errs.append(f"{path}: < minimum")
        if "maximum" in s and value > s["maximum"]:
            errs.append(f"{path}: > maximum")
        if "exclusiveMinimum" in s and value <= s["exclusiveMinimum"]:
            errs.append(f"{path}: <= exclusiveMinimum")
        if "exclusiveMaximum" in s and value >= s["exclusiveMaximum"]:
            errs.append(f"{path}: >= exclusiveMaximum")
    if isinstance(value, str):
        if len(value) < s.get("minLength", 0):
            errs.append(f"{path}: too short")
        if "pattern" in s and re.search(s["pattern"], value) is None:
            errs.append(f"{path}: does not match {s['pattern']}")
    if isinstance(value, list):
        if len(value) < s.get("minItems", 0) or len(value) > s.get("maxItems", math.inf):
            errs.append(f"{path}: wrong length {len(value)}")
        if "items" in s:
            for i, item in enumerate(value):
                errs += validate(item, s["items"], f"{path}[{i}]")
    if isinstance(value, dict):
        props = s.get("properties", {})
        for key in s.get("required", []):
            if key not in value:
                errs.append(f"{path}: missing {key}")
        for key, item in value.items():
            if key in props:
                errs += validate(item, props[key], f"{path}.{key}")
            elif s.get("additionalProperties") is False:
                errs.append(f"{path}: unknown key {key}")
    if "oneOf" in s:
        matches = sum(not validate(value, alt, path) for alt in s["oneOf"])
        if matches != 1:
            errs.append(f"{path}: matches {matches} of oneOf")
    return errs


def _objects(f: Field, path: str = "") -> list[tuple[str, Obj]]:
    """Every mapping declaration under ``f``, with its key path."""
    out: list[tuple[str, Obj]] = []
    if isinstance(f, Obj):
        out.append((path, f))
        for k in f.keys:
            out += _objects(k.spec, f"{path}.{k.name}" if path else k.name)
    elif isinstance(f, ListOf):
        out += _objects(f.item, f"{path}[]")
    elif isinstance(f, ByKind):
        for alt in (f.scalar, f.mapping, f.sequence):
            if alt is not None:
                out += _objects(alt, path)
    return out


def _schema_at(s: dict[str, Any], path: str) -> list[dict[str, Any]]:
    """The object schemas found at a declaration path (through arrays and oneOf)."""
    nodes = [s]
    for part in [p for p in re.split(r"\.|(\[\])", path) if p]:
        nxt: list[dict[str, Any]] = []
        for n in nodes:
            for alt in _alternatives(n):
                if part == "[]":
                    if "items" in alt:
                        nxt.append(alt["items"])
                elif part in alt.get("properties", {}):
                    nxt.append(alt["properties"][part])
        nodes = nxt
    return [alt for n in nodes for alt in _alternatives(n) if alt.get("type") == "object"]


def _alternatives(n: dict[str, Any]) -> list[dict[str, Any]]:
    """A node's shapes: its ``oneOf`` alternatives, or itself when it has
    properties of its own (the top level's ``oneOf`` only says which of
    ``vehicles`` and ``networks`` is required)."""
    return [n] if "properties" in n else list(n.get("oneOf", [n]))


def test_schema_is_draft_2020_12_json() -> None:
    s = schema()
    assert s["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert json.loads(json.dumps(s)) == s
    assert "required" not in s and s["additionalProperties"] is False
    assert s["oneOf"] == [{"required": ["vehicles"]}, {"required": ["networks"]}]


@pytest.mark.parametrize(
    ("path", "obj"), _objects(MISSION), ids=[p or "top" for p, _ in _objects(MISSION)]
)
def test_every_dataclass_field_has_a_key_and_every_key_a_field(path: str, obj: Obj) -> None:
    if obj.cls is not None:
        from_keys = {k.target for k in obj.keys if k.target}
        fields = {f.name for f in dataclasses.fields(obj.cls)}
        assert from_keys | set(obj.extra_fields) == fields, f"{path or 'top'} vs {obj.cls.__name__}"
        assert not from_keys & set(obj.extra_fields)
    # the schema at this path has exactly the declared keys
    found = [
        o for o in _schema_at(schema(), path) if set(o["properties"]) == {k.name for k in obj.keys}
    ]
    assert found, f"schema for {path or 'top'} does not list {[k.name for k in obj.keys]}"


def test_top_level_covers_mission_and_law_config() -> None:
    assert MISSION.cls is Mission
    assert set(LAW_SOURCES) == {f.name for f in dataclasses.fields(LawConfig)}
    declared = {p for p, _ in _objects(MISSION)} | {
        f"{p}.{k.name}" if p else k.name for p, o in _objects(MISSION) for k in o.keys
    }
    for source in LAW_SOURCES.values():
        assert source in declared


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_every_shipped_mission_validates_against_the_schema(path: Path) -> None:
    data = yaml.safe_load(path.read_text())
    assert validate(data, schema()) == []


@pytest.mark.parametrize(
    "name",
    # (not yes_is_not_true: PyYAML's YAML 1.1 reads yes as true before the
    # schema sees it; a YAML 1.2 editor reads a string, which the schema refuses)
    ["bad_sysid", "unknown_key_typo", "vector_length", "enum_typo", "rate_too_high", "bad_link"],
)
def test_the_schema_rejects_what_the_validator_rejects_by_type(name: str) -> None:
    data = yaml.safe_load((BAD / f"{name}.yaml").read_text())
    assert validate(data, schema()) != []


def test_docs_describe_every_key() -> None:
    text = (ROOT / "docs" / "mission-format.md").read_text()
    for path, obj in _objects(MISSION):
        for k in obj.keys:
            assert f"`{k.name}`" in text, f"docs/mission-format.md does not mention {path}.{k.name}"
