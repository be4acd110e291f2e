"""The emulator's PX4 personality, I/O-free with a hand-advanced clock: what
PX4 v1.14 SITL was measured to do (docs/mavlink-protocol.md, PX4 section)."""

from __future__ import annotations

import math
import struct
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle.config import DEFAULT_ORIGIN
from sim_vehicle.px4 import PX4_MODES, Px4Autopilot, Px4ParamStore
from sim_vehicle.telemetry import Kin

ENC = mav.MAVLink(None, 255, 190)
HOVER = Kin((0.0, 0.0, -10.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), False)
GROUND = Kin((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), True)
HOLD, OFFBOARD = PX4_MODES["AUTO.LOITER"], PX4_MODES["OFFBOARD"]
NAN = math.nan


def _decoded(msg: Any) -> Any:
    return mav.MAVLink(None, 1, 1).parse_buffer(msg.pack(ENC))[0]


def _cmd(cmd: int, *p: float) -> Any:
    q = [*p, 0, 0, 0, 0, 0, 0, 0][:7]
    return _decoded(mav.MAVLink_command_long_message(1, 1, cmd, 0, *q))


def _mode(custom: int) -> Any:
    return _cmd(mav.MAV_CMD_DO_SET_MODE, 1, (custom >> 16) & 0xFF, (custom >> 24) & 0xFF)


def _sp(a: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Any:
    return _decoded(mav.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, 1, 3135, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, *a, 0.0, 0.0))  # fmt: skip


def _ack(out: list[Any], cmd: int) -> int:
    (result,) = [m.result for m in out if m.get_type() == "COMMAND_ACK" and m.command == cmd]
    return int(result)


def _px4(**params: float) -> Px4Autopilot:
    return Px4Autopilot(1, DEFAULT_ORIGIN, Px4ParamStore(params), 0.0)


def test_heartbeat_is_px4_in_hold_at_boot() -> None:
    hb = _px4().heartbeat()
    assert hb.autopilot == mav.MAV_AUTOPILOT_PX4 and hb.custom_mode == HOLD == 50593792
    assert PX4_MODES["OFFBOARD"] == 393216 and PX4_MODES["AUTO.LAND"] == 100925440


def test_arming_waits_for_the_prearm_checks_and_says_why_as_an_event() -> None:
    ap = _px4(SIM_PREARM_S=9.3)
    ap.poll(2.1, GROUND)  # EKF ready (SIM_EKF_DELAY 2), pre-arm not yet
    status = ap.build(mav.MAVLINK_MSG_ID_SYS_STATUS, 2.1, GROUND)
    assert status is not None
    assert not status.onboard_control_sensors_health & mav.MAV_SYS_STATUS_PREARM_CHECK
    out = ap.handle(_cmd(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1), 2.1, GROUND)
    assert _ack(out, mav.MAV_CMD_COMPONENT_ARM_DISARM) == mav.MAV_RESULT_TEMPORARILY_REJECTED
    assert [m.get_type() for m in out] == ["EVENT", "COMMAND_ACK"]  # no STATUSTEXT
    assert not ap.armed
    ap.poll(9.3, GROUND)
    status = ap.build(mav.MAVLINK_MSG_ID_SYS_STATUS, 9.3, GROUND)
    assert status is not None and status.onboard_control_sensors_health & (
        mav.MAV_SYS_STATUS_PREARM_CHECK
    )
    out = ap.handle(_cmd(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1), 9.3, GROUND)
    assert _ack(out, mav.MAV_CMD_COMPONENT_ARM_DISARM) == 0 and ap.armed


