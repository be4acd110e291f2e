"""Phases, settings and events of the per-vehicle protocol (no I/O).

``Phase`` names the steps of the start-up sequence of mavlink-protocol.md;
``ProtocolConfig`` holds its timings [s] and rates [Hz]; ``ProtocolEvent``
is what the station logs.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.frames import GeoPoint

__all__ = [
    "AIRBORNE_PHASES",
    "EKF_READY_FLAGS",
    "EKF_UNINITIALIZED",
    "FINAL_PHASES",
    "GUIDED",
    "IDLE_PHASES",
    "TELEMETRY_PHASES",
    "Phase",
    "ProtocolConfig",
    "ProtocolEvent",
    "mode_name",
]

EKF_READY_FLAGS = 1 | 2 | 4 | 16 | 32
"""EKF_STATUS_FLAGS needed to arm (spec step 4): attitude, horizontal and
vertical velocity, absolute horizontal and vertical position."""
EKF_UNINITIALIZED = 1024
_MODE_NAMES = {v: k for k, v in b.COPTER_MODES.items()}
GUIDED = b.COPTER_MODES["GUIDED"]


class Phase(enum.Enum):
    """Where one vehicle is in the start-up / flight / ending sequence."""

    CONNECTING = "connecting"
    CONFIGURING = "configuring"
    SETTING_GUIDED = "guided"
    WAITING_ARMABLE = "waiting"
    ARMING = "arming"
    TAKING_OFF = "takeoff"
    GOING_TO_START = "goto"
    READY = "ready"
    FLYING = "flying"
    ENDING = "ending"
    ENDED = "ended"
    LOST = "lost"
    FAILED = "failed"


AIRBORNE_PHASES = frozenset({Phase.TAKING_OFF, Phase.GOING_TO_START, Phase.READY, Phase.FLYING})
"""Phases in which the vehicle is (or is becoming) airborne under our control."""
TELEMETRY_PHASES = frozenset({Phase.GOING_TO_START, Phase.READY, Phase.FLYING})
"""Phases that need fresh LOCAL_POSITION_NED (stale beyond the timeout -> LOST)."""
FINAL_PHASES = frozenset({Phase.ENDED, Phase.FAILED})
IDLE_PHASES = FINAL_PHASES | {Phase.CONNECTING, Phase.LOST}
"""Phases with no heartbeat watchdog."""


@dataclass(frozen=True)
class ProtocolConfig:
    """Timings [s], rates [Hz] and choices of the start-up and ending sequence.

    - ``control_rate_hz``: LOCAL_POSITION_NED stream rate (the control rate);
      ``status_rate_hz``: EKF_STATUS_REPORT and GPS_RAW_INT (spec: 1-2 Hz).
    - ``guid_timeout_s``, ``wp_yaw_behavior``: parameters set at start-up.
    - ``command_timeout_s``/``command_attempts``: each command is awaited this
      long and sent at most this often (10: with 20 % loss each way a round
      trip fails 36 % of the time, so 5 attempts lost about one start-up of
      ~36 commands in 5, 10 attempts about 1 in 800);
      ``arm_retry_interval_s``/``arm_attempts``:
      a refused arming is retried (spec: every 2 s) up to this many times.
    - ``takeoff_min_alt_m``: take-off height above home, at least (more if the
      start point is higher); ``goto_tolerance_m``/``goto_speed_tolerance_mps``:
      "at the start point" means within this distance and below this speed.
    - ``heartbeat_timeout_s``/``stale_timeout_s``: silence after which the
      vehicle is LOST (stale LOCAL_POSITION_NED counts while airborne).
    - ``end_mode``: Copter mode of the ending (BRAKE, LAND or RTL).
    - ``mission_origin``: the mission frame's geodetic origin, or None until
      the station learns it (``VehicleProtocol.set_reference``).
    """

    control_rate_hz: float = 50.0
    status_rate_hz: float = 2.0
    guid_timeout_s: float = 0.5
    wp_yaw_behavior: int = 0
    command_timeout_s: float = 1.0
    command_attempts: int = 10
    arm_retry_interval_s: float = 2.0
    arm_attempts: int = 15
    origin_request_interval_s: float = 2.0
    takeoff_min_alt_m: float = 2.0
    takeoff_timeout_s: float = 40.0
    goto_tolerance_m: float = 0.3
    goto_speed_tolerance_mps: float = 0.3
    heartbeat_timeout_s: float = 3.0
    stale_timeout_s: float = 1.0
    end_mode: int = b.COPTER_MODES["BRAKE"]
    end_confirm_timeout_s: float = 3.0
    mission_origin: GeoPoint | None = None


@dataclass(frozen=True)
class ProtocolEvent:
    """Something the log should say: ``kind`` is phase, info, param, statustext,
    warning, refused, lost or failed; ``text`` names the vehicle."""

    sysid: int
    kind: str
    text: str
    phase: Phase


def mode_name(custom_mode: int) -> str:
    """The ArduCopter name of a ``custom_mode`` number (the number if unknown)."""
    return _MODE_NAMES.get(custom_mode, str(custom_mode))
