"""PX4's personality: Hold to arm and take off, OFFBOARD to fly (no I/O).

Facts measured on PX4 v1.14 SITL (mavlink-protocol.md, PX4 section):

- Modes are ``custom_mode = main << 16 | sub << 24`` (``px4_mode``), set with
  MAV_CMD_DO_SET_MODE p1 = 1, p2 = main, p3 = sub. Hold (AUTO.LOITER) is
  the boot mode; the vehicle is armed in it.
- Readiness: SYS_STATUS health's pre-arm bit (MAV_SYS_STATUS_PREARM_CHECK),
  ESTIMATOR_STATUS flags (once one is heard; the EKF_STATUS_REPORT bits), a
  3D GPS fix and GPS_GLOBAL_ORIGIN. PX4 has no EKF_STATUS_REPORT.
- Take-off: MAV_CMD_NAV_TAKEOFF with p4-p6 NaN and p7 AMSL, within
  COM_DISARM_PRFLT (10 s) of arming; PX4 climbs in AUTO.TAKEOFF, then Holds.
- OFFBOARD is accepted only while setpoints stream (above 2 Hz): the station
  streams its position setpoint first (``offboard``).
- Integer parameters travel byte-wise: an INT32's bytes in PARAM_SET's and
  PARAM_VALUE's float field with param_type INT32 (a REAL32 PARAM_SET on an
  INT32 parameter is silently ignored).
- The offboard-loss failsafe: COM_OF_LOSS_T [s] without setpoints, then
  COM_OBL_RC_ACT (``OBL_ACTIONS``).
- The envelope (Eq. E1-PX4 in ``envelope_from_px4``): MPC_ACC_HOR,
  MPC_ACC_UP_MAX, MPC_ACC_DOWN_MAX, MPC_JERK_MAX, MPC_XY_VEL_MAX,
  MPC_Z_VEL_MAX_UP/DN and the tilt limit MPC_TILTMAX_AIR.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping
from typing import ClassVar

from gcs_swarm.control.params import Envelope
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.codec import MessageSpec
from gcs_swarm.mavlink.inbound import ParamValue
from gcs_swarm.mavlink.param_values import GRAVITY_MPS2, EndAction, ParamProfile, Setting
from gcs_swarm.mavlink.personality import Health, Personality
from gcs_swarm.mavlink.states import Phase, ProtocolConfig

__all__ = [
    "HOLD",
    "LAND",
    "OBL_ACTIONS",
    "OFFBOARD",
    "POSCTL",
    "PX4",
    "PX4_ENVELOPE_PARAMS",
    "PX4_INT_PARAMS",
    "PX4_LAG_S",
    "PX4_MODES",
    "RTL",
    "TAKEOFF",
    "Px4",
    "envelope_from_px4",
    "px4_failsafe_values",
    "px4_mode",
    "px4_param_set",
]


def px4_mode(main: int, sub: int = 0) -> int:
    """PX4's ``custom_mode``: main mode in bits 16-23, sub mode in bits 24-31."""
    return main << 16 | sub << 24


_MAIN_POSCTL, _MAIN_AUTO, _MAIN_OFFBOARD = 3, 4, 6
PX4_MODES: dict[str, int] = {
    "MANUAL": px4_mode(1),
    "ALTCTL": px4_mode(2),
    "POSCTL": px4_mode(_MAIN_POSCTL),
    "AUTO.TAKEOFF": px4_mode(_MAIN_AUTO, 2),
    "AUTO.LOITER": px4_mode(_MAIN_AUTO, 3),
    "AUTO.MISSION": px4_mode(_MAIN_AUTO, 4),
    "AUTO.RTL": px4_mode(_MAIN_AUTO, 5),
    "AUTO.LAND": px4_mode(_MAIN_AUTO, 6),
    "OFFBOARD": px4_mode(_MAIN_OFFBOARD),
    "STABILIZED": px4_mode(7),
}
"""PX4 v1.14 modes (px4_custom_mode.h); measured: Hold 50593792, AUTO.TAKEOFF
33816576, OFFBOARD 393216, POSCTL 196608, AUTO.LAND 100925440."""
_NAMES = {v: k for k, v in PX4_MODES.items()}
HOLD = PX4_MODES["AUTO.LOITER"]
TAKEOFF = PX4_MODES["AUTO.TAKEOFF"]
OFFBOARD = PX4_MODES["OFFBOARD"]
LAND = PX4_MODES["AUTO.LAND"]
RTL = PX4_MODES["AUTO.RTL"]
POSCTL = PX4_MODES["POSCTL"]

_PREARM_CHECK = 0x10000000
"""MAV_SYS_STATUS_PREARM_CHECK: set in SYS_STATUS health when arming would pass."""
_EKF_READY = 1 | 2 | 4 | 16 | 32
"""ESTIMATOR_STATUS_FLAGS needed: attitude, horizontal and vertical velocity,
absolute horizontal and vertical position (the EKF_STATUS_REPORT bits)."""

