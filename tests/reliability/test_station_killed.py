"""The station is killed (SIGKILL) mid-flight, then restarted (issue 9):
``gcs-swarm run`` runs in a subprocess against an emulator in this process
(real time at 2 x, ideal dynamics, real UDP on 127.0.0.1; every time below is
emulator time). Once the law has flown every vehicle for a second, the
station gets SIGKILL: no goodbye, no zero setpoint. Each emulated vehicle
must then, as ArduCopter does, start braking within its GUID_TIMEOUT (0.5 s,
set by the station at start-up) of the last setpoint and come to a stop
(< 0.05 m/s, then holding) within its braking time. A second
``gcs-swarm run`` then finds them hovering, armed in GUIDED, and takes them
over without a second take-off (never landed, never in take-off) and flies
the formation to the end."""

from __future__ import annotations

import asyncio
import math
import sys
from pathlib import Path

from sim_vehicle import Emulator, EmulatorConfig, VehicleSpec

STARTS = {1: (2.0, 1.0, 12.0), 2: (-1.0, -1.0, 9.0), 3: (3.0, 4.0, 12.0)}  # mission frame, m
GUID_TIMEOUT_S = 0.5
DT = 0.02  # emulator step [s]


def _mission(ports: dict[int, int], duration: float = 120.0) -> str:
    vehicles = "\n".join(
        f"  - {{sysid: {s}, link: 'udpout:127.0.0.1:{ports[s]}', start: {list(p)}}}"
        for s, p in STARTS.items()
    )
    # The emulator does not answer SYSID_MYGCS, FENCE_* or the envelope's
    # parameters yet: the vehicle's own failsafe and the reads are off here
    # (docs/vehicle-safety.md), so this is the GUID_TIMEOUT braking alone.
    return f"""
mission:
  name: killed mid-flight
  duration: {duration:g}
  rate: 50
  startup: {{guid_timeout: {GUID_TIMEOUT_S}, read_envelope: false}}
  failsafe: {{gcs: false, fence: false}}
leader: {{start: [0, 0, 10], force: [0, 0, 0]}}
vehicles:
{vehicles}
"""


def _braking_s(v0: float, brake_acc: float) -> float:
    """Emulator braking: deceleration capped at SIM_BRAKE_ACC while the
    velocity loop (gain 1/s) asks for more, then exponential to 0.05 m/s."""
    v_cap = min(v0, brake_acc)  # speed where the 1/s loop asks exactly brake_acc
    return max(0.0, v0 - v_cap) / brake_acc + math.log(max(v_cap, 0.05) / 0.05)


def test_every_vehicle_brakes_and_stops_on_its_own_when_the_station_is_killed(
    tmp_path: Path,
) -> None:
    specs = tuple(
        VehicleSpec(sysid=s, start_ned_m=(y, x, -z), airborne=True)
        for s, (x, y, z) in STARTS.items()
    )
    cfg = EmulatorConfig(vehicles=specs, dynamics="ideal", clock="realtime", speedup=2.0)

    async def main() -> None:
        async with asyncio.timeout(60), Emulator(cfg) as emu:
            ports = {s: a[1] for s, a in emu.endpoints.items()}
            path = tmp_path / "m.yaml"
            path.write_text(_mission(ports))
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "gcs_swarm", "run", "--no-status", "--no-log", str(path),
                stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.DEVNULL,
            )  # fmt: skip
            try:
                flying = lambda: all(emu.vehicle_state(s).control == "accel" for s in STARTS)  # noqa: E731
                await emu.wait_until(flying)
                await emu.wait_steps(50)  # one second of formation flight
                assert flying()
                assert all(emu.vehicle_state(s).params["GUID_TIMEOUT"] == GUID_TIMEOUT_S
                           for s in STARTS)  # fmt: skip
                proc.kill()  # SIGKILL
                t_kill = emu.sim_time_s
            finally:
                if proc.returncode is None:
                    proc.kill()
                await proc.wait()
            brake_at: dict[int, tuple[float, float]] = {}
            stop_at: dict[int, float] = {}
            while len(stop_at) < len(STARTS) and emu.sim_time_s < t_kill + 15.0:
                await emu.wait_steps(1)
                for s in STARTS:
                    st = emu.vehicle_state(s)
                    speed = math.sqrt(sum(v * v for v in st.vel_ned_m_s))
                    if s not in brake_at and st.control == "brake":
                        brake_at[s] = (st.sim_time_s, speed)
                    if s in brake_at and s not in stop_at and st.control == "hold":
                        assert speed < 0.05
                        stop_at[s] = st.sim_time_s
            for s in STARTS:
                st = emu.vehicle_state(s)
                assert st.armed and st.mode_name == "GUIDED"  # as ArduCopter: mode unchanged
                t_brake, v0 = brake_at[s]
                # The last setpoint came at or before the kill; one step of slack.
                assert t_brake - t_kill <= GUID_TIMEOUT_S + DT + 1e-9
                limit = _braking_s(v0, st.params["SIM_BRAKE_ACC"]) + 2 * DT
                assert stop_at[s] - t_brake <= limit, (s, v0, stop_at[s] - t_brake, limit)
            print({s: (round(brake_at[s][0] - t_kill, 3), round(stop_at[s] - t_kill, 3),
                       round(brake_at[s][1], 3)) for s in STARTS})  # fmt: skip

            # The station restarts while they hover, armed in GUIDED: it takes
            # them over without a second take-off and flies the formation again.
            again = tmp_path / "again.yaml"
            again.write_text(_mission(ports, duration=2.0))
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "gcs_swarm", "run", "--no-status", "--no-log", str(again),
                stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT,
            )  # fmt: skip
            seen: set[str] = set()
            while proc.returncode is None:
                await emu.wait_steps(1)
                for s in STARTS:
                    st = emu.vehicle_state(s)
                    assert st.armed and not st.landed  # never down, never a take-off
                    seen.add(st.control)
                if proc.stdout is not None and proc.stdout.at_eof():
                    break
            out = (await proc.communicate())[0].decode()
            assert proc.returncode == 0, out
            assert "takeoff" not in seen and "accel" in seen
            assert "outcome: completed" in out

    asyncio.run(main())
