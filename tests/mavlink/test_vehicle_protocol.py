"""Unit tests of the per-vehicle protocol state machine, with a hand-advanced
clock: no event loop, no sockets, no sleeps (STYLE.md habits 1 and 11)."""

from __future__ import annotations

import numpy as np
import pytest

from gcs_swarm.mavlink import Phase, VehicleProtocol
from gcs_swarm.mavlink.builders import (
    COPTER_MODES,
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_NAV_TAKEOFF,
    MAV_CMD_REQUEST_MESSAGE,
    MAV_CMD_SET_MESSAGE_INTERVAL,
    TYPE_MASK_ACCEL,
    TYPE_MASK_POSITION,
)
from gcs_swarm.mavlink.inbound import (
    CommandAck,
    EkfStatus,
    GpsRaw,
    Heartbeat,
    ParamValue,
    StatusText,
)
from tests.mavlink.vehicle_harness import (
    BRAKE,
    GUIDED,
    LOITER,
    STABILIZE,
    SYS,
    commands,
    configure,
    hb,
    make,
    origin_msg,
    pos,
    ready_sensors,
)


def test_start_up_sequence_to_ready_then_fly_and_end() -> None:
    vp = make()
    t = 10.0
    vp.handle_message(hb(STABILIZE), t)
    first = vp.take_outbound()
    # Step 2: LOCAL_POSITION_NED at the control rate (50 Hz = 20000 us) and a
    # one-off request for GPS_GLOBAL_ORIGIN.
    (interval,) = commands(first, MAV_CMD_SET_MESSAGE_INTERVAL)
    assert (interval["param1"], interval["param2"]) == (32, 20000)
    assert commands(first, MAV_CMD_REQUEST_MESSAGE)[0]["param1"] == 49
    vp.handle_message(CommandAck(SYS, 1, MAV_CMD_SET_MESSAGE_INTERVAL, 0), t)
    rest = vp.take_outbound()
    assert [c["param1"] for c in commands(rest, MAV_CMD_SET_MESSAGE_INTERVAL)] == [193]
    for _ in range(3):  # EKF_STATUS_REPORT, GPS_RAW_INT, EXTENDED_SYS_STATE
        vp.handle_message(CommandAck(SYS, 1, MAV_CMD_SET_MESSAGE_INTERVAL, 0), t)
    for name, value in (("GUID_TIMEOUT", 0.5), ("WP_YAW_BEHAVIOR", 0.0)):
        vp.take_outbound()
        vp.handle_message(ParamValue(SYS, 1, name, value), t)
    events = [e.text for e in vp.take_events() if e.kind == "param"]
    assert any("GUID_TIMEOUT = 0.5" in e for e in events), events
    # Step 3: GUIDED, confirmed by heartbeat.
    assert vp.phase is Phase.SETTING_GUIDED
    (mode,) = commands(vp.take_outbound(), MAV_CMD_DO_SET_MODE)
    assert (mode["param1"], mode["param2"]) == (1, GUIDED)
    vp.handle_message(CommandAck(SYS, 1, MAV_CMD_DO_SET_MODE, 0), t)
    assert vp.phase is Phase.SETTING_GUIDED
    vp.handle_message(hb(GUIDED), t + 0.5)
    assert vp.phase is Phase.WAITING_ARMABLE
    # Step 4: not armable until EKF flags, 3D fix and origin are all there.
    vp.handle_message(GpsRaw(SYS, 1, 2, 5), t + 1)
    vp.handle_message(EkfStatus(SYS, 1, 1 | 2 | 4 | 16 | 32), t + 1)
    vp.handle_message(pos(1000, (0.0, 0.0, 0.0)), t + 1)
    vp.handle_message(origin_msg(), t + 1)
    assert vp.phase is Phase.WAITING_ARMABLE  # fix 2 is not enough
    np.testing.assert_allclose(vp.offset_m, [0.0, 100.0, -10.0], atol=1e-2)
    vp.handle_message(GpsRaw(SYS, 1, 3, 10), t + 1.5)
    assert vp.phase is Phase.ARMING
    (arm,) = commands(vp.take_outbound(), MAV_CMD_COMPONENT_ARM_DISARM)
    assert arm["param1"] == 1
    # Steps 5-6: accepted -> take-off at once; goto z = 12 m mission = 22 m above
    # this vehicle's origin (its origin is 10 m below the mission origin).
    vp.handle_message(CommandAck(SYS, 1, MAV_CMD_COMPONENT_ARM_DISARM, 0), t + 2)
    assert vp.phase is Phase.TAKING_OFF
    (tko,) = commands(vp.take_outbound(), MAV_CMD_NAV_TAKEOFF)
    assert tko["param7"] == pytest.approx(22.0)
    vp.handle_message(CommandAck(SYS, 1, MAV_CMD_NAV_TAKEOFF, 0), t + 2)
    vp.handle_message(hb(GUIDED, armed=True), t + 2.5)
    vp.handle_message(pos(3000, (0.0, 0.0, -10.0)), t + 5)
    assert vp.phase is Phase.TAKING_OFF
    vp.handle_message(pos(4000, (0.0, 0.0, -21.6)), t + 6)
    assert vp.phase is Phase.GOING_TO_START
    # Position setpoint to the goto point, in this vehicle's own NED frame.
    (sp,) = [m for m in vp.take_outbound() if m.name == "SET_POSITION_TARGET_LOCAL_NED"]
    assert sp["type_mask"] == TYPE_MASK_POSITION and sp["coordinate_frame"] == 1
    np.testing.assert_allclose([sp["x"], sp["y"], sp["z"]], [-100.0, 5.0, -22.0], atol=1e-2)
    vp.handle_message(pos(5000, (-100.0, 5.0, -22.0), (0.5, 0, 0)), t + 7)
    assert vp.phase is Phase.GOING_TO_START  # there but still moving
    vp.handle_message(pos(5020, (-100.1, 5.1, -22.05), (0.05, 0, 0)), t + 7.02)
    assert vp.phase is Phase.READY
    vp.take_outbound()
    # Step 7: acceleration setpoints, mission (x east, y north, z up) -> NED.
    vp.begin_flying(t + 8)
    sp = vp.accel_setpoint((1.0, 2.0, 3.0))
    assert sp["type_mask"] == TYPE_MASK_ACCEL == 3135 and sp["coordinate_frame"] == 1
    assert (sp["afx"], sp["afy"], sp["afz"]) == (2.0, 1.0, -3.0)
    assert sp["target_system"] == SYS and sp.kind == "setpoint"
    p, v = vp.state_mission()
    np.testing.assert_allclose(p, [5.1, 0.0 - 0.1 + 0.0, 12.05], atol=0.02)
    np.testing.assert_allclose(v, [0.0, 0.05, 0.0])
    # Ending: zero acceleration first, then BRAKE confirmed by heartbeat.
    vp.finish(t + 9)
    out = vp.take_outbound()
    assert out[0].name == "SET_POSITION_TARGET_LOCAL_NED" and out[0]["afx"] == 0.0
    assert out[0]["type_mask"] == TYPE_MASK_ACCEL
    (brake,) = commands(out, MAV_CMD_DO_SET_MODE)
    assert brake["param2"] == BRAKE
    vp.handle_message(CommandAck(SYS, 1, MAV_CMD_DO_SET_MODE, 0), t + 9.01)
    assert vp.phase is Phase.ENDING
    vp.handle_message(hb(BRAKE, armed=True), t + 9.5)
    assert vp.phase is Phase.ENDED


