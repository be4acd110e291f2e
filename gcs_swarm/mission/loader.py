"""Read a mission file into a ``Mission``, or fail with every problem at once.

The YAML is composed with the safe loader (``source.compose``: SafeLoader with
the YAML 1.2 core schema and bounded nesting): the node tree keeps line
numbers and nothing is ever constructed from a tag, so ``!!python/object`` is
reported as one line like any other mistake. Only a regular file of at most
``MAX_FILE_BYTES`` is read. Every
problem is one line ``file:line: key.path: message``, sorted by line; whole-file
problems use the path ``(file)``, YAML syntax errors ``(syntax)``.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import yaml

from gcs_swarm.control.params import Avoidance, LawConfig, Limits, Safety
from gcs_swarm.errors import MissionError
from gcs_swarm.mission.checks import run_checks
from gcs_swarm.mission.context import Context, Problem
from gcs_swarm.mission.declarations import INVALID
from gcs_swarm.mission.format import MISSION
from gcs_swarm.mission.model import (
    DEFAULT_NETWORK,
    Emulator,
    Mission,
    Settings,
    Signing,
    Vehicle,
)
from gcs_swarm.mission.source import (
    KEY_FILE_MAX_BYTES,
    SIGNING_KEY_BYTES,
    compose,
    key_file_path,
    read_regular,
    signing_key_bytes,
)

__all__ = [
    "MAX_FILE_BYTES",
    "MAX_PROBLEMS",
    "describe",
    "load_mission",
    "parse_mission",
]

#: A mission file is a few kilobytes; anything over this is refused unread.
MAX_FILE_BYTES = 1 << 20
#: At most this many problems are printed (then a count of the rest).
MAX_PROBLEMS = 100


def _fail(source: str, problems: list[Problem]) -> MissionError:
    problems = sorted(problems, key=lambda p: p.line)  # stable: same line keeps order
    lines = [p.render(source) for p in problems[:MAX_PROBLEMS]]
    if len(problems) > MAX_PROBLEMS:
        more = len(problems) - MAX_PROBLEMS
        lines.append(Problem(1, "(file)", f"{more} more problems not shown").render(source))
    return MissionError("\n".join(lines), lines)


def load_mission(path: str | os.PathLike[str]) -> Mission:
    """Read and validate the mission file at ``path``.

    Raises ``MissionError`` whose message is every problem, one per line, and
    whose ``problems`` attribute is the list of those lines. ``path`` is shown
    in the messages as given.
    """
    source = os.fspath(path)
    try:
        data = read_regular(source, MAX_FILE_BYTES)
    except OSError as err:
        raise _fail(
            source, [Problem(1, "(file)", f"cannot read the file: {err.strerror or err}")]
        ) from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        line = data[: err.start].count(b"\n") + 1
        raise _fail(source, [Problem(line, "(file)", "not UTF-8 text")]) from None
    return parse_mission(text, source, name=Path(source).stem)


def parse_mission(text: str, source: str = "<string>", *, name: str = "mission") -> Mission:
    """Validate YAML ``text``; ``source`` names it in messages, ``name`` is the
    mission name when the file gives none."""
    try:
        root = compose(text)
    except yaml.MarkedYAMLError as err:
        raise _fail(source, [_syntax_problem(err)]) from None
    except yaml.reader.ReaderError as err:  # a character YAML does not allow
        line = text[: err.position].count("\n") + 1
        what = f"character #x{err.character:04x}" if isinstance(err.character, int) else "byte"
        problem = Problem(line, "(syntax)", f"YAML syntax error: {what} is not allowed in YAML")
        raise _fail(source, [problem]) from None
    except yaml.YAMLError as err:
        problem = Problem(1, "(syntax)", f"YAML syntax error: {' '.join(str(err).split())}")
        raise _fail(source, [problem]) from None
    if root is None:
        raise _fail(
            source,
            [Problem(1, "(file)", 'the file is empty; a mission needs at least a "vehicles" list')],
        )
    ctx = Context()
    ctx.defaults["duration"] = Settings(name="").duration
    sections = MISSION.parse(root, "", ctx)
    if sections is INVALID:
        sections = {}
    mission = _assemble(ctx, source, name, sections)
    if ctx.problems or mission is None:
        raise _fail(source, ctx.summary_problems())
    return replace(mission, text=text)


#: PyYAML's token names, in words a user recognises.
_TOKEN_WORDS = {
    "'?'": "a key (name: value)",
    "<block end>": "the end of the block (check the indentation)",
    "'<block mapping start>'": "the start of a mapping",
    "'<block sequence start>'": "the start of a list",
}


def _syntax_problem(err: yaml.MarkedYAMLError) -> Problem:
    mark = err.problem_mark or err.context_mark
    line = mark.line + 1 if mark is not None else 1
    text = err.problem or "not valid YAML"
    for token, words in _TOKEN_WORDS.items():
        text = text.replace(token, words)
    if err.context and not err.context.startswith("while"):
        text = f"{err.context}, {text}"  # e.g. "expected a single document ..., but found ..."
    elif err.context and err.context_mark is not None and err.context_mark.line + 1 != line:
        text += f" ({err.context} at line {err.context_mark.line + 1})"
    if "\\t" in text or "\t" in text:
        text += "; indent with spaces, not tabs"
    return Problem(line, "(syntax)", f"YAML syntax error: {text}")


def _ok(value: Any) -> bool:
    return value is not INVALID


def _assemble(ctx: Context, source: str, name: str, s: dict[str, Any]) -> Mission | None:
    """Build the mission from the parsed sections and run the semantic checks
    on whichever sections parsed; ``None`` if any section failed."""
    settings = s.get("mission", INVALID)
    if settings is None:
        settings = Settings(name=name)
    elif _ok(settings) and settings.name is None:
        settings = replace(settings, name=name)
    emulator = s.get("emulator", INVALID)
    vehicles, networks = _vehicles_and_networks(ctx, s)
    obstacles = s.get("obstacles", INVALID)
    no_obstacles = obstacles is None
    if obstacles is None:
        obstacles = ((), Avoidance())
    limits = s.get("limits", INVALID)
    no_limits = limits is None
    if limits is None:
        limits = (Limits(), Safety())
    parts = [s.get(k, INVALID) for k in ("gains", "leader", "readings")]
    law: LawConfig | None = None
    if all(_ok(x) for x in (*parts, obstacles, limits)):
        gains, leader, readings = parts
        law = LawConfig(
            gains=gains,
            leader=leader,
            obstacles=obstacles[0],
            avoidance=obstacles[1],
            readings=readings,
            limits=limits[0],
            safety=limits[1],
        )
    if law is not None:
        # null / auto / an absent section: decided from the vehicles below.
        safety_auto = no_limits or limits[1].enabled is None
        heading_auto = no_obstacles or str(law.avoidance.heading) == "auto"
        law = _resolve_defaults(
            law, vehicles if _ok(vehicles) else (), safety_auto=safety_auto,
            heading_auto=heading_auto,
        )  # fmt: skip
    events = s.get("events", INVALID)
    if _ok(events) and networks is not None:
        events = _resolve_event_networks(ctx, events, networks)
    if _ok(settings) and settings.signing is not None:
        _check_key_file(ctx, source, settings.signing)
    run_checks(
        ctx,
        settings if _ok(settings) else None,
        vehicles if _ok(vehicles) else None,
        emulator if _ok(emulator) else None,
        law,
        events if _ok(events) else None,
    )
    if _ok(vehicles) and _ok(emulator):
        vehicles = _fill_sim_origins(vehicles, emulator)
    log = s.get("log", INVALID)
    if law is None or not all(_ok(x) for x in (settings, vehicles, emulator, events, log)):
        return None
    return Mission(
        source=source,
        settings=settings,
        vehicles=vehicles,
        law=law,
        emulator=emulator,
        events=tuple(sorted(events, key=lambda e: e.t)),
        log=log,
        networks=networks or (DEFAULT_NETWORK,),
    )


def _vehicles_and_networks(ctx: Context, s: dict[str, Any]) -> tuple[Any, tuple[str, ...] | None]:
    """The flat vehicle list (file order) and the networks' names: exactly one
    of ``vehicles`` (one implicit network, ``DEFAULT_NETWORK``) or
    ``networks`` (names unique). ``(INVALID, None)`` when it does not parse."""
    flat, nets = s.get("vehicles", INVALID), s.get("networks", INVALID)
    if flat is None and nets is None:
        line = min(ctx.lines.values(), default=1)  # the first section's, as for any missing key
        ctx.add(line, "(top level)", 'missing required key "vehicles" (or "networks")')
        return INVALID, None
    if flat is INVALID or nets is INVALID:
        return INVALID, None
    if flat is not None and nets is not None:
        line = min(ctx.line_of("vehicles"), ctx.line_of("networks"))
        ctx.add(line, "networks", 'expected either "vehicles" or "networks", got both')
        return INVALID, None
    if flat is not None:
        return flat, (DEFAULT_NETWORK,)
    first: dict[str, int] = {}
    for j, (name, _) in enumerate(nets):
        if name in first:
            path = f"networks[{j}].name"
            ctx.add(ctx.line_of(path), path,
                    f'duplicate network name "{name}" (also networks[{first[name]}])')  # fmt: skip
        else:
            first[name] = j
    if len(first) != len(nets):
        return INVALID, None
    return tuple(v for _, vs in nets for v in vs), tuple(name for name, _ in nets)


def _resolve_event_networks(ctx: Context, events: Any, networks: tuple[str, ...]) -> Any:
    """Each event's network: the one it names (which must exist), or the
    mission's only network; with several networks it must name one."""
    out, ok = [], True
    for k, e in enumerate(events):
        name = e.network
        path = f"events[{k}].network"
        if name is None and len(networks) > 1:
            ctx.add(ctx.line_of(f"events[{k}]"), path,
                    f"expected the vehicle's network, one of {', '.join(networks)}"
                    " (the mission has several)")  # fmt: skip
            ok = False
        elif name is not None and name not in networks:
            names = ", ".join(networks)
            ctx.add(ctx.line_of(path), path,
                    f'no network is named "{name}"; expected one of {names}')  # fmt: skip
            ok = False
        else:
            name = networks[0] if name is None else name
            out.append(replace(e, network=name, net_index=networks.index(name)))
    return tuple(out) if ok else INVALID


