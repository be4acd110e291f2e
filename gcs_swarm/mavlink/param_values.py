"""What the station reads from and sets on a vehicle, per autopilot, as
values: the envelope from the position controller's parameters (Eq. E1),
the GCS-loss failsafe, the fence around the geofence box (Eqs. F1, F2), and
``ParamProfile``, one autopilot's names and rules (``ARDUCOPTER`` here, PX4's
in px4.py). Pure functions and frozen data; ``vehicle_params.py`` does the
reading and writing with them.

Units on the wire are ArduCopter's own (cm/s, cm/s^2, centidegrees, m, s);
the ``Envelope`` is SI. docs/vehicle-safety.md says why each value.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

from gcs_swarm.control.params import Envelope, Vec3
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.codec import STATION_SYSID, MessageSpec

__all__ = [
    "ARDUCOPTER",
    "ARDUCOPTER_DEFAULTS",
    "ENVELOPE_PARAMS",
    "FAILSAFE_PARAMS",
    "FENCE_PARAMS",
    "GRAVITY_MPS2",
    "MEASURED_LAG_S",
    "EndAction",
    "ParamProfile",
    "Setting",
    "envelope_from_params",
    "failsafe_values",
    "fence_values",
]

EndAction = Literal["hold", "land", "rtl"]
Setting = tuple[str, float, str]
"""(parameter name, value in ArduCopter's unit, why: for the log)."""

GRAVITY_MPS2 = 9.80665
MEASURED_LAG_S = 0.2
"""First-order lag of ArduCopter's achieved acceleration on the command [s]
(mavlink-protocol.md: the measured step response)."""

ENVELOPE_PARAMS = (
    "WPNAV_ACCEL",
    "WPNAV_ACCEL_Z",
    "PSC_JERK_XY",
    "PSC_JERK_Z",
    "WPNAV_SPEED",
    "WPNAV_SPEED_UP",
    "WPNAV_SPEED_DN",
    "ANGLE_MAX",
)
"""The position controller's limits read at start-up (ardupilot-facts.md)."""
FAILSAFE_PARAMS = ("SYSID_MYGCS", "FS_GCS_TIMEOUT", "FS_GCS_ENABLE")
FENCE_PARAMS = ("FENCE_TYPE", "FENCE_ALT_MAX", "FENCE_RADIUS", "FENCE_ACTION", "FENCE_ENABLE")

ARDUCOPTER_DEFAULTS: dict[str, float] = {
    "WPNAV_ACCEL": 250.0,
    "WPNAV_ACCEL_Z": 100.0,
    "PSC_JERK_XY": 5.0,
    "PSC_JERK_Z": 5.0,
    "WPNAV_SPEED": 1000.0,
    "WPNAV_SPEED_UP": 250.0,
    "WPNAV_SPEED_DN": 150.0,
    "ANGLE_MAX": 3000.0,
    "SYSID_MYGCS": 255.0,
    "FS_GCS_ENABLE": 0.0,
    "FS_GCS_TIMEOUT": 5.0,
    "FENCE_ENABLE": 0.0,
    "FENCE_TYPE": 7.0,
    "FENCE_ACTION": 1.0,
    "FENCE_ALT_MAX": 100.0,
    "FENCE_RADIUS": 300.0,
    "GUID_TIMEOUT": 3.0,
    "WP_YAW_BEHAVIOR": 2.0,
}
"""ArduCopter 4.5.6's defaults (ardupilot-facts.md), in its units."""

FS_GCS_FOR_END = {"land": 5, "rtl": 1, "hold": 5}
"""FS_GCS_ENABLE per end action: 5 Land, 1 RTL. A hold (BRAKE) end action
still lands: the failsafe is for a lost station, and a vehicle hovering with
nobody to end it must come down (docs/vehicle-safety.md)."""
FENCE_ACTION_FOR_END = {"rtl": 1, "land": 2, "hold": 2}
"""FENCE_ACTION per end action: 1 RTL (or Land), 2 always Land."""
FENCE_TYPE_ALT_MAX = 1
FENCE_TYPE_CIRCLE = 2
FENCE_RADIUS_MIN_M = 30.0
"""The least FENCE_RADIUS ArduCopter documents (range 30..10000 m)."""
FENCE_ALT_MAX_MIN_M = 10.0
"""The least FENCE_ALT_MAX ArduCopter documents (range 10..1000 m)."""


def _positive(values: Mapping[str, float], name: str) -> float | None:
    v = values.get(name)
    return v if v is not None and math.isfinite(v) and v > 0.0 else None


def envelope_from_params(
    values: Mapping[str, float],
    fallback: Envelope | None = None,
    *,
    lag_s: float = MEASURED_LAG_S,
) -> tuple[Envelope, tuple[str, ...]]:
    """The ``Envelope`` [SI] of a vehicle from its parameters [ArduCopter
    units], and the names missing from ``values`` (or not > 0), whose bound
    is then ``fallback``'s (default: unbounded).

    Eq. E1: accel_xy = min(WPNAV_ACCEL / 100, g tan(ANGLE_MAX / 100 deg)),
    the position controller's horizontal limit and the lean angle's
    (ardupilot-facts.md: accel_max = g tan(ANGLE_MAX)); accel_z =
    WPNAV_ACCEL_Z / 100; jerk_xy, jerk_z = PSC_JERK_XY, PSC_JERK_Z; speeds =
    WPNAV_SPEED, WPNAV_SPEED_UP, WPNAV_SPEED_DN / 100; lag_s measured. The
    lag is ``fallback``'s when no parameter was read at all."""
    fb = fallback if fallback is not None else Envelope()
    got = {n: _positive(values, n) for n in ENVELOPE_PARAMS}
    missing = tuple(n for n, v in got.items() if v is None)

    def cm(name: str, default: float) -> float:
        v = got[name]
        return default if v is None else v / 100.0

    def raw(name: str, default: float) -> float:
        v = got[name]
        return default if v is None else v

    wp_accel, angle = got["WPNAV_ACCEL"], got["ANGLE_MAX"]
    accel_xy = fb.accel_xy
    if wp_accel is not None or angle is not None:
        lean = math.inf if angle is None else GRAVITY_MPS2 * math.tan(math.radians(angle / 100.0))
        accel_xy = min(math.inf if wp_accel is None else wp_accel / 100.0, lean)  # Eq. E1
    envelope = Envelope(
        accel_xy=accel_xy,
        accel_z=cm("WPNAV_ACCEL_Z", fb.accel_z),
        jerk_xy=raw("PSC_JERK_XY", fb.jerk_xy),
        jerk_z=raw("PSC_JERK_Z", fb.jerk_z),
        speed_xy=cm("WPNAV_SPEED", fb.speed_xy),
        speed_up=cm("WPNAV_SPEED_UP", fb.speed_up),
        speed_down=cm("WPNAV_SPEED_DN", fb.speed_down),
        lag_s=fb.lag_s if len(missing) == len(ENVELOPE_PARAMS) else lag_s,
    )
    return envelope, missing


def failsafe_values(
    end: EndAction, timeout_s: float, station_sysid: int = STATION_SYSID
) -> tuple[Setting, ...]:
    """The GCS-loss failsafe for a mission ending with ``end``, in the order
    they are set: who the station is, how long its silence may last, then
    the action (switched on last, once the other two are right)."""
    fs = FS_GCS_FOR_END[end]
    action = "Land" if fs == 5 else "RTL"
    return (
        ("SYSID_MYGCS", float(station_sysid), "the station's system id feeds the failsafe"),
        ("FS_GCS_TIMEOUT", float(timeout_s), "s without the station's HEARTBEAT"),
        ("FS_GCS_ENABLE", float(fs), f"{action} after {timeout_s:g} s without the station"),
    )


def _ceil_dm(x: float) -> float:
    """Up to the next 0.1 m: a backstop rounded outwards, never inwards."""
    return math.ceil(x * 10.0 - 1e-9) / 10.0


def fence_values(
    geofence_min: Vec3,
    geofence_max: Vec3,
    home_m: Sequence[float],
    end: EndAction,
    margin_m: float,
) -> tuple[tuple[Setting, ...], tuple[str, ...]]:
    """The vehicle's own fence around the mission's geofence box (mission
    frame [m]) for a vehicle whose home is ``home_m`` (mission frame [m]),
    and notes on values raised to ArduCopter's least.

    The fence is a backstop outside the station's own: a circle centred on
    the home and a ceiling, both ``margin_m`` beyond the box.
    Eq. F1: FENCE_ALT_MAX = max z + margin - home z (m above home).
    Eq. F2: FENCE_RADIUS = max over the box's corners c of |c_xy - home_xy|
    + margin (the circle about home that holds the whole box).
    Both rounded up to 0.1 m."""
    hx, hy, hz = float(home_m[0]), float(home_m[1]), float(home_m[2])
    notes: list[str] = []
    alt_max = _ceil_dm(geofence_max[2] + margin_m - hz)  # Eq. F1
    corners = [(x, y) for x in (geofence_min[0], geofence_max[0])
               for y in (geofence_min[1], geofence_max[1])]  # fmt: skip
    radius = _ceil_dm(max(math.hypot(x - hx, y - hy) for x, y in corners) + margin_m)  # Eq. F2
    if alt_max < FENCE_ALT_MAX_MIN_M:
        notes.append(f"FENCE_ALT_MAX {alt_max:g} m raised to ArduCopter's least "
                     f"{FENCE_ALT_MAX_MIN_M:g} m")  # fmt: skip
        alt_max = FENCE_ALT_MAX_MIN_M
    if radius < FENCE_RADIUS_MIN_M:
        notes.append(f"FENCE_RADIUS {radius:g} m raised to ArduCopter's least "
                     f"{FENCE_RADIUS_MIN_M:g} m")  # fmt: skip
        radius = FENCE_RADIUS_MIN_M
    act = FENCE_ACTION_FOR_END[end]
    settings = (
        ("FENCE_TYPE", float(FENCE_TYPE_ALT_MAX | FENCE_TYPE_CIRCLE), "max altitude and circle"),
        ("FENCE_ALT_MAX", alt_max, f"m above home: geofence top + {margin_m:g} m"),
        ("FENCE_RADIUS", radius, f"m about home: holds the geofence box + {margin_m:g} m"),
        ("FENCE_ACTION", float(act), "RTL or Land on a breach" if act == 1 else "Land on a breach"),
        ("FENCE_ENABLE", 1.0, "the vehicle's own fence on"),
    )
    return settings, tuple(notes)


EnvelopeFn = Callable[
    [Mapping[str, float], Envelope | None, float], tuple[Envelope, tuple[str, ...]]
]
FailsafeFn = Callable[[EndAction, float, int], tuple[Setting, ...]]
ParamSetFn = Callable[[int, int, str, float], MessageSpec]


@dataclass(frozen=True)
class ParamProfile:
    """One autopilot's parameters as ``VehicleParams`` reads and sets them:
    the envelope's names and how they become an ``Envelope`` (Eq. E1 for
    ArduCopter), the failsafe's names and values, the fence's (empty: no
    fence), how a PARAM_SET is built, and the end modes after which the
    vehicle comes down on its own (its failsafe and fence may be restored)."""

    autopilot: str
    envelope_params: tuple[str, ...]
    envelope: EnvelopeFn
    failsafe_params: tuple[str, ...]
    failsafe: FailsafeFn
    fence_params: tuple[str, ...]
    param_set: ParamSetFn
    ends_on_own: frozenset[int]

    @property
    def safety_params(self) -> frozenset[str]:
        return frozenset(self.failsafe_params + self.fence_params)


def _envelope(
    values: Mapping[str, float], fallback: Envelope | None, lag_s: float
) -> tuple[Envelope, tuple[str, ...]]:
    return envelope_from_params(values, fallback, lag_s=lag_s)


ARDUCOPTER = ParamProfile(
    autopilot="ArduCopter",
    envelope_params=ENVELOPE_PARAMS,
    envelope=_envelope,
    failsafe_params=FAILSAFE_PARAMS,
    failsafe=lambda end, timeout, sysid: failsafe_values(end, timeout, sysid),
    fence_params=FENCE_PARAMS,
    param_set=b.param_set,
    ends_on_own=frozenset({b.COPTER_MODES["LAND"], b.COPTER_MODES["RTL"]}),
)
"""ArduCopter 4.5's parameters (ardupilot-facts.md)."""