MAV_PARAM_TYPE_INT32 = 6
PX4_INT_PARAMS = frozenset(
    {"COM_OBL_RC_ACT", "NAV_DLL_ACT", "NAV_RCL_ACT", "COM_RCL_EXCEPT", "GF_ACTION",
     "COM_ARM_WO_GPS", "SYS_AUTOSTART", "MAV_SYS_ID"}
)  # fmt: skip
"""The INT32 parameters the station may set (PX4 v1.14 parameter metadata)."""

PX4_ENVELOPE_PARAMS = (
    "MPC_ACC_HOR",
    "MPC_ACC_UP_MAX",
    "MPC_ACC_DOWN_MAX",
    "MPC_JERK_MAX",
    "MPC_XY_VEL_MAX",
    "MPC_Z_VEL_MAX_UP",
    "MPC_Z_VEL_MAX_DN",
    "MPC_TILTMAX_AIR",
)
"""The multicopter position controller's limits read at start-up (m/s^2,
m/s^3, m/s, degrees; defaults 3, 4, 3, 8, 12, 3, 1.5, 45 in v1.14)."""
PX4_FAILSAFE_PARAMS = ("COM_OBL_RC_ACT",)
PX4_LAG_S = 0.3
"""Lag of PX4's achieved acceleration on an OFFBOARD acceleration setpoint [s]
(mavlink-protocol.md, PX4: "after a ~0.3 s lag")."""
OF_LOSS_T_S = 1.0
"""COM_OF_LOSS_T the station sets [s] (PX4's default; the sheet's figure)."""

OBL_ACTIONS = {"land": 4, "rtl": 3, "hold": 4}
"""COM_OBL_RC_ACT per end action: 4 Land, 3 Return. A hold end action still
lands, as ArduCopter's GCS failsafe does (FS_GCS_FOR_END): a vehicle hovering
in Hold with no station to end it must come down (docs/vehicle-safety.md).
PX4's default, 0 (Position mode without RC), descends at ~0.75 m/s."""
_OBL_NAMES = {0: "Position", 1: "Altitude", 2: "Manual", 3: "Return", 4: "Land", 5: "Hold",
              6: "Terminate", 7: "Disarm"}  # fmt: skip


def _int_as_float(value: int) -> float:
    """An INT32's bytes read as a float32: how PX4 carries integers."""
    return float(struct.unpack("<f", struct.pack("<i", value))[0])


def _float_as_int(value: float) -> int:
    return int(struct.unpack("<i", struct.pack("<f", value))[0])


def px4_param_set(sysid: int, compid: int, name: str, value: float) -> MessageSpec:
    """PARAM_SET as PX4 takes it: an INT32 parameter (``PX4_INT_PARAMS``)
    with its integer's bytes in the float field and type INT32, others REAL32."""
    if name in PX4_INT_PARAMS:
        raw = _int_as_float(round(value))
        return b.param_set(sysid, compid, name, raw, param_type=MAV_PARAM_TYPE_INT32)
    return b.param_set(sysid, compid, name, value)


def envelope_from_px4(
    values: Mapping[str, float], fallback: Envelope | None, lag_s: float
) -> tuple[Envelope, tuple[str, ...]]:
    """The ``Envelope`` [SI] from PX4's parameters (already SI, degrees for
    the tilt) and the names missing (or not > 0): their bound is
    ``fallback``'s.

    Eq. E1-PX4: accel_xy = min(MPC_ACC_HOR, g tan(MPC_TILTMAX_AIR)); accel_z
    = min(MPC_ACC_UP_MAX, MPC_ACC_DOWN_MAX) (the Envelope bounds |a_z| both
    ways); jerk_xy = jerk_z = MPC_JERK_MAX; speed_xy = MPC_XY_VEL_MAX;
    speed_up, speed_down = MPC_Z_VEL_MAX_UP, MPC_Z_VEL_MAX_DN; lag PX4_LAG_S.
    READING of PX4 v1.14 (PositionControl.cpp, ``_accelerationControl``): an
    OFFBOARD acceleration-only setpoint bypasses the trajectory generator,
    so PX4 itself enforces only the tilt and thrust limits; the MPC_ACC_* and
    MPC_JERK_MAX figures are what PX4 flies in its own modes, and the station
    keeps its commands within them (MPC_JERK_AUTO, 4, is AUTO modes' jerk)."""
    fb = fallback if fallback is not None else Envelope()
    got = {}
    for n in PX4_ENVELOPE_PARAMS:
        v = values.get(n)
        got[n] = v if v is not None and math.isfinite(v) and v > 0.0 else None
    missing = tuple(n for n, v in got.items() if v is None)

    def val(name: str, default: float) -> float:
        v = got[name]
        return default if v is None else v

    acc, tilt = got["MPC_ACC_HOR"], got["MPC_TILTMAX_AIR"]
    accel_xy = fb.accel_xy
    if acc is not None or tilt is not None:
        lean = math.inf if tilt is None else GRAVITY_MPS2 * math.tan(math.radians(min(tilt, 89.0)))
        accel_xy = min(math.inf if acc is None else acc, lean)  # Eq. E1-PX4
    up, down = got["MPC_ACC_UP_MAX"], got["MPC_ACC_DOWN_MAX"]
    accel_z = fb.accel_z if up is None and down is None else min(up or math.inf, down or math.inf)
    jerk = got["MPC_JERK_MAX"]
    envelope = Envelope(
        accel_xy=accel_xy,
        accel_z=accel_z,
        jerk_xy=fb.jerk_xy if jerk is None else jerk,
        jerk_z=fb.jerk_z if jerk is None else jerk,
        speed_xy=val("MPC_XY_VEL_MAX", fb.speed_xy),
        speed_up=val("MPC_Z_VEL_MAX_UP", fb.speed_up),
        speed_down=val("MPC_Z_VEL_MAX_DN", fb.speed_down),
        lag_s=fb.lag_s if len(missing) == len(PX4_ENVELOPE_PARAMS) else PX4_LAG_S,
    )
    return envelope, missing


