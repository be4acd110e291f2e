"""ArduCopter's personality: GUIDED for everything (mavlink-protocol.md).

The vehicle is armed, taken off and flown in GUIDED (custom_mode 4);
``MAV_CMD_DO_SET_MODE`` p1 = 1, p2 = the Copter mode; take-off altitude in
p7 above home; readiness from EKF_STATUS_REPORT's flags and a 3D GPS fix;
GUID_TIMEOUT and WP_YAW_BEHAVIOR set at start-up. No I/O.
"""

from __future__ import annotations

from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.codec import MessageSpec
from gcs_swarm.mavlink.personality import Health, Personality
from gcs_swarm.mavlink.states import EKF_READY_FLAGS, EKF_UNINITIALIZED, Phase, ProtocolConfig
from gcs_swarm.mavlink.states import mode_name as copter_mode_name
from gcs_swarm.mavlink.vehicle_params import ARDUCOPTER, Setting

__all__ = ["ARDUPILOT", "ArduPilot"]


class ArduPilot(Personality):
    """ArduCopter 4.5 (and the bundled emulator, which behaves as one)."""

    name = "ArduCopter"
    ready_mode = fly_mode = b.COPTER_MODES["GUIDED"]
    land_mode = b.COPTER_MODES["LAND"]
    offboard = False
    params = ARDUCOPTER
    status_streams = (
        ("EKF_STATUS_REPORT", b.MSG_ID_EKF_STATUS_REPORT),
        ("GPS_RAW_INT", b.MSG_ID_GPS_RAW_INT),
        ("EXTENDED_SYS_STATE", b.MSG_ID_EXTENDED_SYS_STATE),
    )

    def mode_name(self, custom_mode: int) -> str:
        return copter_mode_name(custom_mode)

    def set_mode(self, sysid: int, compid: int, mode: int) -> MessageSpec:
        return b.set_mode(sysid, compid, mode)

    def takeoff(self, sysid: int, compid: int, up_m: float, amsl_m: float | None) -> MessageSpec:
        return b.takeoff(sysid, compid, up_m)

    def end_mode(self, copter_mode: int) -> int:
        return copter_mode

    def readying_ok(self, phase: Phase, mode: int) -> bool:
        return mode == self.ready_mode

    def armable(self, health: Health) -> bool:
        flags = health.ekf_flags
        ekf = flags & EKF_READY_FLAGS == EKF_READY_FLAGS and not flags & EKF_UNINITIALIZED
        return ekf and health.gps_fix >= 3

    def station_sets(self, config: ProtocolConfig) -> tuple[Setting, ...]:
        return (
            ("GUID_TIMEOUT", config.guid_timeout_s, "s: when setpoints stop it brakes after this"),
            ("WP_YAW_BEHAVIOR", float(config.wp_yaw_behavior), "(heading kept while flying)"),
        )


ARDUPILOT = ArduPilot()