def _check_key_file(ctx: Context, source: str, signing: Signing) -> None:
    """``mission.signing.key_file`` must be a regular file holding a key, now:
    ``run`` reads it before any vehicle is commanded (``/dev/zero`` used to
    pass here and then be read without end)."""
    if signing.key_file is None:
        return
    key = "mission.signing.key_file"
    path = key_file_path(source, signing.key_file)
    try:
        raw = read_regular(path, KEY_FILE_MAX_BYTES)
    except OSError as err:
        ctx.add(ctx.line_of(key), key, f"cannot read the key file {path}: {err.strerror or err}")
        return
    if signing_key_bytes(raw) is None:  # never echo the content: only its length
        ctx.add(
            ctx.line_of(key),
            key,
            f"expected a {SIGNING_KEY_BYTES}-byte signing key (raw, or"
            f" {2 * SIGNING_KEY_BYTES} hex digits) in {path}, got {len(raw)} bytes",
        )


def _resolve_defaults(
    law: LawConfig, vehicles: tuple[Vehicle, ...], *, safety_auto: bool, heading_auto: bool
) -> LawConfig:
    """Defaults that depend on the rest of the mission (issue 10): the safety
    filter (``limits.safety.enabled`` null or absent) is on when any vehicle
    is a real autopilot (its link is not ``sim``) and off for an all-sim
    mission, which then reproduces the paper; ``obstacles.heading: auto``
    (or absent) takes the desired force's azimuth with the filter on (a
    filter holding a vehicle at a face makes the velocity's azimuth swing)
    and the spec's velocity otherwise."""
    safety = law.safety
    if safety_auto:
        safety = replace(safety, enabled=any(not v.is_sim for v in vehicles))
    avoidance = law.avoidance
    if heading_auto:
        avoidance = replace(avoidance, heading="desired" if safety.enabled else "velocity")
    return replace(law, safety=safety, avoidance=avoidance)


