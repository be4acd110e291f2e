"""A seeded generator of hostile mission documents (issue 15), shared by the
suite (tests/mission/test_mission_fuzz.py) and the benchmark
(benchmarks/bench_mission_fuzz.py).

Each document is one of a few small valid missions (a constant, an
expression and a waypoint leader; obstacles, events, limits, signing,
a real vehicle) changed in one to four ways:

- structural: a value anywhere replaced by a hostile YAML snippet (huge or
  malformed numbers, wrong tags, YAML 1.1 forms, collections, expressions
  that fail, aliases, Python tags, long strings), a key deleted, an unknown
  or duplicated key added, a list item repeated;
- textual: a line deleted, repeated or indented differently, the text
  truncated, a character replaced (tabs, NUL, other control characters,
  non-ASCII), a deep ``[[[`` nest or a hostile line inserted.

Only ``random.Random(seed)``: the same seed gives the same documents on every
machine, so a failure names its seed and index and is reproduced exactly.
"""

from __future__ import annotations

import json
import random
import re
import signal
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

from gcs_swarm.errors import MissionError
from gcs_swarm.mission import parse_mission
from gcs_swarm.offline import demand_report

__all__ = ["SNIPPETS", "TEMPLATES", "Hang", "check_document", "documents", "watchdog"]

_BASE = {
    "mission": {"duration": 1, "rate": 20},
    "leader": {"force": [0, 0, 0]},
    "vehicles": [{"sysid": 1, "start": [2, 1, 2]}, {"sysid": 2, "start": [-1, -1, -1]}],
}


def _copy(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _copy(v) for k, v in x.items()}
    return [_copy(v) for v in x] if isinstance(x, list) else x


def _with(**changes: Any) -> dict[str, Any]:
    doc: dict[str, Any] = _copy(_BASE)
    doc.update(changes)
    return doc


#: The valid missions the documents are made from (small: PyYAML's pure-Python
#: parser, not the checks, is most of the time per document).
TEMPLATES: tuple[dict[str, Any], ...] = (
    _with(),
    _with(
        gains={"M": 1, "D": 1, "k": 9, "k_s": 1, "k_r": 0.2, "alpha": 2, "q": 10},
        emulator={"dynamics": "ideal"},
        vehicles=[
            {"sysid": 1, "start": [2, 1, 2]},
            {"sysid": 2, "start": [-1, -1, -1]},
            {"sysid": 3, "start": [3, 4, 2], "reserve": True},
        ],
        events=[{"t": 0.5, "join": 3}],
    ),
    _with(leader={"start": [0, 0, 0], "force": ["10", "10*sin(x/8)", "2*cos(t)"]}),
    _with(leader={"force": {"waypoints": [[0, 0, 0], [5, 5, 2]], "speed": 2}}),
    _with(
        obstacles={"boxes": [{"centre": [8, 0, 1], "half_extents": [1, 1, 1]}], "r0": 2},
        limits={"a_max": 5, "v_max": 3, "z_floor": -10, "safety": {"enabled": True}},
    ),
    _with(
        mission={
            "duration": 1,
            "origin": {"lat": -35.36, "lon": 149.16, "alt": 584},
            "signing": {"key_env": "GCS_SWARM_FUZZ_KEY"},
            "failsafe": {"gcs": True},
        },
        vehicles=[
            {"sysid": 1, "link": "udpin:127.0.0.1:14550", "start": [0, 0, 5]},
            {"sysid": 2, "start": [3, 0, 5]},
        ],
        emulator={"base_port": 5760, "host": "127.0.0.1", "mode": "lockstep"},
    ),
)