def test_arming_refused_is_reported_with_statustext_and_retried_every_2_s() -> None:
    vp = make()
    configure(vp, 0.0, mode=GUIDED)
    ready_sensors(vp, 0.0)
    assert vp.phase is Phase.ARMING
    assert commands(vp.take_outbound(), MAV_CMD_COMPONENT_ARM_DISARM)
    vp.take_events()
    vp.handle_message(StatusText(SYS, 1, 3, "PreArm: Gyros inconsistent"), 0.05)
    vp.handle_message(CommandAck(SYS, 1, MAV_CMD_COMPONENT_ARM_DISARM, 4), 0.06)
    refused = [e.text for e in vp.take_events() if e.kind == "refused"]
    assert refused == [
        f"vehicle {SYS}: arming (attempt 1) refused (failed): PreArm: Gyros inconsistent"
    ]
    # Retry 2 s after the refused attempt was sent, not before.
    assert vp.next_deadline() == pytest.approx(2.0)
    vp.handle_timer(1.99)
    assert not commands(vp.take_outbound(), MAV_CMD_COMPONENT_ARM_DISARM)
    vp.handle_message(hb(GUIDED), 1.99)  # keep the heartbeat watchdog fed
    vp.handle_timer(2.0)
    assert commands(vp.take_outbound(), MAV_CMD_COMPONENT_ARM_DISARM)
    vp.handle_message(CommandAck(SYS, 1, MAV_CMD_COMPONENT_ARM_DISARM, 0), 2.01)
    assert vp.phase is Phase.TAKING_OFF


