"""Keep-out boxes: where a vehicle out of the formation may be (Eq. K1).

A vehicle whose link goes quiet leaves the formation (``Phase.LOST``), but it
is still in the air: it coasts on its last acceleration setpoint until the
autopilot's own timeout (ArduCopter GUID_TIMEOUT, PX4 COM_OF_LOSS_T), brakes,
and then holds or, with its GCS failsafe, lands straight down. The members'
safety filter keeps the vehicle separation from the box this module gives,
until the vehicle is heard again (docs/vehicle-safety.md, "One vehicle's
link lost"). Pure, no I/O.

Eq. K1 (the column). With p, v the vehicle's last reported position [m] and
velocity [m/s] (mission frame, z up), a its last commanded acceleration
[m/s^2], T the coast [s] and b the braking acceleration [m/s^2]:

    r = r_0 + |v| T + |a| T^2 / 2 + (|v| + |a| T)^2 / (2 b)            (K1a)

the farthest it can get in any direction before it stops (coasting at most
|a| for T, then braking at b), plus r_0, what its hold or LAND may wander
from the point where it stopped. The column is the axis-aligned box

    x in [p_x - r, p_x + r],  y in [p_y - r, p_y + r],
    z in [p_z - Z, p_z + r]                                            (K1b)

from ``REACH_M`` = Z below it (the ground is always above that: nothing is
assumed of where the ground is) up to r above where it was; with ``climbs``
(an RTL failsafe, which climbs to RTL_ALT first) its top is Z above it too.
A vehicle the station itself flies to a point (readied, rejoining, a
reserve holding at its start) does not come down: ``down=False`` gives the
cube z in [p_z - r, p_z + r] instead (Eq. K1c). b is the braking
acceleration the vehicle is known to have, never more than
``BRAKE_CAP_MPS2``: a smaller b only widens the column.
"""

from __future__ import annotations

import math

import numpy as np

from gcs_swarm.control.limits import FloatArray
from gcs_swarm.control.params import Box

__all__ = ["BRAKE_CAP_MPS2", "HOLD_DRIFT_M", "REACH_M", "lost_column"]

HOLD_DRIFT_M = 0.5
"""r_0 of Eq. K1a [m]: what a braked vehicle's position hold or LAND may
wander horizontally from where it stopped (GPS position hold; the emulator
lands exactly straight down)."""

BRAKE_CAP_MPS2 = 2.5
"""The largest braking acceleration b Eq. K1a counts on [m/s^2]: ArduCopter's
default WPNAV_ACCEL (250 cm/s^2), with which its position controller brakes
a vehicle whose setpoints stopped."""

REACH_M = 1.0e4
"""Z of Eq. K1b [m]: how far below the vehicle the column reaches (below any
ground), and above it for an RTL failsafe (above any RTL_ALT); finite, for
the distance arithmetic."""


def lost_column(
    pos_m: FloatArray,
    vel_mps: FloatArray,
    accel_mps2: FloatArray,
    *,
    coast_s: float,
    brake_mps2: float,
    climbs: bool = False,
    down: bool = True,
) -> Box:
    """Eq. K1: the column a vehicle last seen at ``pos_m`` moving at
    ``vel_mps`` under ``accel_mps2`` may be in, from now until it is heard
    again (see the module docstring). ``ValueError`` on a non-finite state
    or a coast < 0."""
    p = np.asarray(pos_m, dtype=np.float64).reshape(3)
    v = float(np.linalg.norm(np.asarray(vel_mps, dtype=np.float64)))
    a = float(np.linalg.norm(np.asarray(accel_mps2, dtype=np.float64)))
    if not (np.isfinite(p).all() and math.isfinite(v) and math.isfinite(a)):
        raise ValueError("lost_column: the last state must be finite")
    if not coast_s >= 0.0:
        raise ValueError(f"lost_column: coast {coast_s} s")
    b = min(brake_mps2, BRAKE_CAP_MPS2) if brake_mps2 > 0.0 else BRAKE_CAP_MPS2
    stop = v + a * coast_s
    r = HOLD_DRIFT_M + v * coast_s + 0.5 * a * coast_s**2 + stop * stop / (2.0 * b)  # K1a
    top = float(p[2]) + (REACH_M if climbs else r)
    bottom = float(p[2]) - (REACH_M if down else r)  # K1b; K1c
    return Box(
        centre=(float(p[0]), float(p[1]), 0.5 * (top + bottom)),
        half_extents=(r, r, 0.5 * (top - bottom)),
    )
