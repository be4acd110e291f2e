"""``gcs-swarm run MISSION.yaml``: from a loaded mission to a flown, ended run.

``run_mission`` is the async entry: it starts the bundled emulator on
127.0.0.1 when vehicles are ``sim`` (unless the caller gives the links),
readies the swarm, flies the formation for the mission's duration, and
always ends every vehicle (zero acceleration, then the end action confirmed
by heartbeat), also when it is cancelled or the start-up fails (then LAND).
``run_command`` is the synchronous command-line wrapper: Ctrl-C or SIGTERM
ends the run cleanly, a second Ctrl-C quits at once.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import sys
import time
from collections.abc import Callable, Mapping

from gcs_swarm.errors import StartupError
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.frames import GeoPoint, mission_to_ned, origin_offset_m
from gcs_swarm.mission import GeoPoint as MissionGeoPoint
from gcs_swarm.mission import Mission, load_mission
from gcs_swarm.runtime.station import Station, StationConfig, VehiclePlan
from gcs_swarm.runtime.summary import RunSummary
from sim_vehicle import Emulator, EmulatorConfig, Impairment, VehicleSpec

__all__ = ["END_MODES", "emulator_config", "run_command", "run_mission", "station_config"]

_log = logging.getLogger("gcs_swarm.run")

END_MODES = {
    "hold": b.COPTER_MODES["BRAKE"],
    "land": b.COPTER_MODES["LAND"],
    "rtl": b.COPTER_MODES["RTL"],
}
"""Mission end action -> ArduCopter mode (mavlink-protocol.md, "Ending")."""


LOCKSTEP_GROUND_SPEEDUP = 20.0
"""Pace of a lockstep emulator's ground phases (take-off etc.), x real time."""


def _geo(point: MissionGeoPoint | None) -> GeoPoint | None:
    return None if point is None else GeoPoint(point.lat, point.lon, point.alt)


def station_config(
    mission: Mission, links: Mapping[int, str], *, lockstep: bool = False
) -> StationConfig:
    """The station's view of ``mission``, with each vehicle's connection string.
    ``StartupError`` for a PX4 vehicle: the station speaks ArduCopter's GUIDED
    only (PX4's OFFBOARD is in mavlink-protocol.md "for later")."""
    px4 = [v.sysid for v in mission.vehicles if v.autopilot == "px4"]
    if px4:
        raise StartupError(f"vehicles {px4}: PX4 (OFFBOARD) is not supported by the station yet")
    s = mission.settings
    return StationConfig(
        vehicles=tuple(
            VehiclePlan(v.sysid, links[v.sysid], v.start, v.q, v.reserve) for v in mission.vehicles
        ),
        law=mission.law,
        rate_hz=s.rate,
        duration_s=s.duration,
        end_mode=END_MODES[s.end],
        stale_timeout_s=s.stale_timeout,
        ready_timeout_s=s.startup.ready_timeout,
        guid_timeout_s=s.startup.guid_timeout,
        takeoff_alt_m=s.startup.takeoff_alt,
        mission_origin=_geo(mission.origin_geo()),
        events=tuple((e.t, e.action, e.sysid) for e in mission.events),
        lockstep=lockstep,
    )


def emulator_config(mission: Mission, *, airborne: bool = False) -> EmulatorConfig:
    """The ``sim_vehicle.EmulatorConfig`` of the mission's ``sim`` vehicles.

    Each sim vehicle's EKF origin (its home, on the ground) comes from the
    mission; with ``airborne`` the initial vehicles start armed in GUIDED,
    hovering at their mission start points (the station then takes them
    over); reserves always wait on the ground until their join event.
    """
    origin = mission.origin_geo()
    if origin is None:
        raise StartupError("sim vehicles need a mission origin or a sim first vehicle")
    homes = mission.sim_origins(origin)
    ref = GeoPoint(origin.lat, origin.lon, origin.alt)
    specs = []
    for v in mission.vehicles:
        if not v.is_sim:
            continue
        # Snap each home to GPS_GLOBAL_ORIGIN's resolution (1e-7 deg, 1 mm): the
        # station learns origins from that message, and an origin it cannot
        # represent would put a constant bias of up to ~1 cm on the vehicle.
        home = _snap(homes[v.sysid])
        start = (0.0, 0.0, 0.0)
        if airborne and not v.reserve:
            offset = origin_offset_m(home, ref)
            ned = mission_to_ned(v.start, offset)
            start = (float(ned[0]), float(ned[1]), float(ned[2]))
        specs.append(
            VehicleSpec(
                sysid=v.sysid,
                origin=(home.lat_deg, home.lon_deg, home.alt_m),
                start_ned_m=start,
                airborne=airborne and not v.reserve,
            )
        )
    em = mission.emulator
    imp = em.impairments
    link = Impairment(loss=imp.loss, delay_s=imp.delay, jitter_s=imp.jitter,
                      duplicate=imp.duplicate)  # fmt: skip
    return EmulatorConfig(
        vehicles=tuple(specs),
        host=em.host,
        rate_hz=mission.settings.rate,
        clock=em.mode,
        # Lockstep: steps taken while no vehicle holds the clock (start-up on
        # the ground, after the ending) are paced at speedup x wall clock
        # (sim_vehicle lockstep rule 4); the mission's speedup is realtime-only.
        speedup=em.speedup if em.mode == "realtime" else LOCKSTEP_GROUND_SPEEDUP,
        dynamics="ideal" if em.dynamics == "ideal" else "ardupilot",
        accel_tau_s=em.lag_s,
        ekf_ready_s=em.ekf_ready_delay,
        seed=imp.seed,
        uplink=link,
        downlink=link,
    )


