"""Lockstep over real UDP: exact kinematics, the measured lag and timeout, repeatability."""

from __future__ import annotations

import asyncio
import math
import time

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav
from sv_client import connect

from sim_vehicle import Emulator, EmulatorConfig, Impairment, VehicleSpec
from sim_vehicle.dynamics import GRAVITY_M_S2, DynParams, KinState, step

DT = 0.02
START = (0.0, 0.0, -10.0)


def _cfg(**kw: object) -> EmulatorConfig:
    base: dict[str, object] = {
        "vehicles": (VehicleSpec(sysid=1, start_ned_m=START, airborne=True),),
        "clock": "lockstep",
    }
    base.update(kw)
    return EmulatorConfig(**base)  # type: ignore[arg-type]


async def _accel_steps(emu: Emulator, a: tuple[float, float, float], steps: int) -> None:
    """Answer every LOCAL_POSITION_NED of sysid 1 with acceleration ``a`` for ``steps`` steps."""
    c = await connect(emu.endpoints[1])
    try:
        c.heartbeat()
        await c.recv("HEARTBEAT")
        ack = await c.command(1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 32, 20000)
        assert ack.result == mav.MAV_RESULT_ACCEPTED
        while emu.step_count < steps:
            await c.recv("LOCAL_POSITION_NED")
            c.accel(1, a)
        await emu.wait_steps(0)
    finally:
        c.close()


def test_ideal_acceleration_step_is_exact_after_n_lockstep_steps() -> None:
    a, n = (0.8, -0.3, -0.2), 250

    async def run() -> None:
        async with asyncio.timeout(30), Emulator(_cfg(dynamics="ideal")) as emu:
            await _accel_steps(emu, a, n)
            st = emu.vehicle_state(1)
            assert emu.step_count == n and emu.stats.lockstep_timeouts == 0
            t = n * DT  # the first setpoint answers step 0's telemetry: applied from step 1
            a32 = np.array(a, dtype=np.float32).astype(np.float64)  # afx.. are float32 on the wire
            exp_p = np.add(START, 0.5 * a32 * t * t)
            # 1e-9: Eq. D2 is exact for constant acceleration; only float64 rounding remains
            np.testing.assert_allclose(st.pos_ned_m, exp_p, rtol=0, atol=1e-9)
            np.testing.assert_allclose(st.vel_ned_m_s, a32 * t, rtol=0, atol=1e-9)

    asyncio.run(run())


def test_ardupilot_like_lag_matches_the_measured_step() -> None:
    n = 150  # +1 m/s^2 north for 3 s, as measured on SITL

    async def run() -> None:
        async with asyncio.timeout(30), Emulator(_cfg(accel_shaping=None)) as emu:
            await _accel_steps(emu, (1.0, 0.0, 0.0), n)
            st = emu.vehicle_state(1)
            # the pure dynamics advanced by hand n steps (jerk Eq. D5 at PSC_JERK_XY 5 m/s^3,
            # lean cap D6 at 30 deg, lag D1-D2 at the preset's 0.1 s), from the reported
            # velocity's bias its first setpoint gave it (Eq. D9): the same to rounding
            bias = np.array([EmulatorConfig.ARDUPILOT_VEL_BIAS_NED_M_S])
            ref = KinState(np.array([START]), bias, np.zeros((1, 3)),
                           np.zeros(1, dtype=bool), np.zeros((1, 3)))  # fmt: skip
            one = np.ones(1)
            par = DynParams(0.1 * one, 5.0 * one, 0.0 * one, 5.0 * one, 5.0 * one,
                            GRAVITY_M_S2 * math.tan(math.radians(30.0)) * one)  # fmt: skip
            for _ in range(n):
                ref = step(ref, np.array([[1.0, 0.0, 0.0]]), DT, par)
            np.testing.assert_allclose(st.vel_ned_m_s, ref.vel_ned_m_s[0], rtol=0, atol=1e-9)
            # closed form: the ramp 0.1, 0.2, .. 1.0 m/s^2 over 10 steps (5 m/s^3 x 0.02 s per
            # step) costs DT * sum(1 - k / 10) = 0.09 m/s, the lag tau (1 - e^-t/tau) = 0.1 m/s
            assert abs(st.vel_ned_m_s[0] - (bias[0, 0] + n * DT - 0.09 - 0.1)) < 1e-6
            # SITL, 3 s of +1 m/s^2 from hover: 2.74 m/s (sheet), 2.78 (2026-12-01), 2.80
            # (2026-12-03, timed by the vehicle's echo of the target, which it ignored for the
            # first 2.2 s); the reversed step -1 m/s^2 gave 2.85 m/s, the accel reached
            # 0.97-1.05 m/s^2 (docs/emulator.md). Stated tolerance: 0.1 m/s about 2.80 and
            # 0.05 m/s^2 about 1.0 cover that spread (SITL's loop catches up after a step,
            # which this open-loop model does not)
            assert abs(st.accel_ned_m_s2[0] - 1.0) < 0.05
            assert abs(st.vel_ned_m_s[0] - 2.80) < 0.1
            assert abs(st.vel_ned_m_s[1]) < 0.05 and abs(st.vel_ned_m_s[2]) < 0.05

    asyncio.run(run())


