"""The mission format, declared once: every section, key, type, range,
default and unit. ``loader`` validates files with it, ``schema`` prints it as
JSON Schema, and ``docs/mission-format.md`` describes it for people.

Units are SI; positions are in the mission frame (x east, y north, z up) [m].
Defaults of the law's parameters are read from ``gcs_swarm.control.params``
so that a file which leaves a key out gets exactly the dataclass default.
"""

from __future__ import annotations

import ipaddress
import math
import re
from typing import Any

import yaml

from gcs_swarm.control.params import Gains, Leader, Readings
from gcs_swarm.mission.bounds import (
    DURATION_MAX_S,
    GAIN_MAX,
    POSITION_LIMIT_M,
    SPEED_LIMIT_MPS,
)
from gcs_swarm.mission.context import Context, did_you_mean
from gcs_swarm.mission.fields import (
    INVALID,
    REQUIRED,
    Bool,
    ByKind,
    Const,
    Enum,
    Int,
    Key,
    ListOf,
    NonNeg,
    Num,
    Obj,
    Pos,
    Str,
    Vec3,
)
from gcs_swarm.mission.law_format import GAINS, LEADER, LIMITS, OBSTACLES, READINGS
from gcs_swarm.mission.model import (
    Emulator,
    Event,
    Failsafe,
    GeoPoint,
    Impairments,
    LogSettings,
    Mission,
    Settings,
    Signing,
    Startup,
    Vehicle,
    VelocityBias,
)

__all__ = ["LAW_SOURCES", "LINK_SCHEMES", "MISSION", "check_host", "check_link"]

_EMU = Emulator()
_IMP = Impairments()
_ST = Startup()
_FS = Failsafe()
_VB = VelocityBias()
_SET = Settings(name="")

LINK_SCHEMES = ("udpin", "udpout", "tcp", "tcpin")
#: Vehicles' system ids: 255 is the station's own (mavlink-protocol.md "Identity").
_SYSID = Num(lo=1, hi=254, integer=True, note="255 is the ground station")
_LINK_RE = re.compile(r"(udpin|udpout|tcp|tcpin):([^:\s]+):(\d{1,5})")
_LINK_WHAT = (
    "a connection string udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT or sim"
)


_HOST_LABEL_RE = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)")


def check_host(host: str) -> str | None:
    """None if ``host`` is an IP address or a well-formed host name (RFC 1123),
    else the error message. Syntax only, no name lookup (check needs no
    network): ``999.1.1.1`` is refused, ``localhost`` passes."""
    if re.fullmatch(r"[0-9.]+", host):
        try:
            ipaddress.IPv4Address(host)
        except ValueError:
            return f'"{host}" is not an IPv4 address (four numbers 0..255)'
        return None
    if ":" in host:
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            return f'"{host}" is not an IPv6 address'
        return None
    labels = host.removesuffix(".").split(".")
    if len(host) > 253 or not all(_HOST_LABEL_RE.fullmatch(lab) for lab in labels):
        return f'"{host}" is not an IP address or a host name'
    return None


def check_link(text: str) -> str | None:
    """None if ``text`` is a connection string the station understands
    (pymavlink's spelling), else the error message."""
    if text == "sim":
        return None
    m = _LINK_RE.fullmatch(text)
    if m is None:
        scheme = text.split(":", 1)[0]
        hint = did_you_mean(scheme, (*LINK_SCHEMES, "sim"))
        if scheme == "udp":
            hint = ' (pymavlink\'s "udp:" listens: write "udpin:")'
        return f'expected {_LINK_WHAT}, got "{text}"{hint}'
    port = int(m[3])
    if not 1 <= port <= 65535:
        return f'expected a port 1..65535 in the connection string, got "{text}"'
    bad_host = check_host(m[2])
    if bad_host is not None:
        return f"{bad_host} in the connection string"
    return None


def _geo() -> Obj:
    return Obj(
        name="geo",
        cls=GeoPoint,
        what="a mapping {lat, lon, alt}",
        keys=(
            Key("lat", Num(lo=-90.0, hi=90.0), REQUIRED, "latitude [deg], WGS84"),
            Key("lon", Num(lo=-180.0, hi=180.0), REQUIRED, "longitude [deg], WGS84"),
            Key("alt", Num(lo=-1000.0, hi=10000.0), REQUIRED, "altitude [m] above mean sea level"),
        ),
    )


