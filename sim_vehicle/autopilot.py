"""ArduCopter-like autopilot of one vehicle. NO I/O: decoded messages + ``now`` in, replies out.

Owns mode, arming, boot and EKF readiness, home, the GUIDED setpoint rules,
the GUID_TIMEOUT behaviour, the land detector, auto-disarm, takeoff/land/RTL
sequencing, the GCS failsafe and the fence (rules in ``safety``), parameters
and stream schedules (everything but the vectorised LOCAL_POSITION_NED
stream, whose interval it publishes as ``lpn_interval_s``).

It never touches the dynamics arrays: it publishes a ``ControlTarget`` and
bumps ``version`` whenever that target (or a dynamics parameter) changes; the
emulator's core copies it into the vectorised tracking law (dynamics Eq.
D3); what each control state tracks is built in ``targets``. ``deadline``
is the sim time at which ``poll`` must next run (habit: time is an
argument). READING of the protocol sheet: setpoints are honoured only in
GUIDED, armed and airborne; accel/velocity targets are applied until
GUID_TIMEOUT (floored at 0.1 s as ArduCopter does), then the vehicle brakes to
a hover and stays in GUIDED.

READING of ArduCopter's land detector: docs/emulator.md, "Landing and the land
detector" (``guards.land_detector``); of GUIDED's Accel sub-mode: Eq. D9 there.
"""

from __future__ import annotations

import math
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import commands, guards, reports, telemetry
from sim_vehicle.guards import LAND_DETECT_S
from sim_vehicle.params import ParamStore
from sim_vehicle.targets import ZERO, ControlTarget, TargetBuilder
from sim_vehicle.telemetry import Kin, Vec3

__all__ = ["MODE_NAMES", "Autopilot", "ControlTarget"]

