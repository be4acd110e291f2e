"""The state of one vehicle's protocol and what every part of it uses:
its queries (phase, heartbeat, position, ground, mission-frame state), the
queues of messages and events, the acceleration setpoint, the phase change
(which hands a FLYING vehicle's telemetry row back: telemetry_table.py) and
the ways a vehicle is lost or fails. ``VehicleProtocol`` (vehicle.py) is
this plus its start-up (vehicle_startup.py) and ending (vehicle_ending.py);
mavlink-protocol.md and vehicle.py's docstring describe the phases.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from gcs_swarm.control.params import Envelope
from gcs_swarm.control.velocity_bias import VelocityBiasObserver
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.accel_clip import clip_accel_ned
from gcs_swarm.mavlink.codec import MessageSpec
from gcs_swarm.mavlink.commands import MAV_RESULT_NAMES, CommandQueue, refusal_reason
from gcs_swarm.mavlink.coordinates import GeoOrigin, origin_offset_m
from gcs_swarm.mavlink.inbound import Heartbeat, LocalPositionNed, PositionTarget
from gcs_swarm.mavlink.personality import Health, Personality
from gcs_swarm.mavlink.states import (
    FINAL_PHASES,
    IDLE_PHASES,
    TELEMETRY_PHASES,
    Phase,
    ProtocolConfig,
    ProtocolEvent,
    judge_ground,
)
from gcs_swarm.mavlink.telemetry_table import TelemetryTable
from gcs_swarm.mavlink.vehicle_params import ParamSettings, VehicleParams

__all__: list[str] = []

FloatArray = npt.NDArray[np.float64]


class _VehicleBase:
    """The state and shared helpers of ``VehicleProtocol`` (its arguments there)."""

    def __init__(
        self,
        sysid: int,
        config: ProtocolConfig,
        *,
        goto_m: tuple[float, float, float],
        enabled: bool = True,
        params: ParamSettings | None = None,
        personality: Personality | None = None,
        label: str | None = None,
        status_phase: float = 0.0,
    ) -> None:
        if personality is None:
            from gcs_swarm.mavlink.ardupilot import ARDUPILOT

            personality = ARDUPILOT
        self.personality = personality
        """The autopilot's own modes, commands and rules (personality.py)."""
        self.sysid = sysid
        """The vehicle's key: its system id, plus network index * 256 on
        another network than the first (``mission.vehicle_key``); the link
        puts the system id alone on the wire."""
        self.label = str(sysid) if label is None else label
        """How its messages name it (``blue:7`` on a named network)."""
        if not 0.0 <= status_phase < 1.0:
            raise ValueError(f"status_phase must be in [0, 1), got {status_phase!r}")
        self.status_phase = status_phase
        """The share of the status streams' interval its start-up waits
        before it asks for them (``runtime.config.StationConfig.status_phases``:
        the vehicles of one network spread over the interval)."""
        self.enabled = enabled
        self.config = config
        self.phase = Phase.CONNECTING
        self.compid = 1
        self.heartbeat: Heartbeat | None = None
        self._position: LocalPositionNed | None = None
        self._position_at = -math.inf
        self._table: TelemetryTable | None = None
        """The telemetry table this vehicle's row is in while FLYING (begin_flying)."""
        self._slot = -1
        self.target_echo: PositionTarget | None = None
        self.origin: GeoOrigin | None = None
        self.reference: GeoOrigin | None = config.mission_origin
        self.offset_m: FloatArray | None = None
        self._last_accel_ned: FloatArray = np.zeros(3)
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
        self._velocity_bias = VelocityBiasObserver(config.velocity_bias)
        """The bias of the reported velocity (NED), from every accepted report."""
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
        self._goto_vel: FloatArray | None = None
        """The goto point's velocity [m/s], mission frame (``set_goto``): None
        for a point at rest."""
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
        self._end_on_return = False
        """Lost while (or before) the station ended it: heard again, it is
        ended (``_Ending.finish``), never readied."""
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
            profile=personality.params, label=self.label,
        )  # fmt: skip
        """Envelope read, failsafe and fence set, old values restored (vehicle_params.py)."""

    @property
    def position(self) -> LocalPositionNed | None:
        """The latest accepted LOCAL_POSITION_NED (while FLYING: the
        telemetry table's row, which takes the reports)."""
        t = self._table
        return self._position if t is None else t.position(self._slot)

    @position.setter
    def position(self, pos: LocalPositionNed | None) -> None:
        self._position = pos

    @property
    def position_at(self) -> float:
        """When the latest accepted report was handled [s] (the stale watchdog's clock)."""
        t = self._table
        return self._position_at if t is None else t.seen_s[self._slot]

    @position_at.setter
    def position_at(self, at: float) -> None:
        self._position_at = at

    @property
    def last_accel_ned(self) -> FloatArray:
        """The last acceleration setpoint sent [m/s^2] NED (zero after a hold)."""
        t = self._table
        return self._last_accel_ned if t is None else t.accel_ned[self._slot]

    @last_accel_ned.setter
    def last_accel_ned(self, ned: FloatArray) -> None:
        t = self._table
        if t is None:
            self._last_accel_ned = ned
        else:
            t.accel_ned[self._slot] = ned

    @property
    def velocity_bias(self) -> VelocityBiasObserver:
        """The velocity-bias observer (docs/velocity-bias.md), with every
        report taken (while FLYING its telemetry row feeds it at each
        control step: ``TelemetryTable.observer``)."""
        t = self._table
        if t is not None:
            t.observer(self._slot)
        return self._velocity_bias

    @property
    def vel_correction_ned(self) -> tuple[float, float, float]:
        """Subtracted from the reported velocity before the law sees it."""
        return self.velocity_bias.correction

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
            raise RuntimeError(f"vehicle {self.label} has no position or origin yet")
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
        t = self._table
        if t is None:
            return max(self._hb_at, self._heard_at)
        k = self._slot
        return max(self._hb_at, self._heard_at, t.seen_s[k], t.heard_s[k], t.said_s[k])

    def next_deadline(self) -> float | None:
        """The earliest time [s] at which ``handle_timer`` has work, or None."""
        # Called after every message: the smallest of the candidates, without a list.
        due = min(self._timers.values()) if self._timers else None
        command = self._commands.next_deadline()
        if command is not None and (due is None or command < due):
            due = command
        phase = self.phase
        if phase not in IDLE_PHASES:
            hb = self._silent_since() + self.config.heartbeat_timeout_s
            if due is None or hb < due:
                due = hb
            if phase in TELEMETRY_PHASES:
                stale = self.position_at + self.config.stale_timeout_s
                if stale < due:
                    due = stale
        return due

    def take_outbound(self) -> list[MessageSpec]:
        out = self._out[:]
        self._out.clear()
        return out

    def take_events(self) -> list[ProtocolEvent]:
        events, self._events = self._events, []
        return events

    def _detach(self) -> None:
        """Leaving FLYING: take the table row's report, times and setpoint back."""
        t, k = self._table, self._slot
        if t is None:
            return
        self._position = t.position(k)
        self._position_at = t.seen_s[k]
        self._heard_at = max(self._heard_at, t.seen_s[k], t.said_s[k])
        self._hb_at = max(self._hb_at, t.heard_s[k])  # the unchanged HEARTBEATs it took
        self._last_accel_ned = t.accel_ned[k].copy()
        t.detach(k)
        self._table = None

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

    def _update_offset(self) -> None:
        if self.origin is None or self.reference is None:
            return
        self.offset_m = origin_offset_m(self.origin, self.reference)
        if self._table is not None:
            self._table.set_offset(self._slot, self.offset_m)
        e, n, u = self.offset_m
        self._event(
            "info",
            f"vehicle {self.label}: frame offset {e:+.2f} E {n:+.2f} N {u:+.2f} U m "
            "from the mission origin",
        )

    def _request_origin(self, now: float) -> None:
        self._out.append(b.request_message(self.sysid, self.compid, b.MSG_ID_GPS_GLOBAL_ORIGIN))
        self._timers["origin"] = now + self.config.origin_request_interval_s

    def _refused(self, now: float, what: str, result: int) -> str:
        """Report a refusal with its result and the autopilot's own reasons
        (the STATUSTEXT heard while that command was pending); returns them."""
        why = refusal_reason(self._commands.answered_texts)
        verdict = MAV_RESULT_NAMES.get(result, str(result))
        self._event("refused", f"vehicle {self.label}: {what} refused ({verdict}): {why}")
        return why

    def _reset(self) -> None:
        self._commands.clear()
        self._timers.clear()
        self._disarming = False

    def _lose(self, now: float, why: str) -> None:
        self._end_on_return = self._end_on_return or self.phase is Phase.ENDING
        self._reset()
        self.failure = why
        self._set_phase(Phase.LOST, now)
        self._event("lost", f"vehicle {self.label} lost: {why}")

    def _yield(self, now: float, why: str) -> None:
        """Someone else has the vehicle in flight: out of the formation for good
        and never fought over (``finish`` leaves it alone)."""
        self._fail(now, f"{why}; removed from the formation")
        self._yielded = True

    def _fail(self, now: float, why: str) -> None:
        self._reset()
        self.failure = why
        self._set_phase(Phase.FAILED, now)
        self._event("failed", f"vehicle {self.label}: {why}")

    def _set_phase(self, phase: Phase, now: float) -> None:
        if phase is not self.phase:
            if self._table is not None:
                self._detach()  # only FLYING vehicles are in the table
            self.phase = phase
            self._event("phase", f"vehicle {self.label}: {phase.value}")
            if phase in FINAL_PHASES:
                end = self._end_mode if phase is Phase.ENDED else None
                self.vehicle_params.restore(now, self._commands, self.compid,
                                            armed=self.armed, end_mode=end)  # fmt: skip

    def _event(self, kind: str, text: str) -> None:
        self._events.append(ProtocolEvent(self.sysid, kind, text, self.phase))

    def boot_ms(self) -> int:
        """The ``time_boot_ms`` a setpoint to this vehicle carries: its last report's."""
        t = self._table
        if t is not None:
            return t.boot_ms(self._slot)
        return self._position.time_boot_ms if self._position is not None else 0


def _vec(v: FloatArray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))