def test_arming_refused_too_often_fails_with_the_vehicles_words() -> None:
    vp = make(arm_attempts=3, heartbeat_timeout_s=100.0)
    configure(vp, 0.0, mode=GUIDED)
    ready_sensors(vp, 0.0)
    t = 0.0
    for _ in range(3):
        vp.handle_message(StatusText(SYS, 1, 3, "PreArm: Compass not calibrated"), t)
        vp.handle_message(CommandAck(SYS, 1, MAV_CMD_COMPONENT_ARM_DISARM, 4), t)
        t = vp.next_deadline() or t
        vp.handle_timer(t)
    assert vp.phase is Phase.FAILED
    assert vp.failure == "arming refused 3 times (failed): PreArm: Compass not calibrated"


def test_unanswered_command_is_resent_with_confirmation_then_fails() -> None:
    vp = make(command_attempts=3, heartbeat_timeout_s=100.0)
    vp.handle_message(hb(STABILIZE), 0.0)
    (first,) = commands(vp.take_outbound(), MAV_CMD_SET_MESSAGE_INTERVAL)
    assert first["confirmation"] == 0
    assert vp.next_deadline() == pytest.approx(1.0)
    vp.handle_timer(1.0)
    (again,) = commands(vp.take_outbound(), MAV_CMD_SET_MESSAGE_INTERVAL)
    assert again["confirmation"] == 1 and again["param1"] == first["param1"]
    vp.handle_timer(2.0)
    vp.handle_timer(3.0)
    assert vp.phase is Phase.FAILED
    assert "no answer to SET_MESSAGE_INTERVAL LOCAL_POSITION_NED after 3 attempts" in str(
        vp.failure
    )


def test_armed_guided_vehicle_is_taken_over_without_a_takeoff() -> None:
    # No EXTENDED_SYS_STATE (the stream denied): the height decides, once a
    # LOCAL_POSITION_NED says it (22 m above its origin): in the air.
    vp = make()
    configure(vp, 0.0, mode=GUIDED, armed=True, landed_stream=2)
    assert vp.phase is Phase.WAITING_ARMABLE and not vp.took_over
    ready_sensors(vp, 0.1, ned=(-100.0, 5.0, -22.0))
    assert vp.took_over
    out = vp.take_outbound()
    assert not commands(out, MAV_CMD_COMPONENT_ARM_DISARM)
    assert not commands(out, MAV_CMD_NAV_TAKEOFF)
    assert vp.phase is Phase.READY  # already at its goto point and at rest