def test_guid_timeout_keeps_last_accel_then_brakes_to_hover_in_guided() -> None:
    async def run() -> None:
        # a short wall timeout lets the clock run on once the client stops answering
        cfg = _cfg(lockstep_timeout_s=0.002, accel_shaping=None)  # the ardupilot preset's
        async with asyncio.timeout(60), Emulator(cfg) as emu:
            c = await connect(emu.endpoints[1])
            c.heartbeat()
            await c.recv("HEARTBEAT")
            await c.command(1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 32, 20000)
            while emu.vehicle_state(1).vel_ned_m_s[0] < 2.06:  # the sheet's speed at the stop
                await c.recv("LOCAL_POSITION_NED")
                c.accel(1, (1.0, 0.0, 0.0))
            last = emu.vehicle_state(1)
            await emu.wait_until(lambda: emu.sim_time_s >= last.sim_time_s + 2.9)
            mid = emu.vehicle_state(1)
            assert mid.vel_ned_m_s[0] > last.vel_ned_m_s[0] + 2.7  # still accelerating
            await emu.wait_until(lambda: emu.sim_time_s >= last.sim_time_s + 9.0)
            end = emu.vehicle_state(1)
            c.close()
            assert end.mode_name == "GUIDED" and end.armed
            assert np.linalg.norm(end.vel_ned_m_s) < 0.05  # hovering
            past = end.pos_ned_m[0] - last.pos_ned_m[0]
            # sheet: 5.14 m/s peak, 18.7 m past the last setpoint. The jerk-limited brake
            # (Eq. D5, 5 m/s^3 from +1 to -2.5 m/s^2 at WPNAV_ACCEL) and the 0.2 s lag give
            # 19.8 m: 1.5 m covers that 1.1 m excess (docs/emulator.md) and SITL's spread
            assert abs(past - 18.7) < 1.5, past

    asyncio.run(run())


async def _closed_loop_bytes(seed: int) -> list[bytes]:
    """Three airborne vehicles, noise and impairments, a client flying a P-D law on what it gets."""
    specs = tuple(
        VehicleSpec(sysid=i, start_ned_m=(2.0 * i, -1.0, -10.0), airborne=True) for i in (1, 2, 3)
    )
    imp = Impairment(loss=0.1, delay_s=0.04, jitter_s=0.03, duplicate=0.05)
    # LOCAL_POSITION_NED streamed from the start: over a lossy link a one-shot
    # SET_MESSAGE_INTERVAL could be lost, and a retry would be timed by the wall clock
    cfg = EmulatorConfig(
        vehicles=specs, clock="lockstep", seed=seed, noise_pos_m=0.05, noise_vel_m_s=0.02,
        uplink=imp, downlink=imp, streams={32: 50.0},
    )  # fmt: skip
    frames: list[bytes] = []
    async with Emulator(cfg) as emu:
        clients = {s: await connect(a) for s, a in emu.endpoints.items()}

        async def fly(sysid: int) -> None:
            c = clients[sysid]
            c.heartbeat()  # registers the peer; then answer every position report
            while True:
                m = await c.recv("LOCAL_POSITION_NED")
                a = (-0.8 * m.x - 1.2 * m.vx, -0.8 * (m.y - 3) - 1.2 * m.vy, -1.0 * m.vz)
                c.accel(sysid, a)

        async with asyncio.TaskGroup() as tg:
            tasks = [tg.create_task(fly(s)) for s in clients]
            await emu.wait_steps(120)
            for t in tasks:
                t.cancel()
        assert emu.stats.lockstep_timeouts == 0
        assert emu.stats.link.rx_lost > 0 and emu.stats.link.tx_lost > 0
        for s in sorted(clients):
            parser = mav.MAVLink(None, 0, 0)
            for raw in clients[s].frames:
                msg = parser.parse_buffer(raw)[0]
                if msg.get_type() == "LOCAL_POSITION_NED" and msg.time_boot_ms <= 2000:
                    frames.append(raw)
            clients[s].close()
    return frames


