"""The per-vehicle protocol state machine: start-up, hold, setpoints, ending.

No I/O and no clock of its own (STYLE.md habit 1): every entry point takes
``now`` [s, station monotonic time]; ``next_deadline()`` says when
``handle_timer(now)`` wants to be called; outbound messages are
``MessageSpec`` data collected with ``take_outbound()`` and events for the
log with ``take_events()``.

Phases follow the start-up sequence of mavlink-protocol.md:

    CONNECTING -> CONFIGURING (streams, GUID_TIMEOUT, WP_YAW_BEHAVIOR)
      -> SETTING_GUIDED -> WAITING_ARMABLE -> ARMING -> TAKING_OFF
      -> GOING_TO_START (position setpoints) -> READY (holding)
      -> FLYING (the station streams acceleration setpoints)
      -> ENDING (zero acceleration + end mode) -> ENDED
    WAITING_ARMABLE..GOING_TO_START -> SETTING_GUIDED (the autopilot left GUIDED)
    any -> LOST (heartbeat or telemetry stale) -> CONFIGURING on the next heartbeat
      (-> ENDING instead when it was lost while, or before, the station ended it)
    any -> FAILED (refused too often, or someone else took the vehicle)

GUIDED is confirmed by HEARTBEAT before arming and asked again (at most
``guided_attempts`` times) whenever the autopilot leaves it while the vehicle
is readied: a freshly booted ArduCopter returns to STABILIZE about 1 s after
the first GUIDED. Take-off or take-over is decided from the landed state
(EXTENDED_SYS_STATE, else the armed flag and the height: ``judge_ground``),
never from the armed flag: in the air, armed, in GUIDED is taken over (no
arming, no take-off); armed on the ground takes off at once.
Every command is awaited (COMMAND_ACK or PARAM_VALUE), resent on timeout up
to ``ProtocolConfig.command_attempts`` times; arming is retried every
``arm_retry_interval_s`` (spec: 2 s) and each refusal is reported with the
result and the STATUSTEXT heard while that command was pending
(``refusal_reason``). ``finish`` drops every pending command and retry, then
disarms a vehicle on the ground and gives one in the air the end mode.

The parts: the state, queries and phase change (vehicle_base.py), the
start-up to READY (vehicle_startup.py), the ending (vehicle_ending.py), and
here what comes in (messages, timers) and the flight. While FLYING with the
station's telemetry table, the vehicle's reports are written there and this
protocol hears only those the table does not take, the rate window and the
watchdog (telemetry_table.py); without one, ``handle_message`` takes them
all (the reference path the table is tested against).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.accel_clip import ACCEL_CEILING_MPS2, clip_accel_ned
from gcs_swarm.mavlink.coordinates import GeoOrigin
from gcs_swarm.mavlink.events import describe as describe_event
from gcs_swarm.mavlink.inbound import (
    CommandAck,
    EkfStatus,
    Event,
    ExtendedSysState,
    GpsGlobalOrigin,
    GpsRaw,
    Heartbeat,
    Inbound,
    LocalPositionNed,
    ParamValue,
    PositionTarget,
    StatusText,
    SysStatus,
    plausible,
)
from gcs_swarm.mavlink.states import (
    FINAL_PHASES,
    IDLE_PHASES,
    LANDED_STATE_NAMES,
    READYING_PHASES,
    TELEMETRY_PHASES,
    Phase,
)
from gcs_swarm.mavlink.telemetry_table import RATE_WINDOW_MS, REBOOT_MS, TelemetryTable
from gcs_swarm.mavlink.vehicle_ending import _Ending
from gcs_swarm.mavlink.vehicle_startup import _Startup

__all__ = ["ACCEL_CEILING_MPS2", "RATE_WINDOW_MS", "VehicleProtocol", "clip_accel_ned"]

FloatArray = npt.NDArray[np.float64]

RATE_LOW_FRACTION = 0.8
"""A window whose LOCAL_POSITION_NED rate is below this fraction of the
mission rate is low: the interval is asked again (MAV_CMD_SET_MESSAGE_INTERVAL)."""
RATE_WARN_WINDOWS = 2
"""Consecutive low windows after which the rate "stays low": one warning."""


class VehicleProtocol(_Startup, _Ending):
    """The protocol state of one vehicle (system id ``sysid``).

    ``goto_m`` is where the vehicle goes after take-off, in the mission frame
    [m]; the station may move it with ``set_goto`` (a vehicle readied again
    flies to its rejoin point beside the moving leader, at its velocity).
    """

    def enable(self, now: float) -> None:
        """Start readying a vehicle created with ``enabled=False`` (held back
        by its owner), or one that ended, from its next HEARTBEAT."""
        self.enabled = True
        if self.phase in FINAL_PHASES:
            self.phase = Phase.CONNECTING
            self.failure = None
        if self.phase is Phase.CONNECTING and self.heartbeat is not None:
            self._start_configuring(now)

    def set_reference(self, reference: GeoOrigin) -> None:
        """Fix the mission origin when it is learnt at run time (``first-vehicle``
        with a real first vehicle): offsets exist only once it is known."""
        self.reference = reference
        self._update_offset()

    def set_goto(
        self,
        goto_m: tuple[float, float, float] | FloatArray,
        vel_mps: tuple[float, float, float] | FloatArray | None = None,
    ) -> None:
        """Move the mission-frame point [m] the vehicle flies to before the law;
        ``vel_mps`` [m/s]: the point's own velocity (a rejoin point carried
        by the moving leader), None at rest. A moving point is flown with its
        velocity as the feed-forward (``builders.posvel_setpoint``), and the
        vehicle is READY at it when its velocity matches the point's within
        the speed tolerance, so a vehicle rejoins a moving formation."""
        self._goto_m = np.asarray(goto_m, dtype=np.float64)
        self._goto_vel = None if vel_mps is None else np.asarray(vel_mps, dtype=np.float64)

    def begin_flying(self, now: float, table: TelemetryTable | None = None) -> None:
        """READY -> FLYING: from now on the station streams acceleration
        setpoints. With a ``table`` the vehicle's reports go to its row there
        until it leaves FLYING (telemetry_table.py); without one they come
        through ``handle_message`` (the reference path)."""
        if self.phase is not Phase.READY:
            raise RuntimeError(f"vehicle {self.label} is {self.phase.value}, not ready")
        self._set_phase(Phase.FLYING, now)
        self._rate_t0_ms = None
        self._rate_lows = 0
        if table is not None:
            self._slot = table.attach(self)
            self._table = table

    def handle_message(self, msg: Inbound, now: float) -> None:
        """Feed one decoded message from this vehicle."""
        if msg.sysid != self.sysid:
            return
        if not plausible(msg):
            self.rejected_values += 1  # never reaches the law; the vehicle goes stale
            return
        self._heard_at = now
        if isinstance(msg, Heartbeat):
            self._on_heartbeat(msg, now)
        elif isinstance(msg, LocalPositionNed):
            self._on_position(msg, now)
        elif isinstance(msg, CommandAck):
            self._commands.on_ack(msg.command, msg.result, now)
        elif isinstance(msg, StatusText):
            self._commands.note_text(msg.severity, msg.text)
            self._event("statustext", f"vehicle {self.label} says: {msg.text}")
        elif isinstance(msg, Event):
            # PX4's reasons (an arming refusal has no STATUSTEXT): a reason like any.
            text = describe_event(msg.event_id, msg.log_levels, msg.arguments)
            self._commands.note_text(msg.log_levels & 0x0F, text)
            self._event("statustext", f"vehicle {self.label} event: {text}")
        elif isinstance(msg, SysStatus):
            self._health.sys_health = msg.health
            self._decide(now)
            self._seen(msg)
        elif isinstance(msg, GpsGlobalOrigin):
            self._on_origin(msg, now)
        elif isinstance(msg, EkfStatus):
            self._health.ekf_flags = msg.flags
            self._decide(now)
            self._seen(msg)
        elif isinstance(msg, GpsRaw):
            self._health.gps_fix = msg.fix_type
            self._decide(now)
            self._seen(msg)
        elif isinstance(msg, ExtendedSysState):
            known = msg.landed_state in LANDED_STATE_NAMES
            self.landed_state = msg.landed_state if known else None
            self._decide(now)
            self._seen(msg)
        elif isinstance(msg, ParamValue):
            value = self.personality.param_value(msg)
            self.params[msg.name] = value
            self._commands.on_param(msg.name, now, value)
        elif isinstance(msg, PositionTarget):
            self.target_echo = msg

    def _seen(self, msg: SysStatus | EkfStatus | GpsRaw | ExtendedSysState) -> None:
        """A status message handled: while FLYING (its table row attached:
        only then), the same one again changes nothing here but the time it
        was heard, which the row keeps from now on (``TelemetryTable.unchanged``)."""
        if self._table is not None:
            self._table.message_seen(self._slot, msg)

    def _observe(self, pos: LocalPositionNed) -> None:
        obs = self.velocity_bias
        obs.update(pos.time_boot_ms * 1e-3, pos.x, pos.y, pos.z, pos.vx, pos.vy, pos.vz)

    def _count_report(self, ms: int) -> None:
        """Telemetry-rate watch in flight (issue 15): reports are counted over
        windows of ``RATE_WINDOW_MS`` of the vehicle's own clock (so lockstep
        and load do not matter). rate = reports after the window's first /
        elapsed vehicle time. The telemetry table counts its rows the same
        way (``TelemetryTable.write``)."""
        t0 = self._rate_t0_ms
        if t0 is None or ms < t0:
            self._rate_t0_ms, self._rate_n = ms, 0
            return
        self._rate_n += 1
        if ms - t0 < RATE_WINDOW_MS:
            return
        rate = self._rate_n / ((ms - t0) * 1e-3)
        self._rate_t0_ms, self._rate_n = ms, 0
        self.rate_window(rate)

    def rate_window_queues(self, rate: float) -> bool:
        """Whether ``rate_window(rate)`` would queue something (return True),
        changing nothing: a low window, or the first good one after low ones."""
        return self.rate_low or not rate >= RATE_LOW_FRACTION * self.config.control_rate_hz

    def rate_window(self, rate: float) -> bool:
        """A window of the telemetry-rate watch ended at ``rate`` [Hz]. A low
        window asks for the mission rate again; ``RATE_WARN_WINDOWS`` low ones
        in a row raise one warning. True if something was queued
        (``rate_window_queues``, asked before)."""
        queues = self.rate_window_queues(rate)
        self.telemetry_rate_hz = rate
        self.telemetry_rate_min_hz = min(self.telemetry_rate_min_hz, rate)
        want = self.config.control_rate_hz
        if rate >= RATE_LOW_FRACTION * want:
            was_low = self.rate_low
            if was_low:
                self._event("info", f"vehicle {self.label}: LOCAL_POSITION_NED back at "
                                    f"{rate:.1f} Hz")  # fmt: skip
            self.rate_low, self._rate_lows = False, 0
            return queues
        self._rate_lows += 1
        self.rate_requests += 1
        # Not awaited: asked again every low window (MAVProxy, for one, lowers
        # the rate again every 15 s); the ACK, if any, matches no pending command.
        self._out.append(
            b.set_message_interval(self.sysid, self.compid, b.MSG_ID_LOCAL_POSITION_NED, 1 / want)
        )
        if self._rate_lows >= RATE_WARN_WINDOWS and not self.rate_low:
            self.rate_low = True
            self._event(
                "warning",
                f"vehicle {self.label}: LOCAL_POSITION_NED at {rate:.1f} Hz, below the mission "
                f"rate {want:g} Hz for {self._rate_lows * RATE_WINDOW_MS / 1000:g} s; interval "
                "asked again (a router lowering the stream rate?)",
            )
        return queues

    def handle_timer(self, now: float) -> None:
        """Do whatever is due at ``now``: resends, retries, stale checks."""
        cfg = self.config
        if self.phase not in IDLE_PHASES:
            if now >= self._silent_since() + cfg.heartbeat_timeout_s:
                self._lose(now, f"no HEARTBEAT or other message for {cfg.heartbeat_timeout_s:g} s")
                return
            if self.phase in TELEMETRY_PHASES and now >= self.position_at + cfg.stale_timeout_s:
                self._lose(now, f"no LOCAL_POSITION_NED for {cfg.stale_timeout_s:g} s")
                return
        self._commands.handle_timer(now)
        if self._commands.failed is not None:
            self._fail(now, self._commands.failed)
            return
        for name, due in sorted(self._timers.items(), key=lambda kv: kv[1]):
            if now >= due and self._timers.get(name) == due:
                del self._timers[name]
                self._on_timer(name, now)

    def _on_timer(self, name: str, now: float) -> None:
        if name == "origin" and self.origin is None:
            self._request_origin(now)
        elif name == "arm":
            self._send_arm(now)
        elif name == "mode_confirm":
            self._guided_lost(
                now, f"no HEARTBEAT in {self.personality.ready_label} since it was asked"
            )
        elif name == "offboard":
            self._send_fly_mode(now)
        elif name == "takeoff":
            self._fail(now, f"take-off not complete after {self.config.takeoff_timeout_s:g} s")
        elif name == "end_confirm":
            if self._disarming:
                self._send_disarm(now)
            else:
                self._send_end_mode(now)

    def _on_heartbeat(self, hb: Heartbeat, now: float) -> None:
        if not hb.is_autopilot:
            return
        self.heartbeat = hb
        self.compid = hb.compid
        self._hb_at = now
        phase = self.phase
        if phase in (Phase.CONNECTING, Phase.LOST):
            if phase is Phase.LOST and self._end_on_return:
                self._end_returned(now)
            elif self.enabled:
                self._start_configuring(now)
        elif phase is Phase.SETTING_GUIDED and "mode_confirm" in self._timers:
            if hb.custom_mode == self.personality.ready_mode:
                del self._timers["mode_confirm"]
                self._after_guided(now)
            elif self._guided_accepted:
                # Sent after the accepting ACK, so it shows what became of it:
                # the autopilot left GUIDED again (end of boot): ask at once.
                del self._timers["mode_confirm"]
                label = self.personality.ready_label
                self._guided_lost(now, f"in {self.mode_name} after {label} was accepted")
        elif phase in READYING_PHASES:
            refused, self._takeoff_refused = self._takeoff_refused, None
            if not self.personality.readying_ok(phase, hb.custom_mode):
                self._guided_lost(now)  # then take off again, armed or not
            elif refused is not None and phase is Phase.TAKING_OFF:
                self._after_takeoff_refusal(*refused, now)
            elif phase is Phase.GOING_TO_START and self.personality.offboard:
                if self._in_fly_mode():
                    self._timers.pop("offboard", None)
                elif "offboard" not in self._timers and not self._commands.busy:
                    self._arm_fly_mode(now)  # it left OFFBOARD before READY: again
        elif phase in (Phase.READY, Phase.FLYING):
            if hb.custom_mode != self.personality.fly_mode:
                label = self.personality.fly_label
                self._yield(now, f"left {label} (now {self.mode_name}): someone else has it")
            elif not hb.armed:
                self._yield(now, "disarmed in flight")
            elif self._table is not None:
                # Flying on: the same HEARTBEAT again changes nothing here but the
                # time it was heard, which its table row keeps from now on.
                self._table.message_seen(self._slot, hb)
        elif phase is Phase.ENDING and "end_confirm" in self._timers:
            done = not hb.armed if self._disarming else hb.custom_mode == self._end_mode
            if done:
                del self._timers["end_confirm"]
                self._set_phase(Phase.ENDED, now)

    def _on_position(self, pos: LocalPositionNed, now: float) -> None:
        last = self.position
        if (
            self.phase is Phase.FLYING
            and last is not None
            and 0 <= last.time_boot_ms - pos.time_boot_ms < REBOOT_MS
        ):
            # A duplicated or reordered frame: the law keeps the newest state and
            # answers each telemetry once.
            self.stale_telemetry += 1
            return
        self.position = pos
        self.position_at = now
        self._observe(pos)
        phase = self.phase
        if phase is Phase.FLYING:
            self._count_report(pos.time_boot_ms)
        if phase is Phase.TAKING_OFF:
            # Done within 5 % (at least 0.5 m): measured, 9.5 m of 10 m after 9.4 s.
            if -pos.z >= self._takeoff_up_m - max(0.5, 0.05 * abs(self._takeoff_up_m)):
                self._timers.pop("takeoff", None)
                self._go_to_start(now)
        elif phase in (Phase.GOING_TO_START, Phase.READY):
            self._go_to_start(now)
        elif phase is Phase.ENDING and not self._disarming:
            # Zero acceleration answers every telemetry until the mode is confirmed.
            self._out.append(self.accel_setpoint((0.0, 0.0, 0.0)))
        elif phase is Phase.WAITING_ARMABLE:
            self._decide(now)