def _snap(point: MissionGeoPoint) -> GeoPoint:
    return GeoPoint(round(point.lat * 1e7) / 1e7, round(point.lon * 1e7) / 1e7,
                    round(point.alt * 1e3) / 1e3)  # fmt: skip


async def run_mission(
    mission: Mission,
    *,
    links: Mapping[int, str] | None = None,
    lockstep: bool | None = None,
    sim_airborne: bool = False,
    on_status: Callable[[str], None] | None = None,
    on_summary: Callable[[RunSummary], None] | None = None,
    end_timeout_s: float = 15.0,
) -> RunSummary:
    """Fly ``mission`` and return its summary.

    ``links`` maps system ids to connection strings and overrides the file's
    (tests point them at their own emulator); vehicles still ``sim`` make this
    start the bundled emulator on 127.0.0.1. ``lockstep`` tells the station
    the emulator runs in lockstep (default: from the mission, for sim
    vehicles). ``on_summary`` also receives the summary when the run is
    cancelled or fails to start (the exception then propagates).
    Raises ``StartupError`` when the swarm cannot be readied (everyone who
    took off is landed first) and ``LinkError`` when a link cannot be opened.
    """
    wall0 = time.monotonic()
    given = dict(links or {})
    sims = [v for v in mission.vehicles if v.is_sim and v.sysid not in given]
    if lockstep is None:
        lockstep = bool(sims) and mission.emulator.mode == "lockstep"
    async with contextlib.AsyncExitStack() as stack:
        if sims:
            cfg = emulator_config(mission, airborne=sim_airborne)
            emu = await stack.enter_async_context(Emulator(cfg))
            for v in sims:
                host, port = emu.endpoints[v.sysid]
                given[v.sysid] = f"udpout:{host}:{port}"
            _log.info("bundled emulator: %d vehicles on %s", len(sims), cfg.host)
        for v in mission.vehicles:
            given.setdefault(v.sysid, v.link)
        station_cfg = station_config(mission, given, lockstep=lockstep)
        station = await stack.enter_async_context(
            Station(_with_end_timeout(station_cfg, end_timeout_s), on_status=on_status)
        )
        outcome = "cancelled"
        end_mode: int | None = None
        try:
            await station.ready()
            await station.fly()
            outcome = "completed"
        except StartupError:
            outcome, end_mode = "startup failed", b.COPTER_MODES["LAND"]
            raise
        finally:
            await station.end(end_mode)
            summary = RunSummary.from_station(
                station, outcome=outcome, wall_time_s=time.monotonic() - wall0
            )
            if on_summary is not None:
                on_summary(summary)
    return summary


def _with_end_timeout(cfg: StationConfig, end_timeout_s: float) -> StationConfig:
    from dataclasses import replace

    return replace(cfg, end_timeout_s=end_timeout_s)


def run_command(path: str, *, status: bool = True) -> int:
    """``gcs-swarm run PATH``: exit 0 when the mission completed, 130 when it
    was interrupted. ``SwarmError`` (bad file, start-up failure) propagates
    for the command line to print as one line."""
    mission = load_mission(path)
    return asyncio.run(_main(mission, status=status))


async def _main(mission: Mission, *, status: bool) -> int:
    loop = asyncio.get_running_loop()
    task = asyncio.current_task()
    assert task is not None
    hits = 0

    def interrupt() -> None:
        nonlocal hits
        hits += 1
        if hits == 1:
            print("\nending: zero acceleration and the end action for every vehicle "
                  "(Ctrl-C again to quit at once)", file=sys.stderr)  # fmt: skip
        task.cancel()

    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, interrupt)
    tty = sys.stderr.isatty()

    lines = 0

    def show(line: str) -> None:
        nonlocal lines
        lines += 1
        if tty:
            print("\r" + line[:200].ljust(120), end="", file=sys.stderr, flush=True)
        elif lines % 5 == 1:  # a log file gets one line every 5 s
            print(line, file=sys.stderr)

    def report(summary: RunSummary) -> None:
        if tty:
            print(file=sys.stderr)
        print(summary.format())

    try:
        await run_mission(mission, on_status=show if status else None, on_summary=report)
    except asyncio.CancelledError:
        return 130
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
    return 0
