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
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial

import numpy as np
import numpy.typing as npt

from gcs_swarm.control.params import Envelope
from gcs_swarm.control.velocity_bias import VelocityBiasObserver
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.codec import MessageSpec
from gcs_swarm.mavlink.commands import MAV_RESULT_NAMES, CommandQueue, refusal_reason
from gcs_swarm.mavlink.coordinates import (
    GeoOrigin,
    mission_to_ned,
    origin_offset_m,
)
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
from gcs_swarm.mavlink.personality import Health, Personality
from gcs_swarm.mavlink.states import (
    FINAL_PHASES,
    IDLE_PHASES,
    LANDED_STATE_NAMES,
    READYING_PHASES,
    TELEMETRY_PHASES,
    Phase,
    ProtocolConfig,
    ProtocolEvent,
    judge_ground,
)
from gcs_swarm.mavlink.vehicle_params import ParamSettings, VehicleParams

__all__ = ["ACCEL_CEILING_MPS2", "VehicleProtocol", "clip_accel_ned"]

ACCEL_CEILING_MPS2 = 1000.0
"""Largest acceleration setpoint sent [m/s^2] (about 100 g): beyond any
multicopter, far inside float32, and above every figure of the paper."""

FloatArray = npt.NDArray[np.float64]

RATE_WINDOW_MS = 2000
"""Telemetry-rate window [ms of the vehicle's own time_boot_ms] (issue 15)."""
RATE_LOW_FRACTION = 0.8
"""A window whose LOCAL_POSITION_NED rate is below this fraction of the
mission rate is low: the interval is asked again (MAV_CMD_SET_MESSAGE_INTERVAL)."""
RATE_WARN_WINDOWS = 2
"""Consecutive low windows after which the rate "stays low": one warning."""

_REBOOT_MS = 10_000
"""Telemetry older than the last by more than this is a reboot, not a reorder."""
_FLYING = Phase.FLYING