STABILIZE, GUIDED, LOITER, RTL, LAND, BRAKE = 0, 4, 5, 6, 9, 17
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
ACCEPTED, TEMPORARILY_REJECTED, FAILED = 0, 1, 4
"""MAV_RESULT values of the COMMAND_ACKs the hooks answer."""
LPN = mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED
_ACCEL_ONLY = commands.ECHO_MASK["accel"]
"""The echoed type_mask of an acceleration setpoint (3135)."""
_HEARTBEAT = mav.MAVLink_heartbeat_message
_MOVING = {"brake", "takeoff", "land", "rtl_climb", "rtl_return", "rtl_loiter", "spool", "fall"}


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
        self._guid_timeout: tuple[int, float] | None = None  # (params generation, s): _timeout_s
        params.set("SYSID_THISMAV", sysid)
        self.boot = now
        self.mode = GUIDED if airborne_at is not None else 0
        self.armed = airborne_at is not None
        self.ekf_ready = airborne_at is not None or params["SIM_EKF_DELAY"] <= 0.0
        self.booted = airborne_at is not None or params["SIM_BOOT_S"] <= 0.0
        self._boot_end: float | None = None  # first contact + SIM_BOOT_S
        self.land_complete = airborne_at is None
        self.touch: float | None = None  # when an armed vehicle last touched the ground
        self.breaches = 0  # fence bits breached at the last check
        self.home: Vec3 = (airborne_at[0], airborne_at[1], 0.0) if airborne_at else ZERO
        self.yaw = 0.0
        self.version = 0
        self.rejected = 0  # messages refused for non-finite or absurd numbers
        self.streaming = airborne_at is not None  # lockstep rule 2
        self.lpn_interval_s: float | None = None
        self.lpn_kick = False  # the core sends one LOCAL_POSITION_NED at once, then clears it
        self.deadline = now
        self._ctl = "hold" if airborne_at else "ground"
        self.accel_sub = False  # GUIDED's Accel sub-mode: its velocity reference (Eq. D9)
        self.accel_entry: float | None = None  # Eq. D9: entered then, until the core acted
        self.hold_ned: Vec3 = airborne_at or ZERO
        self.sp: dict[str, Any] = {}  # what GUIDED tracks (for the echo)
        self.echo_mask = 3576
        self._last_sp = -math.inf
        self._t_phase = now  # start of the current takeoff/RTL/ground phase
        self._land_low = False
        self._tk_alt_d = 0.0
        self.last_gcs_hb: float | None = None
        self.wall_s: float | None = None
        """Wall-clock time [s] of this call, set by the emulator in lockstep (None in
        real time). The ground station is not sped up with the emulator, so in lockstep
        the GCS failsafe counts FS_GCS_TIMEOUT in wall-clock seconds of silence; in real
        time sim time is the wall clock (times the speed-up, as a sped-up SITL counts it)."""
        self.last_gcs_hb_wall: float | None = None
        self.fs_active = False
        self._streams: dict[int, list[float]] = {}  # msgid -> [interval s, next due]
        for msgid, hz in (streams or {}).items():
            self.set_interval(msgid, 1.0 / hz if hz > 0 else -1.0, now)
        self.target = ControlTarget()
        self._targets = TargetBuilder(params)  # what each control tracks (Eq. D3 inputs)
        self.set_control(self._ctl, now, Kin(self.hold_ned, ZERO, ZERO, airborne_at is None))

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
    def landed_state(self) -> int:
        """MAV_LANDED_STATE as ArduCopter reports it: land complete 1, landing 4 (LAND,
        RTL's descent), taking off 3 (GUIDED take-off), else in air 2."""
        if self.land_complete:
            return 1  # MAV_LANDED_STATE_ON_GROUND
        if self._ctl == "land":
            return 4  # MAV_LANDED_STATE_LANDING
        if self._ctl in ("spool", "takeoff"):
            return 3  # MAV_LANDED_STATE_TAKEOFF
        return 2  # MAV_LANDED_STATE_IN_AIR

    @property
    def mode_name(self) -> str:
        """Copter mode name (``MODE<n>`` for numbers without a name)."""
        return MODE_NAMES.get(self.mode, f"MODE{self.mode}")

    def heartbeat(self) -> mav.MAVLink_message:
        """This vehicle's HEARTBEAT: a function of ``mode`` and ``armed`` only (an
        override too), which the emulator copies into the fleet row when either
        changes (``EmulatorCore.sync``) for its 1 Hz stream."""
        return telemetry.heartbeat(self.mode, self.armed, self.mode in _GUIDED_LIKE)

    # ---------------------------------------------------------------- streams
    def set_interval(self, msgid: int, interval_s: float, now: float) -> bool:
        """SET_MESSAGE_INTERVAL semantics: interval s, 0 default, < 0 off. False:
        unknown id (``reports.set_interval``)."""
        return reports.set_interval(self, msgid, interval_s, now)

    stream_buckets = True  # ArduPilot's buckets (reports.bucket_due); False: first at once
    FLEET_STREAMS = reports.FLEET_STREAMS  # those it may leave to the status path
    fleet_streams: frozenset[int] = frozenset()  # those it does (EmulatorCore.add)

    def interval_of(self, msgid: int) -> float:
        """Current interval in s of ``msgid`` (-1 when not streamed)."""
        if msgid == LPN:
            return self.lpn_interval_s or -1.0
        if msgid == mav.MAVLINK_MSG_ID_HEARTBEAT:
            return 1.0
        return self._streams[msgid][0] if msgid in self._streams else -1.0

    def build(self, msgid: int, now: float, kin: Kin) -> mav.MAVLink_message | None:
        """One instance of a streamable / requestable message, or None if not available."""
        return reports.build(self, msgid, now, kin)

    def heading(self, kin: Kin) -> float:
        """Yaw (rad): the direction of travel when WP_YAW_BEHAVIOR asks for it and it moves."""
        if self.params["WP_YAW_BEHAVIOR"] != 0 and math.hypot(kin.vel[0], kin.vel[1]) > 0.5:
            self.yaw = math.atan2(kin.vel[1], kin.vel[0])
        return self.yaw

    # ------------------------------------------- autopilot-specific replies
    # Hooks of ``commands.dispatch``: ArduCopter's answers here, PX4's in px4.py.
    unknown_stream_result = mav.MAV_RESULT_DENIED
    """COMMAND_ACK result of a SET_MESSAGE_INTERVAL for a message it cannot stream."""

    def mode_command(self, p: tuple[float, ...], now: float, kin: Kin) -> int:
        """MAV_CMD_DO_SET_MODE: p1 CUSTOM_MODE_ENABLED, p2 the Copter mode."""
        custom = int(p[0]) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        ok = custom and self.set_mode(int(p[1]), now, kin)
        return ACCEPTED if ok else FAILED

    def takeoff_params_ok(self, p: tuple[float, ...]) -> bool:
        """The take-off's numbers are usable (ArduCopter: a finite p7)."""
        return math.isfinite(p[6])

    def takeoff_command(self, p: tuple[float, ...], now: float, kin: Kin) -> int:
        """MAV_CMD_NAV_TAKEOFF: p7 altitude above home."""
        ok = self.takeoff(p[6], now, kin)
        return ACCEPTED if ok else FAILED

    def arm_reply(
        self, ok: bool, why: str | None, now: float
    ) -> tuple[int, list[mav.MAVLink_message]]:
        """The ACK result of an arm/disarm and the reasons sent before it
        (ArduCopter: a STATUSTEXT)."""
        reasons = [telemetry.statustext(mav.MAV_SEVERITY_CRITICAL, why)] if why else []
        return (ACCEPTED if ok else FAILED), reasons

    def setpoint_heard(self, now: float) -> None:
        """A SET_POSITION_TARGET_LOCAL_NED for this vehicle arrived (any mode)."""

    # -------------------------------------------------------------- messages
    def handle(self, msg: mav.MAVLink_message, now: float, kin: Kin) -> list[mav.MAVLink_message]:
        """Apply one decoded inbound message; return the replies (unpacked)."""
        out = commands.dispatch(self, msg, now, kin)
        if type(msg) is not _HEARTBEAT:  # one plans only its own (gcs_heartbeat)
            self._replan(now)
        return out

    # ------------------------------------------------------------ transitions
    def set_mode(self, mode: int, now: float, kin: Kin) -> bool:
        """Switch flight mode (any known mode while disarmed, as ArduCopter)."""
        if mode not in MODE_NAMES:
            return False
        self.mode = mode
        self.streaming = False
        self.accel_sub = False  # a mode entered starts its controllers afresh
        if not self.armed:  # a disarmed vehicle never moves on its own
            self.set_control("ground" if kin.landed else "fall", now, kin)
        elif kin.landed:
            self.set_control("ground", now, kin)
            if mode == LAND and self.land_complete:  # LAND on the ground: disarms at once
                self.disarm_landed(now, kin)
        elif mode == LAND:
            self.set_control("land", now, kin)
        elif mode == RTL:
            self.set_control("rtl_climb", now, kin)
        else:
            self.set_control("brake", now, kin)
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
        self.set_control("ground" if kin.landed else "brake", now, kin)
        return True, None

    def disarm(self, now: float, kin: Kin, force: bool) -> tuple[bool, str | None]:
        """Disarm; refused in flight unless forced (the vehicle then falls)."""
        if not self.armed:
            return True, None
        if not kin.landed and not force:
            return False, "Disarm: vehicle is flying, use force"
        self.armed = False
        self.streaming = False
        self.set_control("ground" if kin.landed else "fall", now, kin)
        self.land_complete = kin.landed
        return True, None

    def disarm_landed(self, now: float, kin: Kin) -> None:
        """Disarm on the ground (land complete, failsafe, fence); the mode stays."""
        self.armed = False
        self.streaming = False
        self.land_complete = True
        self.set_control("ground", now, kin)

    def takeoff(self, alt_m: float, now: float, kin: Kin) -> bool:
        """NAV_TAKEOFF: climb to ``alt_m`` above home (GUIDED, armed, on the ground)."""
        if self.mode != GUIDED or not self.armed or not kin.landed or alt_m <= 0.0:
            return False
        self._tk_alt_d = self.home[2] - alt_m
        self.set_control("spool", now, kin)
        return True

    def stop(self, now: float, kin: Kin) -> None:
        """GUIDED 'init': brake to a stop and hold (invalid setpoint, unsupported frame)."""
        self.sp = {}
        self.echo_mask = 3576
        self.accel_sub = False
        self.set_control("brake", now, kin)

    def apply_setpoint(
        self, kind: str, sp: dict[str, Any], mask: int, now: float, kin: Kin
    ) -> None:
        """Track a GUIDED target: kind in accel, vel, pos, posvel (already in local NED)."""
        self.sp = sp
        self.echo_mask = mask
        self.streaming = True
        if kind in ("accel", "vel"):
            self._last_sp = now
            self.deadline = min(self.deadline, now + self._timeout_s())
        self.set_control(kind, now, kin)

    def stream_accel(self, a: Vec3, now: float) -> None:
        """The station's streamed acceleration setpoint ``a`` (local NED), checked by
        ``commands.stream_accel_fields``: ``setpoint_heard(now)`` then
        ``apply_setpoint("accel", {"a": a}, ECHO_MASK["accel"], now, kin)`` with the calls
        written out (an accel target reads nothing of ``kin``; 50 times a second
        per vehicle). An autopilot that hears or applies setpoints otherwise
        overrides it (``px4``); tests/sim_vehicle/test_stream_accel.py holds both
        to ``dispatch`` bit for bit."""
        self.sp = {"a": a}
        self.echo_mask = _ACCEL_ONLY
        self.streaming = True
        self._last_sp = now
        due = now + self._timeout_s()
        if due < self.deadline:  # min(deadline, due), as apply_setpoint
            self.deadline = due
        # set_control("accel", now, kin): the hold point stays, "accel" is not moving
        if not self.accel_sub:
            self._enter_accel(now)
        self._ctl = "accel"
        self._t_phase = now
        self.target = self._targets.accel(a)
        self.version += 1

    def stream_deferrable(self) -> bool:
        """True when a streamed acceleration setpoint (``stream_accel``) would
        change nothing of this autopilot but ``sp``, ``_last_sp``, ``_t_phase``,
        the target's a_ff and ``version``: GUIDED, armed, flying "accel" from a
        stream, and a deadline no later setpoint can lower (``now`` only grows,
        so ``min(deadline, now + GUID_TIMEOUT)`` keeps it). The emulator may then
        hold such setpoints and call only for the last one (docs/emulator.md,
        the deferred lane): each call overwrites what the one before set."""
        flying = self.mode == GUIDED and self.armed and self.streaming
        stream = self._ctl == "accel" and self.echo_mask == _ACCEL_ONLY
        return flying and stream and self.deadline <= self._last_sp + self._timeout_s()

    def _timeout_s(self) -> float:
        """GUID_TIMEOUT [s], at least 0.1 (read again only after a parameter
        changed: every streamed setpoint asks for it)."""
        p = self.params
        cached = self._guid_timeout
        if cached is None or cached[0] != p.generation:
            cached = self._guid_timeout = (p.generation, max(p["GUID_TIMEOUT"], 0.1))
        return cached[1]

    def set_control(self, ctl: str, now: float, kin: Kin) -> None:
        """Fly ``ctl`` from ``now``: its target (``targets.TargetBuilder``) replaces the
        published one (``version`` bumped); a moving phase is polled at once."""
        if ctl not in ("accel", "brake", "hold"):  # GUID_TIMEOUT's brake and hold keep it
            self.accel_sub = False
        elif ctl == "accel" and not self.accel_sub:
            self._enter_accel(now)
        self._ctl = ctl
        self._t_phase = now
        tg, self.hold_ned, low = self._targets.target(
            ctl, kin, self.sp, self.hold_ned, self.home, self._tk_alt_d
        )
        if low is not None:
            self._land_low = low
        self.target = tg
        self.version += 1
        if ctl in _MOVING:
            self.deadline = now

    VEL_REFERENCE = True  # Eq. D9 applies (ArduCopter; not PX4's OFFBOARD acceleration)

    def _enter_accel(self, now: float) -> None:
        """Eq. D9: GUIDED's Accel sub-mode starts its velocity reference at the
        reported velocity, whose bias the core adds to the vehicle's (``schedule.enter_accel``)."""
        self.accel_sub = True
        self.accel_entry = now

    def refresh(self, now: float, kin: Kin) -> None:
        """Re-derive the target after a parameter change (phase timers kept)."""
        t = self._t_phase
        self.set_control(self._ctl, now, kin)
        self._t_phase = t
        self._replan(now)

    def _hold_here(self, now: float, kin: Kin) -> None:
        self.hold_ned = kin.pos
        self.set_control("hold", now, kin)

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
        out.extend(guards.land_detector(self, now, kin))
        if self._boot_end is not None and not self.booted and now >= self._boot_end - 1e-9:
            # SITL measured: GUIDED accepted at once, then ~1 s later boot ends and the
            # vehicle is back in STABILIZE (HEARTBEAT custom_mode 0).
            self.booted = True
            out.append(telemetry.statustext(mav.MAV_SEVERITY_INFO, "ArduPilot Ready"))
            if not self.armed and self.mode != STABILIZE:
                self.set_mode(STABILIZE, now, kin)
        for msgid, sched in self._streams.items():
            if now >= sched[1] - 1e-6:
                m = self.build(msgid, now, kin)
                if m is not None:
                    out.append(m)
                sched[1] = reports.next_due(sched, now)
        out.extend(self._transitions(now, kin))
        self._update_deadline(now)
        return out

    def _transitions(self, now: float, kin: Kin) -> list[mav.MAVLink_message]:
        out = guards.safety_checks(self, now, kin)
        if out:
            return out
        p, ctl, el = self.params, self._ctl, now - self._t_phase
        if ctl in ("accel", "vel") and now - self._last_sp > self._timeout_s() - 1e-9:
            self.set_control("brake", now, kin)  # GUID_TIMEOUT: brake to a hover, mode unchanged
        elif ctl == "brake" and math.sqrt(sum(v * v for v in kin.vel)) < 0.05:
            self._hold_here(now, kin)
        elif ctl == "fall" and kin.landed:
            self.set_control("ground", now, kin)
        elif ctl == "spool":
            if el >= p["SIM_TKOFF_DLY"]:
                self.set_control("takeoff", now, kin)
        elif ctl == "takeoff" and abs(kin.pos[2] - self._tk_alt_d) < 0.1 and abs(kin.vel[2]) < 0.2:
            self.set_control("hold", now, kin)  # holds the takeoff target
        elif ctl == "land":  # touchdown: the land detector disarms
            low = self.home[2] - kin.pos[2] < p["LAND_ALT_LOW"] / 100
            if low != self._land_low:
                self.set_control("land", now, kin)
                self._t_phase = now - el
        elif ctl == "rtl_climb" and abs(kin.pos[2] - self.hold_ned[2]) < 0.2:
            self.set_control("rtl_return", now, kin)
        elif ctl == "rtl_return":
            d = math.hypot(kin.pos[0] - self.home[0], kin.pos[1] - self.home[1])
            if d < 0.5 and math.hypot(kin.vel[0], kin.vel[1]) < 0.2:
                self.set_control("rtl_loiter", now, kin)
        elif ctl == "rtl_loiter" and el >= p["RTL_LOIT_TIME"] / 1000:
            self.set_control("land", now, kin)
        elif ctl == "ground" and self.armed and p["DISARM_DELAY"] > 0:
            if el >= p["DISARM_DELAY"]:
                self.armed = False  # auto-disarm: no takeoff within DISARM_DELAY
                self.streaming = False
                self.version += 1
        return out

    def _replan(self, now: float) -> None:
        """The deadline no later than the state now asks (after a message or a
        parameter changed it: an auto-disarm, the GCS failsafe, the fence)."""
        d = self.deadline
        self._update_deadline(now)
        self.deadline = min(d, self.deadline)

    def _update_deadline(self, now: float) -> None:
        d = math.inf  # the 1 Hz HEARTBEAT is the emulator's stream (schedule), not a poll
        if not self.ekf_ready:
            d = min(d, self.boot + self.params["SIM_EKF_DELAY"])
        d = min(d, reports.first_due(self, status_path=False))  # not the status path's
        if self._boot_end is not None and not self.booted:
            d = min(d, self._boot_end)
        if self.touch is not None and self.armed and not self.land_complete:
            d = min(d, self.touch + LAND_DETECT_S)
        ctl = self._ctl
        if ctl in _MOVING or (self.armed and self.params["FENCE_ENABLE"] != 0):
            d = now
        elif ctl in ("accel", "vel"):
            d = min(d, self._last_sp + self._timeout_s())
        elif ctl == "ground" and self.armed and self.params["DISARM_DELAY"] > 0:
            d = min(d, self._t_phase + self.params["DISARM_DELAY"])
        self.deadline = min(d, guards.gcs_due(self, now))

    def contact(self, now: float) -> None:
        """A ground station was first heard (or connected): boot ends SIM_BOOT_S later,
        as SITL's does about 1 s after its first connection."""
        if self._boot_end is None and not self.booted:
            self._boot_end = now + max(self.params["SIM_BOOT_S"], 0.0)
            self.deadline = min(self.deadline, self._boot_end)

    def gcs_heartbeat(self, now: float) -> list[mav.MAVLink_message]:
        """A HEARTBEAT from SYSID_MYGCS arrived (feeds the GCS failsafe, whose
        check it plans: ``handle`` plans nothing else for a HEARTBEAT)."""
        self.last_gcs_hb = now
        self.last_gcs_hb_wall = self.wall_s
        self.deadline = min(self.deadline, guards.gcs_due(self, now))
        if self.fs_active:
            self.fs_active = False
            return [telemetry.statustext(mav.MAV_SEVERITY_WARNING, "GCS Failsafe Cleared")]
        return []

    def origin_request_ok(self) -> bool:
        """True when GPS_GLOBAL_ORIGIN can be sent (the EKF has set it)."""
        return self.ekf_ready