_HUGE = "9" * 400
#: Hostile YAML values (flow style, so they fit after ``key:`` or ``-``).
SNIPPETS: tuple[str, ...] = (
    _HUGE, "-" + _HUGE, "9" * 5000, "1" * 4301, "0x" + "f" * 400, "0o" + "7" * 500,
    "1e308", "-1e308", "1e999", "-1e999", "1e-320", ".nan", ".inf", "-.inf", ".NaN",
    "!!float abc", "!!int x1", "!!int 0x_", "!!int 1.5", "!!float 1:30", "!!str 5",
    "!!binary AAAA", "!!timestamp 2001-01-01", "!!bool maybe", "!!null x",
    "!!python/object/apply:os.system [ls]", "!!python/name:os.system", "!custom 1",
    "1:30", "-1:30", "190:20:30.15", "010", "-010", "0o17", "0x1F", "0b101", "1_000",
    "+1", "-0", "0", "-1", "1", "2", "254", "255", "256", "65535", "65536", "0.5", "-0.0",
    "yes", "no", "on", "off", "y", "n", "True", "FALSE", "~", "null", '""', '"  "',
    '"\\0"', '"\\x1b[2J"', '"\\u202e"', "'" + "x" * 5000 + "'", '"sim"', "sim",
    '"udpin:999.1.1.1:1"', '"udpin:127.0.0.1:99999"', '"udpin:127.0.0.1:5760"',
    '"tcp:host:0"', '"udp:127.0.0.1:14550"', "999.1.1.1", "::1", "a..b", "-bad-",
    "/dev/zero", "/dev/stdin", "/", ".", "nope.key", "GCS-KEY", "'a b'", "lockstep",
    "realtime", "arducopter", "first-vehicle", "hold", "land",
    "[]", "{}", "[1]", "[1, 2]", "[1, 2, 3]", "[1, 2, 3, 4]", "[[1, 2, 3]]", "{a: 1}",
    "[1e300, 0, 0]", "[0, 2.0e5, 0]", "[.nan, 0, 0]", "[" + _HUGE + ", 0, 1]",
    '["1/0", 0, 0]', '["sqrt(-1)", 0, 0]', '["log(0)", 0, 0]', '["9**9**9", 0, 0]',
    '["10.0**400", 0, 0]', '["1e999", 0, 0]', '["x % 0", 0, 0]', '["1/t", 0, 0]',
    '["sqrt(1 - t)", 0, 0]', '["exp(t*100)", 0, 0]', '["hypot(1e308, 1e308, 1e308)", 0, 0]',
    '["(-8)**(1/3)", 0, 0]', '["__import__(\'os\')", 0, 0]', '["x.__class__", 0, 0]',
    '["lambda: 1", 0, 0]', '["' + "(" * 150 + "1" + ")" * 150 + '", 0, 0]',
    '["' + "-" * 900 + '1", 0, 0]', '["' + "x+" * 600 + 'x", 0, 0]', '["", 0, 0]',
    '["' + _HUGE + '", 0, 0]', '["sin(x, y)", 0, 0]', '["max(x)", "y", "z"]',
    '["t**t**t", "vx*1e300", "floor(1e300*1e10)"]', '["clip(x, 1, 0)", "sign(0)", "atan2(0, 0)"]',
    "{waypoints: [[0, 0, 0]], speed: 1e9}", "{waypoints: [], speed: 1}",
    "{waypoints: [[1e6, 0, 0]], speed: 1}", "{waypoints: [[0, 0, 0]], speed: -1}",
    "[{centre: [0, 0, 0], half_extents: [1, 1, 1]}]", "[{centre: [0, 0, 0]}]",
    "&a [1, 2, 3]", "*a", "*nowhere", "&b {sysid: 1, start: [0, 0, 1]}",
    "[" * 70 + "]" * 70, "{a: " * 70 + "1" + "}" * 70, "{<<: {a: 1}}", "{? [1, 2] : 3}",
)  # fmt: skip

_KEYS = (
    "mission", "vehicles", "leader", "gains", "emulator", "limits", "obstacles", "events",
    "readings", "log", "duration", "rate", "sysid", "start", "link", "force", "host",
    "base_port", "signing", "key_file", "key_env", "origin", "reserve", "q", "t", "join",
    "leave", "speed", "waypoints", "envelope", "safety", "separation", "geofence",
    "unknown", "Duration", "<<", "", "1", "null",
)  # fmt: skip

_CHARS = "\t\x00\x01\x1b\x7f\r\u00e9\u202e\ufeff\U0001f600:[]{},#&*!|>'\"%@`- "


def documents(seed: int, n: int) -> Iterator[str]:
    """``n`` hostile documents from ``seed`` (module docstring)."""
    rng = random.Random(seed)
    for _ in range(n):
        yield _document(rng)


def _flow(x: Any) -> str:
    """``x`` in YAML flow style (strings as JSON, which YAML reads alike;
    plain where a name is plain)."""
    if isinstance(x, str) and _PLAIN_RE.fullmatch(x):
        return x
    if isinstance(x, dict):
        return "{" + ", ".join(f"{_flow(k)}: {_flow(v)}" for k, v in x.items()) + "}"
    if isinstance(x, list):
        return "[" + ", ".join(_flow(v) for v in x) + "]"
    if isinstance(x, bool):
        return "true" if x else "false"
    if x is None:
        return "null"
    return json.dumps(x) if isinstance(x, str) else repr(x)


_PLAIN_RE = re.compile(r"(?!(?:true|false|null|yes|no|on|off|y|n)$)[A-Za-z_][A-Za-z0-9_]*")


def _block(x: Any, indent: str) -> list[str]:
    """``x`` (a mapping) in YAML block style, lists of numbers in flow style."""
    lines = []
    for k, v in x.items():
        if isinstance(v, dict) and v:
            lines += [f"{indent}{_flow(k)}:", *_block(v, indent + "  ")]
        elif isinstance(v, list) and v and all(isinstance(i, dict) for i in v):
            lines.append(f"{indent}{_flow(k)}:")
            for item in v:
                sub = _block(item, indent + "    ") if item else [indent + "    {}"]
                lines.append(f"{indent}  - {sub[0].strip()}")
                lines += sub[1:]
        else:
            lines.append(f"{indent}{_flow(k)}: {_flow(v)}")
    return lines


