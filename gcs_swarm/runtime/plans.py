"""From a loaded mission to what the station and the bundled emulator are
given: ``station_config`` (the vehicles, by key, with their links and
parameter settings), ``shard_of_network``, ``shard_config`` and
``check_shard_events`` (which shard owns a network, a shard's vehicles and
events, the events a sharded run refuses), ``emulator_config`` (one
network's sim vehicles),
``param_settings``, ``signing_key``, and the end modes and exit codes of
``gcs-swarm run`` (``gcs_swarm.runtime.run`` re-exports all but the shards').
"""

from __future__ import annotations

import os
from collections.abc import Collection, Mapping
from dataclasses import replace

from gcs_swarm.control.velocity_bias import BiasSettings
from gcs_swarm.errors import StartupError, UsageError
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.codec import SIGNING_KEY_BYTES, STATION_SYSID
from gcs_swarm.mavlink.coordinates import (
    GeoOrigin,
    mission_to_ned,
    origin_offset_m,
    vector_mission_to_ned,
)
from gcs_swarm.mavlink.vehicle_params import ParamSettings
from gcs_swarm.mission import GeoPoint as MissionGeoPoint
from gcs_swarm.mission import Mission, Vehicle
from gcs_swarm.mission.source import (
    KEY_FILE_MAX_BYTES,
    key_file_path,
    read_regular,
    signing_key_bytes,
)
from gcs_swarm.runtime.station import StationConfig, VehiclePlan
from sim_vehicle import EmulatorConfig, Impairment, VehicleSpec

__all__ = [
    "END_MODES",
    "EXIT_CODES",
    "LOCKSTEP_GROUND_SPEEDUP",
    "check_shard_events",
    "check_shards",
    "emulator_config",
    "param_settings",
    "shard_config",
    "shard_of_network",
    "signing_key",
    "station_config",
    "steps_per_network",
]


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
        gcs_failsafe=fs.gcs_for(vehicle.autopilot),
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


def steps_per_network(mission: Mission, lockstep: bool) -> bool:
    """Whether a run of ``mission`` steps per network (``mission.step:
    network``, docs/formation-law.md section 3b): in real time only. In
    lockstep every network's emulator reports the same instant and waits for
    its answers, so the step is the whole swarm's, as with ``step: swarm``.
    A step per network there would let a network whose reports came first
    run its emulator a step ahead of the others: the states the law reads,
    and so the flight, would hang on the order the sockets were read in
    (measured before this rule: a sharded run of the two-network demo, 10 s,
    took 977, 991 and 998 steps in three runs against 501, radii 1e-3 m
    apart)."""
    return mission.settings.step == "network" and not lockstep


