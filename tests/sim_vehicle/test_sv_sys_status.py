"""SYS_STATUS as ground-station tools read it: MAVProxy (checked by hand,
MAVProxy 1.8 against ``sim-vehicle``) announces "fence breach" when the
geofence health bit is clear and "Arming checks disabled" when the pre-arm
check bit is not enabled; ArduCopter sets both as below."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle.telemetry import sys_status


def test_prearm_check_is_enabled_and_healthy_only_once_the_ekf_is_ready() -> None:
    bit = mav.MAV_SYS_STATUS_PREARM_CHECK
    for ready in (False, True):
        m = sys_status(ready)
        assert m.onboard_control_sensors_present & bit
        assert m.onboard_control_sensors_enabled & bit
        assert bool(m.onboard_control_sensors_health & bit) is ready


def test_geofence_is_healthy_and_gps_ahrs_follow_the_ekf() -> None:
    not_ready, ready = sys_status(False), sys_status(True)
    for m in (not_ready, ready):
        assert m.onboard_control_sensors_health & mav.MAV_SYS_STATUS_GEOFENCE
    for bit in (mav.MAV_SYS_STATUS_SENSOR_GPS, mav.MAV_SYS_STATUS_AHRS):
        assert not not_ready.onboard_control_sensors_health & bit
        assert ready.onboard_control_sensors_health & bit
