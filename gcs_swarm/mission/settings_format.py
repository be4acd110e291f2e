"""The ``mission:`` section of the mission format (name, duration, rate,
origin, end action, start-up, signing, the vehicles' own failsafe, the
velocity bias) and the geodetic point both it and ``vehicles[].origin`` take.
Declared with ``declarations`` and ``scalars``; assembled into the whole file
by ``format``.
"""

from __future__ import annotations

from typing import Any

import yaml

from gcs_swarm.mission.bounds import DURATION_MAX_S
from gcs_swarm.mission.context import Context
from gcs_swarm.mission.declarations import INVALID, REQUIRED, ByKind, Key, Obj
from gcs_swarm.mission.model import (
    Failsafe,
    GeoPoint,
    Settings,
    Signing,
    Startup,
    VelocityBias,
)
from gcs_swarm.mission.scalars import (
    Bool,
    Const,
    Enum,
    Int,
    Num,
    Pos,
    Str,
)

__all__ = ["FAILSAFE", "SETTINGS", "SIGNING", "geo_field"]

_ST = Startup()
_FS = Failsafe()
_VB = VelocityBias()
_SET = Settings(name="")


def geo_field() -> Obj:
    """A geodetic point {lat, lon, alt} (a new declaration per use)."""
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
                mapping=geo_field(),
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
            "step",
            Enum(choices=("swarm", "network")),
            _SET.step,
            "one control step once every vehicle's report is in (swarm), or one "
            "per network once its vehicles' are (network: lower latency on many networks)",
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
                    Key(
                        "handshakes_per_network",
                        Num(lo=1, hi=254, integer=True, nullable=True),
                        _ST.handshakes_per_network,
                        "at most this many vehicles of one network configure at once "
                        "(streams, parameters); the others wait in the order heard",
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
