"""A vehicle's life with a hand-advanced clock: boot, EKF, take-off, landing, failsafe, fence.

The I/O-free ``Autopilot`` and the vectorised ``Fleet`` stepped together in a
loop as the server does (poll at the autopilot's deadline or when the landed
flag changes), no sockets, no event loop. Times are sim seconds; "within one
step" tolerances are the 0.02 s physics step.
"""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import safety
from sim_vehicle.autopilot import Autopilot
from sim_vehicle.config import DEFAULT_ORIGIN
from sim_vehicle.fleet import Fleet
from sim_vehicle.params import ParamStore
from sim_vehicle.telemetry import Kin

DT = 0.02
ENC = mav.MAVLink(None, 255, 190)
ESS = mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE


def _decoded(msg: Any, src: int = 255) -> Any:
    enc = mav.MAVLink(None, src, 190)
    return mav.MAVLink(None, 1, 1).parse_buffer(msg.pack(enc))[0]


def _cmd(cmd: int, *p: float) -> Any:
    q = [*p, 0, 0, 0, 0, 0, 0, 0][:7]
    return _decoded(mav.MAVLink_command_long_message(1, 1, cmd, 0, *q))


def _hb(src: int = 255) -> Any:
    return _decoded(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3), src)


class Sim:
    """One autopilot on one fleet row, advanced by hand (the server's order of work)."""

    def __init__(self, airborne: bool = False, **params: float) -> None:
        start = (0.0, 0.0, -10.0) if airborne else (0.0, 0.0, 0.0)
        self.ap = Autopilot(
            1, DEFAULT_ORIGIN, ParamStore(params), 0.0, airborne_at=start if airborne else None
        )
        self.f = Fleet()
        self.f.add(1, 1, start, landed=not airborne)
        self.f.set_target(0, self.ap.target)
        self.t = 0.0
        self.sent: list[Any] = []

    @property
    def kin(self) -> Kin:
        f = self.f
        return Kin(tuple(f.pos[0]), tuple(f.vel[0]), tuple(f.acc[0]), bool(f.landed[0]))

    def send(self, msg: Any) -> list[Any]:
        out = self.ap.handle(msg, self.t, self.kin)
        self.f.set_target(0, self.ap.target)
        self.sent += out
        return out

    def run(self, seconds: float, until: Any = None) -> None:
        for _ in range(round(seconds / DT)):
            self.f.step(DT)
            self.t = round(self.t + DT, 9)
            if self.ap.deadline <= self.t + 1e-9 or self.f.changed:
                self.sent += self.ap.poll(self.t, self.kin)
                self.f.set_target(0, self.ap.target)
            if until is not None and until():
                return

    def texts(self) -> list[str]:
        return [m.text for m in self.sent if m.get_type() == "STATUSTEXT"]

    def ess(self) -> int:
        (ack, msg) = self.send(_cmd(mav.MAV_CMD_REQUEST_MESSAGE, ESS))
        assert ack.result == mav.MAV_RESULT_ACCEPTED and msg.vtol_state == 0
        return int(msg.landed_state)

    def take_off(self, alt: float = 5.0) -> None:
        assert self.send(_cmd(mav.MAV_CMD_DO_SET_MODE, 1, 4))[0].result == 0
        assert self.send(_cmd(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1))[-1].result == 0
        assert self.send(_cmd(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt))[0].result == 0
        self.run(20.0, until=lambda: self.ap.control == "hold")
        assert abs(self.kin.pos[2] + alt) < 0.1