# ---------------------------------------------------------------- mission:
def _build_settings(v: dict[str, Any], ctx: Context, node: yaml.Node, path: str) -> Any:
    rate, startup = v["rate"], v["startup"]
    ok = True
    min_rate = 2.0 / startup.guid_timeout
    if rate < min_rate:
        ctx.add(
            ctx.line_of("mission.rate"),
            "mission.rate",
            f"expected at least 2 setpoints per GUID_TIMEOUT (mission.startup.guid_timeout"
            f" = {startup.guid_timeout:g} s), i.e. >= {min_rate:g} Hz, got {rate:g}",
        )
        ok = False
    if v["stale_timeout"] < 3.0 / rate:
        ctx.add(
            ctx.line_of("mission.stale_timeout"),
            "mission.stale_timeout",
            f"expected at least 3 telemetry periods at {rate:g} Hz (>= {3.0 / rate:g} s),"
            f" got {v['stale_timeout']:g}",
        )
        ok = False
    ctx.defaults["rate"] = rate
    ctx.defaults["duration"] = v["duration"]
    if not ok:
        return INVALID
    return Settings(**v)


def _build_signing(v: dict[str, Any], ctx: Context, node: yaml.Node, path: str) -> Any:
    if (v["key_file"] is None) == (v["key_env"] is None):
        ctx.add(node, path, "expected exactly one of key_file or key_env")
        return INVALID
    return Signing(**v)


SIGNING = Obj(
    name="signing",
    cls=Signing,
    build=_build_signing,
    keys=(
        Key(
            "key_file",
            Str(),
            None,
            "file holding the 32-byte key (raw, or 64 hex digits), relative to the mission",
        ),
        Key(
            "key_env",
            Str(
                what="an environment variable name (letters, digits, _; not a digit first)",
                pattern=r"[A-Za-z_][A-Za-z0-9_]*",
            ),
            None,
            "environment variable holding the key as 64 hex digits",
        ),
        Key(
            "allow_rebind",
            Bool(),
            False,
            "let a well-signed new address take over a vehicle silent for 5 s "
            "(default: a system id stays bound to its first address for the run)",
        ),
    ),
)


FAILSAFE = Obj(
    name="failsafe",
    cls=Failsafe,
    keys=(
        Key(
            "gcs",
            Bool(nullable=True),
            _FS.gcs,
            "set FS_GCS_ENABLE (from mission.end), FS_GCS_TIMEOUT, SYSID_MYGCS; "
            "null: ardupilot vehicles only",
        ),
        Key(
            "timeout",
            Num(lo=2.0, hi=120.0),
            _FS.timeout,
            "FS_GCS_TIMEOUT: the vehicle's failsafe after this long without the station [s]",
        ),
        Key(
            "fence",
            Bool(nullable=True),
            _FS.fence,
            "set the vehicle's fence around limits.geofence; null: ardupilot vehicles, "
            "where a geofence is given",
        ),
        Key(
            "fence_margin",
            Num(lo=0.0, hi=1000.0),
            _FS.fence_margin,
            "the vehicle's fence lies this far beyond limits.geofence [m]",
        ),
        Key("restore", Bool(), _FS.restore, "put the old values back when each vehicle ends"),
    ),
)


