"""A vehicle's start-up, from its first HEARTBEAT to READY (holding at its
start point): streams and parameters (CONFIGURING), GUIDED confirmed by
HEARTBEAT (SETTING_GUIDED), the ground-or-air decision (WAITING_ARMABLE,
``judge_ground``), arming, take-off, the way to the start point and, for
an ``offboard`` autopilot (PX4), the fly mode after a lead of streamed
setpoints. The phases and their rules: vehicle.py's docstring and
mavlink-protocol.md. No I/O; time is an argument.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial

import numpy as np

from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.commands import MAV_RESULT_NAMES
from gcs_swarm.mavlink.coordinates import (
    GeoOrigin,
    mission_to_ned_floats,
    vector_mission_to_ned_floats,
)
from gcs_swarm.mavlink.inbound import GpsGlobalOrigin
from gcs_swarm.mavlink.states import READYING_PHASES, Phase
from gcs_swarm.mavlink.vehicle_base import _vec, _VehicleBase

__all__: list[str] = []


class _Startup(_VehicleBase):
    """CONNECTING -> ... -> READY (module docstring)."""

    def _on_origin(self, msg: GpsGlobalOrigin, now: float) -> None:
        origin = GeoOrigin.from_mavlink(msg.lat_e7, msg.lon_e7, msg.alt_mm)
        self.origin = origin
        self._timers.pop("origin", None)
        self._event(
            "info",
            f"vehicle {self.label}: EKF origin {origin.lat_deg:.7f} {origin.lon_deg:.7f} "
            f"{origin.alt_m:.2f} m",
        )
        self._update_offset()
        self._decide(now)

    def _start_configuring(self, now: float) -> None:
        self._reset()
        self._arm_tries = self._guided_asks = 0
        self.took_over = self._arm_sent = self._yielded = False
        self.landed_state = None
        self._set_phase(Phase.CONFIGURING, now)
        cfg, s, c = self.config, self.sysid, self.compid
        pers = self.personality
        # The status streams go at this vehicle's own phase of their interval
        # (``status_phase``), and what follows them waits with them.
        status_at = now + self.status_phase / cfg.status_rate_hz
        for label, msg_id, hz, at in (
            ("LOCAL_POSITION_NED", b.MSG_ID_LOCAL_POSITION_NED, cfg.control_rate_hz, now),
            *((lb, i, cfg.status_rate_hz, status_at) for lb, i in pers.status_streams),
        ):
            make = partial(b.set_message_interval, s, c, msg_id, 1.0 / hz)
            done: Callable[[int, float], None] = partial(self._refused_if, f"stream {label}")
            if msg_id == b.MSG_ID_EXTENDED_SYS_STATE:
                done = self._landed_stream_acked
            self._commands.push(
                now, f"SET_MESSAGE_INTERVAL {label}", make, done,
                command=b.MAV_CMD_SET_MESSAGE_INTERVAL, not_before=at,
            )  # fmt: skip
        self.vehicle_params.start(now, self._commands, c)  # reads first: the old values
        for name, value, why in pers.station_sets(cfg):
            make = partial(pers.params.param_set, s, c, name, value)
            self._commands.push(  # only its echo answers it, not a late copy of the read
                now, f"PARAM_SET {name}", make, partial(self._param_set, name, why),
                param=name, expect=value,
            )  # fmt: skip
        self._request_origin(now)

    def _refused_if(self, what: str, result: int, now: float) -> None:
        if result != 0:
            self._refused(now, what, result)

    def _landed_stream_acked(self, result: int, now: float) -> None:
        if result != 0:
            verdict = MAV_RESULT_NAMES.get(result, str(result))
            self._event(
                "info",
                f"vehicle {self.label}: no EXTENDED_SYS_STATE stream ({verdict}): on the "
                "ground or in the air is judged from the armed flag and the height",
            )

    def _param_set(self, name: str, why: str, result: int, now: float) -> None:
        value = self.params.get(name, math.nan)
        self._event("param", f"vehicle {self.label}: {name} = {value:g} {why}")
        if not self._commands.busy and self.phase is Phase.CONFIGURING:
            self._after_configuring(now)

    def _after_configuring(self, now: float) -> None:
        hb = self.heartbeat
        if hb is not None and hb.custom_mode == self.personality.ready_mode:
            self._after_guided(now)
        else:
            self._set_phase(Phase.SETTING_GUIDED, now)
            self._send_guided(now)

    def _send_guided(self, now: float) -> None:
        if self._guided_asks >= self.config.guided_attempts:
            self._fail(
                now,
                f"{self.personality.ready_label} not kept: asked {self._guided_asks} times, "
                f"the vehicle is in "
                f"{self.mode_name}",
            )
            return
        self._guided_asks += 1
        pers = self.personality
        make = partial(pers.set_mode, self.sysid, self.compid, pers.ready_mode)
        self._commands.push(
            now, f"set mode {pers.ready_label}", make, self._guided_acked,
            command=b.MAV_CMD_DO_SET_MODE,
        )  # fmt: skip

    def _guided_acked(self, result: int, now: float) -> None:
        self._guided_accepted = result == 0
        if result != 0:
            self._refused(now, self.personality.ready_label, result)
        # Confirm in the next HEARTBEAT (spec step 3); ask again if it does not come.
        self._timers["mode_confirm"] = now + 2 * self.config.command_timeout_s

    def _guided_lost(self, now: float, why: str | None = None) -> None:
        """The autopilot left GUIDED while the vehicle is readied (ArduCopter's
        end-of-boot STABILIZE), or no HEARTBEAT confirmed it (``why``): ask for
        it again, confirm it by HEARTBEAT, then decide afresh; nothing is armed
        or taken off meanwhile."""
        why = why or f"in {self.mode_name} while {self.phase.value}"
        for name in ("arm", "takeoff", "offboard"):
            self._timers.pop(name, None)
        self._set_phase(Phase.SETTING_GUIDED, now)
        if self._guided_asks < self.config.guided_attempts:  # else _send_guided fails it
            # The first loss is routine (ArduCopter's end-of-boot STABILIZE, on
            # every fresh start: docs/mavlink-protocol.md): the log has it; a
            # second one is worth the operator's attention.
            self._event(
                "info" if self._guided_asks == 1 else "warning",
                f"vehicle {self.label}: {why}: asking for {self.personality.ready_label} again "
                f"({self._guided_asks + 1} of at most {self.config.guided_attempts})",
            )
        self._send_guided(now)

    def _guided(self) -> bool:
        """The latest HEARTBEAT says the ready mode (GUIDED; PX4 Hold), or one
        the autopilot may show in this readying phase."""
        hb = self.heartbeat
        if hb is None:
            return False
        if self.phase in READYING_PHASES:
            return self.personality.readying_ok(self.phase, hb.custom_mode)
        return hb.custom_mode == self.personality.ready_mode

    def _after_guided(self, now: float) -> None:
        self._set_phase(Phase.WAITING_ARMABLE, now)
        self._decide(now)

    def _decide(self, now: float) -> None:
        """WAITING_ARMABLE (GUIDED confirmed) -> take-over, take-off or arming,
        from the landed state and height (``judge_ground``), never from the
        armed flag alone."""
        if self.phase is not Phase.WAITING_ARMABLE or self.position is None:
            return
        if self.offset_m is not None:  # the fence, queued before the arming
            self.vehicle_params.home_known(now, self._commands, self.compid, _vec(self.offset_m))
        if not self._guided():
            self._guided_lost(now)
            return
        ground, where = self._ground()
        if not ground:
            # Flying: taken over once it has its origin. Disarmed in the air is
            # never armed; it waits.
            if self.armed and self.offset_m is not None:
                if not self.took_over:
                    self.took_over = True
                    self._event(
                        "info",
                        f"vehicle {self.label} is {where}, armed in {self.mode_name}: "
                        "taking it over without a take-off",
                    )
                self._go_to_start(now)
            return
        self.took_over = False
        if self.offset_m is None:
            return
        if self.armed:
            self._event(
                "info",
                f"vehicle {self.label} is armed {where}: arming is a no-op; "
                "taking off at once (it disarms itself after DISARM_DELAY)",
            )
            self._send_takeoff(now)
            return
        if self.personality.armable(self._health):
            self._set_phase(Phase.ARMING, now)
            self._send_arm(now)

    def _send_arm(self, now: float) -> None:
        if self.phase is not Phase.ARMING:
            return
        if not self._guided():  # confirmed right before every attempt
            self._guided_lost(now)
            return
        self._arm_tries += 1
        self._arm_sent = True
        make = partial(b.arm, self.sysid, self.compid)
        self._commands.push(
            now, "arm", make, self._arm_acked, command=b.MAV_CMD_COMPONENT_ARM_DISARM
        )

    def _arm_acked(self, result: int, now: float) -> None:
        if self.phase is not Phase.ARMING:
            return
        if result == 0:
            self._send_takeoff(now)  # at once: ArduCopter disarms after DISARM_DELAY
            return
        why = self._refused(now, f"arming (attempt {self._arm_tries})", result)
        if self._arm_tries >= self.config.arm_attempts:
            verdict = MAV_RESULT_NAMES.get(result, str(result))
            self._fail(now, f"arming refused {self._arm_tries} times ({verdict}): {why}")
        else:
            self._timers["arm"] = self._commands.last_sent_at + self.config.arm_retry_interval_s

    def _send_takeoff(self, now: float) -> None:
        assert self.position is not None and self.offset_m is not None
        if not self._guided():
            self._guided_lost(now)
            return
        up_now = -self.position.z
        goto_up = float(self._goto_m[2] - self.offset_m[2])
        alt = max(self.config.takeoff_min_alt_m, goto_up - up_now)
        self._takeoff_up_m = up_now + alt
        self._set_phase(Phase.TAKING_OFF, now)
        self._timers["takeoff"] = now + self.config.takeoff_timeout_s
        # PX4 wants the target's altitude AMSL: the EKF origin's plus the height
        # above it (LOCAL_POSITION_NED is relative to that origin).
        amsl = None if self.origin is None else self.origin.alt_m + self._takeoff_up_m
        make = partial(self.personality.takeoff, self.sysid, self.compid, alt, amsl)
        self._commands.push(
            now, f"take-off to {alt:.1f} m", make, self._takeoff_acked,
            command=b.MAV_CMD_NAV_TAKEOFF,
        )  # fmt: skip

    def _takeoff_acked(self, result: int, now: float) -> None:
        if result == 0 or self.phase is not Phase.TAKING_OFF:
            return
        # Decide on the next HEARTBEAT, not on the one we have: it can be up to
        # a second old, and ArduCopter's end of boot (back to STABILIZE) or its
        # DISARM_DELAY may have come since (seen in the emulator: an arm sent
        # 20 ms after the boot's end, a stale GUIDED, and every retry refused).
        self._takeoff_refused = (result, self._refused(now, "take-off", result))

    def _after_takeoff_refusal(self, result: int, why: str, now: float) -> None:
        """The first HEARTBEAT after a refused take-off says GUIDED: re-arm a
        vehicle that disarmed itself, or fail with the autopilot's words."""
        if not self.armed and self.on_ground and self._arm_tries < self.config.arm_attempts:
            # It disarmed itself (DISARM_DELAY) before the take-off came.
            self._timers.pop("takeoff", None)
            self._set_phase(Phase.WAITING_ARMABLE, now)
            what = f"vehicle {self.label}: disarmed before its take-off; arming again"
            self._event("warning", what)
            self._decide(now)
        else:
            verdict = MAV_RESULT_NAMES.get(result, str(result))
            state = "armed" if self.armed else "disarmed"
            self._fail(now, f"take-off refused ({verdict}) in {self.mode_name}, {state}: {why}")

    def _go_to_start(self, now: float) -> None:
        """GOING_TO_START until at the goto point and slow, in the fly mode,
        then READY (holding). An ``offboard`` autopilot (PX4) gets the
        position setpoint streamed for ``offboard_lead_s`` before the fly
        mode is asked: it refuses OFFBOARD without a stream."""
        if self.phase is not Phase.READY:
            if self.phase is not Phase.GOING_TO_START:
                self._set_phase(Phase.GOING_TO_START, now)
                self._fly_asks = 0
                self._arm_fly_mode(now)
            pos, vel = self.state_mission()
            cfg = self.config
            if self._goto_vel is not None:  # a moving point: its velocity, not rest
                vel = vel - self._goto_vel
            if (
                np.linalg.norm(pos - self._goto_m) <= cfg.goto_tolerance_m
                and np.linalg.norm(vel) <= cfg.goto_speed_tolerance_mps
                and self._in_fly_mode()
            ):
                self._set_phase(Phase.READY, now)
        self._answer_hold()

    def _in_fly_mode(self) -> bool:
        hb = self.heartbeat
        return hb is not None and hb.custom_mode == self.personality.fly_mode

    def _arm_fly_mode(self, now: float) -> None:
        """Ask the fly mode ``offboard_lead_s`` from now (PX4, not yet in it)."""
        if self.personality.offboard and not self._in_fly_mode():
            self._timers["offboard"] = now + self.config.offboard_lead_s

    def _send_fly_mode(self, now: float) -> None:
        pers = self.personality
        if self.phase is not Phase.GOING_TO_START or self._in_fly_mode():
            return
        if self._fly_asks >= self.config.guided_attempts:
            self._fail(now, f"{pers.fly_label} not entered: asked {self._fly_asks} times, "
                       f"the vehicle is in {self.mode_name}")  # fmt: skip
            return
        self._fly_asks += 1
        make = partial(pers.set_mode, self.sysid, self.compid, pers.fly_mode)
        self._commands.push(
            now, f"set mode {pers.fly_label}", make, self._fly_mode_acked,
            command=b.MAV_CMD_DO_SET_MODE,
        )  # fmt: skip

    def _fly_mode_acked(self, result: int, now: float) -> None:
        if self.phase is not Phase.GOING_TO_START:
            return
        if result != 0:
            self._refused(now, self.personality.fly_label, result)
            self._arm_fly_mode(now)  # the stream goes on; ask again after the lead
        else:  # confirmed by HEARTBEAT, asked again if none comes
            self._timers["offboard"] = now + 2 * self.config.command_timeout_s

    def _answer_hold(self) -> None:
        """Position setpoint to the goto point, sent in answer to each telemetry
        (with the point's velocity as the feed-forward when it moves)."""
        if self.offset_m is not None:
            ned = mission_to_ned_floats(self._goto_m, self.offset_m)  # at every report
            self.last_accel_ned = np.zeros(3)
            v = self._goto_vel
            if v is None:
                spec = b.position_setpoint(self.sysid, self.compid, self.boot_ms(), ned)
            else:
                vel = vector_mission_to_ned_floats(v)
                spec = b.posvel_setpoint(self.sysid, self.compid, self.boot_ms(), ned, vel)
            self._out.append(spec)
