"""Eq. D9: GUIDED's Accel sub-mode starts its velocity reference at the reported velocity.

ArduCopter 4.5.6 enters the sub-mode (``ModeGuided::set_accel`` ->
``pva_control_start`` -> ``AC_PosControl::init_xy_controller`` /
``init_z_controller``) with its desired velocity at the EKF's velocity, the
reported one, bias included, and then flies that velocity plus the setpoints'
integral. Measured on the SITL octahedron (docs/sitl.md, 2026-12-07): each
vehicle's velocity (the derivative of its reported position) settled at its
reported velocity at the switch plus the commands' integral, to 0.5 cm/s over
40 s. The emulator adds the reported velocity's bias (Eq. T1) to the
vehicle's velocity when it enters the sub-mode; these tests fly it over UDP in
lockstep, and hold the rule (when the sub-mode is entered, kept, left) on the
autopilots themselves.
"""

from __future__ import annotations

import asyncio
from typing import Literal

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav
from sv_client import Client, connect

from sim_vehicle import Emulator, EmulatorConfig, VehicleSpec
from sim_vehicle.autopilot import Autopilot
from sim_vehicle.fleet import Fleet
from sim_vehicle.schedule import enter_accel
from sim_vehicle.telemetry import Kin
from sim_vehicle.vehicles import autopilot_for

BIAS = (0.02, -0.01, 0.015)
START = (0.0, 0.0, -10.0)
ZERO = (0.0, 0.0, 0.0)
GUIDED, LOITER = 4, 5


def _cfg(**kw: object) -> EmulatorConfig:
    base: dict[str, object] = {
        "vehicles": (VehicleSpec(sysid=1, start_ned_m=START, airborne=True),),
        "clock": "lockstep",
        "vel_bias_ned_m_s": BIAS,
        "vel_bias_flip_s": 0.0,
    }
    base.update(kw)
    return EmulatorConfig(**base)  # type: ignore[arg-type]


async def _zero_accel(emu: Emulator, c: Client, steps: int) -> None:
    """Answer sysid 1's LOCAL_POSITION_NED with a zero acceleration for ``steps`` steps."""
    end = emu.step_count + steps
    while emu.step_count < end:
        await c.recv("LOCAL_POSITION_NED")
        c.accel(1, ZERO)
    await emu.wait_steps(0)


def test_entering_accel_flies_the_bias_and_only_on_entry() -> None:
    async def run() -> None:
        # silent steps wait out the lockstep timeout (the vehicle holds the clock)
        async with asyncio.timeout(60), Emulator(_cfg(lockstep_timeout_s=0.01)) as emu:
            c = await connect(emu.endpoints[1])
            c.heartbeat()
            await c.recv("HEARTBEAT")
            ack = await c.command(1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 32, 20000)
            assert ack.result == mav.MAV_RESULT_ACCEPTED
            assert np.allclose(emu.vehicle_state(1).vel_ned_m_s, ZERO, atol=1e-12)  # hovering
            await _zero_accel(emu, c, 50)
            st = emu.vehicle_state(1)
            # the bias, added once, exactly; a zero command changes nothing after it
            np.testing.assert_allclose(st.vel_ned_m_s, BIAS, rtol=0, atol=1e-12)
            # the station reads the vehicle's velocity plus its bias: twice it (float32)
            lpn = await c.recv("LOCAL_POSITION_NED")
            np.testing.assert_allclose((lpn.vx, lpn.vy, lpn.vz), 2 * np.array(BIAS), atol=1e-6)
            # silent past GUID_TIMEOUT (3 s): it brakes to a hover in the same sub-mode
            t_quiet = emu.step_count + 300
            while emu.step_count < t_quiet:
                await c.recv("LOCAL_POSITION_NED")
            v_hold = np.array(emu.vehicle_state(1).vel_ned_m_s)
            assert np.linalg.norm(v_hold) < 0.005, v_hold
            await _zero_accel(emu, c, 50)  # no second bias: the sub-mode was kept
            v = np.array(emu.vehicle_state(1).vel_ned_m_s)
            assert np.linalg.norm(v - v_hold) < 0.005, (v, v_hold)
            # a mode change ends the sub-mode: back in GUIDED, the first setpoint enters it again
            for mode in (LOITER, GUIDED):
                ack = await c.command(1, mav.MAV_CMD_DO_SET_MODE, 1, mode)
                assert ack.result == mav.MAV_RESULT_ACCEPTED
            t_stop = emu.step_count + 300  # the mode change's brake to a hover
            while emu.step_count < t_stop:
                await c.recv("LOCAL_POSITION_NED")
            v_hold = np.array(emu.vehicle_state(1).vel_ned_m_s)
            await _zero_accel(emu, c, 50)
            v = np.array(emu.vehicle_state(1).vel_ned_m_s)
            # the bias again, on top of what the brake's lag left (< 5 mm/s, checked above)
            assert np.linalg.norm(v - v_hold - np.array(BIAS)) < 0.005, (v, v_hold)
            c.close()

    asyncio.run(run())


