"""PX4 v1.14 personality of one emulated vehicle. NO I/O: decoded messages + ``now`` in.

``Px4Autopilot`` is the ArduCopter-like ``Autopilot`` with PX4's edges, as
measured on PX4 SITL with its SIH quadrotor (docs/mavlink-protocol.md, PX4):

- HEARTBEAT autopilot 12 (MAV_AUTOPILOT_PX4), ``custom_mode = main << 16 |
  sub << 24``; boots in Hold (AUTO.LOITER); MAV_CMD_DO_SET_MODE p2 = main,
  p3 = sub. Inside, each PX4 mode is flown by the ArduCopter machinery
  (``_TO_INSIDE``): OFFBOARD as GUIDED (setpoints honoured), Hold as
  LOITER, AUTO.LAND as LAND, AUTO.RTL as RTL; POSCTL (the default
  offboard-loss action, no RC) holds horizontally and descends (LAND's
  descent at MPC_LAND_SPEED; SITL: ~0.75 m/s).
- Pre-arm checks pass SIM_PREARM_S after boot (SITL: 9.2-9.4 s; SYS_STATUS
  health's MAV_SYS_STATUS_PREARM_CHECK bit says so). An arm before that is
  COMMAND_ACK 1 (temporarily rejected) with the reason as an EVENT (410), no
  STATUSTEXT.
- Arming without a take-off disarms after COM_DISARM_PRFLT (10 s).
- MAV_CMD_NAV_TAKEOFF: p7 is AMSL (NaN: MIS_TAKEOFF_ALT), at least
  MIS_TAKEOFF_ALT above home; p5/p6 NaN mean here. p5 = p6 = 0 (latitude and
  longitude 0) is acknowledged, switches to AUTO.TAKEOFF and never leaves
  the ground. After the climb the vehicle Holds.
- OFFBOARD is refused (ACK 1) in flight unless setpoints stream above 2 Hz
  (the last two each within 0.5 s); chosen disarmed it is accepted, and then
  arming needs the stream. In OFFBOARD with no setpoint for COM_OF_LOSS_T
  the vehicle goes to COM_OBL_RC_ACT (0-2 Position, 3 Return, 4 Land, 5 Hold,
  6-7 disarm).
- Acceleration setpoints (type_mask 3135) are gravity-compensated NED (az = 0
  hovers), flown through a first-order lag (SIM_ACC_TAU, 0.3 s measured)
  with no jerk limit (SIM_ACC_SHAPE 0: PX4's offboard acceleration bypasses
  its trajectory generator).
- Eq. D8, the loop's dead time: a setpoint takes effect SIM_SP_DELAY after
  it is heard (0.1 s in the preset, fitted to PX4 SITL: docs/emulator.md).
  PX4's offboard-loss clock still starts when a setpoint is heard.
- Parameters: PX4's names on the wire (ArduCopter's stay inside, hidden);
  INT32 values travel byte-wise in the float; a REAL32 PARAM_SET on an INT32
  parameter is ignored; SET_MESSAGE_INTERVAL of EKF_STATUS_REPORT is ACK 4;
  ESTIMATOR_STATUS streams instead.
"""

from __future__ import annotations

import math
import struct
from collections import deque
from collections.abc import Sequence
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import telemetry
from sim_vehicle.autopilot import (
    ACCEPTED,
    FAILED,
    GUIDED,
    LAND,
    LOITER,
    RTL,
    TEMPORARILY_REJECTED,
    Autopilot,
)
from sim_vehicle.commands import ECHO_MASK
from sim_vehicle.params import _I32, _R32, PARAM_TABLE, ParamStore
from sim_vehicle.targets import NO_KIN
from sim_vehicle.telemetry import Kin, Vec3

__all__ = ["PX4_MODES", "PX4_PARAMS", "EventMessage", "Px4Autopilot", "Px4ParamStore", "px4_mode"]