def test_boot_ends_in_stabilize_after_guided_was_accepted() -> None:
    s = Sim(SIM_BOOT_S=1.0, SIM_EKF_DELAY=0.0)
    s.run(2.0)  # nobody connected yet: boot does not end (SITL waits for its connection)
    assert "ArduPilot Ready" not in s.texts()
    s.ap.contact(s.t)  # the station's first frame (the server calls this), t = 2.0
    (ack,) = s.send(_cmd(mav.MAV_CMD_DO_SET_MODE, 1, 4))
    assert ack.result == mav.MAV_RESULT_ACCEPTED and s.ap.heartbeat().custom_mode == 4
    s.run(0.98)  # t = 2.98: still GUIDED
    assert s.ap.mode == 4 and "ArduPilot Ready" not in s.texts()
    s.run(0.02)  # t = 3.0, 1 s after the first contact: boot ends
    assert "ArduPilot Ready" in s.texts()
    assert s.ap.mode == 0 and s.ap.heartbeat().custom_mode == 0
    assert s.send(_cmd(mav.MAV_CMD_DO_SET_MODE, 1, 4))[0].result == 0  # set again: stays
    s.run(5.0)
    assert s.ap.mode == 4
    air = Sim(airborne=True, SIM_BOOT_S=1.0)
    air.ap.contact(0.0)
    air.run(2.0)
    assert air.ap.mode == 4 and "ArduPilot Ready" not in air.texts()


def test_ekf_and_gps_not_ready_until_the_configured_delay() -> None:
    s = Sim(SIM_EKF_DELAY=25.0)
    gps, ekf = mav.MAVLINK_MSG_ID_GPS_RAW_INT, mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT
    abs_pos = mav.EKF_POS_HORIZ_ABS | mav.EKF_POS_VERT_ABS | mav.EKF_VELOCITY_HORIZ
    s.run(24.98)
    assert s.ap.build(gps, s.t, s.kin).fix_type < 3
    assert s.ap.build(ekf, s.t, s.kin).flags & abs_pos != abs_pos
    out = s.send(_cmd(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1))
    assert out[-1].result == mav.MAV_RESULT_FAILED and out[0].text.startswith("PreArm")
    s.run(0.02)
    assert s.ap.build(gps, s.t, s.kin).fix_type == 3
    assert s.ap.build(ekf, s.t, s.kin).flags & abs_pos == abs_pos
    assert s.send(_cmd(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1))[-1].result == 0


def test_land_disarms_a_second_after_touchdown_and_a_disarmed_vehicle_never_moves() -> None:
    s = Sim(SIM_EKF_DELAY=0.0)
    assert s.ess() == 1  # on the ground
    s.take_off(5.0)
    assert s.ess() == 2  # in the air
    s.send(_cmd(mav.MAV_CMD_DO_SET_MODE, 1, 9))  # LAND
    assert s.ess() == 4  # landing
    s.run(30.0, until=lambda: s.kin.landed)
    touchdown = s.t
    s.run(0.96)
    assert s.ap.armed and s.ess() == 4  # not yet: the detector needs 1 s on the ground
    s.run(2.0, until=lambda: not s.ap.armed)
    assert abs(s.t - touchdown - 1.0) <= DT + 1e-9  # 1 s after touchdown, within one step
    assert s.ess() == 1 and s.ap.mode == 9
    rest = s.kin.pos
    for mode in (6, 9, 4, 17, 5):  # RTL, LAND, GUIDED, BRAKE, LOITER on the ground, disarmed
        assert s.send(_cmd(mav.MAV_CMD_DO_SET_MODE, 1, mode))[0].result == 0
        s.run(5.0)
        assert s.kin.pos == rest and s.kin.vel == (0.0, 0.0, 0.0) and not s.ap.armed
    s.take_off(7.0)  # a take-off after a landing works
    assert s.ess() == 2