def station_config(
    mission: Mission, links: Mapping[int, str], *, lockstep: bool = False
) -> StationConfig:
    """The station's view of ``mission``, with each vehicle's connection string
    (``links``, by key: ``Vehicle.key``, the system id without networks) and
    autopilot (ArduCopter GUIDED or PX4 OFFBOARD: mavlink/personality.py)."""
    s = mission.settings
    return StationConfig(
        vehicles=tuple(
            VehiclePlan(
                v.key,
                links[v.key],
                v.start,
                v.q,
                v.reserve,
                param_settings(mission, v),
                autopilot=v.autopilot,
                setpoint=v.setpoint,
                label=mission.label(v.key) if mission.multi_network else "",
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
        handshakes_per_network=s.startup.handshakes_per_network,
        takeoff_alt_m=s.startup.takeoff_alt,
        start_tolerance_m=s.startup.start_tolerance,
        start_speed_tolerance_mps=s.startup.start_speed_tolerance,
        mission_origin=_geo(mission.origin_geo()),
        events=tuple((e.t, e.action, e.key) for e in mission.events),
        lockstep=lockstep,
        delay_compensation=s.delay_compensation,
        step_per_network=steps_per_network(mission, lockstep),
        velocity_bias=BiasSettings(
            correct=s.velocity_bias.correct,
            window_s=s.velocity_bias.window,
            max_mps=s.velocity_bias.max,
        ),
        signing_key=signing_key(mission),
        allow_rebind=s.signing is not None and s.signing.allow_rebind,
    )


def shard_config(full: StationConfig, keys: Collection[int]) -> StationConfig:
    """The part of the station ``full`` a link shard runs: the vehicles of
    ``keys`` and only their join/leave events (the rest are other shards';
    docs/architecture.md, "Scaled out: shards")."""
    return replace(
        full,
        vehicles=tuple(p for p in full.vehicles if p.sysid in keys),
        events=tuple(e for e in full.events if e[2] in keys),
    )


def shard_of_network(mission: Mission, shards: int) -> dict[int, int]:
    """Which shard owns each network (index -> shard): round robin over the
    networks in order, as ``run_sharded`` assigns them (shard i gets
    ``nets[i::shards]``)."""
    nets = sorted({v.net_index for v in mission.vehicles})
    return {n: i % shards for i, n in enumerate(nets)}


def check_shards(mission: Mission, shards: int) -> None:
    """``UsageError`` unless ``mission`` can be flown by ``shards`` shards,
    each owning whole networks (module docstring: what is not sharded yet)."""
    nets = len({v.net_index for v in mission.vehicles})
    if shards < 1:
        raise UsageError(f"--shards: expected a whole number >= 1, got {shards}")
    if shards > nets:
        raise UsageError(
            f"--shards {shards}: a shard owns whole networks and the mission has {nets}"
            " (name more networks: docs/mission-format.md, networks)"
        )
    check_shard_events(mission, shards)


def check_shard_events(mission: Mission, shards: int) -> None:
    """``UsageError`` for the events a shard cannot run as one station would.
    A shard runs its events at its own steps, and it steps only while one of
    its vehicles flies (``swarm.shard``): a join must find its shard flying.
    A departed vehicle's rejoin is not sharded yet: it is readied to its
    slot beside the leader (``swarm.step.run_step``), which only the
    controller knows."""
    owner = shard_of_network(mission, shards)
    flying: dict[int, set[int]] = {i: set() for i in range(shards)}
    for v in mission.initial:
        flying[owner[v.net_index]].add(v.key)
    left: set[int] = set()
    for e in mission.events:  # in time order (the loader sorts them)
        shard = owner[e.net_index]
        what = f"events: vehicle {mission.label(e.key)} joins at t={e.t:g} s"
        if e.action == "leave":
            flying[shard].discard(e.key)
            left.add(e.key)
        elif e.key in left:
            raise UsageError(f"--shards {shards}: {what} after leaving; not sharded yet")
        elif not flying[shard]:
            raise UsageError(f"--shards {shards}: {what} when no vehicle of its shard flies"
                             " (a shard steps only while one does); not sharded yet")  # fmt: skip
        else:
            flying[shard].add(e.key)


def emulator_config(
    mission: Mission, *, airborne: bool = False, network: int | None = None
) -> EmulatorConfig:
    """The ``sim_vehicle.EmulatorConfig`` of the mission's ``sim`` vehicles
    (those of network index ``network`` only: one emulator serves one
    network, whose system ids it speaks; None: every one, for a mission with
    one network).

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
    sims = [v for v in mission.vehicles if v.is_sim]
    mine = [v for v in sims if network is None or v.net_index == network]
    if len({v.net_index for v in mine}) > 1:
        raise ValueError("one emulator serves one network: name it (network=)")
    for v in mine:
        # Snap each home to GPS_GLOBAL_ORIGIN's resolution (1e-7 deg, 1 mm): the
        # station learns origins from that message, and an origin it cannot
        # represent would put a constant bias of up to ~1 cm on the vehicle.
        home = _snap(homes[v.key])
        start, moving = (0.0, 0.0, 0.0), None
        if airborne and not v.reserve:
            offset = origin_offset_m(home, ref)
            ned = mission_to_ned(v.start, offset)
            start = (float(ned[0]), float(ned[1]), float(ned[2]))
            if v.start_velocity is not None:  # Eq. D9: flown from the first setpoint
                vel = vector_mission_to_ned(v.start_velocity)
                moving = (float(vel[0]), float(vel[1]), float(vel[2]))
        specs.append(
            VehicleSpec(
                sysid=v.sysid,
                origin=(home.lat_deg, home.lon_deg, home.alt_m),
                start_ned_m=start,
                airborne=airborne and not v.reserve,
                start_vel_ned_m_s=moving,
                autopilot="px4" if v.autopilot == "px4" else "ardupilot",
            )
        )
    em = mission.emulator
    imp = em.impairments
    # The k-th sim vehicle of the mission (over every network) on base_port + 10 k;
    # shared: network j's on base_port + 10 j (docs/mission-format.md, networks).
    first = sims.index(mine[0]) if mine else 0
    base_port = em.base_port + 10 * first if em.base_port else 0
    shared_port = em.base_port + 10 * (mine[0].net_index if mine else 0) if em.base_port else 0
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
        heartbeats=em.heartbeats,
        overrun=em.overrun,
        base_port=0 if em.shared else base_port,
        shared_port=shared_port if em.shared else None,
        params={} if em.accel_max is None else {"SIM_ACC_MAX": em.accel_max},
        seed=imp.seed,
        uplink=link,
        downlink=link,
        signing_key=signing_key(mission),
    )


def _snap(point: MissionGeoPoint) -> GeoOrigin:
    return GeoOrigin(round(point.lat * 1e7) / 1e7, round(point.lon * 1e7) / 1e7,
                    round(point.alt * 1e3) / 1e3)  # fmt: skip
