"""Phases, settings and events of the per-vehicle protocol (no I/O).

``Phase`` names the steps of the start-up sequence of mavlink-protocol.md;
``ProtocolConfig`` holds its timings [s] and rates [Hz]; ``ProtocolEvent``
is what the station logs.
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass, field

from gcs_swarm.control.velocity_bias import BiasSettings
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.coordinates import GeoOrigin
from gcs_swarm.mission.model import Startup

__all__ = [
    "AIRBORNE_PHASES",
    "EKF_READY_FLAGS",
    "EKF_UNINITIALIZED",
    "FINAL_PHASES",
    "GUIDED",
    "IDLE_PHASES",
    "INCOMING_PHASES",
    "LANDED_STATE_NAMES",
    "NAMED_AT_MOST",
    "READYING_PHASES",
    "TELEMETRY_PHASES",
    "Phase",
    "ProtocolConfig",
    "ProtocolEvent",
    "describe_states",
    "judge_ground",
    "mode_name",
    "state_words",
]

EKF_READY_FLAGS = 1 | 2 | 4 | 16 | 32
"""EKF_STATUS_FLAGS needed to arm (spec step 4): attitude, horizontal and
vertical velocity, absolute horizontal and vertical position."""
EKF_UNINITIALIZED = 1024
_MODE_NAMES = {v: k for k, v in b.COPTER_MODES.items()}
GUIDED = b.COPTER_MODES["GUIDED"]
LANDED_STATE_NAMES = {1: "on the ground", 2: "in the air", 3: "taking off", 4: "landing"}
"""EXTENDED_SYS_STATE.landed_state (MAV_LANDED_STATE) values that say
something; 0 (undefined) is missing, as is the message."""


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

    # Members are singletons compared by identity: hash them by identity too,
    # in C (Enum's own __hash__ is a Python function hashing the name, and
    # every message of a vehicle tests its phase against a few sets).
    __hash__ = object.__hash__


AIRBORNE_PHASES = frozenset({Phase.TAKING_OFF, Phase.GOING_TO_START, Phase.READY, Phase.FLYING})
"""Phases in which the vehicle is (or is becoming) airborne under our control."""
TELEMETRY_PHASES = frozenset({Phase.GOING_TO_START, Phase.READY, Phase.FLYING})
"""Phases that need fresh LOCAL_POSITION_NED (stale beyond the timeout -> LOST)."""
READYING_PHASES = frozenset(
    {Phase.WAITING_ARMABLE, Phase.ARMING, Phase.TAKING_OFF, Phase.GOING_TO_START}
)
"""Phases after GUIDED was confirmed and before the vehicle holds at its start:
a HEARTBEAT with another mode here is the autopilot (ArduCopter returns to
STABILIZE when it finishes booting) and GUIDED is asked again; in READY and
FLYING it means someone else took the vehicle."""
INCOMING_PHASES = frozenset(
    {Phase.CONFIGURING, Phase.SETTING_GUIDED, Phase.WAITING_ARMABLE, Phase.ARMING,
     Phase.TAKING_OFF, Phase.GOING_TO_START, Phase.READY}
)  # fmt: skip
"""Phases of a vehicle on its way into the formation, from its take-over to
READY: being readied at start-up, a reserve holding at its start, a vehicle
heard again flying to its rejoin point."""
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
      a refused arming is retried (spec: every 2 s) up to this many times;
      ``guided_attempts``: GUIDED is asked at most this often while readying
      (a first time, then each time the autopilot leaves it or a HEARTBEAT
      does not confirm it: on SITL twice, the second after "ArduPilot Ready").
    - ``ground_height_m``: with no EXTENDED_SYS_STATE landed state, an armed
      vehicle less than this above its EKF origin (LOCAL_POSITION_NED -z; the
      origin is where it booted, on the ground) is on the ground; a disarmed
      one always is.
    - ``takeoff_min_alt_m``: take-off height above home, at least (more if the
      start point is higher); ``goto_tolerance_m``/``goto_speed_tolerance_mps``:
      "at the start point" means within this distance and below this speed.
    - ``heartbeat_timeout_s``/``stale_timeout_s``: silence after which the
      vehicle is LOST (stale LOCAL_POSITION_NED counts while airborne).
    - ``end_mode``: Copter mode of the ending (BRAKE, LAND or RTL; each
      personality reads it as its own: PX4 Hold, Land, RTL).
    - ``offboard_lead_s``: how long setpoints stream before OFFBOARD is
      asked (PX4 refuses it without a stream; measured: 1 s at 50 Hz is enough).
    - ``mission_origin``: the mission frame's geodetic origin, or None until
      the station learns it (``VehicleProtocol.set_reference``).
    - ``velocity_bias``: the estimate of a constant bias in the reported
      velocity and whether the law's velocity is corrected by it
      (``gcs_swarm.control.velocity_bias``, docs/velocity-bias.md).
    """

    control_rate_hz: float = 50.0
    status_rate_hz: float = 2.0
    guid_timeout_s: float = 0.5
    wp_yaw_behavior: int = 0
    command_timeout_s: float = 1.0
    command_attempts: int = Startup.command_attempts
    arm_retry_interval_s: float = 2.0
    arm_attempts: int = 15
    guided_attempts: int = 8
    ground_height_m: float = 1.0
    origin_request_interval_s: float = 2.0
    takeoff_min_alt_m: float = Startup.takeoff_alt
    takeoff_timeout_s: float = 40.0
    goto_tolerance_m: float = Startup.start_tolerance
    goto_speed_tolerance_mps: float = Startup.start_speed_tolerance
    heartbeat_timeout_s: float = 3.0
    stale_timeout_s: float = 1.0
    end_mode: int = b.COPTER_MODES["BRAKE"]
    end_confirm_timeout_s: float = 3.0
    offboard_lead_s: float = 1.0
    mission_origin: GeoOrigin | None = None
    velocity_bias: BiasSettings = field(default_factory=BiasSettings)


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