def test_armed_in_loiter_is_switched_to_guided_then_taken_over() -> None:
    vp = make()
    configure(vp, 0.0, mode=LOITER, armed=True)
    assert vp.phase is Phase.SETTING_GUIDED
    vp.handle_message(CommandAck(SYS, 1, MAV_CMD_DO_SET_MODE, 0), 0.1)
    vp.handle_message(hb(GUIDED, armed=True), 0.2)
    ready_sensors(vp, 0.3, ned=(-90.0, 5.0, -22.0))
    assert vp.phase is Phase.GOING_TO_START
    assert not commands(vp.take_outbound(), MAV_CMD_NAV_TAKEOFF)


def _flying(vp: VehicleProtocol, t: float) -> None:
    configure(vp, t, mode=GUIDED, armed=True)
    ready_sensors(vp, t, ned=(-100.0, 5.0, -22.0))
    vp.begin_flying(t)
    vp.take_outbound()
    vp.take_events()


def test_stale_telemetry_loses_the_vehicle_and_a_return_readies_it_again() -> None:
    vp = make(stale_timeout_s=1.0, heartbeat_timeout_s=3.0)
    _flying(vp, 0.0)
    vp.handle_message(pos(2000, (-100.0, 5.0, -22.0)), 0.5)
    assert vp.next_deadline() == pytest.approx(1.5)
    vp.handle_timer(1.49)
    assert vp.phase is Phase.FLYING
    vp.handle_timer(1.5)
    assert vp.phase is Phase.LOST
    assert [e.text for e in vp.take_events() if e.kind == "lost"] == [
        f"vehicle {SYS} lost: no LOCAL_POSITION_NED for 1 s"
    ]
    # It comes back: readied again from the stream requests on.
    vp.handle_message(hb(GUIDED, armed=True), 5.0)
    assert vp.phase is Phase.CONFIGURING
    assert commands(vp.take_outbound(), MAV_CMD_SET_MESSAGE_INTERVAL)


def test_lost_heartbeats_with_telemetry_flowing_do_not_lose_the_vehicle() -> None:
    # A lossy link drops a few HEARTBEATs in a row (1 Hz); telemetry (50 Hz)
    # still arrives, so the vehicle is there: only silence of every message
    # for heartbeat_timeout_s loses it.
    vp = make(stale_timeout_s=1.0, heartbeat_timeout_s=3.0)
    _flying(vp, 0.0)
    t = 0.0
    for k in range(1, 301):  # 6 s of telemetry at 50 Hz, no HEARTBEAT at all
        t = 0.02 * k
        vp.handle_message(pos(1000 + 20 * k, (-100.0, 5.0, -22.0)), t)
        vp.handle_timer(t)
    assert vp.phase is Phase.FLYING
    assert not [e for e in vp.take_events() if e.kind == "lost"]
    # Then total silence: lost once the first watchdog is due (stale telemetry, 1 s).
    vp.handle_timer(t + 1.0)
    assert vp.phase is Phase.LOST


def test_someone_else_taking_the_vehicle_removes_it_for_good() -> None:
    vp = make()
    _flying(vp, 0.0)
    vp.handle_message(hb(LOITER, armed=True), 0.5)
    assert vp.phase is Phase.FAILED
    assert "left GUIDED (now LOITER)" in str(vp.failure)
    vp.handle_message(hb(GUIDED, armed=True), 0.6)  # no fight with the pilot
    assert vp.phase is Phase.FAILED


