"""``gcs-swarm run MISSION.yaml``: from a loaded mission to a flown, ended run.

``run_mission`` is the async entry: it starts the bundled emulator on
127.0.0.1 when vehicles are ``sim`` (unless the caller gives the links),
readies the swarm, flies the formation for the mission's duration, and
always ends every vehicle (zero acceleration, then the end action confirmed
by heartbeat), also when it is cancelled or the start-up fails (then LAND
for the airborne ones; those on the ground are disarmed and every pending
retry is dropped).
The command line's wrapper (Ctrl-C, the status line, what is printed) is
``gcs_swarm.commands.run_command``: nothing here prints.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import shutil
import time
from collections.abc import Callable, Mapping
from contextlib import AbstractAsyncContextManager
from pathlib import Path
from typing import TYPE_CHECKING

from gcs_swarm.errors import LinkError, StartupError
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mission import Mission
from gcs_swarm.offline import demand_report, envelope_demand
from gcs_swarm.report.artefacts import RunFolder, create_run_folder
from gcs_swarm.report.record import FlightRecorder
from gcs_swarm.runtime.ending import EndRequest, unless_ended
from gcs_swarm.runtime.plans import (
    END_MODES,
    EXIT_CODES,
    emulator_config,
    param_settings,
    signing_key,
    station_config,
)
from gcs_swarm.runtime.run_report import (
    frame_sink,
    run_recorder,
    vehicle_param_records,
    write_run_report,
    write_vehicle_params,
)
from gcs_swarm.runtime.station import Station, StationConfig
from gcs_swarm.runtime.summary import RunSummary
from gcs_swarm.runtime.tlog import TlogWriter
from sim_vehicle import Emulator

if TYPE_CHECKING:
    from gcs_swarm.control.envelope import Demand

View = Callable[[Station, EndRequest, FlightRecorder | None], AbstractAsyncContextManager[object]]
"""An operator view's lifetime over the running station (``gcs_swarm.view.live``)."""

__all__ = [
    "END_MODES",
    "EXIT_CODES",
    "emulator_config",
    "param_settings",
    "run_mission",
    "signing_key",
    "station_config",
]

_log = logging.getLogger("gcs_swarm.run")