def test_rtl_lands_and_disarms_and_a_guided_descent_idles_until_disarm_delay() -> None:
    s = Sim(SIM_EKF_DELAY=0.0, RTL_ALT=600, RTL_LOIT_TIME=0, DISARM_DELAY=3)
    s.take_off(5.0)
    s.send(_cmd(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH))
    s.run(60.0, until=lambda: not s.ap.armed)
    assert s.kin.landed and s.ap.mode == 6 and s.ess() == 1
    s.take_off(5.0)
    sp = mav.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, 1, 3135, 0, 0, 0, 0, 0, 0, 0.0, 0.0, 0.5, 0, 0
    )  # accelerate down at 0.5 m/s^2, streamed until touchdown
    while not s.kin.landed:
        s.send(_decoded(sp))
        s.run(0.02)
    touchdown = s.t
    s.run(1.1)
    assert s.ap.armed and s.ap.land_complete and s.ess() == 1  # GUIDED: idles, armed
    s.run(5.0, until=lambda: not s.ap.armed)
    assert abs(s.t - touchdown - 1.0 - 3.0) <= DT + 1e-9  # then DISARM_DELAY (3 s)


def test_gcs_failsafe_listens_only_to_sysid_mygcs() -> None:
    s = Sim(airborne=True, FS_GCS_ENABLE=1, FS_GCS_TIMEOUT=5.0)
    s.send(_hb(255))  # the station: feeds the failsafe
    for _ in range(8):  # another GCS keeps talking: does not count
        s.run(1.0)
        s.send(_hb(200))
    assert s.ap.mode == 6 and "GCS Failsafe" in s.texts()  # RTL 5 s after the last 255
    s.send(_hb(255))
    assert "GCS Failsafe Cleared" in s.texts()
    mine = Sim(airborne=True, FS_GCS_ENABLE=5, SYSID_MYGCS=200)
    for _ in range(8):
        mine.send(_hb(200))
        mine.run(1.0)
    assert mine.ap.mode == 4  # fed by 200 = SYSID_MYGCS
    mine.run(5.0)
    assert mine.ap.mode == 9  # FS_GCS_ENABLE 5: LAND
    quiet = Sim(airborne=True, FS_GCS_ENABLE=1)
    quiet.run(10.0)
    assert quiet.ap.mode == 4  # never heard its GCS: never triggers (ArduCopter)


def test_gcs_failsafe_counts_wall_seconds_in_lockstep() -> None:
    """In lockstep sim time outruns the station's 1 Hz wall-clock HEARTBEAT: the
    failsafe waits FS_GCS_TIMEOUT of wall time (the server sets ``wall_s``)."""
    s = Sim(airborne=True, FS_GCS_ENABLE=5, FS_GCS_TIMEOUT=5.0)
    s.ap.wall_s = 100.0
    s.send(_hb(255))
    s.ap.wall_s = 104.0  # 4 s of wall time while 30 s of sim time pass
    s.run(30.0)
    assert s.ap.mode == 4 and "GCS Failsafe" not in s.texts()
    s.ap.wall_s = 105.5  # 5.5 s of wall silence: LAND
    s.run(0.2)
    assert s.ap.mode == 9 and "GCS Failsafe" in s.texts()


def test_gcs_failsafe_actions_as_arducopter() -> None:
    act = safety.gcs_failsafe
    modes = {v: act(v, 16, 4, False, False) for v in range(8)}
    assert modes[0] is None
    assert {v: a.mode for v, a in modes.items() if a} == {
        1: 6, 2: 6, 3: 6, 4: 9, 5: 9, 6: 6, 7: 17
    }  # fmt: skip
    assert act(1, 16, 5, False, False).mode is None  # LOITER: pilot control continues
    assert act(1, 0, 5, False, False).mode == 6
    assert act(1, 16, 4, False, True).disarm  # landed: disarm
    assert act(1, 8, 9, True, False).mode == 9  # landing continues with FS_OPTIONS 8