def _armed() -> Px4Autopilot:
    ap = _px4(SIM_PREARM_S=0.0, SIM_EKF_DELAY=0.0)
    ap.poll(0.0, GROUND)
    ap.handle(_cmd(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0, GROUND)
    assert ap.armed
    return ap


def test_takeoff_zero_latlon_is_acked_and_disarms_after_ten_seconds() -> None:
    ap = _armed()
    out = ap.handle(_cmd(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10), 0.5, GROUND)
    assert _ack(out, mav.MAV_CMD_NAV_TAKEOFF) == 0
    assert ap.heartbeat().custom_mode == PX4_MODES["AUTO.TAKEOFF"]
    assert ap.control == "ground"  # never leaves the ground
    ap.poll(9.9, GROUND)
    assert ap.armed
    ap.poll(10.0, GROUND)  # COM_DISARM_PRFLT after arming
    assert not ap.armed


def test_takeoff_nan_position_amsl_altitude_climbs_then_holds() -> None:
    ap = _armed()
    home_amsl = DEFAULT_ORIGIN[2]
    out = ap.handle(_cmd(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, home_amsl + 8.0),
                    0.5, GROUND)  # fmt: skip
    assert _ack(out, mav.MAV_CMD_NAV_TAKEOFF) == 0 and ap.control == "spool"
    assert ap._tk_alt_d == -8.0  # 8 m above home (NED down)
    ap.poll(4.0, GROUND)
    assert ap.control == "takeoff"
    at_top = Kin((0.0, 0.0, -8.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), False)
    ap.poll(12.0, at_top)
    ap.poll(12.02, at_top)
    assert ap.control == "hold" and ap.heartbeat().custom_mode == HOLD
    # A p7 below MIS_TAKEOFF_ALT above home climbs to MIS_TAKEOFF_ALT (2.5 m).
    low = _armed()
    low.handle(_cmd(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, home_amsl + 1.0), 0.5, GROUND)
    assert low._tk_alt_d == -2.5


def _in_offboard(ap: Px4Autopilot, t: float) -> float:
    for k in range(5):  # a 50 Hz stream before the switch
        ap.handle(_sp(), t + 0.02 * k, HOVER)
    t += 0.1
    out = ap.handle(_mode(OFFBOARD), t, HOVER)
    assert _ack(out, mav.MAV_CMD_DO_SET_MODE) == 0
    return t


def _flying() -> Px4Autopilot:
    ap = Px4Autopilot(1, DEFAULT_ORIGIN, Px4ParamStore(), 0.0, airborne_at=HOVER.pos)
    assert ap.armed and ap.heartbeat().custom_mode == HOLD  # an airborne start holds
    return ap


def test_offboard_needs_a_setpoint_stream_above_2_hz() -> None:
    ap = _flying()
    out = ap.handle(_mode(OFFBOARD), 1.0, HOVER)
    assert _ack(out, mav.MAV_CMD_DO_SET_MODE) == mav.MAV_RESULT_TEMPORARILY_REJECTED
    ap.handle(_sp(), 1.0, HOVER)
    ap.handle(_sp(), 1.6, HOVER)  # 0.6 s apart: below 2 Hz
    out = ap.handle(_mode(OFFBOARD), 1.6, HOVER)
    assert _ack(out, mav.MAV_CMD_DO_SET_MODE) == mav.MAV_RESULT_TEMPORARILY_REJECTED
    ap.handle(_sp(), 2.0, HOVER)  # 0.4 s apart: 2.5 Hz
    out = ap.handle(_mode(OFFBOARD), 2.0, HOVER)
    assert _ack(out, mav.MAV_CMD_DO_SET_MODE) == 0 and ap.heartbeat().custom_mode == OFFBOARD


def test_acceleration_setpoints_fly_in_offboard_only_and_az_zero_hovers() -> None:
    ap = _flying()
    ap.handle(_sp((1.0, 0.0, 0.0)), 0.0, HOVER)
    assert ap.target.a_ff == (0.0, 0.0, 0.0)  # in Hold: recorded, not flown
    t = _in_offboard(ap, 0.0)
    ap.handle(_sp((1.0, -0.5, 0.0)), t, HOVER)
    assert ap.control == "accel" and ap.target.a_ff == (1.0, -0.5, 0.0)
    assert ap.holding  # lockstep: an OFFBOARD vehicle holds the clock


def test_offboard_loss_goes_to_com_obl_rc_act_after_com_of_loss_t() -> None:
    for act, mode in ((0, "POSCTL"), (4, "AUTO.LAND"), (5, "AUTO.LOITER"), (3, "AUTO.RTL")):
        ap = _flying()
        ap.params.set("COM_OBL_RC_ACT", act)
        t = _in_offboard(ap, 0.0)
        last = t - 0.02  # the stream's last setpoint
        ap.poll(last + 0.99, HOVER)
        assert ap.heartbeat().custom_mode == OFFBOARD
        assert ap.deadline <= last + 1.0 + 1e-3  # it asks to be polled when the loss is due
        ap.poll(last + 1.01, HOVER)
        assert ap.heartbeat().custom_mode == PX4_MODES[mode], act
        assert ap.failsafe_at == last + 1.01


def test_position_failsafe_descends() -> None:
    ap = _flying()
    t = _in_offboard(ap, 0.0)
    ap.poll(t + 1.2, HOVER)
    assert ap.heartbeat().custom_mode == PX4_MODES["POSCTL"] and ap.control == "land"


def test_int32_parameters_travel_bytewise_and_real32_sets_are_ignored() -> None:
    ap = _px4()
    as_float = struct.unpack("<f", struct.pack("<i", 5))[0]
    set_real = _decoded(mav.MAVLink_param_set_message(1, 1, b"COM_OBL_RC_ACT", 5.0,
                                                      mav.MAV_PARAM_TYPE_REAL32))  # fmt: skip
    assert ap.handle(set_real, 0.0, GROUND) == [] and ap.params["COM_OBL_RC_ACT"] == 0
    set_int = _decoded(mav.MAVLink_param_set_message(1, 1, b"COM_OBL_RC_ACT", as_float,
                                                     mav.MAV_PARAM_TYPE_INT32))  # fmt: skip
    (echo,) = ap.handle(set_int, 0.0, GROUND)
    assert ap.params["COM_OBL_RC_ACT"] == 5
    assert echo.param_type == mav.MAV_PARAM_TYPE_INT32
    assert struct.unpack("<i", struct.pack("<f", echo.param_value))[0] == 5
    # ArduCopter's names stay inside: unknown on the wire, as on PX4.
    read = _decoded(mav.MAVLink_param_request_read_message(1, 1, b"GUID_TIMEOUT", -1))
    assert ap.handle(read, 0.0, GROUND) == []


def test_no_ekf_status_report_but_estimator_status() -> None:
    ap = _px4()
    out = ap.handle(_cmd(mav.MAV_CMD_SET_MESSAGE_INTERVAL, 193, 500000), 0.0, GROUND)
    assert _ack(out, mav.MAV_CMD_SET_MESSAGE_INTERVAL) == mav.MAV_RESULT_FAILED
    out = ap.handle(_cmd(mav.MAV_CMD_SET_MESSAGE_INTERVAL, 230, 500000), 0.0, GROUND)
    assert _ack(out, mav.MAV_CMD_SET_MESSAGE_INTERVAL) == 0
    sent = ap.poll(2.5, GROUND)
    assert any(m.get_type() == "ESTIMATOR_STATUS" and m.flags & 0x37 == 0x37 for m in sent)


def test_sim_vehicle_autopilot_px4_defaults_to_18570() -> None:
    from sim_vehicle.cli import build_config, parse_args

    cfg = build_config(parse_args(["--autopilot", "px4", "--count", "3"]))
    assert cfg.base_port == 18570 and {v.autopilot for v in cfg.vehicles} == {"px4"}
    assert build_config(parse_args(["--count", "1"])).base_port == 5760  # ArduCopter's


def _vel_sp(v: tuple[float, float, float], a: tuple[float, float, float]) -> Any:
    return _decoded(mav.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, 1, 3079, 0.0, 0.0, 0.0, *v, *a, 0.0, 0.0))  # fmt: skip


