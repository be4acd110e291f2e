"""The mission format, declared once: every section, key, type, range,
default and unit. ``loader`` validates files with it, ``schema`` prints it as
JSON Schema, and ``docs/mission-format.md`` describes it for people.

This module assembles the whole file (``MISSION``) and declares the
``vehicles`` and ``events`` sections; the others are declared beside it:
``mission`` in ``settings_format``, ``emulator`` in ``emulator_format``, the
law's (``gains``, ``leader``, ``obstacles``, ``limits``, ``readings``) in
``law_format``; connection strings are checked in ``addresses``.

Units are SI; positions are in the mission frame (x east, y north, z up) [m].
Defaults of the law's parameters are read from ``gcs_swarm.control.params``
so that a file which leaves a key out gets exactly the dataclass default.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import yaml

from gcs_swarm.control.params import Gains, Leader, Readings
from gcs_swarm.mission.addresses import LINK_WHAT, check_link
from gcs_swarm.mission.bounds import GAIN_MAX
from gcs_swarm.mission.context import Context
from gcs_swarm.mission.declarations import INVALID, REQUIRED, ByKind, Key, ListOf, Obj
from gcs_swarm.mission.emulator_format import EMULATOR
from gcs_swarm.mission.law_format import GAINS, LEADER, LIMITS, OBSTACLES, READINGS
from gcs_swarm.mission.model import (
    Emulator,
    Event,
    LogSettings,
    Mission,
    Vehicle,
)
from gcs_swarm.mission.scalars import (
    Bool,
    Enum,
    NonNeg,
    Num,
    Pos,
    Str,
    Vec3,
)
from gcs_swarm.mission.settings_format import SETTINGS, geo_field

__all__ = ["LAW_SOURCES", "MISSION"]

#: Each axis of a sim vehicle's start velocity [m/s]: a vehicle settling at its start
#: (the replay twin's SITL vehicles moved at up to 0.2 m/s), not one in cruise.
START_SPEED_LIMIT_M_S = 10.0
#: Vehicles' system ids: 255 is the station's own (mavlink-protocol.md "Identity").
_SYSID = Num(lo=1, hi=254, integer=True, note="255 is the ground station")


# ---------------------------------------------------------------- vehicles:
_SIM_ONLY = (
    (
        "origin",
        "only a sim vehicle takes an origin; a real one reports its own (GPS_GLOBAL_ORIGIN)",
    ),
    ("start_velocity", "only a sim vehicle takes a start velocity; a real one flies from its own"),
)
"""A vehicle's keys only the emulator's vehicles take, and why a real one does not."""


def _build_vehicle(v: dict[str, Any], ctx: Context, node: yaml.Node, path: str) -> Any:
    ok = True
    link, autopilot = v["link"], v["autopilot"]
    if autopilot is None:
        autopilot = "sim" if link == "sim" else "ardupilot"
    if link == "sim" and autopilot not in ("sim", "px4"):
        ctx.add(
            ctx.line_of(f"{path}.autopilot"),
            f"{path}.autopilot",
            f'expected sim or px4 for link sim (the bundled emulator), got "{autopilot}"',
        )
        ok = False
    for key, why in _SIM_ONLY:
        if v[key] is not None and link != "sim":
            ctx.add(ctx.line_of(f"{path}.{key}"), f"{path}.{key}", why)
            ok = False
    if not ok:
        return INVALID
    q = v["q"] if v["q"] is not None else ctx.defaults.get("q", Gains().q_default)
    setpoint = v["setpoint"]
    if setpoint is None:  # PX4's velocity loop takes out its drag and bias (docs/setpoints.md)
        setpoint = "velocity+acceleration" if autopilot == "px4" else "acceleration"
    return Vehicle(
        sysid=v["sysid"],
        link=link,
        autopilot=autopilot,
        start=v["start"],
        q=q,
        reserve=v["reserve"],
        origin=v["origin"],
        setpoint=setpoint,
        start_velocity=v["start_velocity"],
        where=path,
    )


VEHICLE = Obj(
    name="vehicle",
    cls=Vehicle,
    build=_build_vehicle,
    extra_fields=("network", "net_index", "where"),
    keys=(
        Key("sysid", _SYSID, REQUIRED, "MAVLink system id (255 is the ground station)"),
        Key(
            "link",
            Str(
                what=LINK_WHAT,
                pattern=r"^(sim|(udpin|udpout|tcp|tcpin):[^:\s]+:[0-9]{1,5})$",
                check=check_link,
            ),
            "sim",
            "connection string, or sim for the bundled emulator",
        ),
        Key(
            "autopilot",
            Enum(choices=("ardupilot", "sim", "px4")),
            None,
            "ardupilot, px4 (OFFBOARD) or sim (the emulator's ArduCopter; px4 on link sim is "
            "the emulator's PX4); default: sim for link sim, else ardupilot",
        ),
        Key(
            "setpoint",
            Enum(choices=("acceleration", "velocity+acceleration")),
            None,
            "acceleration (type_mask 3135) or velocity+acceleration (3079: the velocity the "
            "law's accelerations integrate to, Eq. V1); default: velocity+acceleration for "
            "px4, else acceleration",
        ),
        Key("start", Vec3(), REQUIRED, "start position, mission frame [m]"),
        Key("q", Pos(hi=GAIN_MAX), None, "charge of Eq. 9 [C]; default: gains.q"),
        Key("reserve", Bool(), False, "true: not in the formation until a join event"),
        Key(
            "origin",
            ByKind(
                sequence=Vec3("[east, north, up]"),
                mapping=geo_field(),
                what="[east, north, up] or a mapping {lat, lon, alt}",
            ),
            None,
            "sim only: home (EKF origin), mission frame [m] or geodetic;"
            " default [i * emulator.origin_spread, 0, emulator.ground]",
        ),
        Key(
            "start_velocity",
            Vec3("[east, north, up]", limit=START_SPEED_LIMIT_M_S),
            None,
            "sim only, with emulator.spawn air: the velocity it flies from at its first"
            " acceleration setpoint, mission frame [m/s] (a replay of a vehicle still moving"
            " when its formation started); default: at rest",
        ),
    ),
)


# ---------------------------------------------------------------- networks:
_NETWORK_PATTERN = r"^[A-Za-z][A-Za-z0-9_-]{0,31}$"
_NETWORK_WHAT = "a network name (a letter, then up to 31 letters, digits, _ or -)"


def _build_network(v: dict[str, Any], ctx: Context, node: yaml.Node, path: str) -> Any:
    """A network's vehicles, each told its network; ``path`` is ``networks[j]``."""
    index = int(path[path.rindex("[") + 1 : -1])
    vehicles = tuple(replace(x, network=v["name"], net_index=index) for x in v["vehicles"])
    return (v["name"], vehicles)