SETTINGS = Obj(
    name="mission",
    cls=Settings,
    build=_build_settings,
    keys=(
        Key("name", Str(), None, "a name for logs and the status line; default: the file name"),
        Key("duration", Pos(hi=DURATION_MAX_S), _SET.duration, "length of the formation phase [s]"),
        Key("rate", Num(lo=1.0, hi=100.0), _SET.rate, "control and telemetry rate [Hz]"),
        Key(
            "origin",
            ByKind(
                scalar=Const(value="first-vehicle"),
                mapping=_geo(),
                what='"first-vehicle" or a mapping {lat, lon, alt}',
            ),
            _SET.origin,
            "mission-frame origin {lat, lon, alt}, or first-vehicle (that vehicle's EKF origin)",
        ),
        Key(
            "end",
            Enum(choices=("hold", "land", "rtl")),
            _SET.end,
            "what every vehicle does at the end",
        ),
        Key(
            "stale_timeout",
            Pos(),
            _SET.stale_timeout,
            "a vehicle silent this long leaves the formation [s]",
        ),
        Key(
            "link_budget",
            Pos(),
            _SET.link_budget,
            "most setpoints per second one link carries (vehicles on it x rate)",
        ),
        Key(
            "delay_compensation",
            Bool(),
            _SET.delay_compensation,
            "predict each state to when its setpoint lands (TIMESYNC round trips); "
            "real-time links only",
        ),
        Key(
            "startup",
            Obj(
                name="startup",
                cls=Startup,
                keys=(
                    Key(
                        "takeoff_alt",
                        Num(lo=0.5, hi=500.0),
                        _ST.takeoff_alt,
                        "take-off height above each vehicle's home [m]",
                    ),
                    Key(
                        "ready_timeout",
                        Pos(),
                        _ST.ready_timeout,
                        "every vehicle armed, airborne and at its start within [s]",
                    ),
                    Key(
                        "guid_timeout",
                        Num(lo=0.1, hi=5.0),
                        _ST.guid_timeout,
                        "GUID_TIMEOUT set on ArduPilot vehicles [s]",
                    ),
                    Key(
                        "start_tolerance",
                        Num(lo=0.01, hi=100.0),
                        _ST.start_tolerance,
                        "a vehicle is at its start within this distance of it [m]",
                    ),
                    Key(
                        "start_speed_tolerance",
                        Num(lo=0.01, hi=100.0),
                        _ST.start_speed_tolerance,
                        "... and below this speed [m/s]",
                    ),
                    Key(
                        "read_envelope",
                        Bool(nullable=True),
                        _ST.read_envelope,
                        "read each vehicle's WPNAV_*, PSC_JERK_*, ANGLE_MAX at start-up; "
                        "null: ardupilot vehicles only",
                    ),
                    Key(
                        "command_attempts",
                        Int(1, 100),
                        _ST.command_attempts,
                        "each command sent at most this many times, 1 s apart",
                    ),
                ),
            ),
            Startup,
            "start-up sequence settings",
        ),
        Key(
            "signing",
            SIGNING,
            None,
            "MAVLink 2 message signing, both ways: where the key is (never the key itself)",
        ),
        Key("failsafe", FAILSAFE, Failsafe, "what the station sets on each vehicle itself"),
        Key(
            "velocity_bias",
            Obj(
                name="velocity_bias",
                cls=VelocityBias,
                keys=(
                    Key(
                        "correct",
                        Bool(),
                        _VB.correct,
                        "take the estimated bias out of the velocity the law damps (Eq. 1)",
                    ),
                    Key(
                        "window",
                        Num(lo=1.0, hi=600.0),
                        _VB.window,
                        "seconds of each vehicle's telemetry per estimate [s]",
                    ),
                    Key(
                        "max",
                        Num(lo=0.0, hi=5.0),
                        _VB.max,
                        "largest bias applied; a longer estimate is held here and reported [m/s]",
                    ),
                ),
            ),
            VelocityBias,
            "a constant bias in the reported velocity, estimated from the positions "
            "(docs/velocity-bias.md)",
        ),
    ),
)


# ---------------------------------------------------------------- vehicles:
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
    if v["origin"] is not None and link != "sim":
        ctx.add(
            ctx.line_of(f"{path}.origin"),
            f"{path}.origin",
            "only a sim vehicle takes an origin; a real one reports its own (GPS_GLOBAL_ORIGIN)",
        )
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
    )


VEHICLE = Obj(
    name="vehicle",
    cls=Vehicle,
    build=_build_vehicle,
    keys=(
        Key("sysid", _SYSID, REQUIRED, "MAVLink system id (255 is the ground station)"),
        Key(
            "link",
            Str(
                what=_LINK_WHAT,
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
                mapping=_geo(),
                what="[east, north, up] or a mapping {lat, lon, alt}",
            ),
            None,
            "sim only: home (EKF origin), mission frame [m] or geodetic;"
            " default [i * emulator.origin_spread, 0, emulator.ground]",
        ),
    ),
)


# ---------------------------------------------------------------- emulator:
def _build_emulator(v: dict[str, Any], ctx: Context, node: yaml.Node, path: str) -> Any:
    ok = True
    if v["mode"] == "lockstep" and v["speedup"] != 1.0:
        ctx.add(
            ctx.line_of("emulator.speedup"),
            "emulator.speedup",
            "speedup applies to mode realtime; lockstep runs as fast as the station answers",
        )
        ok = False
    if v["dynamics"] == "ideal" and v["lag"] not in (None, 0.0):
        ctx.add(
            ctx.line_of("emulator.lag"),
            "emulator.lag",
            "ideal dynamics have no lag; use dynamics ardupilot-like",
        )
        ok = False
    return Emulator(**v) if ok else INVALID


