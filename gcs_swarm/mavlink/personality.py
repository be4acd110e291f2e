"""What differs between the autopilots the station flies, behind one small
interface (no I/O): ``VehicleProtocol`` runs the same start-up, flight and
ending for every vehicle and asks its ``Personality`` for the modes, the
messages and the rules that are the autopilot's own.

- ``ready_mode``: the mode a vehicle is armed and taken off in (ArduCopter
  GUIDED, PX4 Hold); ``fly_mode``: the mode the formation is flown in
  (GUIDED, OFFBOARD); ``offboard``: True when setpoints must already stream
  before ``fly_mode`` is asked (PX4 refuses OFFBOARD without a stream
  above 2 Hz), so the station streams its position setpoint first.
- ``readying_ok(phase, mode)``: a HEARTBEAT mode the vehicle may show while
  it is readied (PX4 goes through AUTO.TAKEOFF and back to Hold by itself).
- ``set_mode``, ``takeoff``: the commands, each autopilot's way.
- ``end_mode``: the mission's ending (named by its ArduCopter mode number,
  as the station carries it) as this autopilot's mode.
- ``armable``: readiness from what the vehicle reports (``Health``).
- ``param_value``: a PARAM_VALUE's value decoded (PX4 packs integers
  byte-wise), ``params``: the parameters read and set (``ParamProfile``),
  ``station_sets``: those the station always sets at start-up.

``personality_for("ardupilot" | "sim" | "px4")`` picks one.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass

from gcs_swarm.mavlink.codec import MessageSpec
from gcs_swarm.mavlink.inbound import ParamValue
from gcs_swarm.mavlink.states import Phase, ProtocolConfig
from gcs_swarm.mavlink.vehicle_params import ParamProfile, Setting

__all__ = ["Health", "Personality", "personality_for"]


@dataclass
class Health:
    """What readiness is judged from: EKF_STATUS_REPORT or ESTIMATOR_STATUS
    flags (EKF_STATUS_FLAGS bits), GPS_RAW_INT fix type, SYS_STATUS health
    bits (None: none heard), the EKF origin known."""

    ekf_flags: int = 0
    gps_fix: int = 0
    sys_health: int | None = None
    origin: bool = False


class Personality(abc.ABC):
    """One autopilot's modes, commands and rules (module docstring)."""

    name: str
    ready_mode: int
    fly_mode: int
    land_mode: int
    offboard: bool
    params: ParamProfile
    status_streams: tuple[tuple[str, int], ...]
    """(label, message id) streamed at the status rate (LOCAL_POSITION_NED
    goes at the control rate for every autopilot)."""

    @abc.abstractmethod
    def mode_name(self, custom_mode: int) -> str:
        """The name of a HEARTBEAT ``custom_mode`` (the number if unknown)."""

    @abc.abstractmethod
    def set_mode(self, sysid: int, compid: int, mode: int) -> MessageSpec:
        """MAV_CMD_DO_SET_MODE to ``mode`` (a ``custom_mode`` value)."""

    @abc.abstractmethod
    def takeoff(self, sysid: int, compid: int, up_m: float, amsl_m: float | None) -> MessageSpec:
        """MAV_CMD_NAV_TAKEOFF climbing ``up_m`` [m] above the vehicle, whose
        target is ``amsl_m`` [m AMSL] (None when the origin's altitude is unknown)."""

    @abc.abstractmethod
    def end_mode(self, copter_mode: int) -> int:
        """The ending named by an ArduCopter mode number, as this autopilot's mode."""

    @abc.abstractmethod
    def readying_ok(self, phase: Phase, mode: int) -> bool:
        """May the vehicle show ``mode`` while it is readied in ``phase``?"""

    @abc.abstractmethod
    def armable(self, health: Health) -> bool:
        """Ready to arm, from what the vehicle reports."""

    @abc.abstractmethod
    def station_sets(self, config: ProtocolConfig) -> tuple[Setting, ...]:
        """Parameters the station always sets in CONFIGURING (name, value, why)."""

    def param_value(self, msg: ParamValue) -> float:
        """The value a PARAM_VALUE carries (REAL32, or integers cast to float)."""
        return msg.value

    @property
    def ready_label(self) -> str:
        return self.mode_name(self.ready_mode)

    @property
    def fly_label(self) -> str:
        return self.mode_name(self.fly_mode)


def personality_for(autopilot: str) -> Personality:
    """The personality of a mission's ``autopilot`` (``sim`` is the bundled
    emulator's ArduCopter)."""
    if autopilot == "px4":
        from gcs_swarm.mavlink.px4 import PX4

        return PX4
    from gcs_swarm.mavlink.ardupilot import ARDUPILOT

    return ARDUPILOT