def test_a_setpoint_takes_effect_sim_sp_delay_after_it_is_heard() -> None:
    """Eq. D8: the setpoint is flown SIM_SP_DELAY (0.1 s) after it is heard, not
    before; the offboard-loss clock runs from when it was heard."""
    ap = Px4Autopilot(1, DEFAULT_ORIGIN, Px4ParamStore({"SIM_SP_DELAY": 0.1}), 0.0,
                      airborne_at=HOVER.pos)  # fmt: skip
    t = _in_offboard(ap, 0.0)
    ap.poll(t + 0.2, HOVER)  # the pre-switch stream has taken effect
    ap.handle(_sp((1.0, -0.5, 0.0)), t + 0.2, HOVER)
    assert ap.target.a_ff == (0.0, 0.0, 0.0)
    assert ap.deadline <= t + 0.3 + 1e-9  # it asks to be polled when the setpoint is due
    ap.poll(t + 0.28, HOVER)
    assert ap.target.a_ff == (0.0, 0.0, 0.0)
    ap.poll(t + 0.3, HOVER)
    assert ap.control == "accel" and ap.target.a_ff == (1.0, -0.5, 0.0)
    ap.poll(t + 0.2 + 1.01, HOVER)  # COM_OF_LOSS_T after it was heard, not after its effect
    assert ap.heartbeat().custom_mode == PX4_MODES["POSCTL"]