def _document(rng: random.Random) -> str:
    doc = _copy(rng.choice(TEMPLATES))
    raw: dict[str, str] = {}
    for _ in range(rng.randint(1, 4)):
        if rng.random() < 0.7:
            _mutate(rng, doc, raw)
    if rng.random() < 0.1:  # block style, as people write
        text = "".join(f"{line}\n" for line in _block(doc, ""))
    else:  # one section per line, flow style inside
        text = "".join(f"{_flow(k)}: {_flow(v)}\n" for k, v in doc.items())
    for mark, snippet in raw.items():
        text = text.replace(f'"{mark}"', snippet).replace(f"'{mark}'", snippet)
        text = text.replace(mark, snippet)
    for _ in range(rng.choice((0, 0, 1, 2))):
        text = _mutate_text(rng, text)
    return text


def _containers(node: Any, out: list[Any]) -> list[Any]:
    if isinstance(node, dict | list):
        out.append(node)
        for child in node.values() if isinstance(node, dict) else node:
            _containers(child, out)
    return out


def _mutate(rng: random.Random, doc: Any, raw: dict[str, str]) -> None:
    target = rng.choice(_containers(doc, []))
    mark = f"@@{len(raw)}@@"
    how = rng.random()
    if isinstance(target, dict):
        keys = list(target)
        if keys and how < 0.6:
            raw[mark] = rng.choice(SNIPPETS)
            target[rng.choice(keys)] = mark
        elif keys and how < 0.75:
            del target[rng.choice(keys)]
        else:
            raw[mark] = rng.choice(SNIPPETS)
            target[rng.choice(_KEYS) + rng.choice(("", "", "_", "2"))] = mark
    elif target:
        i = rng.randrange(len(target))
        if how < 0.6:
            raw[mark] = rng.choice(SNIPPETS)
            target[i] = mark
        elif how < 0.8:
            target.append(_copy(target[i]))
        else:
            del target[i]


def _mutate_text(rng: random.Random, text: str) -> str:
    lines = text.split("\n")
    i = rng.randrange(len(lines))
    how = rng.randrange(7)
    if how == 0:
        del lines[i]
    elif how == 1:
        lines.insert(i, lines[i])
    elif how == 2:
        lines[i] = " " * rng.choice((1, 3, 8)) + lines[i]
    elif how == 3:
        return text[: rng.randrange(len(text) + 1)]
    elif how == 4:
        if lines[i]:
            k = rng.randrange(len(lines[i]))
            lines[i] = lines[i][:k] + rng.choice(_CHARS) + lines[i][k + 1 :]
    elif how == 5:
        lines.insert(i, "x: " + "[" * rng.choice((10, 65, 200, 3000)))
    else:
        lines.insert(i, f"{rng.choice(_KEYS)}: {rng.choice(SNIPPETS)}")
    return "\n".join(lines)


#: ``fuzz.yaml:LINE: key.path: message``; a key path may hold quoted names (``a."b c"``).
_LINE_RE = re.compile(r'^fuzz\.yaml:(\d+): ((?:[^\s"]|"(?:[^"\\]|\\.)*")+|\(top level\)): \S.*$')


def check_document(text: str) -> str:
    """What ``gcs-swarm check`` does with ``text`` (validation, then the
    envelope warning of a valid mission), in process: ``"ok"`` or
    ``"refused"`` with every line ``fuzz.yaml:LINE: key.path: message``.
    Anything else raised is a bug: it propagates."""
    try:
        mission = parse_mission(text, "fuzz.yaml")
    except MissionError as err:
        lines = str(err).splitlines()
        assert lines and list(err.problems) == lines, lines
        n_lines = len(text.splitlines()) + 1  # YAML breaks lines at \r too
        for line in lines:
            m = _LINE_RE.match(line)
            assert m is not None, f"not file:line: key: message: {line!r}"
            assert 1 <= int(m[1]) <= n_lines, line
        return "refused"
    envelope = mission.law.limits.envelope
    if envelope.bounded:
        demand_report(mission, envelope)
    return "ok"


class Hang(Exception):
    """A document took longer than the watchdog allowed."""


@contextmanager
def watchdog(limit_s: float) -> Iterator[None]:
    """Raise ``Hang`` in the block if it runs over ``limit_s`` of wall time
    (SIGALRM; the main thread only). Not a timing: a generous bound that
    turns a hang into a failure naming the document."""

    def alarm(signum: int, frame: FrameType | None) -> None:
        raise Hang(f"over {limit_s:g} s")

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, limit_s)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
