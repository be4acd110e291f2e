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
import os
import shutil
import time
from collections.abc import Callable, Mapping
from contextlib import AbstractAsyncContextManager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gcs_swarm.control.velocity_bias import BiasSettings
from gcs_swarm.errors import LinkError, StartupError
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.codec import SIGNING_KEY_BYTES, STATION_SYSID
from gcs_swarm.mavlink.coordinates import GeoOrigin, mission_to_ned, origin_offset_m
from gcs_swarm.mavlink.vehicle_params import ParamSettings
from gcs_swarm.mission import GeoPoint as MissionGeoPoint
from gcs_swarm.mission import Mission, Vehicle
from gcs_swarm.mission.source import (
    KEY_FILE_MAX_BYTES,
    key_file_path,
    read_regular,
    signing_key_bytes,
)
from gcs_swarm.offline import demand_report, envelope_demand
from gcs_swarm.report.artefacts import RunFolder, create_run_folder, write_json, write_report
from gcs_swarm.report.record import FlightRecorder
from gcs_swarm.report.replay import safety_applied
from gcs_swarm.runtime.ending import EndRequest, unless_ended
from gcs_swarm.runtime.station import Station, StationConfig, VehiclePlan
from gcs_swarm.runtime.summary import RunSummary
from gcs_swarm.runtime.tlog import TlogWriter
from sim_vehicle import Emulator, EmulatorConfig, Impairment, VehicleSpec

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

END_MODES = {
    "hold": b.COPTER_MODES["BRAKE"],
    "land": b.COPTER_MODES["LAND"],
    "rtl": b.COPTER_MODES["RTL"],
}
"""Mission end action -> ArduCopter mode (mavlink-protocol.md, "Ending")."""

EXIT_CODES = {"completed": 0, "degraded": 1, "failed": 1, "startup failed": 2, "cancelled": 130}
"""``gcs-swarm run``'s exit code per outcome (``Station.outcome``): only a
run in which every vehicle that flew ended is 0."""


LOCKSTEP_GROUND_SPEEDUP = 20.0
"""Pace of a lockstep emulator's ground phases (take-off etc.), x real time."""


def _geo(point: MissionGeoPoint | None) -> GeoOrigin | None:
    return None if point is None else GeoOrigin(point.lat, point.lon, point.alt)


def _key_bytes(raw: bytes, where: str) -> bytes:
    key = signing_key_bytes(raw)
    if key is not None:
        return key
    # Never echo the content: only its length.
    raise StartupError(
        f"{where}: expected a {SIGNING_KEY_BYTES}-byte signing key "
        f"(raw, or {2 * SIGNING_KEY_BYTES} hex digits), got {len(raw)} bytes"
    )


def signing_key(mission: Mission) -> bytes | None:
    """The MAVLink 2 signing key ``mission.signing`` names (None: no signing),
    read from its file or environment variable. ``StartupError`` when it is
    missing or malformed; the message never contains the key."""
    sig = mission.settings.signing
    if sig is None:
        return None
    if sig.key_env is not None:
        value = os.environ.get(sig.key_env)
        if value is None:
            raise StartupError(f"signing key: environment variable {sig.key_env} is not set")
        return _key_bytes(value.encode("utf-8", "replace"), f"signing key in ${sig.key_env}")
    assert sig.key_file is not None
    path = key_file_path(mission.source, sig.key_file)
    try:
        raw = read_regular(path, KEY_FILE_MAX_BYTES)
    except OSError as err:
        raise StartupError(f"signing key file {path}: {err.strerror or err}") from None
    return _key_bytes(raw, f"signing key file {path}")


def param_settings(mission: Mission, vehicle: Vehicle) -> ParamSettings:
    """What the station reads and sets among ``vehicle``'s parameters: the
    mission's ``startup.read_envelope`` and ``failsafe`` keys, where null
    means on for an ``ardupilot`` vehicle and off for a ``sim`` one (today's
    emulator does not answer these parameters: docs/vehicle-safety.md). A
    ``px4`` vehicle, real or emulated, counts as real: the emulator's PX4
    answers its parameters (COM_OF_LOSS_T, COM_OBL_RC_ACT, MPC_*); PX4 gets
    no fence from the station (ArduCopter's FENCE_* only)."""
    s, limits = mission.settings, mission.law.limits
    fs, real = s.failsafe, vehicle.autopilot in ("ardupilot", "px4")

    def on(choice: bool | None) -> bool:
        return real if choice is None else choice

    return ParamSettings(
        read_envelope=on(s.startup.read_envelope),
        gcs_failsafe=on(fs.gcs),
        gcs_timeout_s=fs.timeout,
        fence=on(fs.fence) and limits.geofence_min is not None,
        fence_margin_m=fs.fence_margin,
        restore=fs.restore,
        end=s.end,
        geofence_min=limits.geofence_min,
        geofence_max=limits.geofence_max,
        station_sysid=STATION_SYSID,
        # The envelope of a vehicle that does not answer a read: the mission's
        # (limits.envelope; unbounded when it names none).
        fallback=limits.envelope,
    )


