"""Semantic checks of a mission: what no single key's type can catch
(duplicate system ids, shared starts, an obstacle on the leader's start,
events for the wrong vehicle, a link asked to carry too much, ...).

Each check reads only sections that parsed cleanly and records one problem
line per mistake, at the line of the key it is about.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Sequence

import yaml

from gcs_swarm.control.params import Box, LawConfig, Vec3, WaypointForce
from gcs_swarm.mission.context import Context
from gcs_swarm.mission.model import Emulator, Event, GeoPoint, Settings, Vehicle

__all__ = ["key_line", "run_checks"]

#: Two starts closer than this [m] count as the same point (Eq. 9 is singular there).
SAME_POINT_M = 1e-6


def _fmt(p: Sequence[float]) -> str:
    return "[" + ", ".join(f"{x:g}" for x in p) + "]"


def _inside(box: Box, p: Vec3) -> bool:
    return all(abs(p[i] - box.centre[i]) <= box.half_extents[i] for i in range(3))


def run_checks(
    ctx: Context,
    settings: Settings | None,
    vehicles: tuple[Vehicle, ...] | None,
    emulator: Emulator | None,
    law: LawConfig | None,
    events: tuple[Event, ...] | None,
) -> None:
    """Record every semantic problem; a ``None`` section failed to parse and
    the checks that need it are skipped (its own errors are already there)."""
    if vehicles is not None:
        _check_vehicles(ctx, vehicles)
        if emulator is not None:
            _check_ground(ctx, vehicles, emulator, settings)
            _check_ports(ctx, vehicles, emulator)
            if settings is not None:
                _check_compensation(ctx, vehicles, emulator, settings)
        if settings is not None:
            _check_links(ctx, vehicles, settings)
        if events is not None:
            _check_events(ctx, vehicles, events)
    if law is not None:
        _check_law(ctx, law, vehicles)
        if settings is not None and settings.failsafe.fence and law.limits.geofence_min is None:
            key = "mission.failsafe.fence"
            ctx.add(ctx.line_of(key), key, "expected limits.geofence for the vehicles' own fence")


def _check_vehicles(ctx: Context, vehicles: tuple[Vehicle, ...]) -> None:
    first_of: dict[int, int] = {}
    for i, v in enumerate(vehicles):
        path = f"vehicles[{i}].sysid"
        if v.sysid in first_of:
            ctx.add(
                ctx.line_of(path),
                path,
                f"duplicate system id {v.sysid} (also vehicles[{first_of[v.sysid]}])",
            )
        else:
            first_of[v.sysid] = i
    for i, v in enumerate(vehicles):
        for j in range(i):
            if math.dist(v.start, vehicles[j].start) < SAME_POINT_M:
                path = f"vehicles[{i}].start"
                ctx.add(
                    ctx.line_of(path),
                    path,
                    f"same start as vehicles[{j}] {_fmt(v.start)}; vehicles must start apart",
                )
                break
    if all(v.reserve for v in vehicles):
        ctx.add(
            ctx.line_of("vehicles"),
            "vehicles",
            "every vehicle is a reserve; at least one must fly from the start",
        )


def _check_ground(
    ctx: Context, vehicles: tuple[Vehicle, ...], emulator: Emulator, settings: Settings | None
) -> None:
    """A sim vehicle must start above its own home (the emulator's ground)."""
    origin = settings.origin if settings is not None else None
    for i, v in enumerate(vehicles):
        if not v.is_sim:
            continue
        if isinstance(v.origin, GeoPoint):
            if not isinstance(origin, GeoPoint):
                continue
            ground = v.origin.alt - origin.alt
            where = "its origin"
        elif v.origin is not None:
            ground = v.origin[2]
            where = f"vehicles[{i}].origin"
        else:
            ground = emulator.ground
            where = "emulator.ground"
        if v.start[2] <= ground:
            path = f"vehicles[{i}].start"
            ctx.add(
                ctx.line_of(path),
                path,
                f"z = {v.start[2]:g} is not above this sim vehicle's ground"
                f" (z = {ground:g}, {where})",
            )


def _check_ports(ctx: Context, vehicles: tuple[Vehicle, ...], emulator: Emulator) -> None:
    """The k-th sim vehicle listens on base_port + 10 k: the last must be a port."""
    n_sim = sum(v.is_sim for v in vehicles)
    last = emulator.base_port + 10 * (n_sim - 1)
    if emulator.base_port and not emulator.shared and n_sim and last > 65535:
        path = "emulator.base_port"
        ctx.add(
            ctx.line_of(path),
            path,
            f"{n_sim} sim vehicles need ports up to {emulator.base_port} + 10 x {n_sim - 1}"
            f" = {last}, over 65535",
        )


def _check_compensation(
    ctx: Context, vehicles: tuple[Vehicle, ...], emulator: Emulator, settings: Settings
) -> None:
    """Delay compensation maps vehicle time to the station's clock: it needs
    the bundled emulator in real time at speed-up 1 (lockstep: ignored)."""
    sims = any(v.is_sim for v in vehicles)
    if settings.delay_compensation and sims and emulator.mode == "realtime":
        if emulator.speedup != 1.0:
            ctx.add(
                ctx.line_of("mission.delay_compensation"),
                "mission.delay_compensation",
                f"needs real time: emulator.speedup 1, got {emulator.speedup:g}",
            )


def _check_links(ctx: Context, vehicles: tuple[Vehicle, ...], settings: Settings) -> None:
    """Rule: a link carries (vehicles on it) x rate setpoints per second, at
    most ``mission.link_budget``; each sim vehicle has its own endpoint. A
    real vehicle with ``origin: first-vehicle`` must start above z = 0 (the
    first vehicle's home)."""
    on_link: dict[str, list[int]] = defaultdict(list)
    for i, v in enumerate(vehicles):
        if not v.is_sim:
            on_link[v.link].append(i)
    for link, idx in on_link.items():
        load = len(idx) * settings.rate
        if load > settings.link_budget:
            path = f"vehicles[{idx[0]}].link"
            ctx.add(
                ctx.line_of(path),
                path,
                f"{len(idx)} vehicles x {settings.rate:g} Hz = {load:g} setpoints/s on {link},"
                f" over mission.link_budget = {settings.link_budget:g};"
                " lower mission.rate or split the link",
            )
    if settings.origin == "first-vehicle":
        for i, v in enumerate(vehicles):
            if not v.is_sim and v.start[2] <= 0.0:
                path = f"vehicles[{i}].start"
                ctx.add(
                    ctx.line_of(path),
                    path,
                    f"z = {v.start[2]:g} is not above the first vehicle's home"
                    " (z = 0 with mission.origin first-vehicle)",
                )


def _check_events(ctx: Context, vehicles: tuple[Vehicle, ...], events: tuple[Event, ...]) -> None:
    """Replay the events in time order (file order for ties): a join needs a
    vehicle out of the formation, a leave one in it."""
    by_id = {v.sysid: v for v in vehicles}
    active = {v.sysid for v in vehicles if not v.reserve}
    order = sorted(range(len(events)), key=lambda k: events[k].t)
    for k in order:
        e = events[k]
        path = f"events[{k}].{e.action}"
        vehicle = by_id.get(e.sysid)
        if vehicle is None:
            ctx.add(ctx.line_of(path), path, f"no vehicle has system id {e.sysid}")
        elif e.action == "join":
            if e.sysid in active:
                why = (
                    "it flies from the start: mark it reserve: true"
                    if not vehicle.reserve
                    else "it has joined already"
                )
                ctx.add(
                    ctx.line_of(path),
                    path,
                    f"vehicle {e.sysid} is already in the formation at t = {e.t:g} s ({why})",
                )
            active.add(e.sysid)
        else:
            if e.sysid not in active:
                ctx.add(
                    ctx.line_of(path),
                    path,
                    f"vehicle {e.sysid} is not in the formation at t = {e.t:g} s",
                )
            active.discard(e.sysid)


def _check_law(ctx: Context, law: LawConfig, vehicles: tuple[Vehicle, ...] | None) -> None:
    leader_line = ctx.line_of("leader.start")
    for b, box in enumerate(law.obstacles):
        path = f"obstacles.boxes[{b}]"
        if _inside(box, law.leader.start):
            ctx.add(
                ctx.line_of(path),
                path,
                f"contains the leader's start {_fmt(law.leader.start)}"
                f" (leader.start, line {leader_line})",
            )
        for i, v in enumerate(vehicles or ()):
            if _inside(box, v.start):
                vpath = f"vehicles[{i}].start"
                ctx.add(ctx.line_of(vpath), vpath, f"{_fmt(v.start)} is inside {path}")
    force = law.leader.force
    if isinstance(force, WaypointForce):
        lam = law.gains.time_scale  # the leader cruises at speed / lambda (leader.py)
        if force.cruise_speed / lam > law.limits.v_max:
            path = "leader.force.speed"
            scaled = f" / gains.time_scale {lam:g}" if lam != 1.0 else ""
            ctx.add(
                ctx.line_of(path),
                path,
                f"expected at most limits.v_max = {law.limits.v_max:g} m/s,"
                f" got {force.cruise_speed:g}{scaled}",
            )
        for w, point in enumerate(force.waypoints):
            for b, box in enumerate(law.obstacles):
                if _inside(box, point):
                    path = f"leader.force.waypoints[{w}]"
                    ctx.add(
                        ctx.line_of(path), path, f"{_fmt(point)} is inside obstacles.boxes[{b}]"
                    )
    _check_fence(ctx, law, vehicles)
    if law.safety.enabled and vehicles is not None:
        for i, v in enumerate(vehicles):
            for j in range(i):
                d = math.dist(v.start, vehicles[j].start)
                if SAME_POINT_M <= d < law.safety.separation:
                    path = f"vehicles[{i}].start"
                    ctx.add(
                        ctx.line_of(path),
                        path,
                        f"{d:g} m from vehicles[{j}], closer than"
                        f" limits.safety.separation = {law.safety.separation:g}",
                    )


def _check_fence(ctx: Context, law: LawConfig, vehicles: tuple[Vehicle, ...] | None) -> None:
    lim = law.limits
    points: list[tuple[str, Vec3]] = [("leader.start", law.leader.start)]
    points += [(f"vehicles[{i}].start", v.start) for i, v in enumerate(vehicles or ())]
    for path, p in points:
        if p[2] < lim.z_floor:
            ctx.add(
                ctx.line_of(path), path, f"z = {p[2]:g} is below limits.z_floor = {lim.z_floor:g}"
            )
        elif lim.geofence_min is not None and lim.geofence_max is not None:
            lo, hi = lim.geofence_min, lim.geofence_max
            if not all(lo[k] <= p[k] <= hi[k] for k in range(3)):
                ctx.add(
                    ctx.line_of(path),
                    path,
                    f"{_fmt(p)} is outside limits.geofence {_fmt(lo)}..{_fmt(hi)}",
                )


def key_line(text: str, path: str) -> int:
    """1-based line of the dotted key ``path`` (e.g. ``gains.time_scale``) in
    the mission ``text``, or of its nearest present ancestor; 1 if none."""
    try:
        node: yaml.Node | None = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return 1
    line = 1
    for part in path.split("."):
        if not isinstance(node, yaml.MappingNode):
            break
        hit = next((kv for kv in node.value if getattr(kv[0], "value", None) == part), None)
        if hit is None:
            break
        line = hit[0].start_mark.line + 1
        node = hit[1]
    return line