def test_no_bias_no_change_in_the_ideal_preset() -> None:
    async def run() -> None:
        cfg = _cfg(dynamics="ideal", vel_bias_ned_m_s=None)
        async with asyncio.timeout(30), Emulator(cfg) as emu:
            c = await connect(emu.endpoints[1])
            c.heartbeat()
            await c.recv("HEARTBEAT")
            await c.command(1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 32, 20000)
            await _zero_accel(emu, c, 20)
            assert emu.vehicle_state(1).vel_ned_m_s == ZERO  # bit for bit: nothing added
            c.close()

    asyncio.run(run())


def _ap(autopilot: Literal["ardupilot", "px4"]) -> Autopilot:
    spec = VehicleSpec(sysid=1, start_ned_m=START, airborne=True, autopilot=autopilot)
    return autopilot_for(_cfg(vehicles=(spec,)), spec, 0.0)


def test_the_entry_is_marked_once() -> None:
    kin = Kin(START, ZERO, ZERO, False)
    ap = _ap("ardupilot")
    ap.stream_accel(ZERO, 1.0)
    assert ap.accel_entry == 1.0
    ap.accel_entry = None  # the core acted
    ap.stream_accel(ZERO, 1.02)
    ap.apply_setpoint("accel", {"a": ZERO}, 3135, 1.04, kin)
    assert ap.accel_entry is None
    # a position setpoint leaves the sub-mode; the next acceleration enters it again
    ap.apply_setpoint("posvel", {"p": START, "v": ZERO}, 3520, 1.06, kin)
    ap.stream_accel(ZERO, 1.08)
    assert ap.accel_entry == 1.08
    assert ap.VEL_REFERENCE and not _ap("px4").VEL_REFERENCE


def test_enter_accel_adds_the_bias_only_with_a_reference_and_a_start_replaces_it() -> None:
    f = Fleet()
    row = f.add(1, 1, START, landed=False)
    f.vel[row] = (0.1, 0.2, 0.3)
    f.vbias[row] = BIAS
    f.boot[row] = 0.0
    enter_accel(f, row, 5.0, False, None)  # PX4: no velocity reference
    assert f.vel[row].tolist() == [0.1, 0.2, 0.3]
    enter_accel(f, row, 5.0, True, None)  # before the reversal (flip 0: never)
    np.testing.assert_allclose(f.vel[row], np.add((0.1, 0.2, 0.3), BIAS), rtol=0, atol=1e-15)
    f.vbias_flip[row], f.vbias_tau[row] = 4.0, 14.0  # 1 tau after the flip: (2/e - 1) of it
    f.vel[row] = ZERO
    enter_accel(f, row, 18.0, True, None)
    np.testing.assert_allclose(f.vel[row], np.array(BIAS) * (2 / np.e - 1), rtol=0, atol=1e-15)
    enter_accel(f, row, 18.0, True, (0.5, -0.25, 0.125))  # a moving spawn's start: that alone
    assert f.vel[row].tolist() == [0.5, -0.25, 0.125]


def test_a_moving_spawn_hovers_then_flies_from_its_start_velocity() -> None:
    v0 = (0.05, 0.17, -0.01)
    spec = VehicleSpec(sysid=1, start_ned_m=START, airborne=True, start_vel_ned_m_s=v0)

    async def run() -> None:
        cfg = _cfg(vehicles=(spec,), lockstep_timeout_s=0.01)
        async with asyncio.timeout(60), Emulator(cfg) as emu:
            c = await connect(emu.endpoints[1])
            c.heartbeat()
            await c.recv("HEARTBEAT")
            await c.command(1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 32, 20000)
            for _ in range(20):  # reports, no setpoint: it hovers where it was spawned
                await c.recv("LOCAL_POSITION_NED")
            st = emu.vehicle_state(1)
            assert st.vel_ned_m_s == ZERO and st.pos_ned_m == START
            await _zero_accel(emu, c, 50)
            # the start velocity, as it is (the bias not added on that entry)
            np.testing.assert_allclose(emu.vehicle_state(1).vel_ned_m_s, v0, rtol=0, atol=1e-12)
            c.close()

    asyncio.run(run())