EMULATOR = Obj(
    name="emulator",
    cls=Emulator,
    build=_build_emulator,
    keys=(
        Key(
            "mode",
            Enum(choices=("lockstep", "realtime")),
            _EMU.mode,
            "lockstep: one step per answered telemetry; realtime: wall clock x speedup",
        ),
        Key(
            "speedup",
            Num(lo=0.0, hi=1000.0, lo_open=True),
            _EMU.speedup,
            "realtime only: simulated seconds per wall-clock second",
        ),
        Key(
            "dynamics",
            Enum(choices=("ideal", "ardupilot-like")),
            _EMU.dynamics,
            "ideal: exact double integrator; ardupilot-like: lagged",
        ),
        Key(
            "lag",
            Num(lo=0.0, hi=5.0, nullable=True),
            _EMU.lag,
            "first-order acceleration lag [s]; default 0.1 for ardupilot-like",
        ),
        Key("accel_max", Pos(nullable=True), None, "clamp on |acceleration| [m/s^2]; null: 5"),
        Key(
            "ekf_ready_delay", NonNeg(3600.0), _EMU.ekf_ready_delay, "arming refused this long [s]"
        ),
        Key("noise_pos", NonNeg(1000.0), _EMU.noise_pos, "std of position noise on telemetry [m]"),
        Key(
            "noise_vel",
            NonNeg(SPEED_LIMIT_MPS),
            _EMU.noise_vel,
            "std of velocity noise on telemetry [m/s]",
        ),
        Key(
            "velocity_bias_ned",
            Vec3("[north, east, down] m/s", limit=10.0),
            None,
            "constant added to every reported velocity; absent: ArduCopter SITL's figure "
            "for ardupilot-like, none for ideal",
        ),
        Key(
            "ground",
            Num(lo=-POSITION_LIMIT_M, hi=POSITION_LIMIT_M),
            _EMU.ground,
            "mission-frame z of the sim vehicles' homes [m]",
        ),
        Key(
            "origin_spread", NonNeg(1000.0), _EMU.origin_spread, "east spacing of default homes [m]"
        ),
        Key(
            "spawn",
            Enum(choices=("ground", "air")),
            _EMU.spawn,
            "ground: landed at home, full start-up; air: hovering at the start, armed, GUIDED",
        ),
        Key(
            "host",
            Str(what="an IP address or a host name", check=check_host),
            _EMU.host,
            "address the emulator's endpoints bind to",
        ),
        Key("base_port", Int(0, 65535), _EMU.base_port, "k-th sim vehicle on base_port + 10 k"),
        Key("shared", Bool(), _EMU.shared, "all sim vehicles on one endpoint (by system id)"),
        Key(
            "impairments",
            Obj(
                name="impairments",
                cls=Impairments,
                keys=(
                    Key(
                        "loss",
                        Num(lo=0.0, hi=1.0, hi_open=True),
                        _IMP.loss,
                        "probability a packet is lost",
                    ),
                    Key("delay", Num(lo=0.0, hi=10.0), _IMP.delay, "added one-way delay [s]"),
                    Key(
                        "jitter", Num(lo=0.0, hi=10.0), _IMP.jitter, "random extra delay, up to [s]"
                    ),
                    Key(
                        "duplicate",
                        Num(lo=0.0, hi=1.0),
                        _IMP.duplicate,
                        "probability a packet is sent twice",
                    ),
                    Key(
                        "seed",
                        Int(0, 2**63 - 1),
                        _IMP.seed,
                        "seed of the impairment random numbers",
                    ),
                ),
            ),
            Impairments,
            "seeded link impairments, both directions",
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
    )


EVENT = Obj(
    name="event",
    cls=Event,
    build=_build_event,
    extra_fields=("action", "sysid"),
    keys=(
        Key("t", NonNeg(), REQUIRED, "time from the formation start [s]"),
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
    extra_fields=("source", "law", "text"),
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
            REQUIRED,
            "the vehicles",
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