def px4_failsafe_values(
    end: EndAction, timeout_s: float, station_sysid: int
) -> tuple[Setting, ...]:
    """PX4's offboard-loss action for a mission ending with ``end``:
    COM_OBL_RC_ACT (``OBL_ACTIONS``). Its delay, COM_OF_LOSS_T, the station
    always sets (``Px4.station_sets``, as GUID_TIMEOUT on ArduCopter); the
    mission's failsafe.timeout is ArduCopter's GCS-heartbeat timeout."""
    act = OBL_ACTIONS[end]
    return (("COM_OBL_RC_ACT", float(act), f"{_OBL_NAMES[act]} when the setpoints stop"),)


PX4_PARAMS = ParamProfile(
    autopilot="PX4",
    envelope_params=PX4_ENVELOPE_PARAMS,
    envelope=envelope_from_px4,
    failsafe_params=PX4_FAILSAFE_PARAMS,
    failsafe=px4_failsafe_values,
    fence_params=(),
    param_set=px4_param_set,
    ends_on_own=frozenset({LAND, RTL}),
)


class Px4(Personality):
    """PX4 v1.14 multicopters (module docstring)."""

    name = "PX4"
    ready_mode = HOLD
    fly_mode = OFFBOARD
    land_mode = LAND
    offboard = True
    params = PX4_PARAMS
    status_streams = (
        ("SYS_STATUS", b.MSG_ID_SYS_STATUS),
        ("ESTIMATOR_STATUS", b.MSG_ID_ESTIMATOR_STATUS),
        ("GPS_RAW_INT", b.MSG_ID_GPS_RAW_INT),
        ("EXTENDED_SYS_STATE", b.MSG_ID_EXTENDED_SYS_STATE),
    )
    _READYING: ClassVar[dict[Phase, frozenset[int]]] = {
        Phase.WAITING_ARMABLE: frozenset({HOLD}),
        Phase.ARMING: frozenset({HOLD}),
        Phase.TAKING_OFF: frozenset({HOLD, TAKEOFF}),
        Phase.GOING_TO_START: frozenset({HOLD, TAKEOFF, OFFBOARD}),
    }
    _END: ClassVar[dict[int, int]] = {
        b.COPTER_MODES["LAND"]: LAND,
        b.COPTER_MODES["RTL"]: RTL,
        b.COPTER_MODES["GUIDED"]: OFFBOARD,
    }

    def mode_name(self, custom_mode: int) -> str:
        return _NAMES.get(custom_mode, str(custom_mode))

    def set_mode(self, sysid: int, compid: int, mode: int) -> MessageSpec:
        return b.set_mode_main_sub(sysid, compid, (mode >> 16) & 0xFF, (mode >> 24) & 0xFF)

    def takeoff(self, sysid: int, compid: int, up_m: float, amsl_m: float | None) -> MessageSpec:
        # Without the origin's altitude, NaN: PX4 then climbs to MIS_TAKEOFF_ALT.
        return b.takeoff_amsl(sysid, compid, math.nan if amsl_m is None else amsl_m)

    def end_mode(self, copter_mode: int) -> int:
        return self._END.get(copter_mode, HOLD)  # BRAKE, LOITER: Hold

    def readying_ok(self, phase: Phase, mode: int) -> bool:
        return mode in self._READYING.get(phase, frozenset({HOLD}))

    def armable(self, health: Health) -> bool:
        prearm = health.sys_health is not None and bool(health.sys_health & _PREARM_CHECK)
        ekf = health.ekf_flags & _EKF_READY == _EKF_READY
        return prearm and ekf and health.gps_fix >= 3

    def station_sets(self, config: ProtocolConfig) -> tuple[Setting, ...]:
        why = "s: when setpoints stop, the offboard-loss failsafe after this"
        return (("COM_OF_LOSS_T", OF_LOSS_T_S, why),)

    def param_value(self, msg: ParamValue) -> float:
        if msg.param_type == MAV_PARAM_TYPE_INT32:
            return float(_float_as_int(msg.value))
        return msg.value


PX4 = Px4()
