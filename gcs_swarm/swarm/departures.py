"""Vehicles out of the formation but in the air: their keep-out columns (Eq. K1).

``lost_keep_out`` reads what the station last knew of a vehicle that went
LOST (its last report, its last command) and what its autopilot will do
without the station (how long it coasts on the last setpoint, how hard it
brakes, whether its GCS failsafe climbs for RTL), and gives the box
``gcs_swarm.control.keep_out.lost_column`` makes of them. ``SwarmCore`` hands
it to the members' safety filter until the vehicle is heard again.
``live_columns`` gives, at each step, the columns of the vehicles out of
the formation that are heard and in the air, at their latest reports: those
that left it (a ``leave`` event, a failure, a pilot taking over), and, as
cubes (they do not come down), those being readied into it (a reserve
holding at its start, a vehicle flying to its rejoin point)
(docs/vehicle-safety.md, "Vehicles out of the formation"). No I/O.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from gcs_swarm.control.keep_out import lost_column
from gcs_swarm.control.limits import FloatArray
from gcs_swarm.control.loop import ControlLoop
from gcs_swarm.control.params import Box
from gcs_swarm.mavlink.px4 import OF_LOSS_T_S
from gcs_swarm.mavlink.states import INCOMING_PHASES, Phase
from gcs_swarm.mavlink.vehicle import VehicleProtocol
from gcs_swarm.mavlink.vehicle_params import ParamSettings

if TYPE_CHECKING:  # types only: the runtime layer is above this one, the core beside
    from gcs_swarm.runtime.config import VehiclePlan
    from gcs_swarm.swarm.core import SwarmCore

_OUT_PHASES = frozenset({Phase.ENDING, Phase.ENDED, Phase.FAILED})
"""Phases of a vehicle that flew and left while heard: ending (its end mode
asked), ended (in its end mode: holding, landing) or failed (someone else
took it)."""

__all__ = [
    "column",
    "departure_terms",
    "describe",
    "keep_out_lost",
    "live_columns",
    "lost_keep_out",
]


def departure_terms(
    autopilot: str, params: ParamSettings, guid_timeout_s: float
) -> tuple[float, bool]:
    """(coast [s], climbs) of Eq. K1 for a vehicle of ``autopilot`` (the
    mission's: ardupilot, sim or px4) with ``params`` (what the station sets
    on it): how long its autopilot flies on the last setpoint (ArduCopter
    GUID_TIMEOUT as the station sets it; PX4 COM_OF_LOSS_T if longer), and
    whether its GCS failsafe climbs first (set, with the mission's ``end``
    rtl)."""
    coast = guid_timeout_s if autopilot != "px4" else max(guid_timeout_s, OF_LOSS_T_S)
    return coast, params.gcs_failsafe and params.end == "rtl"


def column(
    control: ControlLoop,
    pos_m: FloatArray,
    vel_mps: FloatArray,
    accel_mps2: FloatArray,
    terms: tuple[float, bool],
    *,
    down: bool = True,
) -> Box:
    """Eq. K1 for a vehicle last at ``pos_m``, ``vel_mps`` under ``accel_mps2``
    (mission frame), braking at most as the envelope in force and
    ``limits.a_max`` allow, with ``terms`` from ``departure_terms``; with
    ``down`` False the cube of Eq. K1c."""
    brake = min(control.envelope.accel_xy, control.config.limits.a_max)
    accel = np.asarray(accel_mps2, dtype=np.float64)
    if not np.isfinite(accel).all():
        accel = np.zeros(3)
    return lost_column(pos_m, vel_mps, accel, coast_s=terms[0], brake_mps2=brake,
                       climbs=terms[1], down=down)  # fmt: skip


def lost_keep_out(
    vp: VehicleProtocol, plan: VehiclePlan, control: ControlLoop, guid_timeout_s: float
) -> Box | None:
    """Eq. K1's column for ``vp``, LOST now, or None when the station never
    had its position and origin (it was never placed: nothing to keep out
    of): from its last report in the mission frame (``state_mission``) and
    the last acceleration sent to it (NED, turned to the mission frame)."""
    if vp.position is None or vp.offset_m is None:
        return None
    pos, vel = vp.state_mission()
    a_ned = np.asarray(vp.last_accel_ned, dtype=np.float64)
    accel = np.array((a_ned[1], a_ned[0], -a_ned[2]))  # NED -> (e, n, up)
    return column(control, pos, vel, accel,
                  departure_terms(plan.autopilot, plan.params, guid_timeout_s))  # fmt: skip


def describe(label: str, box: Box, separation_m: float, *, heard: bool = False) -> str:
    """The log line of a keep-out box taken: of a vehicle unheard, or
    (``heard``) of one out of the formation, heard and in the air (it moves
    with the vehicle)."""
    c, h = box.centre, box.half_extents
    box_xyz = (f"x {c[0]:.1f} +/- {h[0]:.1f}, y {c[1]:.1f} +/- {h[1]:.1f} m, "
               f"up to z {c[2] + h[2]:.1f} m")  # fmt: skip
    if heard:
        return (f"vehicle {label} out of the formation and in the air: the others keep "
                f"{separation_m:g} m from where it may be (now {box_xyz}) while it is")  # fmt: skip
    return (f"vehicle {label} left unheard, still in the air: the others keep "
            f"{separation_m:g} m from the column {box_xyz}, until it is heard again")  # fmt: skip


def keep_out_lost(
    vp: VehicleProtocol, plan: VehiclePlan, control: ControlLoop, guid_timeout_s: float
) -> tuple[str, int] | None:
    """``vp`` left the formation LOST: its column (``lost_keep_out``) kept by
    the members' filter from now on (``ControlLoop.keep_out_of``; the filter
    off: nothing, and a warning). Returns what to log and at which level, or
    None when there is no column to keep."""
    box = lost_keep_out(vp, plan, control, guid_timeout_s)
    if box is None:
        return None
    safety = control.config.safety
    if not safety.enabled:
        return (f"vehicle {vp.label} lost in the air with the safety filter off: "
                "nothing keeps the others out from under it", logging.WARNING)  # fmt: skip
    control.keep_out_of(vp.sysid, box)
    return describe(vp.label, box, safety.separation), logging.WARNING


def live_columns(core: SwarmCore, now: float) -> dict[int, Box]:
    """The keep-out boxes (Eq. K1) of the vehicles out of the formation that
    are heard and in the air, by key: not on the ground, with a report
    within the stale timeout of ``now`` [s], and either flown and left (an
    out phase, ``_OUT_PHASES``: a column down) or on their way in
    (``INCOMING_PHASES``: a cube, Eq. K1c: the station flies it to a
    point). Each stands at its latest report, with its velocity and no
    coast (its autopilot flies its own mode, or the station's point);
    none with the filter off, and none for a LOST vehicle
    (``keep_out_lost`` keeps its last one)."""
    control = core.control
    out: dict[int, Box] = {}
    if not control.config.safety.enabled or len(core.flying) == len(core.vehicles):
        return out  # every step: the usual case, nobody out, costs no set of N keys
    stale = core.config.stale_timeout_s
    for sysid in sorted(core.vehicles.keys() - core.flying):
        vp = core.vehicles[sysid]
        left = vp.phase in _OUT_PHASES and sysid in core.flown
        if not (left or vp.phase in INCOMING_PHASES) or sysid in control.keep_out:
            continue
        if vp.position is None or vp.offset_m is None or now - vp.position_at > stale:
            continue
        if vp.on_ground:
            continue
        pos, vel = vp.state_mission()
        plan = core.plans[sysid]
        climbs = departure_terms(plan.autopilot, plan.params, 0.0)[1]
        out[sysid] = column(control, pos, vel, np.zeros(3), (0.0, climbs and left), down=left)
    return out