def _fill_sim_origins(vehicles: tuple[Vehicle, ...], emulator: Emulator) -> tuple[Vehicle, ...]:
    """Default home of the k-th sim vehicle: [k * origin_spread, 0, ground] [m]."""
    out = []
    k = 0
    for v in vehicles:
        if v.is_sim:
            if v.origin is None:
                v = replace(v, origin=(k * emulator.origin_spread, 0.0, emulator.ground))
            k += 1
        out.append(v)
    return tuple(out)


def describe(mission: Mission) -> str:
    """One line describing a valid mission, for ``gcs-swarm check``."""
    n = len(mission.vehicles)
    sim = sum(v.is_sim for v in mission.vehicles)
    kinds = "sim" if sim == n else ("real" if sim == 0 else f"{sim} sim, {n - sim} real")
    law = mission.law
    s = mission.settings
    parts = [
        f'"{s.name}"',
        f"{n} vehicle{'s' if n != 1 else ''} ({kinds})"
        + (f" on {len(mission.networks)} networks" if mission.multi_network else ""),
        f"{len(mission.reserves)} reserve",
        f"{len(mission.events)} event{'s' if len(mission.events) != 1 else ''}",
        f"{len(law.obstacles)} obstacle{'s' if len(law.obstacles) != 1 else ''}",
        f"leader force {type(law.leader.force).__name__}",
        f"{s.duration:g} s at {s.rate:g} Hz",
        f"end {s.end}",
    ]
    return ", ".join(parts)
