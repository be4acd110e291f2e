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
from gcs_swarm.mission.bounds import leader_path_problem
from gcs_swarm.mission.context import Context
from gcs_swarm.mission.model import DEFAULT_NETWORK, Emulator, Event, GeoPoint, Settings, Vehicle
from gcs_swarm.mission.source import compose

__all__ = ["earlier_within", "key_line", "run_checks"]

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
        if settings is not None:
            found = leader_path_problem(law.leader, law.gains, settings.duration)
            if found is not None:
                ctx.add(ctx.line_of(found[0]), found[0], found[1])
        if settings is not None and settings.failsafe.fence and law.limits.geofence_min is None:
            key = "mission.failsafe.fence"
            ctx.add(ctx.line_of(key), key, "expected limits.geofence for the vehicles' own fence")


def _check_vehicles(ctx: Context, vehicles: tuple[Vehicle, ...]) -> None:
    first_of: dict[int, int] = {}
    for i, v in enumerate(vehicles):
        path = f"{vehicles[i].where}.sysid"
        if v.key in first_of:  # a system id is unique within its network
            ctx.add(
                ctx.line_of(path),
                path,
                f"duplicate system id {v.sysid} (also {vehicles[first_of[v.key]].where})",
            )
        else:
            first_of[v.key] = i
    _check_network_links(ctx, vehicles)
    starts = [v.start for v in vehicles]
    for i, hit in enumerate(earlier_within(starts, SAME_POINT_M)):
        if hit is not None:
            path = f"{vehicles[i].where}.start"
            ctx.add(
                ctx.line_of(path),
                path,
                f"same start as {vehicles[hit[0]].where} {_fmt(vehicles[i].start)};"
                " vehicles must start apart",
            )
    if all(v.reserve for v in vehicles):
        ctx.add(
            ctx.line_of("vehicles"),
            "vehicles",
            "every vehicle is a reserve; at least one must fly from the start",
        )


def _check_network_links(ctx: Context, vehicles: tuple[Vehicle, ...]) -> None:
    """A link (connection string) belongs to one network: each network has its
    own system-id space, so one link cannot carry two (the ids would clash)."""
    first: dict[str, Vehicle] = {}
    for v in vehicles:
        if v.is_sim:
            continue  # the bundled emulator serves each network on its own endpoints
        other = first.setdefault(v.link, v)
        if other.net_index != v.net_index:
            path = f"{v.where}.link"
            ctx.add(ctx.line_of(path), path,
                    f"{v.link} is network {other.network}'s link ({other.where}); a link"
                    " carries one network")  # fmt: skip


def _check_ground(
    ctx: Context, vehicles: tuple[Vehicle, ...], emulator: Emulator, settings: Settings | None
) -> None:
    """A sim vehicle must start above its own home (the emulator's ground),
    only one spawned in the air takes a start velocity, and its home must be
    placeable: with ``origin: first-vehicle`` and a real first vehicle the
    origin is known only in flight, too late for the emulator, which starts
    first."""
    origin = settings.origin if settings is not None else None
    if origin == "first-vehicle" and not vehicles[0].is_sim and any(v.is_sim for v in vehicles):
        key = "mission.origin"
        ctx.add(
            ctx.line_of(key),
            key,
            "sim vehicles with a real first vehicle need a geodetic origin {lat, lon, alt}:"
            " the first vehicle's origin is known only once it reports it",
        )
    for i, v in enumerate(vehicles):
        if not v.is_sim:
            continue
        if v.start_velocity is not None and (emulator.spawn != "air" or v.reserve):
            path = f"{v.where}.start_velocity"
            ctx.add(ctx.line_of(path), path,
                    "a start velocity needs emulator.spawn: air and a vehicle flying from"
                    " the start (one on the ground or in reserve starts at rest)")  # fmt: skip
        if isinstance(v.origin, GeoPoint):
            if not isinstance(origin, GeoPoint):
                continue
            ground = v.origin.alt - origin.alt
            where = "its origin"
        elif v.origin is not None:
            ground = v.origin[2]
            where = f"{vehicles[i].where}.origin"
        else:
            ground = emulator.ground
            where = "emulator.ground"
        if v.start[2] <= ground:
            path = f"{vehicles[i].where}.start"
            ctx.add(
                ctx.line_of(path),
                path,
                f"z = {v.start[2]:g} is not above this sim vehicle's ground"
                f" (z = {ground:g}, {where})",
            )