def test_setpoints_on_their_way_are_dropped_when_offboard_is_left() -> None:
    ap = Px4Autopilot(1, DEFAULT_ORIGIN, Px4ParamStore({"SIM_SP_DELAY": 0.1}), 0.0,
                      airborne_at=HOVER.pos)  # fmt: skip
    t = _in_offboard(ap, 0.0)
    ap.handle(_sp((2.0, 0.0, 0.0)), t, HOVER)
    ap.handle(_mode(HOLD), t + 0.02, HOVER)
    ap.poll(t + 0.2, HOVER)
    assert ap.heartbeat().custom_mode == HOLD and ap.control == "hold"
    assert ap.target.a_ff == (0.0, 0.0, 0.0)


def test_velocity_setpoints_feel_the_drag_the_velocity_loop_leaves() -> None:
    """Eq. D7 on a PX4: SIH's whole drag (SIM_DRAG) on raw acceleration setpoints,
    SIM_DRAG_VEL on velocity setpoints (the part PX4's velocity loop leaves)."""
    ap = Px4Autopilot(1, DEFAULT_ORIGIN, Px4ParamStore({"SIM_DRAG": 1.0, "SIM_DRAG_VEL": 0.45}),
                      0.0, airborne_at=HOVER.pos)  # fmt: skip
    t = _in_offboard(ap, 0.0)
    ap.handle(_sp((1.0, 0.0, 0.0)), t, HOVER)
    assert ap.control == "accel" and ap.target.drag == 1.0
    ap.handle(_vel_sp((2.0, 0.0, 0.0), (0.5, 0.0, 0.0)), t + 0.02, HOVER)
    assert ap.control == "vel" and ap.target.drag == 0.45 and ap.target.wv == 1.0
    assert ap.target.v_t == (2.0, 0.0, 0.0) and ap.target.a_ff == (0.5, 0.0, 0.0)


def test_the_px4_preset_has_the_fitted_delay_and_drag() -> None:
    """The values fitted to PX4 SITL (docs/emulator.md, 'PX4'); an ArduCopter has none."""
    from sim_vehicle.params import ParamStore
    from sim_vehicle.px4 import PX4_OVERRIDES

    assert PX4_OVERRIDES["SIM_SP_DELAY"] == 0.1 and PX4_OVERRIDES["SIM_DRAG_VEL"] == 0.45
    ac = ParamStore()
    assert ac["SIM_SP_DELAY"] == 0.0 and ac["SIM_DRAG_VEL"] == 0.0