def judge_ground(
    landed_state: int | None, armed: bool, height_m: float | None, ground_height_m: float
) -> tuple[bool, str]:
    """Is the vehicle on the ground, and why (words for the log)?

    ``landed_state`` (EXTENDED_SYS_STATE) decides when the vehicle sends one
    of ``LANDED_STATE_NAMES``: 1 is the ground; 2, 3 and 4 (in the air, taking
    off, landing) are not. Without it: a disarmed vehicle is on the ground,
    and an armed one is when its ``height_m`` above its EKF origin [m] is
    below ``ground_height_m`` (or unknown). The armed flag alone never says
    airborne: a late arm command leaves a vehicle armed on the ground
    (mavlink-protocol.md, "Start-up sequence")."""
    if landed_state in LANDED_STATE_NAMES:
        return landed_state == 1, f"{LANDED_STATE_NAMES[landed_state]} (EXTENDED_SYS_STATE)"
    if not armed:
        return True, "disarmed (no landed state)"
    if height_m is None:
        return True, "armed, height unknown (no landed state)"
    ground = height_m < ground_height_m
    where = "on the ground" if ground else "in the air"
    up = round(height_m, 1) + 0.0  # never "-0.0 m"
    return ground, f"{where} ({up:.1f} m above its EKF origin, no landed state)"


NAMED_AT_MOST = 8
"""``describe_states`` names at most this many vehicles in one state (the
rest counted): 250 vehicles of a network that failed alike make one clause
of a one-line error, not 250 (``StartupError.reasons`` keeps each one)."""


def state_words(phase: Phase, failure: str | None) -> str:
    """A vehicle's state in words: its phase, and its failure in its own words."""
    return phase.value + (f" ({failure})" if failure else "")


def describe_states(what: str, states: Sequence[tuple[str, str]]) -> str:
    """``what: vehicle 2 waiting`` from (label, ``state_words``) pairs;
    vehicles in the same state share one clause, in order of first
    appearance: ``what: 3 vehicles 2, 3, 4 failed (...); vehicle 5 takeoff``."""
    labels_of: dict[str, list[str]] = {}
    for label, state in states:
        labels_of.setdefault(state, []).append(label)
    clauses = []
    for state, labels in labels_of.items():
        named = ", ".join(labels[:NAMED_AT_MOST])
        if len(labels) > NAMED_AT_MOST:
            named += f" and {len(labels) - NAMED_AT_MOST} more"
        count = "vehicle" if len(labels) == 1 else f"{len(labels)} vehicles"
        clauses.append(f"{count} {named} {state}")
    return f"{what}: {'; '.join(clauses)}" if clauses else what