def test_fence_breach_returns_home() -> None:
    s = Sim(SIM_EKF_DELAY=0.0, FENCE_ENABLE=1, FENCE_ALT_MAX=8.0, RTL_ALT=500)
    s.send(_cmd(mav.MAV_CMD_DO_SET_MODE, 1, 4))
    s.send(_cmd(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1))
    s.send(_cmd(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 12.0))
    s.run(20.0, until=lambda: s.ap.mode == 6)
    assert "Fence Breached" in s.texts() and s.ap.mode == 6
    assert 8.0 < -s.kin.pos[2] < 8.2  # breached just above FENCE_ALT_MAX (one step's climb)
    assert safety.fence_action(2, 1.0, False).mode == 9
    assert safety.fence_action(4, 1.0, False).mode == 17
    assert safety.fence_action(1, 150.0, False).mode == 9  # > 100 m outside: LAND
    assert safety.fence_breaches(1, 7, 100.0, 300.0, 50.0, 301.0) == (2, 1.0)


def test_extended_sys_state_streams_and_shows_the_take_off() -> None:
    s = Sim(SIM_EKF_DELAY=0.0)
    (ack,) = s.send(_cmd(mav.MAV_CMD_SET_MESSAGE_INTERVAL, ESS, 200000))
    assert ack.result == mav.MAV_RESULT_ACCEPTED
    s.send(_cmd(mav.MAV_CMD_DO_SET_MODE, 1, 4))
    s.send(_cmd(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1))
    s.send(_cmd(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 5.0))
    s.run(20.0, until=lambda: s.ap.control == "hold")
    states = [m.landed_state for m in s.sent if m.get_msgId() == ESS]
    assert len(states) >= 5 * s.t - 1  # 5 Hz
    assert states[0] == 1 and 3 in states and states[-1] in (2, 3)
    seq = [x for i, x in enumerate(states) if i == 0 or states[i - 1] != x]
    assert seq[:2] == [1, 3]  # on the ground, then taking off


def test_parameters_the_station_reads_and_sets_have_arducopter_defaults_and_types() -> None:
    r32, i8, i16, i32 = (mav.MAV_PARAM_TYPE_REAL32, mav.MAV_PARAM_TYPE_INT8,
                         mav.MAV_PARAM_TYPE_INT16, mav.MAV_PARAM_TYPE_INT32)  # fmt: skip
    expected = {  # ArduCopter 4.5.6 (Parameters.cpp, AC_Fence, AC_WPNav, AC_PosControl)
        "WPNAV_ACCEL": (250, r32), "WPNAV_ACCEL_Z": (100, r32), "WPNAV_SPEED": (1000, r32),
        "WPNAV_SPEED_UP": (250, r32), "WPNAV_SPEED_DN": (150, r32), "PSC_JERK_XY": (5, r32),
        "PSC_JERK_Z": (5, r32), "ANGLE_MAX": (3000, i16), "SYSID_MYGCS": (255, i16),
        "FS_GCS_ENABLE": (0, i8), "FS_GCS_TIMEOUT": (5, r32), "FS_OPTIONS": (16, i32),
        "FENCE_ENABLE": (0, i8), "FENCE_TYPE": (7, i8), "FENCE_ACTION": (1, i8),
        "FENCE_ALT_MAX": (100, r32), "FENCE_ALT_MIN": (-10, r32), "FENCE_RADIUS": (300, r32),
        "FENCE_MARGIN": (2, r32),
    }  # fmt: skip
    ap = Sim(airborne=True).ap
    for name, (value, kind) in expected.items():
        msg = _decoded(mav.MAVLink_param_request_read_message(1, 1, name.encode(), -1))
        (pv,) = ap.handle(msg, 0.0, Kin((0, 0, -10), (0, 0, 0), (0, 0, 0), False))
        assert (pv.param_id, pv.param_value, pv.param_type) == (name, value, kind)
    set_ = mav.MAVLink_param_set_message(1, 1, b"FENCE_ACTION", 2.4, r32)  # an integer: rounded
    (pv,) = ap.handle(_decoded(set_), 0.0, Kin((0, 0, -10), (0, 0, 0), (0, 0, 0), False))
    assert pv.param_value == 2.0 and pv.param_type == i8