def station_config(
    mission: Mission, links: Mapping[int, str], *, lockstep: bool = False
) -> StationConfig:
    """The station's view of ``mission``, with each vehicle's connection string
    and autopilot (ArduCopter GUIDED or PX4 OFFBOARD: mavlink/personality.py)."""
    s = mission.settings
    return StationConfig(
        vehicles=tuple(
            VehiclePlan(
                v.sysid,
                links[v.sysid],
                v.start,
                v.q,
                v.reserve,
                param_settings(mission, v),
                autopilot=v.autopilot,
                setpoint=v.setpoint,
            )
            for v in mission.vehicles
        ),
        law=mission.law,
        rate_hz=s.rate,
        duration_s=s.duration,
        end_mode=END_MODES[s.end],
        stale_timeout_s=s.stale_timeout,
        ready_timeout_s=s.startup.ready_timeout,
        guid_timeout_s=s.startup.guid_timeout,
        command_attempts=s.startup.command_attempts,
        takeoff_alt_m=s.startup.takeoff_alt,
        start_tolerance_m=s.startup.start_tolerance,
        start_speed_tolerance_mps=s.startup.start_speed_tolerance,
        mission_origin=_geo(mission.origin_geo()),
        events=tuple((e.t, e.action, e.sysid) for e in mission.events),
        lockstep=lockstep,
        delay_compensation=s.delay_compensation,
        velocity_bias=BiasSettings(
            correct=s.velocity_bias.correct,
            window_s=s.velocity_bias.window,
            max_mps=s.velocity_bias.max,
        ),
        signing_key=signing_key(mission),
        allow_rebind=s.signing is not None and s.signing.allow_rebind,
    )


def emulator_config(mission: Mission, *, airborne: bool = False) -> EmulatorConfig:
    """The ``sim_vehicle.EmulatorConfig`` of the mission's ``sim`` vehicles.

    Each sim vehicle's EKF origin (its home, on the ground) comes from the
    mission; with ``airborne`` (or ``emulator.spawn: air``) the initial
    vehicles start armed in GUIDED, hovering at their mission start points
    (the station then takes them over); reserves always start on the ground
    (the station readies them with the others: take-off, then holding at
    their start until their join event). ``emulator.accel_max`` sets SIM_ACC_MAX,
    ``noise_pos``/``noise_vel`` the seeded telemetry noise, ``base_port`` and
    ``shared`` where the endpoints bind.
    """
    airborne = airborne or mission.emulator.spawn == "air"
    origin = mission.origin_geo()
    if origin is None:
        raise StartupError("sim vehicles need a mission origin or a sim first vehicle")
    homes = mission.sim_origins(origin)
    ref = GeoOrigin(origin.lat, origin.lon, origin.alt)
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
                autopilot="px4" if v.autopilot == "px4" else "ardupilot",
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
        accel_tau_s=em.lag,  # None: the preset's (one default, in sim_vehicle's config)
        ekf_ready_s=em.ekf_ready_delay,
        noise_pos_m=em.noise_pos,
        noise_vel_m_s=em.noise_vel,
        vel_bias_ned_m_s=em.velocity_bias_ned,
        vel_bias_flip_s=em.velocity_bias_flip,
        base_port=0 if em.shared else em.base_port,
        shared_port=em.base_port if em.shared else None,
        params={} if em.accel_max is None else {"SIM_ACC_MAX": em.accel_max},
        seed=imp.seed,
        uplink=link,
        downlink=link,
        signing_key=signing_key(mission),
    )