class VehicleProtocol:
    """The protocol state of one vehicle (system id ``sysid``).

    ``goto_m`` is where the vehicle goes after take-off, in the mission frame
    [m]; the station may move it with ``set_goto`` (joiners chase the leader).
    """

    def __init__(
        self,
        sysid: int,
        config: ProtocolConfig,
        *,
        goto_m: tuple[float, float, float],
        enabled: bool = True,
        params: ParamSettings | None = None,
        personality: Personality | None = None,
    ) -> None:
        if personality is None:
            from gcs_swarm.mavlink.ardupilot import ARDUPILOT

            personality = ARDUPILOT
        self.personality = personality
        """The autopilot's own modes, commands and rules (personality.py)."""
        self.sysid = sysid
        self.enabled = enabled
        self.config = config
        self.phase = Phase.CONNECTING
        self.compid = 1
        self.heartbeat: Heartbeat | None = None
        self.position: LocalPositionNed | None = None
        self.position_at = -math.inf
        self.target_echo: PositionTarget | None = None
        self.origin: GeoOrigin | None = None
        self.reference: GeoOrigin | None = config.mission_origin
        self.offset_m: FloatArray | None = None
        self.last_accel_ned: FloatArray = np.zeros(3)
        self.failure: str | None = None
        self.took_over = False
        """Found flying (in the air, armed, GUIDED): readied without a take-off."""
        self.landed_state: int | None = None
        """EXTENDED_SYS_STATE.landed_state when it says something, else None."""
        self.clipped_setpoints = 0
        """Acceleration setpoints scaled to ACCEL_CEILING_MPS2 or zeroed (NaN)."""
        self.rejected_values = 0
        """Messages refused for implausible numbers (NaN, 1e30 m, ...)."""
        self.stale_telemetry = 0
        """LOCAL_POSITION_NED not newer than the last one (duplicated or reordered)."""
        self.velocity_bias = VelocityBiasObserver(config.velocity_bias)
        """The bias of the reported velocity (NED), from every accepted report."""
        self.vel_correction_ned: tuple[float, float, float] = (0.0, 0.0, 0.0)
        """Subtracted from the reported velocity before the law sees it."""
        self.params: dict[str, float] = {}
        self.telemetry_rate_hz: float | None = None
        """LOCAL_POSITION_NED per second of vehicle time over the last window, in flight."""
        self.telemetry_rate_min_hz = math.inf
        """Lowest windowed rate in flight [Hz] (inf before the first window)."""
        self.rate_requests = 0
        """SET_MESSAGE_INTERVAL re-sent in flight because the rate was low."""
        self.rate_low = False
        """The rate has stayed low for ``RATE_WARN_WINDOWS`` windows (until one is not)."""
        self._rate_t0_ms: int | None = None
        self._rate_n = 0
        self._rate_lows = 0
        self._goto_m = np.asarray(goto_m, dtype=np.float64)
        self._hb_at = -math.inf
        self._heard_at = -math.inf
        """Last message of any kind: the link watchdog (a lost HEARTBEAT with
        telemetry still flowing is a lossy link, not a lost vehicle)."""
        self._health = Health()
        self._guided_asks = 0
        self._guided_accepted = False
        self._arm_sent = False
        """An arm command went out since the readying began (it may still land)."""
        self._yielded = False
        """Someone else took the vehicle in flight: the station leaves it alone."""
        self._disarming = False
        self._out: list[MessageSpec] = []
        self._events: list[ProtocolEvent] = []
        self._commands = CommandQueue(
            self._out, timeout_s=config.command_timeout_s, attempts=config.command_attempts
        )
        self._timers: dict[str, float] = {}
        self._arm_tries = 0
        self._fly_asks = 0
        self._takeoff_refused: tuple[int, str] | None = None
        """(MAV_RESULT, reason) of a refused take-off, decided on the next HEARTBEAT."""
        self._takeoff_up_m = 0.0
        self._end_mode = config.end_mode
        self.vehicle_params = VehicleParams(
            sysid, params or ParamSettings(), self.params, self._event,
            station_sets={n: v for n, v, _ in personality.station_sets(config)},
            profile=personality.params,
        )  # fmt: skip
        """Envelope read, failsafe and fence set, old values restored (vehicle_params.py)."""

    # ----------------------------------------------------------------- queries
    @property
    def mode_name(self) -> str:
        hb = self.heartbeat
        return "-" if hb is None else self.personality.mode_name(hb.custom_mode)

    @property
    def armed(self) -> bool:
        return self.heartbeat is not None and self.heartbeat.armed

    @property
    def envelope(self) -> Envelope:
        """What this vehicle's position controller delivers (read at start-up)."""
        return self.vehicle_params.envelope

    @property
    def restoring(self) -> bool:
        """True while an ended vehicle's old parameter values are being put back."""
        return self.phase in FINAL_PHASES and self._commands.busy

    @property
    def on_ground(self) -> bool:
        """On the ground by the landed state, or the armed flag and height."""
        return self._ground()[0]

    def _ground(self) -> tuple[bool, str]:
        height = None if self.position is None else -self.position.z
        return judge_ground(self.landed_state, self.armed, height, self.config.ground_height_m)

    @property
    def goto_m(self) -> FloatArray:
        return self._goto_m

    def state_mission(self) -> tuple[FloatArray, FloatArray]:
        """Latest (position [m], velocity [m/s]) in the mission frame."""
        if self.position is None or self.offset_m is None:
            raise RuntimeError(f"vehicle {self.sysid} has no position or origin yet")
        p, o, c = self.position, self.offset_m, self.vel_correction_ned
        # p = (e, n, -d) + o_i; v = (v_e, v_n, -v_d) (formation-law.md s1) less
        # the velocity bias (docs/velocity-bias.md), written out because it runs
        # for every vehicle at every step.
        return (
            np.array((p.y + o[0], p.x + o[1], -p.z + o[2])),
            np.array((p.vy - c[1], p.vx - c[0], -(p.vz - c[2]))),
        )

    def _silent_since(self) -> float:
        """Since when nothing has been heard from the vehicle (a HEARTBEAT or
        any other message); the watchdog runs only after a first HEARTBEAT."""
        return max(self._hb_at, self._heard_at)

    def next_deadline(self) -> float | None:
        """The earliest time [s] at which ``handle_timer`` has work, or None."""
        deadlines = list(self._timers.values())
        command = self._commands.next_deadline()
        if command is not None:
            deadlines.append(command)
        if self.phase not in IDLE_PHASES:
            deadlines.append(self._silent_since() + self.config.heartbeat_timeout_s)
            if self.phase in TELEMETRY_PHASES:
                deadlines.append(self.position_at + self.config.stale_timeout_s)
        return min(deadlines) if deadlines else None

    def take_outbound(self) -> list[MessageSpec]:
        out = self._out[:]
        self._out.clear()
        return out

    def take_events(self) -> list[ProtocolEvent]:
        events, self._events = self._events, []
        return events

    # ----------------------------------------------------------- station input
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

    def set_goto(self, goto_m: tuple[float, float, float] | FloatArray) -> None:
        """Move the mission-frame point [m] the vehicle flies to before the law."""
        self._goto_m = np.asarray(goto_m, dtype=np.float64)

    def begin_flying(self, now: float) -> None:
        """READY -> FLYING: from now on the station streams acceleration setpoints."""
        if self.phase is not Phase.READY:
            raise RuntimeError(f"vehicle {self.sysid} is {self.phase.value}, not ready")
        self._set_phase(Phase.FLYING, now)
        self._rate_t0_ms = None
        self._rate_lows = 0

    @property
    def outbound_waiting(self) -> bool:
        """Something is queued for ``take_outbound``."""
        return bool(self._out)

    def accel_setpoint(self, accel_mps2: npt.ArrayLike) -> MessageSpec:
        """The SET_POSITION_TARGET_LOCAL_NED for a mission-frame acceleration [m/s^2].

        Whatever the law asks, the frame is sendable: a norm above
        ``ACCEL_CEILING_MPS2`` is scaled down to it (direction kept; the cubic
        spring of Eq. 7 asks 10^4 m/s^2 at 30 m, more than float32 holds
        further out, and no vehicle follows either), and a non-finite
        command becomes zero; both are counted in ``clipped_setpoints``."""
        ned, clipped = clip_accel_ned(np.asarray(accel_mps2, dtype=np.float64).reshape(1, 3))
        self.clipped_setpoints += int(clipped[0])
        self.last_accel_ned = ned[0]
        x, y, z = ned[0].tolist()
        return b.accel_setpoint(self.sysid, self.compid, self.boot_ms(), (x, y, z))

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
        ground, where = self._ground()
        undo = self.armed or self._arm_sent
        if self.phase is Phase.LOST:
            # Best effort, not awaited: it may still hear us. Otherwise its own
            # GUID_TIMEOUT (set short at start-up) brakes it to a hover.
            if undo and ground:
                self._out.append(b.arm(self.sysid, self.compid, armed=False))
            elif self.armed:
                self._out.append(self.accel_setpoint((0.0, 0.0, 0.0)))
                self._out.append(self.personality.set_mode(self.sysid, self.compid, self._end_mode))
            return
        self._reset()
        if ground and not undo:
            if self.phase is not Phase.FAILED:
                self._set_phase(Phase.ENDED, now)
            return
        self._set_phase(Phase.ENDING, now)
        if ground:
            self._event("info", f"vehicle {self.sysid} is {where}: disarming it")
            self._disarming = True
            self._send_disarm(now)
        else:
            self._out.append(self.accel_setpoint((0.0, 0.0, 0.0)))
            self._send_end_mode(now)

    # --------------------------------------------------------- vehicle input
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
            self._event("statustext", f"vehicle {self.sysid} says: {msg.text}")
        elif isinstance(msg, Event):
            # PX4's reasons (an arming refusal has no STATUSTEXT): a reason like any.
            text = describe_event(msg.event_id, msg.log_levels, msg.arguments)
            self._commands.note_text(msg.log_levels & 0x0F, text)
            self._event("statustext", f"vehicle {self.sysid} event: {text}")
        elif isinstance(msg, SysStatus):
            self._health.sys_health = msg.health
            self._decide(now)
        elif isinstance(msg, GpsGlobalOrigin):
            self._on_origin(msg, now)
        elif isinstance(msg, EkfStatus):
            self._health.ekf_flags = msg.flags
            self._decide(now)
        elif isinstance(msg, GpsRaw):
            self._health.gps_fix = msg.fix_type
            self._decide(now)
        elif isinstance(msg, ExtendedSysState):
            known = msg.landed_state in LANDED_STATE_NAMES
            self.landed_state = msg.landed_state if known else None
            self._decide(now)
        elif isinstance(msg, ParamValue):
            value = self.personality.param_value(msg)
            self.params[msg.name] = value
            self._commands.on_param(msg.name, now, value)
        elif isinstance(msg, PositionTarget):
            self.target_echo = msg

    def flying_position(self, pos: LocalPositionNed, now: float) -> bool:
        """``handle_message(pos, now)`` for a LOCAL_POSITION_NED, written out for
        the FLYING phase (50 Hz per vehicle: the station's hot path); True if
        ``pos`` became ``position``. Other phases take ``handle_message``.
        ``tests/mavlink/test_batch.py`` checks both give the same state."""
        if self.phase is not _FLYING or pos.sysid != self.sysid:
            self.handle_message(pos, now)
            return self.position is pos
        if not plausible(pos):
            self.rejected_values += 1
            return False
        self._heard_at = now
        # _on_position's FLYING branch, inline: calling it (and its phase tests
        # for the other phases) measured ~0.3 ms more per step at 250 vehicles.
        last = self.position
        if last is not None and 0 <= last.time_boot_ms - pos.time_boot_ms < _REBOOT_MS:
            self.stale_telemetry += 1
            return False
        self.position = pos
        self.position_at = now
        self._observe(pos)
        self._count_report(pos.time_boot_ms)
        return True

    def _observe(self, pos: LocalPositionNed) -> None:
        obs = self.velocity_bias
        obs.update(pos.time_boot_ms * 1e-3, pos.x, pos.y, pos.z, pos.vx, pos.vy, pos.vz)
        self.vel_correction_ned = obs.correction

    def _count_report(self, ms: int) -> None:
        """Telemetry-rate watch in flight (issue 15): reports are counted over
        windows of ``RATE_WINDOW_MS`` of the vehicle's own clock (so lockstep
        and load do not matter). rate = reports after the window's first /
        elapsed vehicle time. A low window asks for the mission rate again;
        ``RATE_WARN_WINDOWS`` low ones in a row raise one warning."""
        t0 = self._rate_t0_ms
        if t0 is None or ms < t0:
            self._rate_t0_ms, self._rate_n = ms, 0
            return
        self._rate_n += 1
        if ms - t0 < RATE_WINDOW_MS:
            return
        rate = self._rate_n / ((ms - t0) * 1e-3)
        self._rate_t0_ms, self._rate_n = ms, 0
        self.telemetry_rate_hz = rate
        self.telemetry_rate_min_hz = min(self.telemetry_rate_min_hz, rate)
        want = self.config.control_rate_hz
        if rate >= RATE_LOW_FRACTION * want:
            if self.rate_low:
                self._event("info", f"vehicle {self.sysid}: LOCAL_POSITION_NED back at "
                                    f"{rate:.1f} Hz")  # fmt: skip
            self.rate_low, self._rate_lows = False, 0
            return
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
                f"vehicle {self.sysid}: LOCAL_POSITION_NED at {rate:.1f} Hz, below the mission "
                f"rate {want:g} Hz for {self._rate_lows * RATE_WINDOW_MS / 1000:g} s; interval "
                "asked again (a router lowering the stream rate?)",
            )

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

    # ------------------------------------------------------------ internals
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
            if self.enabled:
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
            and 0 <= last.time_boot_ms - pos.time_boot_ms < _REBOOT_MS
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

    def _on_origin(self, msg: GpsGlobalOrigin, now: float) -> None:
        origin = GeoOrigin.from_mavlink(msg.lat_e7, msg.lon_e7, msg.alt_mm)
        self.origin = origin
        self._timers.pop("origin", None)
        self._event(
            "info",
            f"vehicle {self.sysid}: EKF origin {origin.lat_deg:.7f} {origin.lon_deg:.7f} "
            f"{origin.alt_m:.2f} m",
        )
        self._update_offset()
        self._decide(now)

    def _update_offset(self) -> None:
        if self.origin is None or self.reference is None:
            return
        self.offset_m = origin_offset_m(self.origin, self.reference)
        e, n, u = self.offset_m
        self._event(
            "info",
            f"vehicle {self.sysid}: frame offset {e:+.2f} E {n:+.2f} N {u:+.2f} U m "
            "from the mission origin",
        )

    def _start_configuring(self, now: float) -> None:
        self._reset()
        self._arm_tries = self._guided_asks = 0
        self.took_over = self._arm_sent = self._yielded = False
        self.landed_state = None
        self._set_phase(Phase.CONFIGURING, now)
        cfg, s, c = self.config, self.sysid, self.compid
        pers = self.personality
        for label, msg_id, hz in (
            ("LOCAL_POSITION_NED", b.MSG_ID_LOCAL_POSITION_NED, cfg.control_rate_hz),
            *((lb, i, cfg.status_rate_hz) for lb, i in pers.status_streams),
        ):
            make = partial(b.set_message_interval, s, c, msg_id, 1.0 / hz)
            done: Callable[[int, float], None] = partial(self._refused_if, f"stream {label}")
            if msg_id == b.MSG_ID_EXTENDED_SYS_STATE:
                done = self._landed_stream_acked
            self._commands.push(
                now, f"SET_MESSAGE_INTERVAL {label}", make, done,
                command=b.MAV_CMD_SET_MESSAGE_INTERVAL,
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
                f"vehicle {self.sysid}: no EXTENDED_SYS_STATE stream ({verdict}): on the "
                "ground or in the air is judged from the armed flag and the height",
            )

    def _param_set(self, name: str, why: str, result: int, now: float) -> None:
        value = self.params.get(name, math.nan)
        self._event("param", f"vehicle {self.sysid}: {name} = {value:g} {why}")
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
            self._event(
                "warning",
                f"vehicle {self.sysid}: {why}: asking for {self.personality.ready_label} again "
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
                        f"vehicle {self.sysid} is {where}, armed in {self.mode_name}: "
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
                f"vehicle {self.sysid} is armed {where}: arming is a no-op; "
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
            what = f"vehicle {self.sysid}: disarmed before its take-off; arming again"
            self._event("warning", what)
            self._decide(now)
        else:
            verdict = MAV_RESULT_NAMES.get(result, str(result))
            state = "armed" if self.armed else "disarmed"
            self._fail(now, f"take-off refused ({verdict}) in {self.mode_name}, {state}: {why}")

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
                self._event("info", f"vehicle {self.sysid}: falling back to LAND")
                self._end_mode = land
                self._send_end_mode(now)
                return
        hb = self.heartbeat
        if result == 0 and hb is not None and hb.custom_mode == self._end_mode:
            self._set_phase(Phase.ENDED, now)
        else:
            self._timers["end_confirm"] = now + self.config.end_confirm_timeout_s

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
        """Position setpoint to the goto point, sent in answer to each telemetry."""
        if self.offset_m is not None:
            ned = mission_to_ned(self._goto_m, self.offset_m)
            self.last_accel_ned = np.zeros(3)
            spec = b.position_setpoint(self.sysid, self.compid, self.boot_ms(), _vec(ned))
            self._out.append(spec)

    def _request_origin(self, now: float) -> None:
        self._out.append(b.request_message(self.sysid, self.compid, b.MSG_ID_GPS_GLOBAL_ORIGIN))
        self._timers["origin"] = now + self.config.origin_request_interval_s

    def _refused(self, now: float, what: str, result: int) -> str:
        """Report a refusal with its result and the autopilot's own reasons
        (the STATUSTEXT heard while that command was pending); returns them."""
        why = refusal_reason(self._commands.answered_texts)
        verdict = MAV_RESULT_NAMES.get(result, str(result))
        self._event("refused", f"vehicle {self.sysid}: {what} refused ({verdict}): {why}")
        return why

    def _reset(self) -> None:
        self._commands.clear()
        self._timers.clear()
        self._disarming = False

    def _lose(self, now: float, why: str) -> None:
        self._reset()
        self.failure = why
        self._set_phase(Phase.LOST, now)
        self._event("lost", f"vehicle {self.sysid} lost: {why}")

    def _yield(self, now: float, why: str) -> None:
        """Someone else has the vehicle in flight: out of the formation for good
        and never fought over (``finish`` leaves it alone)."""
        self._fail(now, f"{why}; removed from the formation")
        self._yielded = True

    def _fail(self, now: float, why: str) -> None:
        self._reset()
        self.failure = why
        self._set_phase(Phase.FAILED, now)
        self._event("failed", f"vehicle {self.sysid}: {why}")

    def _set_phase(self, phase: Phase, now: float) -> None:
        if phase is not self.phase:
            self.phase = phase
            self._event("phase", f"vehicle {self.sysid}: {phase.value}")
            if phase in FINAL_PHASES:
                end = self._end_mode if phase is Phase.ENDED else None
                self.vehicle_params.restore(now, self._commands, self.compid,
                                            armed=self.armed, end_mode=end)  # fmt: skip

    def _event(self, kind: str, text: str) -> None:
        self._events.append(ProtocolEvent(self.sysid, kind, text, self.phase))

    def boot_ms(self) -> int:
        """The ``time_boot_ms`` a setpoint to this vehicle carries: its last report's."""
        return self.position.time_boot_ms if self.position is not None else 0


def clip_accel_ned(accel_mps2: FloatArray) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Mission-frame accelerations ``(N, 3)`` [m/s^2] as the NED accelerations
    setpoints carry (a_ned = (a_y, a_x, -a_z)), each sendable: a row whose
    norm is above ``ACCEL_CEILING_MPS2`` is scaled down to it (direction kept),
    a non-finite row, or one whose norm overflows, becomes zero. Also returns
    which rows were changed. The input is not modified."""
    a = np.array(accel_mps2, dtype=np.float64)  # a copy: clipped in place
    norm = np.sqrt(np.einsum("ij,ij->i", a, a))
    clip = ~(norm <= ACCEL_CEILING_MPS2)  # True for NaN too
    if clip.any():
        finite = np.isfinite(norm)
        scale = clip & finite
        a[scale] *= (ACCEL_CEILING_MPS2 / norm[scale])[:, None]
        a[~finite] = 0.0
    ned = np.empty_like(a)
    ned[:, 0] = a[:, 1]
    ned[:, 1] = a[:, 0]
    ned[:, 2] = -a[:, 2]
    return ned, clip


def _vec(v: FloatArray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))
