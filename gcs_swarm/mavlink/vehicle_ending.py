"""A vehicle's ending (``finish``): pending commands dropped, then zero
acceleration and the end mode in the air, a disarm on the ground, each
confirmed by HEARTBEAT and asked again if none comes; a refused end mode
falls back to LAND. vehicle.py's docstring and mavlink-protocol.md.
No I/O; time is an argument.
"""

from __future__ import annotations

from functools import partial

from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.states import Phase
from gcs_swarm.mavlink.vehicle_base import _VehicleBase

__all__: list[str] = []


class _Ending(_VehicleBase):
    """ENDING -> ENDED (module docstring)."""

    def finish(self, now: float, *, mode: int | None = None) -> None:
        """End this vehicle. Every pending command and retry is dropped first
        (no late arm or take-off goes out). In the air: zero acceleration, then
        ``mode`` (default the config's end mode) confirmed by heartbeat. On the
        ground (``on_ground``): disarmed if it is armed or an arm command went
        out (MAV_CMD_COMPONENT_ARM_DISARM 0, which ArduCopter refuses in flight;
        then the end mode follows), confirmed by heartbeat; otherwise it just
        stops being readied. A vehicle someone else took in flight (it left
        GUIDED, or was disarmed) is left alone, as is a failed one on the
        ground with nothing to undo."""
        if self.phase in (Phase.ENDING, Phase.ENDED) or self._yielded:
            return
        self._end_mode = self.personality.end_mode(self.config.end_mode if mode is None else mode)
        ground, _ = self._ground()
        undo = self.armed or self._arm_sent
        if self.phase is Phase.LOST:
            # Best effort, not awaited: it may still hear us. Otherwise its own
            # GUID_TIMEOUT (set short at start-up) brakes it to a hover. Heard
            # again, it is ended then (``_end_returned``), not readied.
            self._end_on_return = True
            if undo and ground:
                self._out.append(b.arm(self.sysid, self.compid, armed=False))
            elif self.armed:
                self._out.append(self.accel_setpoint((0.0, 0.0, 0.0)))
                self._out.append(self.personality.set_mode(self.sysid, self.compid, self._end_mode))
            return
        self._end(now)

    def _end_returned(self, now: float) -> None:
        """A HEARTBEAT of a vehicle lost while (or before) the station ended it:
        ended now as ``finish`` ends one, with the end mode it was given."""
        self._end_on_return = False
        self._event("warning", f"vehicle {self.label} heard again while the station ends it: "
                    "ending it")  # fmt: skip
        self._end(now)

    def _end(self, now: float) -> None:
        """``finish`` of a vehicle that is heard: disarm on the ground, else
        zero acceleration and the end mode."""
        ground, where = self._ground()
        undo = self.armed or self._arm_sent
        self._reset()
        if ground and not undo:
            if self.phase is not Phase.FAILED:
                self._set_phase(Phase.ENDED, now)
            return
        self._set_phase(Phase.ENDING, now)
        if ground:
            self._event("info", f"vehicle {self.label} is {where}: disarming it")
            self._disarming = True
            self._send_disarm(now)
        else:
            self._out.append(self.accel_setpoint((0.0, 0.0, 0.0)))
            self._send_end_mode(now)

    def _send_disarm(self, now: float) -> None:
        make = partial(b.arm, self.sysid, self.compid, armed=False)
        self._commands.push(
            now, "disarm", make, self._disarm_acked,
            command=b.MAV_CMD_COMPONENT_ARM_DISARM, urgent=True,
        )  # fmt: skip

    def _disarm_acked(self, result: int, now: float) -> None:
        if self.phase is not Phase.ENDING or not self._disarming:
            return
        if result != 0:
            # ArduCopter refuses to disarm a vehicle it thinks is flying: end it
            # as one.
            self._refused(now, "disarm", result)
            self._disarming = False
            self._out.append(self.accel_setpoint((0.0, 0.0, 0.0)))
            self._send_end_mode(now)
            return
        # Confirmed by a HEARTBEAT that says disarmed (the ACK may be a late
        # answer to an earlier arm command); asked again if none comes.
        self._timers["end_confirm"] = now + self.config.end_confirm_timeout_s

    def _send_end_mode(self, now: float) -> None:
        make = partial(self.personality.set_mode, self.sysid, self.compid, self._end_mode)
        self._commands.push(
            now, f"set mode {self.personality.mode_name(self._end_mode)}", make,
            self._end_mode_acked,
            command=b.MAV_CMD_DO_SET_MODE, urgent=True,
        )  # fmt: skip

    def _end_mode_acked(self, result: int, now: float) -> None:
        if self.phase is not Phase.ENDING:
            return
        land = self.personality.land_mode
        if result != 0:
            self._refused(now, f"mode {self.personality.mode_name(self._end_mode)}", result)
            if self._end_mode != land:
                self._event("info", f"vehicle {self.label}: falling back to LAND")
                self._end_mode = land
                self._send_end_mode(now)
                return
        hb = self.heartbeat
        if result == 0 and hb is not None and hb.custom_mode == self._end_mode:
            self._set_phase(Phase.ENDED, now)
        else:
            self._timers["end_confirm"] = now + self.config.end_confirm_timeout_s