def test_lockstep_runs_are_bit_for_bit_repeatable() -> None:
    async def run() -> None:
        async with asyncio.timeout(60):
            first = await _closed_loop_bytes(seed=4)
            second = await _closed_loop_bytes(seed=4)
            other = await _closed_loop_bytes(seed=5)
        assert len(first) > 200
        assert first == second
        assert first != other  # the seed matters, so the comparison can fail

    asyncio.run(run())


def test_lockstep_timeout_counts_from_the_last_step_not_from_the_first_wait() -> None:
    """The datagram bringing the last answer takes the step itself and the timeout timer
    is armed once for many steps: answering slowly (5 ms per step) for longer than the
    timeout must never count a timeout; going silent must, once, no sooner than
    ``lockstep_timeout_s`` after the last step (a lower bound: safe on a slow machine)."""
    timeout_s = 0.2

    async def run() -> None:
        cfg = _cfg(lockstep_timeout_s=timeout_s)
        async with asyncio.timeout(30), Emulator(cfg) as emu:
            c = await connect(emu.endpoints[1])
            try:
                c.heartbeat()
                await c.recv("HEARTBEAT")
                await c.command(1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 32, 20000)
                loop = asyncio.get_running_loop()
                t0 = loop.time()
                for _ in range(100):  # >= 0.5 s of answering: the timer fired and re-armed
                    await c.recv("LOCAL_POSITION_NED")
                    await asyncio.sleep(0.005)
                    c.accel(1, (0.1, 0.0, 0.0))
                assert loop.time() - t0 > 2 * timeout_s
                await emu.wait_steps(1)
                assert emu.stats.lockstep_timeouts == 0
                silent, k = loop.time(), emu.step_count
                await emu.wait_until(lambda: emu.step_count > k)
                # 10 ms: the last step came just before ``silent`` (wait_steps resumes after it)
                assert loop.time() - silent >= timeout_s - 0.01
                assert emu.stats.lockstep_timeouts == 1
            finally:
                c.close()

    asyncio.run(run())


def test_a_stalled_process_is_not_a_lockstep_timeout() -> None:
    """A loaded machine (or a garbage collection) stalls the whole process,
    station and emulator alike, for longer than ``lockstep_timeout_s``: the
    answer then arrives one loop turn after the timeout timer. That is not a
    lost answer (issue 15 item 12: one timeout failed test_tlog_of_a_run
    under load). Here the client stalls 0.6 s (> the 0.5 s timeout) between
    reading a telemetry and answering it (one task switch, as the station's
    control task), at six steps in a row; the event loop's order is
    deterministic (before: 2 of the 6 counted as timeouts, the step taken
    without its answer)."""

    async def run() -> None:
        async with asyncio.timeout(30), Emulator(_cfg(dynamics="ideal")) as emu:
            c = await connect(emu.endpoints[1])
            c.heartbeat()
            await c.recv("HEARTBEAT")
            ack = await c.command(1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 32, 20000)
            assert ack.result == mav.MAV_RESULT_ACCEPTED
            stalls = 0
            while emu.step_count < 100:
                await c.recv("LOCAL_POSITION_NED")
                if 50 <= emu.step_count < 56:
                    stalls += 1
                    time.sleep(0.6)  # noqa: ASYNC251 - the whole process stalls, on purpose
                    await asyncio.sleep(0)  # the answer is one task switch away
                c.accel(1, (0.1, 0.0, 0.0))
            assert stalls == 6 and emu.stats.lockstep_timeouts == 0
            c.close()

    asyncio.run(run())