def px4_mode(main: int, sub: int = 0) -> int:
    """PX4's ``custom_mode``: main mode in bits 16-23, sub mode in bits 24-31."""
    return main << 16 | sub << 24


PX4_MODES = {
    "POSCTL": px4_mode(3),
    "AUTO.TAKEOFF": px4_mode(4, 2),
    "AUTO.LOITER": px4_mode(4, 3),
    "AUTO.RTL": px4_mode(4, 5),
    "AUTO.LAND": px4_mode(4, 6),
    "OFFBOARD": px4_mode(6),
}
_POSCTL_IN, _TAKEOFF_IN = 16, 100
"""Inside numbers of POSCTL (ArduCopter's POSHOLD) and AUTO.TAKEOFF (none)."""
_TO_INSIDE = {
    PX4_MODES["OFFBOARD"]: GUIDED,
    PX4_MODES["AUTO.LOITER"]: LOITER,
    PX4_MODES["AUTO.LAND"]: LAND,
    PX4_MODES["AUTO.RTL"]: RTL,
    PX4_MODES["POSCTL"]: _POSCTL_IN,
    PX4_MODES["AUTO.TAKEOFF"]: _TAKEOFF_IN,
}
_TO_PX4 = {v: k for k, v in _TO_INSIDE.items()}
_NAMES = {v: k for k, v in PX4_MODES.items()}
_OBL_INSIDE = {0: _POSCTL_IN, 1: _POSCTL_IN, 2: _POSCTL_IN, 3: RTL, 4: LAND, 5: LOITER}
"""COM_OBL_RC_ACT -> inside mode (6 Terminate and 7 Disarm disarm)."""

PX4_PARAMS: dict[str, tuple[float, int, str]] = {
    "MAV_SYS_ID": (1, _I32, "system id"),
    "COM_OF_LOSS_T": (1.0, _R32, "s without offboard setpoints before COM_OBL_RC_ACT"),
    "COM_OBL_RC_ACT": (
        0,
        _I32,
        "offboard loss: 0 Position 1 Altitude 2 Manual 3 Return 4 Land 5 Hold 6 Terminate 7 Disarm",
    ),
    "COM_DISARM_PRFLT": (10.0, _R32, "s armed on the ground without take-off before disarming"),
    "NAV_DLL_ACT": (0, _I32, "GCS link loss action (stored only)"),
    "MIS_TAKEOFF_ALT": (2.5, _R32, "m, take-off altitude when none (or a lower one) is given"),
    "MPC_ACC_HOR": (3.0, _R32, "m/s^2, horizontal acceleration in auto modes"),
    "MPC_ACC_UP_MAX": (4.0, _R32, "m/s^2, upward acceleration"),
    "MPC_ACC_DOWN_MAX": (3.0, _R32, "m/s^2, downward acceleration"),
    "MPC_JERK_MAX": (8.0, _R32, "m/s^3, jerk in position mode"),
    "MPC_JERK_AUTO": (4.0, _R32, "m/s^3, jerk in auto modes"),
    "MPC_XY_VEL_MAX": (12.0, _R32, "m/s, horizontal speed"),
    "MPC_Z_VEL_MAX_UP": (3.0, _R32, "m/s, climb speed"),
    "MPC_Z_VEL_MAX_DN": (1.5, _R32, "m/s, descent speed"),
    "MPC_TILTMAX_AIR": (45.0, _R32, "deg, tilt limit"),
    "MPC_TKO_SPEED": (1.5, _R32, "m/s, take-off climb speed"),
    "MPC_LAND_SPEED": (0.7, _R32, "m/s, final landing (and POSCTL without RC) descent"),
    "SIM_PREARM_S": (9.3, _R32, "s after boot before the pre-arm checks pass (SITL 9.2-9.4)"),
}
"""PX4 v1.14's names and defaults (parameter metadata), in PX4's units."""
_TABLE = {**PARAM_TABLE, **PX4_PARAMS}
_VISIBLE = frozenset(PX4_PARAMS) | {n for n in PARAM_TABLE if n.startswith("SIM_")}
PX4_OVERRIDES: dict[str, float] = {
    "SIM_ACC_TAU": 0.3, "SIM_ACC_SHAPE": 0.0, "SIM_BOOT_S": 0.0, "SIM_DRAG": 1.0,
    "SIM_DRAG_VEL": 0.45, "SIM_SP_DELAY": 0.1,
}  # fmt: skip
"""The emulator's own settings for a PX4 (measured lag, no shaping, no end of boot)."""