def test_refused_end_mode_falls_back_to_land_at_once() -> None:
    vp = make()
    _flying(vp, 0.0)
    vp.finish(1.0)
    vp.take_outbound()
    vp.handle_message(StatusText(SYS, 1, 3, "Mode change to BRAKE failed"), 1.1)
    vp.handle_message(CommandAck(SYS, 1, MAV_CMD_DO_SET_MODE, 4), 1.1)
    (land,) = commands(vp.take_outbound(), MAV_CMD_DO_SET_MODE)
    assert land["param2"] == COPTER_MODES["LAND"]
    refused = [e.text for e in vp.take_events() if e.kind == "refused"]
    assert refused == [f"vehicle {SYS}: mode BRAKE refused (failed): Mode change to BRAKE failed"]
    # Accepted, but the heartbeat has not shown LAND yet: ask again after the timeout.
    vp.handle_message(CommandAck(SYS, 1, MAV_CMD_DO_SET_MODE, 0), 1.2)
    vp.handle_message(hb(GUIDED, armed=True), 1.3)
    assert vp.phase is Phase.ENDING
    assert vp.next_deadline() == pytest.approx(1.2 + vp.config.end_confirm_timeout_s)
    vp.handle_message(hb(GUIDED, armed=True), 4.0)
    vp.handle_timer(1.2 + vp.config.end_confirm_timeout_s)
    assert commands(vp.take_outbound(), MAV_CMD_DO_SET_MODE)[0]["param2"] == COPTER_MODES["LAND"]
    vp.handle_message(CommandAck(SYS, 1, MAV_CMD_DO_SET_MODE, 0), 4.3)
    vp.handle_message(hb(COPTER_MODES["LAND"], armed=True), 4.5)
    assert vp.phase is Phase.ENDED


def test_zero_acceleration_answers_telemetry_while_ending() -> None:
    vp = make()
    _flying(vp, 0.0)
    vp.accel_setpoint((3.0, 0.0, 0.0))
    vp.finish(1.0, mode=COPTER_MODES["RTL"])
    vp.take_outbound()
    vp.handle_message(pos(3000, (-100.0, 5.0, -22.0)), 1.02)
    (sp,) = vp.take_outbound()
    assert (sp["afx"], sp["afy"], sp["afz"], sp["type_mask"]) == (0.0, 0.0, 0.0, 3135)
    np.testing.assert_array_equal(vp.last_accel_ned, 0.0)


def test_vehicle_on_the_ground_just_stops_being_readied() -> None:
    vp = make()
    configure(vp, 0.0)
    vp.take_outbound()
    vp.finish(0.5, mode=COPTER_MODES["LAND"])
    assert vp.phase is Phase.ENDED
    assert vp.take_outbound() == []


def test_messages_from_other_systems_and_non_autopilots_are_ignored() -> None:
    vp = make()
    vp.handle_message(Heartbeat(SYS + 1, 1, 2, 3, 0, 0, 4), 0.0)
    vp.handle_message(Heartbeat(SYS, 154, 26, 8, 0, 0, 4), 0.0)  # a gimbal: autopilot INVALID
    assert vp.phase is Phase.CONNECTING and vp.take_outbound() == []


def test_mode_switched_by_someone_else_before_arming_is_set_back_to_guided() -> None:
    # Seen in the HEARTBEAT before the vehicle is armable: GUIDED is asked at
    # once and no arm goes out in LAND ("Arm: Mode not armable" never happens).
    vp = make(heartbeat_timeout_s=100.0)
    configure(vp, 0.0, mode=GUIDED)
    vp.handle_message(hb(COPTER_MODES["LAND"]), 0.5)  # another station switched it
    assert vp.phase is Phase.SETTING_GUIDED
    (guided,) = commands(vp.take_outbound(), MAV_CMD_DO_SET_MODE)
    assert guided["param2"] == GUIDED
    ready_sensors(vp, 1.0)
    assert not commands(vp.take_outbound(), MAV_CMD_COMPONENT_ARM_DISARM)
    vp.handle_message(CommandAck(SYS, 1, MAV_CMD_DO_SET_MODE, 0), 1.03)
    vp.handle_message(hb(GUIDED), 2.0)
    assert vp.phase is Phase.ARMING
    assert commands(vp.take_outbound(), MAV_CMD_COMPONENT_ARM_DISARM)
    vp.handle_message(CommandAck(SYS, 1, MAV_CMD_COMPONENT_ARM_DISARM, 0), 2.01)
    assert vp.phase is Phase.TAKING_OFF
