"""A real-time emulator held behind the wall clock (its loop blocked, as a
loaded machine holds it) with ``overrun: skip`` sends each stream once when
it runs again, not once per step it missed (``server.Emulator._run_realtime``);
with ``catch_up`` (the default, as SITL's simulated clock) every step missed
sends its report, exact in sim time.

ArduCopter 4.5.6 reschedules a message more than an interval late from
now, "we do not want to try to catch up too much"
(``GCS_MAVLINK::update_send``), and PX4's streams likewise from 1.5
intervals late; the emulator used to take the missed steps one after the
other, each with its LOCAL_POSITION_NED, so the station got several reports
of one vehicle within a millisecond and could answer only the last (what
``catch_up`` still does, as SITL would). Here a
vehicle streams LOCAL_POSITION_NED at 50 Hz to a UDP client on 127.0.0.1;
the event loop is blocked for 150 ms (7 steps): afterwards the physics has
gone on by those steps (the steps' count, the reported time), one report
tells of them, and no two reports ever carry times less than a step apart.
With ``catch_up`` the same hold gives reports every 20 ms of vehicle time,
those of the held steps arriving within a few milliseconds of each other.
"""

from __future__ import annotations

import asyncio
import itertools
import time
from typing import Any, Literal

from pymavlink.dialects.v20 import ardupilotmega as mav
from sv_client import connect

from sim_vehicle import Emulator, EmulatorConfig, VehicleSpec

HOLD_S = 0.15
STEP_MS = 20


def _held(mode: Literal["catch_up", "skip"]) -> tuple[list[tuple[float, int]], float,
                                                          float, float, int, int]:  # fmt: skip
    """(arrival, time_boot_ms) of each report, the hold's start and end, the
    steps taken less those the wall clock paced, the overrun and late steps."""

    async def run() -> tuple[list[tuple[float, int]], float, float, float, int, int]:
        spec = VehicleSpec(sysid=1, start_ned_m=(0.0, 0.0, -5.0), airborne=True)
        lpn = {mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 50.0}
        cfg = EmulatorConfig(vehicles=(spec,), streams=lpn, overrun=mode)
        loop = asyncio.get_running_loop()
        seen: list[tuple[float, int]] = []  # (arrival, time_boot_ms) of each report
        async with asyncio.timeout(20), Emulator(cfg) as emu:
            c = await connect(emu.endpoints[1])
            received = c.datagram_received

            def note(data: bytes, addr: Any) -> None:
                before = c.queue.qsize()
                received(data, addr)
                while c.queue.qsize() > before:
                    m = c.queue.get_nowait()
                    if m.get_msgId() == mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
                        seen.append((loop.time(), int(m.time_boot_ms)))

            c.datagram_received = note  # type: ignore[method-assign]
            c.heartbeat()
            await c.wait_datagrams(12)  # streaming
            steps0, overrun0 = emu.step_count, emu.stats.overrun_steps
            held_from = t0 = loop.time()
            time.sleep(HOLD_S)  # noqa: ASYNC251 - the point: the loop held, no step, no read
            held_to = loop.time()
            await asyncio.sleep(0.2)
            paced = (loop.time() - t0) * 1000 / STEP_MS  # the steps the wall clock took
            steps = emu.step_count - steps0 - paced
            overrun = emu.stats.overrun_steps - overrun0
            c.close()
            return seen, held_from, held_to, steps, overrun, emu.stats.late_steps

    return asyncio.run(run())


def test_a_held_emulator_that_skips_reports_once_when_it_runs_again() -> None:
    seen, held_from, held_to, steps, overrun, late = _held("skip")
    # The physics kept the wall clock (within 2 steps: where in its period
    # each end fell, and the loop's own latency).
    assert abs(steps) <= 2, steps
    missed = int(HOLD_S * 1000 / STEP_MS) - 2  # the steps due within the hold, less 2
    assert overrun >= missed and late >= missed
    # Never two reports of one vehicle less than a step apart in vehicle time.
    times = [t for _, t in seen]
    assert all(b - a >= STEP_MS for a, b in itertools.pairwise(times)), times
    # The first report after the hold came alone, not in a burst of the held
    # steps' (catch_up sends about seven within a few milliseconds): within
    # 5 ms of it at most one more, the next step's when the machine ran that
    # one late and the one after on time (measured, with two test workers
    # and a busy loop on two cores: 380 ms of vehicle time 3.4 ms after 360).
    after = [(at, t) for at, t in seen if at >= held_to]
    assert len(after) >= 3
    assert sum(at - after[0][0] < 0.005 for at, _ in after) <= 2, after[:4]
    # ... and tells of the steps missed: its vehicle time is past the hold's.
    before = [t for at, t in seen if at < held_from]
    assert after[0][1] - before[-1] >= HOLD_S * 1000 - STEP_MS


def test_a_held_emulator_that_catches_up_sends_every_step_s_report() -> None:
    seen, _, held_to, steps, overrun, late = _held("catch_up")
    assert abs(steps) <= 2 and overrun == 0 and late >= int(HOLD_S * 1000 / STEP_MS) - 2
    times = [t for _, t in seen]
    assert all(b - a == STEP_MS for a, b in itertools.pairwise(times)), times  # none skipped
    after = [at for at, _ in seen if at >= held_to]
    assert after[1] - after[0] < 0.005  # the held steps' reports: a burst
