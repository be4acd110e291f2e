"""The autopilot's watchdogs: the land detector, the GCS failsafe and the fence. NO I/O.

Functions of an ``Autopilot`` called from its ``poll`` (as ``commands`` is
from ``handle``); the rules themselves are in ``safety`` (pure) and in the
``autopilot`` docstring (land detector).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import safety, telemetry
from sim_vehicle.telemetry import Kin

if TYPE_CHECKING:
    from sim_vehicle.autopilot import Autopilot

__all__ = ["LAND_DETECT_S", "gcs_due", "land_detector", "safety_checks"]

LAND_DETECT_S = 1.0
"""LAND_DETECTOR_TRIGGER_SEC: time on the ground before "land complete"."""


def land_detector(ap: Autopilot, now: float, kin: Kin) -> list[mav.MAVLink_message]:
    """Land complete after LAND_DETECT_S on the ground (module docstring)."""
    if not ap.armed:
        ap.land_complete, ap.touch = True, None
        return []
    if not kin.landed:
        ap.land_complete, ap.touch = False, None
        return []
    if ap.land_complete:
        return []
    if ap.touch is None:
        ap.touch = now
    if now - ap.touch < LAND_DETECT_S - 1e-9:
        return []
    ap.land_complete = True
    if ap.control == "land":  # LAND, or RTL's final descent: disarm on landing
        ap.disarm_landed(now, kin)
        return [telemetry.statustext(mav.MAV_SEVERITY_INFO, "Land complete: disarmed")]
    if ap.control not in ("spool", "takeoff", "ground"):
        ap.set_control("ground", now, kin)  # idles armed; DISARM_DELAY runs from now
    return []


def _act(
    ap: Autopilot, act: safety.Action | None, now: float, kin: Kin
) -> list[mav.MAVLink_message]:
    if act is None:
        return []
    if act.disarm:
        ap.disarm_landed(now, kin)
    elif act.mode is not None and act.mode != ap.mode:
        ap.set_mode(act.mode, now, kin)
    return [telemetry.statustext(act.severity, act.text)]


def safety_checks(ap: Autopilot, now: float, kin: Kin) -> list[mav.MAVLink_message]:
    """GCS failsafe and fence (``safety`` module), while armed."""
    p, out = ap.params, []
    if ap.armed and ap.last_gcs_hb is not None and p["FS_GCS_ENABLE"] != 0:
        if ap.wall_s is not None and ap.last_gcs_hb_wall is not None:  # lockstep: wall time
            lost = ap.wall_s - ap.last_gcs_hb_wall > p["FS_GCS_TIMEOUT"]
        else:
            lost = now - ap.last_gcs_hb > p["FS_GCS_TIMEOUT"]
        if lost and not ap.fs_active:
            ap.fs_active = True
            landing = ap.control == "land"
            act = safety.gcs_failsafe(
                int(p["FS_GCS_ENABLE"]), int(p["FS_OPTIONS"]), ap.mode, landing,
                ap.land_complete,
            )  # fmt: skip
            out += _act(ap, act, now, kin)
    if ap.armed and p["FENCE_ENABLE"] != 0:
        alt = ap.home[2] - kin.pos[2]
        dist = math.hypot(kin.pos[0] - ap.home[0], kin.pos[1] - ap.home[1])
        bits, outside = safety.fence_breaches(
            1, int(p["FENCE_TYPE"]), p["FENCE_ALT_MAX"], p["FENCE_RADIUS"], alt, dist
        )
        new, ap.breaches = bits & ~ap.breaches, bits
        if new:
            act = safety.fence_action(int(p["FENCE_ACTION"]), outside, ap.land_complete)
            out += _act(ap, act, now, kin)
    else:
        ap.breaches = 0
    return out


def gcs_due(ap: Autopilot, now: float) -> float:
    """When ``ap``'s GCS failsafe must be looked at (inf: it cannot trigger)."""
    p = ap.params
    if not ap.armed or ap.last_gcs_hb is None or p["FS_GCS_ENABLE"] == 0:
        return math.inf
    due = ap.last_gcs_hb + p["FS_GCS_TIMEOUT"] + 1e-3
    # lockstep: sim time runs faster than the station's wall clock; look again
    # every 0.1 s of sim time once it could be due (safety_checks)
    return due if ap.wall_s is None else max(due, now + 0.1)