class Px4ParamStore(ParamStore):
    """PX4's parameters on the wire over ArduCopter's inside (module docstring)."""

    def __init__(self, overrides: dict[str, float] | None = None) -> None:
        super().__init__(overrides, table=_TABLE, visible=_VISIBLE)

    def wire_value(self, name: str) -> float:
        if self.table[name][1] == _I32:  # the integer's bytes, as PX4 sends them
            return float(struct.unpack("<f", struct.pack("<i", round(self.values[name])))[0])
        return self.values[name]

    def decode_set(self, name: str, value: float, param_type: int) -> float | None:
        if self.table[name][1] == _I32:
            if param_type != _I32:
                return None  # PX4: a REAL32 PARAM_SET on an INT32 is silently ignored
            return float(struct.unpack("<i", struct.pack("<f", value))[0])
        return value


class EventMessage(mav.MAVLink_message):  # type: ignore[misc]
    """EVENT (410), which pymavlink 2.4.50's dialect lacks (common.xml's
    definition; wire order id, time, sequence, destination ids, log levels,
    40 argument bytes; CRC_EXTRA 160). Only packed here."""

    msgname = "EVENT"
    crc_extra = 160
    _packer = struct.Struct("<IIHBBB40B")

    def __init__(self, event_id: int, time_ms: int, sequence: int, args: Sequence[int]) -> None:
        super().__init__(410, "EVENT")
        self._fieldnames = ["id", "event_time_boot_ms", "sequence", "log_levels"]
        self.id, self.event_time_boot_ms, self.sequence = event_id, time_ms, sequence
        self.log_levels = 0x44  # warning, internally and externally
        self.arguments = (list(args) + [0] * 40)[:40]

    def pack(self, mav_: Any, force_mavlink1: bool = False) -> bytes:
        payload = self._packer.pack(self.id, self.event_time_boot_ms, self.sequence, 0, 0,
                                    self.log_levels, *self.arguments)  # fmt: skip
        packed: bytes = self._pack(mav_, self.crc_extra, payload, force_mavlink1=force_mavlink1)
        return packed


EVENT_NOT_READY = 22831554
"""check_estimator_missing_data: "Waiting for estimator to initialize"."""
EVENT_NO_OFFBOARD = 19865031
"""check_modes_offboard_signal: "No offboard signal"."""
EVENT_MODE_NOT_ARMABLE = 18648929
"""check_modes_cannot_takeoff: "Mode not suitable for arming"."""
_ARMABLE_INSIDE = {LOITER, _POSCTL_IN, GUIDED}
_STREAM_GAP_S = 0.5
"""A setpoint stream is "above 2 Hz" when its last two setpoints, and the
last and now, are each at most this far apart."""


