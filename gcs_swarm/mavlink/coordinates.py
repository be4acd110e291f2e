"""The one frame conversion of the station: vehicle LOCAL_NED <-> mission frame.

Mission frame (formation-law.md section 1): x east, y north, z up, metres,
origin at the mission origin. A vehicle's LOCAL_POSITION_NED is north, east,
down relative to its own EKF origin. With ``o_i`` that origin expressed in
the mission frame (east, north, up offset from the mission origin):

- position:           ``p = (e, n, -d) + o_i``
- velocity, accel:    ``v = (v_e, v_n, -v_d)``, ``a_ned = (a_y, a_x, -a_z)``

The offset comes from the vehicle's GPS_GLOBAL_ORIGIN against the mission
origin with the flat-earth formula of mavlink-protocol.md ("Frames and
origins"): north = dlat R, east = dlon R cos(lat), up = dalt, R = 6378137 m.
Pure numpy; arrays are shaped (3,) or (N, 3) (the ``_floats`` forms take
one point and give its three floats).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = [
    "EARTH_RADIUS_M",
    "GeoOrigin",
    "mission_to_ned",
    "mission_to_ned_floats",
    "ned_to_mission",
    "origin_offset_m",
    "vector_mission_to_ned",
    "vector_mission_to_ned_floats",
    "vector_ned_to_mission",
]

EARTH_RADIUS_M = 6378137.0
"""Equatorial radius used by the flat-earth offset (mavlink-protocol.md)."""

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class GeoOrigin:
    """A vehicle's EKF origin or the mission origin as the MAVLink layer holds
    it: latitude and longitude [deg], altitude [m] (AMSL). (The mission file's
    own point is ``gcs_swarm.mission.GeoPoint``.)"""

    lat_deg: float
    lon_deg: float
    alt_m: float

    @classmethod
    def from_mavlink(cls, lat_e7: int, lon_e7: int, alt_mm: int) -> GeoOrigin:
        """From GPS_GLOBAL_ORIGIN's integer fields (degE7, degE7, mm)."""
        return cls(lat_e7 * 1e-7, lon_e7 * 1e-7, alt_mm * 1e-3)


def origin_offset_m(origin: GeoOrigin, reference: GeoOrigin) -> FloatArray:
    """Offset of ``origin`` from ``reference`` in the mission frame, [m] (east, north, up).

    Flat earth about the reference latitude; error is well under a centimetre
    per kilometre at swarm scale.
    """
    dlat = math.radians(origin.lat_deg - reference.lat_deg)
    dlon = math.radians(origin.lon_deg - reference.lon_deg)
    north = dlat * EARTH_RADIUS_M
    east = dlon * EARTH_RADIUS_M * math.cos(math.radians(reference.lat_deg))
    up = origin.alt_m - reference.alt_m
    return np.array([east, north, up], dtype=np.float64)


def vector_ned_to_mission(v_ned: npt.ArrayLike) -> FloatArray:
    """A free vector (velocity, acceleration): (n, e, d) -> (e, n, -d)."""
    v = np.asarray(v_ned, dtype=np.float64)
    return np.stack([v[..., 1], v[..., 0], -v[..., 2]], axis=-1)


def vector_mission_to_ned(v_mission: npt.ArrayLike) -> FloatArray:
    """A free vector: (x east, y north, z up) -> (north, east, down) = (y, x, -z)."""
    v = np.asarray(v_mission, dtype=np.float64)
    return np.stack([v[..., 1], v[..., 0], -v[..., 2]], axis=-1)


def ned_to_mission(pos_ned_m: npt.ArrayLike, offset_m: npt.ArrayLike) -> FloatArray:
    """A position: p = (e, n, -d) + o_i (formation-law.md section 1)."""
    return vector_ned_to_mission(pos_ned_m) + np.asarray(offset_m, dtype=np.float64)


def mission_to_ned(pos_mission_m: npt.ArrayLike, offset_m: npt.ArrayLike) -> FloatArray:
    """Inverse of ``ned_to_mission``: (n, e, d) of p - o_i."""
    rel = np.asarray(pos_mission_m, dtype=np.float64) - np.asarray(offset_m, dtype=np.float64)
    return vector_mission_to_ned(rel)


Floats3 = tuple[float, float, float]


def mission_to_ned_floats(pos_mission_m: FloatArray, offset_m: FloatArray) -> Floats3:
    """``mission_to_ned`` of one point (shape (3,)), the same operations on
    its floats: about a microsecond of numpy's per-call cost less, for what
    runs at every report (a holding vehicle's answer)."""
    p, o = pos_mission_m, offset_m
    return (float(p[1] - o[1]), float(p[0] - o[0]), -float(p[2] - o[2]))


def vector_mission_to_ned_floats(v_mission: FloatArray) -> Floats3:
    """``vector_mission_to_ned`` of one vector (shape (3,)) as floats."""
    v = v_mission
    return (float(v[1]), float(v[0]), -float(v[2]))