def _check_ports(ctx: Context, vehicles: tuple[Vehicle, ...], emulator: Emulator) -> None:
    """The k-th sim vehicle listens on base_port + 10 k (every one on
    base_port when shared): the last must be a port, and none may be the port
    a ``udpin`` vehicle listens on (both would bind it)."""
    n_sim = sum(v.is_sim for v in vehicles)
    if not emulator.base_port or not n_sim:
        return
    last = emulator.base_port + 10 * (n_sim - 1)
    if not emulator.shared and last > 65535:
        path = "emulator.base_port"
        ctx.add(
            ctx.line_of(path),
            path,
            f"{n_sim} sim vehicles need ports up to {emulator.base_port} + 10 x {n_sim - 1}"
            f" = {last}, over 65535",
        )
    # Shared: one endpoint per network with sim vehicles, base_port + 10 j.
    n_nets = len({v.net_index for v in vehicles if v.is_sim})
    ports = (
        set(range(emulator.base_port, emulator.base_port + 10 * n_nets, 10))
        if emulator.shared
        else set(range(emulator.base_port, last + 1, 10))
    )
    for i, v in enumerate(vehicles):
        scheme, _, rest = v.link.partition(":")
        port = int(rest.rpartition(":")[2]) if scheme == "udpin" else None
        if port in ports:
            path = f"{vehicles[i].where}.link"
            ctx.add(
                ctx.line_of(path),
                path,
                f"port {port} is also a sim vehicle's (emulator.base_port = {emulator.base_port},"
                f" line {ctx.line_of('emulator.base_port')}): both would bind it",
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
            path = f"{vehicles[idx[0]].where}.link"
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
                path = f"{vehicles[i].where}.start"
                ctx.add(
                    ctx.line_of(path),
                    path,
                    f"z = {v.start[2]:g} is not above the first vehicle's home"
                    " (z = 0 with mission.origin first-vehicle)",
                )


def _check_events(ctx: Context, vehicles: tuple[Vehicle, ...], events: tuple[Event, ...]) -> None:
    """Replay the events in time order (file order for ties): a join needs a
    vehicle out of the formation, a leave one in it."""
    by_id = {v.key: v for v in vehicles}
    active = {v.key for v in vehicles if not v.reserve}
    order = sorted(range(len(events)), key=lambda k: events[k].t)
    for k in order:
        e = events[k]
        path = f"events[{k}].{e.action}"
        vehicle = by_id.get(e.key)
        if vehicle is None:
            where = "" if e.network == DEFAULT_NETWORK else f" in network {e.network}"
            ctx.add(ctx.line_of(path), path, f"no vehicle has system id {e.sysid}{where}")
        elif e.action == "join":
            if e.key in active:
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
            active.add(e.key)
        else:
            if e.key not in active:
                ctx.add(
                    ctx.line_of(path),
                    path,
                    f"vehicle {e.sysid} is not in the formation at t = {e.t:g} s",
                )
            active.discard(e.key)


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
        for v in vehicles or ():
            if _inside(box, v.start):
                vpath = f"{v.where}.start"
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
    if law.safety.enabled and vehicles is not None and law.safety.separation > SAME_POINT_M:
        starts = [v.start for v in vehicles]
        same = earlier_within(starts, SAME_POINT_M)
        for i, hit in enumerate(earlier_within(starts, law.safety.separation)):
            if hit is not None and same[i] is None:  # a shared start is reported already
                path = f"{vehicles[i].where}.start"
                ctx.add(
                    ctx.line_of(path),
                    path,
                    f"{hit[1]:g} m from {vehicles[hit[0]].where}, closer than"
                    f" limits.safety.separation = {law.safety.separation:g}",
                )


def earlier_within(points: Sequence[Vec3], radius: float) -> list[tuple[int, float] | None]:
    """For each point i, ``(j, distance)`` of one earlier point j < i closer
    than ``radius`` [m] (the lowest j in i's grid cell, else the first found
    in the cells around), or None. O(N): a hash grid of cells of side
    ``radius / 2``, whose diagonal (0.87 radius) is under ``radius``, so a
    point with an earlier one in its own cell is answered at once, and only
    the first point of a cell searches the 5 x 5 x 5 cells around it (each
    point is then looked at by at most 124 such searches)."""
    side = radius / 2.0
    cells: dict[tuple[int, int, int], list[int]] = {}
    out: list[tuple[int, float] | None] = []
    for i, p in enumerate(points):
        key = (math.floor(p[0] / side), math.floor(p[1] / side), math.floor(p[2] / side))
        own = cells.setdefault(key, [])
        hit: tuple[int, float] | None = None
        if own:
            hit = (own[0], math.dist(p, points[own[0]]))
        else:
            hit = _search_around(points, cells, key, p, radius)
        own.append(i)
        out.append(hit)
    return out


def _search_around(
    points: Sequence[Vec3],
    cells: dict[tuple[int, int, int], list[int]],
    key: tuple[int, int, int],
    p: Vec3,
    radius: float,
) -> tuple[int, float] | None:
    best: tuple[int, float] | None = None
    kx, ky, kz = key
    for dx in range(-2, 3):
        for dy in range(-2, 3):
            for dz in range(-2, 3):
                for j in cells.get((kx + dx, ky + dy, kz + dz), ()):
                    d = math.dist(p, points[j])
                    if d < radius and (best is None or j < best[0]):
                        best = (j, d)
                        break  # the lowest index of this cell comes first
    return best


def _check_fence(ctx: Context, law: LawConfig, vehicles: tuple[Vehicle, ...] | None) -> None:
    lim = law.limits
    points: list[tuple[str, Vec3]] = [("leader.start", law.leader.start)]
    points += [(f"{v.where}.start", v.start) for v in vehicles or ()]
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
        node = compose(text)
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