def _snap(point: MissionGeoPoint) -> GeoOrigin:
    return GeoOrigin(round(point.lat * 1e7) / 1e7, round(point.lon * 1e7) / 1e7,
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
    folder: RunFolder | None = None
    recorder: FlightRecorder | None = None
    tlog: TlogWriter | None = None
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
                tlog = await stack.enter_async_context(TlogWriter(folder.tlog, on_error=log_failed))
                recorder = FlightRecorder(
                    name=mission.settings.name,
                    source="run",
                    boxes=mission.law.obstacles,
                    r0=mission.law.avoidance.r0,
                    rate_hz=mission.settings.rate,
                    safety=safety_applied(mission),
                    sink=_note_sink(tlog),
                )
            if sims:
                cfg = emulator_config(mission, airborne=sim_airborne)
                try:
                    emu = await stack.enter_async_context(Emulator(cfg))
                except OSError as err:  # e.g. emulator.host does not resolve, a port in use
                    raise LinkError(
                        f"bundled emulator on {cfg.host}: {err.strerror or err}"
                    ) from None
                for v in sims:
                    host, port = emu.endpoints[v.sysid]
                    given[v.sysid] = f"udpout:{host}:{port}"
                _log.info("bundled emulator: %d vehicles on %s", len(sims), cfg.host)
            for v in mission.vehicles:
                given.setdefault(v.sysid, v.link)
            station_cfg = station_config(mission, given, lockstep=lockstep)
            station = await stack.enter_async_context(
                Station(
                    _with_end_timeout(station_cfg, end_timeout_s),
                    on_status=on_status,
                    recorder=recorder,
                    on_frame=None if tlog is None else _frame_sink(tlog),
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
                logging_error=None if tlog is None else tlog.error,
            )
            if folder is not None:
                _write_vehicle_params(folder, station)
            if folder is not None and recorder is not None:
                await _write_run_report(folder, recorder, summary, picture=picture)
            if on_summary is not None:
                on_summary(summary)
    return summary


def _write_vehicle_params(folder: RunFolder, station: Station) -> None:
    """``vehicle_params.json``: each vehicle's envelope and every parameter the
    station changed on it (old, new, read-back, restored)."""
    records = [vp.vehicle_params.record() for _, vp in sorted(station.vehicles.items())]
    try:
        write_json({"vehicles": records}, folder.vehicle_params)
    except OSError as err:  # never let the record hide how the flight ended
        _log.error("%s: not written: %s", folder.vehicle_params, err.strerror or err)


def _note_sink(tlog: TlogWriter) -> Callable[[bytes], None]:
    def sink(frame: bytes) -> None:
        tlog.write(frame)

    return sink


def _frame_sink(tlog: TlogWriter) -> Callable[[bytes, str], None]:
    def sink(frame: bytes, direction: str) -> None:
        tlog.write(frame)

    return sink


async def _write_run_report(
    folder: RunFolder, recorder: FlightRecorder, summary: RunSummary, *, picture: bool
) -> None:
    """``summary.json`` and ``report.png`` of the run, off the event loop
    (matplotlib takes about a second); the station's link counters go in too."""
    extra: dict[str, Any] = {
        "outcome": summary.outcome,
        "wall_time_s": summary.wall_time_s,
        "startup": {
            "start_tolerance_m": summary.start_tolerance_m,
            "start_speed_tolerance_mps": summary.start_speed_tolerance_mps,
        },
        "links": {
            "messages_sent": summary.messages_sent,
            "setpoints_dropped": summary.setpoints_dropped,
            "messages_dropped": summary.messages_dropped,
            "bad_packets": summary.bad_packets,
            "unknown_sysid_messages": summary.unknown_sysid_messages,
            "spoofed": summary.spoofed,
            "signature_rejected": summary.signature_rejected,
            "rebinds_refused": summary.rebinds_refused,
        },
        # What only the live station knows (a replay of the .tlog cannot).
        "station": {
            "failure": summary.failure,
            "clipped_setpoints": summary.clipped_setpoints,
            "logging_error": summary.logging_error,
            "telemetry_rate": {
                str(v.sysid): {"min_hz": v.telemetry_rate_min_hz, "requests": v.rate_requests}
                for v in summary.vehicles
            },
            "velocity_bias": {
                str(v.sysid): {
                    "estimate_ned_mps": list(v.velocity_bias_ned_mps),
                    "corrected": v.velocity_bias_corrected,
                    "at_cap": v.velocity_bias_saturated,
                }
                for v in summary.vehicles
            },
        },
    }
    rec = recorder.record()
    try:
        await asyncio.shield(
            asyncio.to_thread(
                write_report, rec, folder.summary, folder.picture if picture else None, extra=extra
            )
        )
    except Exception as err:  # never let the report hide how the flight ended
        _log.error("%s: report not written: %s", folder.path, err)


def _with_end_timeout(cfg: StationConfig, end_timeout_s: float) -> StationConfig:
    from dataclasses import replace

    return replace(cfg, end_timeout_s=end_timeout_s)
