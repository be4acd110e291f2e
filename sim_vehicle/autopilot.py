"""ArduCopter-like autopilot of one vehicle. NO I/O: decoded messages + ``now`` in, replies out.

Owns mode, arming, EKF readiness, home, the GUIDED setpoint rules, the
GUID_TIMEOUT behaviour, auto-disarm, takeoff/land/RTL sequencing, the GCS
failsafe, parameters and stream schedules (everything but the vectorised
LOCAL_POSITION_NED stream, whose interval it publishes as ``lpn_interval_s``).

It never touches the dynamics arrays: it publishes a ``ControlTarget`` and
bumps ``version`` whenever that target (or a dynamics parameter) changes; the
server copies it into the vectorised tracking law (dynamics Eq. D3).
``deadline`` is the sim time at which ``poll`` must next run (habit: time is
an argument). READING of the protocol sheet: setpoints are honoured only in
GUIDED, armed and airborne; accel/velocity targets are applied until
GUID_TIMEOUT (floored at 0.1 s as ArduCopter does), then the vehicle brakes to
a hover and stays in GUIDED.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import commands, telemetry
from sim_vehicle.dynamics import GRAVITY_M_S2
from sim_vehicle.params import ParamStore
from sim_vehicle.telemetry import Kin, Vec3

__all__ = ["MODE_NAMES", "Autopilot", "ControlTarget"]

GUIDED, LOITER, RTL, LAND, BRAKE = 4, 5, 6, 9, 17
MODE_NAMES = {
    0: "STABILIZE",
    2: "ALT_HOLD",
    4: "GUIDED",
    5: "LOITER",
    6: "RTL",
    9: "LAND",
    16: "POSHOLD",
    17: "BRAKE",
}
_GUIDED_LIKE = {4, 5, 6, 16, 17}
LPN = mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED
ZERO: Vec3 = (0.0, 0.0, 0.0)
_MOVING = {"brake", "takeoff", "land", "rtl_climb", "rtl_return", "rtl_loiter", "spool", "fall"}


@dataclass(frozen=True)
class ControlTarget:
    """Inputs of dynamics Eq. D3 for one vehicle (NED, SI units); see ``dynamics.Targets``."""

    a_ff: Vec3 = ZERO
    p_t: Vec3 = ZERO
    v_t: Vec3 = ZERO
    wp: Vec3 = ZERO
    wv: float = 0.0
    vmax_xy: float = 10.0
    vmax_up: float = 2.5
    vmax_dn: float = 1.5
    acc_lim: float = 5.0
    acc_max: float = 5.0
    tau_s: float = 0.2


class Autopilot:
    """One vehicle's flight stack. Call ``handle`` per message, ``poll`` at ``deadline``."""

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
        self.sysid, self.compid, self.origin, self.params = sysid, compid, origin, params
        params.set("SYSID_THISMAV", sysid)
        self.boot = now
        self.mode = GUIDED if airborne_at is not None else 0
        self.armed = airborne_at is not None
        self.ekf_ready = airborne_at is not None or params["SIM_EKF_DELAY"] <= 0.0
        self.home: Vec3 = (airborne_at[0], airborne_at[1], 0.0) if airborne_at else ZERO
        self.yaw = 0.0
        self.version = 0
        self.rejected = 0  # messages refused for non-finite or absurd numbers
        self.streaming = airborne_at is not None  # lockstep rule 2
        self.lpn_interval_s: float | None = None
        self.lpn_kick = False  # the server sends one LOCAL_POSITION_NED at once, then clears it
        self.deadline = now
        self._ctl = "hold" if airborne_at else "ground"
        self._hold: Vec3 = airborne_at or ZERO
        self._sp: dict[str, Any] = {}  # what GUIDED tracks (for the echo)
        self._echo_mask = 3576
        self._last_sp = -math.inf
        self._t_phase = now  # start of the current takeoff/RTL/ground phase
        self._land_low = False
        self._tk_alt_d = 0.0
        self._last_gcs_hb: float | None = None
        self._fs_active = False
        self._next_hb = now
        self._streams: dict[int, list[float]] = {}  # msgid -> [interval s, next due]
        for msgid, hz in (streams or {}).items():
            self.set_interval(msgid, 1.0 / hz if hz > 0 else -1.0, now)
        self.target = ControlTarget()
        self._base: tuple[int, ControlTarget] | None = None  # (params generation, base target)
        self._set_ctl(self._ctl, now, Kin(self._hold, ZERO, ZERO, airborne_at is None))

    # ------------------------------------------------------------------ state
    @property
    def holding(self) -> bool:
        """Lockstep rule 2: armed, GUIDED, airborne and streaming setpoints."""
        return (
            self.armed
            and self.mode == GUIDED
            and self.streaming
            and self._ctl not in ("ground", "spool", "fall")
        )

    @property
    def control(self) -> str:
        """What the flight controller does now: ground, takeoff, hold, brake,
        accel, vel, pos, posvel, land, rtl_*, ..."""
        return self._ctl

    @property
    def mode_name(self) -> str:
        """Copter mode name (``MODE<n>`` for numbers without a name)."""
        return MODE_NAMES.get(self.mode, f"MODE{self.mode}")

    def heartbeat(self) -> mav.MAVLink_message:
        """This vehicle's HEARTBEAT."""
        return telemetry.heartbeat(self.mode, self.armed, self.mode in _GUIDED_LIKE)

    # ---------------------------------------------------------------- streams
    def set_interval(self, msgid: int, interval_s: float, now: float) -> bool:
        """SET_MESSAGE_INTERVAL semantics: interval s, 0 default, < 0 off. False: unknown id."""
        if msgid not in commands.STREAMABLE:
            return False
        if interval_s == 0.0:
            interval_s = 1.0 / commands.STREAMABLE[msgid]
        if msgid == LPN:
            self.lpn_interval_s = interval_s if interval_s > 0 else None
            self.lpn_kick = interval_s > 0
            self.version += 1
        elif interval_s > 0:
            self._streams[msgid] = [interval_s, now]  # first one at once (lockstep rule 1)
            self.deadline = now
        else:
            self._streams.pop(msgid, None)
        return True

    def interval_of(self, msgid: int) -> float:
        """Current interval in s of ``msgid`` (-1 when not streamed)."""
        if msgid == LPN:
            return self.lpn_interval_s or -1.0
        if msgid == mav.MAVLINK_MSG_ID_HEARTBEAT:
            return 1.0
        return self._streams[msgid][0] if msgid in self._streams else -1.0

    def build(self, msgid: int, now: float, kin: Kin) -> mav.MAVLink_message | None:
        """One instance of a streamable / requestable message, or None if not available."""
        t = now - self.boot
        if msgid == mav.MAVLINK_MSG_ID_HEARTBEAT:
            return self.heartbeat()
        if msgid == mav.MAVLINK_MSG_ID_SYS_STATUS:
            return telemetry.sys_status(self.ekf_ready)
        if msgid == mav.MAVLINK_MSG_ID_GPS_RAW_INT:
            return telemetry.gps_raw_int(t, self.origin, kin, 3 if self.ekf_ready else 1)
        if msgid == mav.MAVLINK_MSG_ID_ATTITUDE:
            return telemetry.attitude(t, kin, self._heading(kin))
        if msgid == LPN:
            return mav.MAVLink_local_position_ned_message(
                round(t * 1000) & 0xFFFFFFFF, *kin.pos, *kin.vel
            )
        if msgid == mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            return telemetry.global_position_int(
                t, self.origin, self.home[2], kin, self._heading(kin)
            )
        if msgid == mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT:
            return telemetry.ekf_status_report(self.ekf_ready)
        if msgid == mav.MAVLINK_MSG_ID_HOME_POSITION:
            return telemetry.home_position(t, self.origin, self.home) if self.ekf_ready else None
        if msgid == mav.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN:
            return telemetry.gps_global_origin(t, self.origin) if self.ekf_ready else None
        if msgid == mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return telemetry.autopilot_version(self.sysid)
        if msgid == mav.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED:
            if self.mode != GUIDED or not self.armed:
                return None
            sp = self._sp
            return telemetry.position_target_local_ned(
                t,
                self._echo_mask,
                sp.get("p", self._hold),
                sp.get("v", ZERO),
                sp.get("a", ZERO),
                self.yaw,
            )
        return None

    def _heading(self, kin: Kin) -> float:
        if self.params["WP_YAW_BEHAVIOR"] != 0 and math.hypot(kin.vel[0], kin.vel[1]) > 0.5:
            self.yaw = math.atan2(kin.vel[1], kin.vel[0])
        return self.yaw

    # -------------------------------------------------------------- messages
    def handle(self, msg: mav.MAVLink_message, now: float, kin: Kin) -> list[mav.MAVLink_message]:
        """Apply one decoded inbound message; return the replies (unpacked)."""
        return commands.dispatch(self, msg, now, kin)

    # ------------------------------------------------------------ transitions
    def set_mode(self, mode: int, now: float, kin: Kin) -> bool:
        """Switch flight mode (any known mode while disarmed, as ArduCopter)."""
        if mode not in MODE_NAMES:
            return False
        self.mode = mode
        self.streaming = False
        if kin.landed:
            self._set_ctl("ground", now, kin)
        elif mode == LAND:
            self._set_ctl("land", now, kin)
        elif mode == RTL:
            self._set_ctl("rtl_climb", now, kin)
        else:
            self._set_ctl("brake", now, kin)
        return True

    def arm(self, now: float, kin: Kin, force: bool) -> tuple[bool, str | None]:
        """Arm; (ok, STATUSTEXT reason when refused)."""
        if self.armed:
            return True, None
        if self.mode in (RTL, LAND):  # mandatory, even when forced
            return False, "Arm: Mode not armable"
        if not force and not self.ekf_ready:
            return False, "PreArm: Need Position Estimate"
        self.armed = True
        self.streaming = False
        self.home = (kin.pos[0], kin.pos[1], kin.pos[2])
        self._set_ctl("ground" if kin.landed else "brake", now, kin)
        return True, None

    def disarm(self, now: float, kin: Kin, force: bool) -> tuple[bool, str | None]:
        """Disarm; refused in flight unless forced (the vehicle then falls)."""
        if not self.armed:
            return True, None
        if not kin.landed and not force:
            return False, "Disarm: vehicle is flying, use force"
        self.armed = False
        self.streaming = False
        self._set_ctl("ground" if kin.landed else "fall", now, kin)
        return True, None

    def takeoff(self, alt_m: float, now: float, kin: Kin) -> bool:
        """NAV_TAKEOFF: climb to ``alt_m`` above home (GUIDED, armed, on the ground)."""
        if self.mode != GUIDED or not self.armed or not kin.landed or alt_m <= 0.0:
            return False
        self._tk_alt_d = self.home[2] - alt_m
        self._set_ctl("spool", now, kin)
        return True

    def stop(self, now: float, kin: Kin) -> None:
        """GUIDED 'init': brake to a stop and hold (invalid setpoint, unsupported frame)."""
        self._sp = {}
        self._echo_mask = 3576
        self._set_ctl("brake", now, kin)

    def apply_setpoint(
        self, kind: str, sp: dict[str, Any], mask: int, now: float, kin: Kin
    ) -> None:
        """Track a GUIDED target: kind in accel, vel, pos, posvel (already in local NED)."""
        self._sp = sp
        self._echo_mask = mask
        self.streaming = True
        if kind in ("accel", "vel"):
            self._last_sp = now
            self.deadline = min(self.deadline, now + self._timeout_s())
        self._set_ctl(kind, now, kin)

    def _timeout_s(self) -> float:
        return max(self.params["GUID_TIMEOUT"], 0.1)

    def _base_target(self) -> ControlTarget:
        """The limits every target starts from (cached until a parameter changes)."""
        p = self.params
        if self._base is not None and self._base[0] == p.generation:
            return self._base[1]
        acc_max = p["SIM_ACC_MAX"]
        vxy, vup, vdn = p["WPNAV_SPEED"] / 100, p["WPNAV_SPEED_UP"] / 100, p["WPNAV_SPEED_DN"] / 100
        base = ControlTarget(
            vmax_xy=vxy, vmax_up=vup, vmax_dn=vdn, tau_s=p["SIM_ACC_TAU"],
            acc_lim=acc_max, acc_max=acc_max,
        )  # fmt: skip
        self._base = (p.generation, base)
        return base

    def _set_ctl(self, ctl: str, now: float, kin: Kin) -> None:
        self._ctl = ctl
        self._t_phase = now
        p = self.params
        hold = kin.pos
        b = base = self._base_target()
        one: Vec3 = (1.0, 1.0, 1.0)
        sp = self._sp
        # The streamed kinds build their target field by field: ``replace`` costs
        # several times more, 50 times a second per vehicle.
        if ctl == "accel":
            tg = ControlTarget(
                sp["a"], ZERO, ZERO, ZERO, 0.0, b.vmax_xy, b.vmax_up, b.vmax_dn,
                b.acc_lim, b.acc_max, b.tau_s,
            )  # fmt: skip
        elif ctl == "vel":
            tg = ControlTarget(
                sp.get("a", ZERO), ZERO, sp["v"], ZERO, 1.0, b.vmax_xy, b.vmax_up, b.vmax_dn,
                b.acc_lim, b.acc_max, b.tau_s,
            )  # fmt: skip
        elif ctl in ("pos", "posvel"):
            self._hold = sp["p"]
            tg = ControlTarget(
                sp.get("a", ZERO), sp["p"], sp.get("v", ZERO), one, 1.0, b.vmax_xy, b.vmax_up,
                b.vmax_dn, b.acc_lim, b.acc_max, b.tau_s,
            )  # fmt: skip
        elif ctl in ("ground", "spool"):
            tg = base
        elif ctl == "fall":
            g = GRAVITY_M_S2
            tg = replace(base, a_ff=(0.0, 0.0, g), acc_lim=g, acc_max=g)
        elif ctl == "brake":
            tg = replace(base, wv=1.0, acc_lim=p["SIM_BRAKE_ACC"])
        elif ctl == "land":
            self._hold = hold
            low = self.home[2] - kin.pos[2] < p["LAND_ALT_LOW"] / 100
            speed = p["LAND_SPEED"] / 100 if low else base.vmax_dn
            tg = replace(base, p_t=hold, v_t=(0.0, 0.0, speed), wp=(1.0, 1.0, 0.0), wv=1.0)
            self._land_low = low
        else:
            if ctl == "takeoff":
                self._hold = (hold[0], hold[1], self._tk_alt_d)
            elif ctl == "rtl_climb":
                self._hold = (hold[0], hold[1], min(hold[2], self.home[2] - p["RTL_ALT"] / 100))
            elif ctl in ("rtl_return", "rtl_loiter"):
                self._hold = (self.home[0], self.home[1], self._hold[2])
            elif ctl != "hold":  # pragma: no cover - programming error
                raise AssertionError(ctl)
            tg = replace(base, p_t=self._hold, wp=one, wv=1.0)
            if ctl == "takeoff":
                tg = replace(tg, acc_lim=p["WPNAV_ACCEL_Z"] / 100)
        if ctl == "brake":
            self._hold = hold
        self.target = tg
        self.version += 1
        if ctl in _MOVING:
            self.deadline = now

    def refresh(self, now: float, kin: Kin) -> None:
        """Re-derive the target after a parameter change (phase timers kept)."""
        t = self._t_phase
        self._set_ctl(self._ctl, now, kin)
        self._t_phase = t

    def _hold_here(self, now: float, kin: Kin) -> None:
        self._hold = kin.pos
        self._set_ctl("hold", now, kin)

    # ---------------------------------------------------------------- timers
    def poll(self, now: float, kin: Kin) -> list[mav.MAVLink_message]:
        """Run timers and transitions due at ``now``; return messages to send."""
        out: list[mav.MAVLink_message] = []
        t = now - self.boot
        p = self.params
        if not self.ekf_ready and t >= p["SIM_EKF_DELAY"]:
            self.ekf_ready = True
            self.home = kin.pos
            out.append(telemetry.gps_global_origin(t, self.origin))
            out.append(telemetry.home_position(t, self.origin, self.home))
            out.append(telemetry.statustext(mav.MAV_SEVERITY_INFO, "EKF3 IMU0 origin set"))
        if now >= self._next_hb - 1e-6:
            out.append(self.heartbeat())
            self._next_hb = max(self._next_hb + 1.0, now + 0.5)
        for msgid, sched in self._streams.items():
            if now >= sched[1] - 1e-6:
                m = self.build(msgid, now, kin)
                if m is not None:
                    out.append(m)
                sched[1] = max(sched[1] + sched[0], now + 0.5 * sched[0])
        out.extend(self._transitions(now, kin))
        self._update_deadline(now)
        return out

    def _transitions(self, now: float, kin: Kin) -> list[mav.MAVLink_message]:
        out: list[mav.MAVLink_message] = []
        p, ctl, el = self.params, self._ctl, now - self._t_phase
        if self.armed and self._last_gcs_hb is not None and p["FS_GCS_ENABLE"] != 0:
            lost = now - self._last_gcs_hb > p["FS_GCS_TIMEOUT"]
            if lost and not self._fs_active and not kin.landed:
                self._fs_active = True
                out.append(telemetry.statustext(mav.MAV_SEVERITY_CRITICAL, "GCS Failsafe"))
                self.set_mode(LAND if p["FS_GCS_ENABLE"] == 5 else RTL, now, kin)
                return out
        if ctl in ("accel", "vel") and now - self._last_sp > self._timeout_s() - 1e-9:
            self._set_ctl("brake", now, kin)  # GUID_TIMEOUT: brake to a hover, mode unchanged
        elif ctl == "brake" and math.sqrt(sum(v * v for v in kin.vel)) < 0.05:
            self._hold_here(now, kin)
        elif ctl == "fall" and kin.landed:
            self._set_ctl("ground", now, kin)
        elif ctl == "spool":
            if el >= p["SIM_TKOFF_DLY"]:
                self._set_ctl("takeoff", now, kin)
        elif ctl == "takeoff" and abs(kin.pos[2] - self._tk_alt_d) < 0.1 and abs(kin.vel[2]) < 0.2:
            self._set_ctl("hold", now, kin)  # holds the takeoff target
        elif ctl == "land":
            low = self.home[2] - kin.pos[2] < p["LAND_ALT_LOW"] / 100
            if kin.landed and el > 0.5:
                self.armed = False  # land complete -> disarm, mode stays
                self.streaming = False
                self._set_ctl("ground", now, kin)
            elif low != self._land_low:
                self._set_ctl("land", now, kin)
                self._t_phase = now - el
        elif ctl == "rtl_climb" and abs(kin.pos[2] - self._hold[2]) < 0.2:
            self._set_ctl("rtl_return", now, kin)
        elif ctl == "rtl_return":
            d = math.hypot(kin.pos[0] - self.home[0], kin.pos[1] - self.home[1])
            if d < 0.5 and math.hypot(kin.vel[0], kin.vel[1]) < 0.2:
                self._set_ctl("rtl_loiter", now, kin)
        elif ctl == "rtl_loiter" and el >= p["RTL_LOIT_TIME"] / 1000:
            self._set_ctl("land", now, kin)
        elif ctl == "ground" and self.armed and p["DISARM_DELAY"] > 0:
            if el >= p["DISARM_DELAY"]:
                self.armed = False  # auto-disarm: no takeoff within DISARM_DELAY
                self.streaming = False
                self.version += 1
        return out

    def _update_deadline(self, now: float) -> None:
        d = self._next_hb
        if not self.ekf_ready:
            d = min(d, self.boot + self.params["SIM_EKF_DELAY"])
        for sched in self._streams.values():
            d = min(d, sched[1])
        ctl = self._ctl
        if ctl in _MOVING:
            d = now
        elif ctl in ("accel", "vel"):
            d = min(d, self._last_sp + self._timeout_s())
        elif ctl == "ground" and self.armed and self.params["DISARM_DELAY"] > 0:
            d = min(d, self._t_phase + self.params["DISARM_DELAY"])
        if self.armed and self._last_gcs_hb is not None and self.params["FS_GCS_ENABLE"] != 0:
            d = min(d, self._last_gcs_hb + self.params["FS_GCS_TIMEOUT"] + 1e-3)
        self.deadline = d

    def gcs_heartbeat(self, now: float) -> None:
        """A GCS HEARTBEAT arrived (feeds the GCS failsafe)."""
        self._last_gcs_hb = now
        self._fs_active = False

    def origin_request_ok(self) -> bool:
        """True when GPS_GLOBAL_ORIGIN can be sent (the EKF has set it)."""
        return self.ekf_ready