NETWORK = Obj(
    name="network",
    build=_build_network,
    what="a mapping with keys name, vehicles",
    keys=(
        Key(
            "name",
            Str(what=_NETWORK_WHAT, pattern=_NETWORK_PATTERN),
            REQUIRED,
            "the network's name (unique; names its .tlog)",
        ),
        Key(
            "vehicles",
            ListOf(item=VEHICLE, min_items=1, what="a list of vehicles (at least one)"),
            REQUIRED,
            "the network's vehicles: system ids 1..254 of their own",
        ),
    ),
)


# ---------------------------------------------------------------- events:
def _build_event(v: dict[str, Any], ctx: Context, node: yaml.Node, path: str) -> Any:
    join, leave = v["join"], v["leave"]
    if (join is None) == (leave is None):
        what = "both" if join is not None else "neither"
        ctx.add(node, path, f'expected exactly one of "join" or "leave", got {what}')
        return INVALID
    if v["t"] > ctx.defaults.get("duration", math.inf):
        ctx.add(
            ctx.line_of(f"{path}.t"),
            f"{path}.t",
            f"expected a time within the mission"
            f" (mission.duration = {ctx.defaults['duration']:g} s), got {v['t']:g}",
        )
        return INVALID
    return Event(
        t=v["t"],
        action="join" if join is not None else "leave",
        sysid=join if join is not None else leave,
        # None: the mission's only network, resolved with the networks (loader)
        network=v["network"],
    )


EVENT = Obj(
    name="event",
    cls=Event,
    build=_build_event,
    extra_fields=("action", "sysid", "network", "net_index"),
    keys=(
        Key("t", NonNeg(), REQUIRED, "time from the formation start [s]"),
        Key(
            "network",
            Str(what=_NETWORK_WHAT, pattern=_NETWORK_PATTERN),
            None,
            "the network of the vehicle (required when the mission has several)",
            target=None,
        ),
        Key(
            "join",
            _SYSID,
            None,
            "system id of a reserve (or departed) vehicle that joins",
            target=None,
        ),
        Key("leave", _SYSID, None, "system id of a vehicle that leaves", target=None),
    ),
)


LOG = Obj(
    name="log",
    cls=LogSettings,
    keys=(Key("dir", Str(), LogSettings().dir, "directory for run artefacts"),),
)

#: The whole file. ``gains`` comes before ``vehicles`` so a vehicle's default
#: charge is known; ``mission`` before ``events`` for the duration.
MISSION = Obj(
    name="top",
    partial=True,
    cls=Mission,
    extra_fields=("source", "law", "text", "vehicles", "networks"),
    what="a mapping of sections (mission, vehicles, gains, ...)",
    keys=(
        Key(
            "mission",
            SETTINGS,
            None,
            "name, duration, rate, origin, end action, start-up",
            target="settings",
        ),
        Key("gains", GAINS, Gains, "gains of Eqs. 1, 7, 9", target=None),
        Key("emulator", EMULATOR, Emulator, "the bundled emulator, for vehicles on link sim"),
        Key(
            "vehicles",
            ListOf(item=VEHICLE, min_items=1, what="a list of vehicles (at least one)"),
            None,
            'the vehicles, all on one network (named "default"); or "networks"',
            target=None,
        ),
        Key(
            "networks",
            ListOf(item=NETWORK, min_items=1, what="a list of networks (at least one)"),
            None,
            "vehicles grouped in named networks, each with its own links and system ids;"
            ' instead of "vehicles"',
            target=None,
        ),
        Key("leader", LEADER, Leader, "the virtual leader (Eq. 13)", target=None),
        Key("obstacles", OBSTACLES, None, "boxes and the avoidance field", target=None),
        Key("events", ListOf(item=EVENT), (), "vehicles joining or leaving"),
        Key(
            "limits",
            LIMITS,
            None,
            "acceleration, speed, altitude and geofence limits; safety filter",
            target=None,
        ),
        Key(
            "readings",
            READINGS,
            Readings,
            "printed-variant switches of formation-law.md",
            target=None,
        ),
        Key("log", LOG, LogSettings, "run artefacts"),
    ),
)

#: Where each field of ``LawConfig`` comes from in the file (kept in step by a test).
LAW_SOURCES = {
    "gains": "gains",
    "leader": "leader",
    "obstacles": "obstacles.boxes",
    "avoidance": "obstacles",
    "readings": "readings",
    "limits": "limits",
    "safety": "limits.safety",
}