async def run_mission(
    mission: Mission,
    *,
    links: Mapping[int, str] | None = None,
    lockstep: bool | None = None,
    sim_airborne: bool = False,
    on_status: Callable[[str], None] | None = None,
    on_summary: Callable[[RunSummary], None] | None = None,
    end_timeout_s: float = 15.0,
    log_dir: str | Path | None = None,
    picture: bool = True,
    on_folder: Callable[[RunFolder], None] | None = None,
    view: View | None = None,
) -> RunSummary:
    """Fly ``mission`` and return its summary.

    With ``log_dir`` (``gcs-swarm run`` gives the mission's ``log.dir``) the
    run gets a folder there holding ``flight.tlog`` (every frame
    in and out, plus the station's annotations), a copy of the mission,
    ``summary.json`` and ``report.png`` (unless ``picture`` is False); the
    summary and picture are written however the run ends. ``on_folder``
    gets the folder as soon as it exists. ``view`` is entered once the station
    is up; its ``EndRequest`` (the page's Hold, Land, Return) ends the run
    with that end action, as the end of the mission's duration does.

    ``links`` maps vehicle keys (``Vehicle.key``: the system id on a mission
    without networks) to connection strings and overrides the file's (tests
    point them at their own emulator); vehicles still ``sim`` make this
    start the bundled emulator on 127.0.0.1, one per network. ``lockstep`` tells the station
    the emulator runs in lockstep (default: from the mission, for sim
    vehicles). ``on_summary`` also receives the summary when the run is
    cancelled or fails to start (the exception then propagates).
    Raises ``StartupError`` when the swarm cannot be readied (everyone who
    took off is landed first) and ``LinkError`` when a link cannot be opened.
    """
    wall0 = time.monotonic()
    given = dict(links or {})
    sims = [v for v in mission.vehicles if v.is_sim and v.key not in given]
    if lockstep is None:
        lockstep = bool(sims) and mission.emulator.mode == "lockstep"
    folder: RunFolder | None = None
    recorder: FlightRecorder | None = None
    tlogs: list[TlogWriter] = []
    """One per network, in the mission's order (the first holds the station's notes)."""
    if log_dir is not None:
        folder = create_run_folder(mission, base_dir=log_dir)
        if on_folder is not None:
            on_folder(folder)
    station: Station | None = None
    outcome = "cancelled"

    def log_failed(text: str) -> None:  # logging stopped: say so once, fly on
        if station is not None:
            station.warn(text)
        else:
            _log.warning("%s", text)

    try:
        async with contextlib.AsyncExitStack() as stack:
            if folder is not None:
                for path in folder.tlogs(mission.networks):
                    tlogs.append(await stack.enter_async_context(
                        TlogWriter(path, on_error=log_failed)))  # fmt: skip
                recorder = run_recorder(mission, tlogs[0])
            # One emulator per network: each speaks its own system ids, on its
            # own endpoints (and its own lockstep; the station answers them all).
            for j in sorted({v.net_index for v in sims}):
                cfg = emulator_config(mission, airborne=sim_airborne, network=j)
                try:
                    emu = await stack.enter_async_context(Emulator(cfg))
                except OSError as err:  # e.g. emulator.host does not resolve, a port in use
                    raise LinkError(
                        f"bundled emulator on {cfg.host}: {err.strerror or err}"
                    ) from None
                mine = [v for v in sims if v.net_index == j]
                for v in mine:
                    host, port = emu.endpoints[v.sysid]
                    given[v.key] = f"udpout:{host}:{port}"
                _log.info("bundled emulator: %d vehicles on %s", len(mine), cfg.host)
            for v in mission.vehicles:
                given.setdefault(v.key, v.link)
            station_cfg = station_config(mission, given, lockstep=lockstep)
            network_of = {given[v.key]: v.net_index for v in mission.vehicles}
            station = await stack.enter_async_context(
                Station(
                    _with_end_timeout(station_cfg, end_timeout_s),
                    on_status=on_status,
                    recorder=recorder,
                    on_frame_for=None
                    if not tlogs
                    else lambda link: frame_sink(tlogs[network_of[link]]),
                )
            )
            end_mode: int | None = None
            flew = False
            request = None if view is None else EndRequest()
            if view is not None and request is not None:
                await stack.enter_async_context(view(station, request, recorder))
            # What the gains ask of the vehicle: a whole-mission simulation (seconds),
            # so off the event loop, while the swarm is readied (heartbeats and the
            # vehicles' hold must not stall: their GCS failsafe waits only 5 s).
            demand: asyncio.Future[Demand] | None = None
            if mission.law.limits.envelope.bounded or any(
                p.params.read_envelope for p in station_cfg.vehicles
            ):
                demand = asyncio.ensure_future(asyncio.to_thread(envelope_demand, mission))
            try:
                if not await unless_ended(request, station.ready()):
                    envelope = station.apply_envelope()
                    if demand is not None and envelope.bounded:
                        for line in demand_report(mission, envelope, demand=await demand):
                            station.warn(line)
                    await unless_ended(request, station.fly())
                    flew = True
                if station.failure is not None:
                    end_mode = END_MODES["hold"]  # the law failed in flight: brake everyone
                elif request is not None and request.action is not None:
                    end_mode = END_MODES[request.action]  # the operator's button
                    station.warn(f"ending on the operator's request: {request.action}")
            except StartupError:
                outcome, end_mode = "startup failed", b.COPTER_MODES["LAND"]
                raise
            finally:
                if demand is not None:
                    demand.cancel()  # not needed any more (its thread finishes alone)
                await station.end(end_mode)
            if flew:
                outcome = station.outcome()
    finally:
        if station is None and folder is not None:
            # Nothing was flown or commanded (the links or the emulator did not
            # open): no empty run folder is left behind.
            shutil.rmtree(folder.path, ignore_errors=True)
        # After the station, the emulator and the log have closed: the summary's
        # counters and the flight record then cover every frame in the .tlog.
        if station is not None:
            summary = RunSummary.from_station(
                station,
                outcome=outcome,
                wall_time_s=time.monotonic() - wall0,
                logging_error=next((t.error for t in tlogs if t.error), None),
            )
            if folder is not None:
                write_vehicle_params(folder, vehicle_param_records(station.vehicles))
            if folder is not None and recorder is not None:
                await write_run_report(folder, recorder, summary, picture=picture,
                                       networks=mission.networks)  # fmt: skip
            if on_summary is not None:
                on_summary(summary)
    return summary


def _with_end_timeout(cfg: StationConfig, end_timeout_s: float) -> StationConfig:
    from dataclasses import replace

    return replace(cfg, end_timeout_s=end_timeout_s)
