"""Where mission problems are collected: ``Problem`` (one line of output),
``Context`` (all problems, the line of every key path), and the wording
helpers ``describe_node`` (what the user wrote) and ``did_you_mean``.
"""

from __future__ import annotations

import difflib
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import yaml

__all__ = ["MAX_PER_KIND", "TAG", "Context", "Problem", "describe_node", "did_you_mean"]

#: Prefix of YAML's standard tags.
TAG = "tag:yaml.org,2002:"


@dataclass(frozen=True)
class Problem:
    """One mistake: ``line`` is 1-based; ``path`` like ``vehicles[2].sysid``."""

    line: int
    path: str
    message: str

    def render(self, file: str) -> str:
        """The one-line form ``file:line: path: message``; characters that
        are not printable (newlines, terminal escapes) are shown escaped, so
        one problem is always one line whatever the file contains."""
        return _printable(f"{file}:{self.line}: {self.path}: {self.message}")


def _printable(text: str) -> str:
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


#: Problems kept per kind (key path with its list indices dropped); the rest are counted.
MAX_PER_KIND = 20
_INDEX_RE = re.compile(r"\[\d+\]")


@dataclass
class Context:
    """Problems found so far, the line of every parsed key path, and the
    values other fields' defaults depend on (``defaults``).

    Only the first ``MAX_PER_KIND`` problems of one kind (``vehicles[].start``
    for every ``vehicles[i].start``) are kept; ``omitted`` counts the rest
    by kind, with the line of the first one left out, so memory stays
    bounded however many vehicles share a mistake."""

    problems: list[Problem] = field(default_factory=list)
    lines: dict[str, int] = field(default_factory=dict)
    defaults: dict[str, Any] = field(default_factory=dict)
    nodes_seen: int = 0
    too_big: bool = False
    kinds: dict[str, int] = field(default_factory=dict)
    omitted: dict[str, tuple[int, int]] = field(default_factory=dict)

    def add(self, where: yaml.Node | int, path: str, message: str) -> None:
        """Record a problem at a node (its start line) or at a 1-based line."""
        line = where if isinstance(where, int) else where.start_mark.line + 1
        path = path or "(top level)"
        kind = _INDEX_RE.sub("[]", path)
        n = self.kinds.get(kind, 0) + 1
        self.kinds[kind] = n
        if n <= MAX_PER_KIND:
            self.problems.append(Problem(line, path, message))
        else:
            first, count = self.omitted.get(kind, (line, 0))
            self.omitted[kind] = (first, count + 1)

    def summary_problems(self) -> list[Problem]:
        """The kept problems and one line per kind saying how many were left out."""
        more = [
            Problem(line, kind, f"{count} more problems of this kind not shown"
                    f" (the first {MAX_PER_KIND} are)")
            for kind, (line, count) in self.omitted.items()
        ]  # fmt: skip
        return [*self.problems, *more]

    def line_of(self, path: str) -> int:
        """Line of ``path``, or of its nearest parsed ancestor, or 1."""
        while path:
            if path in self.lines:
                return self.lines[path]
            cut = max(path.rfind("."), path.rfind("["))
            path = path[:cut] if cut > 0 else ""
        return 1


def did_you_mean(word: str, choices: Sequence[str]) -> str:
    """`` (did you mean "x"?)`` when a choice is close to ``word``, else ``""``."""
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    if not close:
        lowered = {c.lower(): c for c in choices}
        if word.lower() in lowered:
            close = [lowered[word.lower()]]
    return f' (did you mean "{close[0]}"?)' if close else ""


#: Plain words YAML 1.1 reads as booleans (strings in YAML 1.2, which mission files follow).
_YAML11_BOOLS = frozenset({"yes", "no", "on", "off", "y", "n"})


def describe_node(node: yaml.Node) -> str:
    """What the user wrote, for ``got ...``: quoted strings, numbers as
    written, the kind of a collection."""
    if isinstance(node, yaml.MappingNode):
        return "a mapping"
    if isinstance(node, yaml.SequenceNode):
        n = len(node.value)
        return f"a list of {n} item{'s' if n != 1 else ''}"
    text = str(node.value)
    shown = text if len(text) <= 40 else text[:37] + "..."
    if node.tag == TAG + "str":
        if getattr(node, "style", None) is None and text.lower() in _YAML11_BOOLS:
            return f"{shown} (YAML 1.1 reads it as a boolean, YAML 1.2 as a string)"
        return json.dumps(shown)
    if node.tag == TAG + "null":
        return "nothing (null)"
    return shown