class Px4Autopilot(Autopilot):
    """One emulated PX4 (module docstring)."""

    unknown_stream_result = FAILED

    def __init__(
        self,
        sysid: int,
        origin: Vec3,
        params: ParamStore,
        now: float,
        *,
        compid: int = 1,
        airborne_at: Vec3 | None = None,
        streams: dict[int, float] | None = None,
    ) -> None:
        self._sp_times: tuple[float, float] = (-math.inf, -math.inf)
        self._sp_queue: deque[tuple[float, str, dict[str, Any], int]] = deque()
        """Setpoints heard, not yet in effect (Eq. D8): (due, kind, setpoint, echo mask)."""
        self._event_seq = 0
        self._refusal: int | None = None
        self.failsafe_at: float | None = None
        """Sim time the offboard-loss failsafe last engaged (None: never)."""
        super().__init__(sysid, origin, params, now, compid=compid, airborne_at=airborne_at,
                         streams=streams)  # fmt: skip
        params.set("MAV_SYS_ID", sysid)
        self._sync_params()
        self.prearm_ok = airborne_at is not None or params["SIM_PREARM_S"] <= 0.0
        self.mode = LOITER  # Hold: the boot mode (an airborne start hovers in it)

    # ------------------------------------------------------------- identity
    @property
    def mode_name(self) -> str:
        return _NAMES.get(_TO_PX4.get(self.mode, -1), f"MODE{self.mode}")

    def heartbeat(self) -> mav.MAVLink_message:
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self.mode == GUIDED:
            base |= mav.MAV_MODE_FLAG_GUIDED_ENABLED
        elif self.mode != _POSCTL_IN:
            base |= mav.MAV_MODE_FLAG_AUTO_ENABLED
        if self.armed:
            base |= mav.MAV_MODE_FLAG_SAFETY_ARMED
        return mav.MAVLink_heartbeat_message(
            type=mav.MAV_TYPE_QUADROTOR,
            autopilot=mav.MAV_AUTOPILOT_PX4,
            base_mode=base,
            custom_mode=_TO_PX4.get(self.mode, PX4_MODES["AUTO.LOITER"]),
            system_status=mav.MAV_STATE_ACTIVE if self.armed else mav.MAV_STATE_STANDBY,
            mavlink_version=3,
        )

    # ------------------------------------------------------------- streams
    def set_interval(self, msgid: int, interval_s: float, now: float) -> bool:
        if msgid == mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT:
            return False  # PX4 has none: ACK 4
        if msgid == mav.MAVLINK_MSG_ID_ESTIMATOR_STATUS:
            if interval_s > 0 or interval_s == 0.0:
                self._streams[msgid] = [interval_s or 1.0, now]
                self.deadline = now
            else:
                self._streams.pop(msgid, None)
            return True
        return super().set_interval(msgid, interval_s, now)

    def build(self, msgid: int, now: float, kin: Kin) -> mav.MAVLink_message | None:
        if msgid == mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT:
            return None
        if msgid == mav.MAVLINK_MSG_ID_SYS_STATUS:
            m = telemetry.sys_status(self.ekf_ready)
            if not self.prearm_ok:
                m.onboard_control_sensors_health &= ~mav.MAV_SYS_STATUS_PREARM_CHECK
            return m
        if msgid == mav.MAVLINK_MSG_ID_ESTIMATOR_STATUS:
            flags = 1 | 2 | 4 | 8 | 16 | 32 if self.ekf_ready else 0
            return mav.MAVLink_estimator_status_message(
                round((now - self.boot) * 1e6), flags, 0.1, 0.1, 0.1, 0.1, 0.0, 0.0, 0.5, 0.5
            )
        return super().build(msgid, now, kin)

    # ---------------------------------------------------- commands (hooks)
    def mode_command(self, p: tuple[float, ...], now: float, kin: Kin) -> int:
        if not int(p[0]) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED or not math.isfinite(p[2]):
            return FAILED
        inside = _TO_INSIDE.get(px4_mode(int(p[1]), int(p[2])))
        if inside is None:
            return FAILED
        if inside == GUIDED and self.armed and not self._streaming_setpoints(now):
            return TEMPORARILY_REJECTED  # no offboard signal
        if inside == _TAKEOFF_IN:
            nan = math.nan
            return self.takeoff_command((0.0, 0.0, 0.0, nan, nan, nan, nan), now, kin)
        self.set_mode(inside, now, kin)
        if inside == _POSCTL_IN and self.armed and not kin.landed:
            self.set_control("land", now, kin)  # no RC: holds position, descends
        return ACCEPTED

    def set_mode(self, mode: int, now: float, kin: Kin) -> bool:
        if mode in (_POSCTL_IN, _TAKEOFF_IN):  # unknown to ArduCopter's table
            self.mode = mode
            self.streaming = False
            if mode == _POSCTL_IN and self.armed and not kin.landed:
                self.set_control("brake", now, kin)
            return True
        return super().set_mode(mode, now, kin)

    def takeoff_params_ok(self, p: tuple[float, ...]) -> bool:
        return True  # NaN is "as you are" / MIS_TAKEOFF_ALT

    def takeoff_command(self, p: tuple[float, ...], now: float, kin: Kin) -> int:
        if not self.armed:
            return TEMPORARILY_REJECTED
        self.mode = _TAKEOFF_IN
        self.streaming = False
        lat, lon, alt = p[4], p[5], p[6]
        if lat == 0.0 and lon == 0.0:
            return ACCEPTED  # latitude/longitude 0: it never leaves the ground
        home_amsl = self.origin[2] - self.home[2]
        minimum = self.params["MIS_TAKEOFF_ALT"]
        up = alt - home_amsl if math.isfinite(alt) else minimum
        up = max(up, minimum)
        if kin.landed:
            self._tk_alt_d = self.home[2] - up
            self.set_control("spool", now, kin)
        return ACCEPTED

    def arm(self, now: float, kin: Kin, force: bool) -> tuple[bool, str | None]:
        self._refusal = None
        if not self.armed and not force:
            if not self.prearm_ok:
                self._refusal = EVENT_NOT_READY
            elif self.mode not in _ARMABLE_INSIDE:
                self._refusal = EVENT_MODE_NOT_ARMABLE
            elif self.mode == GUIDED and not self._streaming_setpoints(now):
                self._refusal = EVENT_NO_OFFBOARD
            if self._refusal is not None:
                return False, None
        return super().arm(now, kin, force)

    def arm_reply(
        self, ok: bool, why: str | None, now: float
    ) -> tuple[int, list[mav.MAVLink_message]]:
        if ok:
            return ACCEPTED, []
        if self._refusal is None:  # disarm refused in flight, or a mandatory check
            return super().arm_reply(ok, why, now)
        self._event_seq = (self._event_seq + 1) & 0xFFFF
        ms = round((now - self.boot) * 1000) & 0xFFFFFFFF
        event = EventMessage(self._refusal, ms, self._event_seq, ())
        return TEMPORARILY_REJECTED, [event]

    def setpoint_heard(self, now: float) -> None:
        self._sp_times = (self._sp_times[1], now)

    stream_buckets = False  # each stream on its own, the first message at once
    FLEET_STREAMS: frozenset[int] = frozenset()  # no status path (reports)
    VEL_REFERENCE = False  # OFFBOARD acceleration: a feed-forward, no velocity reference (D9)

    def stream_deferrable(self) -> bool:
        return False  # each setpoint is heard (the stream-loss clock) and queued (Eq. D8)

    def stream_accel(self, a: Vec3, now: float) -> None:
        # Heard (the stream-loss clock), then queued by Eq. D8: the queue reads no Kin
        # (the due setpoint is applied with the kinematics of its due time).
        self.setpoint_heard(now)
        self.apply_setpoint("accel", {"a": a}, ECHO_MASK["accel"], now, NO_KIN)

    def apply_setpoint(
        self, kind: str, sp: dict[str, Any], mask: int, now: float, kin: Kin
    ) -> None:
        """Eq. D8: a setpoint takes effect SIM_SP_DELAY after it is heard."""
        delay = self.params["SIM_SP_DELAY"]
        if delay <= 0.0:
            super().apply_setpoint(kind, sp, mask, now, kin)
            return
        due = now + delay
        self._sp_queue.append((due, kind, sp, mask))
        self.deadline = min(self.deadline, due)

    def _apply_due(self, now: float, kin: Kin) -> None:
        """Eq. D8: the queued setpoints now due, in order, if OFFBOARD still flies them."""
        q = self._sp_queue
        while q and q[0][0] <= now + 1e-9:
            _due, kind, sp, mask = q.popleft()
            if self.mode == GUIDED and self.armed and not kin.landed:
                super().apply_setpoint(kind, sp, mask, now, kin)
        if q and self.mode != GUIDED:
            q.clear()  # left OFFBOARD: what was on its way is never flown

    def _streaming_setpoints(self, now: float) -> bool:
        before, last = self._sp_times
        return now - last <= _STREAM_GAP_S + 1e-9 and last - before <= _STREAM_GAP_S + 1e-9

    # ------------------------------------------------------------- timers
    def refresh(self, now: float, kin: Kin) -> None:
        self._sync_params()
        super().refresh(now, kin)

    def _sync_params(self) -> None:
        """Feed PX4's parameters to the ArduCopter machinery inside."""
        p = self.params
        for inside, value in (
            ("DISARM_DELAY", p["COM_DISARM_PRFLT"]),
            ("WPNAV_SPEED", 100 * p["MPC_XY_VEL_MAX"]),
            ("WPNAV_SPEED_UP", 100 * p["MPC_TKO_SPEED"]),
            ("WPNAV_SPEED_DN", 100 * p["MPC_Z_VEL_MAX_DN"]),
            ("WPNAV_ACCEL", 100 * p["MPC_ACC_HOR"]),
            ("WPNAV_ACCEL_Z", 100 * p["MPC_ACC_UP_MAX"]),
            ("LAND_SPEED", 100 * p["MPC_LAND_SPEED"]),
            ("GUID_TIMEOUT", 1e9),  # PX4 changes mode on a stream loss instead (poll)
        ):
            if p[inside] != value:
                p.set(inside, value)

    def poll(self, now: float, kin: Kin) -> list[mav.MAVLink_message]:
        if self._sp_queue:
            self._apply_due(now, kin)
        out = super().poll(now, kin)
        p = self.params
        if not self.prearm_ok and now - self.boot >= p["SIM_PREARM_S"] - 1e-9 and self.ekf_ready:
            self.prearm_ok = True
        if self.mode == _TAKEOFF_IN and self.control == "hold":
            self.mode = LOITER  # take-off done: Hold
        loss = p["COM_OF_LOSS_T"]
        if (
            self.mode == GUIDED
            and self.armed
            and not self.land_complete
            and now - self._sp_times[1] > loss + 1e-9
        ):
            out.append(self._offboard_lost(now, kin))
        self._px4_deadline(now)
        return out

    def _offboard_lost(self, now: float, kin: Kin) -> mav.MAVLink_message:
        act = round(self.params["COM_OBL_RC_ACT"])
        self.failsafe_at = now
        inside = _OBL_INSIDE.get(act)
        if inside is None:
            self.disarm_landed(now, kin) if kin.landed else self.disarm(now, kin, force=True)
            return telemetry.statustext(mav.MAV_SEVERITY_CRITICAL, "Failsafe activated: disarm")
        self.set_mode(inside, now, kin)
        if inside == _POSCTL_IN:
            self.set_control("land", now, kin)  # no RC: holds position, descends
        what = _NAMES.get(_TO_PX4[inside], "?")
        return telemetry.statustext(mav.MAV_SEVERITY_CRITICAL, f"Failsafe activated: {what}")

    def _update_deadline(self, now: float) -> None:
        super()._update_deadline(now)
        self._px4_deadline(now)

    def _px4_deadline(self, now: float) -> None:
        d = self.deadline
        if not self.prearm_ok:
            d = min(d, self.boot + self.params["SIM_PREARM_S"])
        if self.mode == GUIDED and self.armed:
            due = self._sp_times[1] + self.params["COM_OF_LOSS_T"] + 1e-3
            d = min(d, max(due, now))
        if self.mode == _TAKEOFF_IN:
            d = now
        if self._sp_queue:
            d = min(d, max(self._sp_queue[0][0], now))
        self.deadline = d
