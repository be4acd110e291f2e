"""The loaded mission: frozen dataclasses, SI units, mission frame.

Owns the shape of a validated mission file. The formation law's own
parameters are ``gcs_swarm.control.params.LawConfig`` (a field of ``Mission``);
everything else the station, the emulator and the logger need lives here.

Frame: the mission frame is x east, y north, z up, metres, with its origin at
the mission origin (formation-law.md section 1). Geodetic points are degrees
and metres above mean sea level.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from gcs_swarm.control.params import LawConfig, Vec3
from gcs_swarm.control.velocity_bias import BiasSettings

__all__ = [
    "DEFAULT_NETWORK",
    "DEFAULT_SIM_HOME",
    "EARTH_RADIUS_M",
    "KEY_STRIDE",
    "Autopilot",
    "Dynamics",
    "Emulator",
    "EmulatorMode",
    "EndAction",
    "Event",
    "EventAction",
    "Failsafe",
    "GeoPoint",
    "Heartbeats",
    "Impairments",
    "LogSettings",
    "Mission",
    "Overrun",
    "Settings",
    "Signing",
    "Spawn",
    "Startup",
    "Vehicle",
    "VelocityBias",
    "enu_offset_m",
    "geodetic_at",
    "key_label",
    "vehicle_key",
]

Autopilot = Literal["ardupilot", "sim", "px4"]
Setpoint = Literal["acceleration", "velocity+acceleration"]
EndAction = Literal["hold", "land", "rtl"]
EmulatorMode = Literal["lockstep", "realtime"]
Dynamics = Literal["ideal", "ardupilot-like"]
Spawn = Literal["ground", "air"]
Heartbeats = Literal["together", "spread"]
Overrun = Literal["catch_up", "skip"]
EventAction = Literal["join", "leave"]

#: Name of the one network of a mission without ``networks:`` (docs/mission-format.md).
DEFAULT_NETWORK = "default"
#: A vehicle's key is ``network index * KEY_STRIDE + system id``: unique over
#: the mission's networks, and equal to the system id in the first network.
KEY_STRIDE = 256


def vehicle_key(net_index: int, sysid: int) -> int:
    """The vehicle's identity in the station: (network, system id) as one
    integer, ``net_index * KEY_STRIDE + sysid`` (the system id itself in
    network 0, so a mission without networks keys vehicles as it always did)."""
    return net_index * KEY_STRIDE + sysid


def key_label(key: int, networks: tuple[str, ...] = (DEFAULT_NETWORK,)) -> str:
    """How a vehicle is named to people: its system id alone in a mission
    without networks (``"7"``), else ``"network:sysid"`` (``"blue:7"``)."""
    index, sysid = divmod(key, KEY_STRIDE)
    if networks == (DEFAULT_NETWORK,) and index == 0:
        return str(sysid)
    name = networks[index] if index < len(networks) else f"#{index}"
    return f"{name}:{sysid}"


#: Flat-earth radius of mavlink-protocol.md "Frames and origins" [m].
EARTH_RADIUS_M = 6378137.0


@dataclass(frozen=True)
class GeoPoint:
    """A geodetic point: ``lat`` and ``lon`` [deg, WGS84], ``alt`` [m AMSL]."""

    lat: float
    lon: float
    alt: float


#: Ground location of the bundled emulator's first vehicle when the mission
#: origin is ``first-vehicle`` (ArduPilot SITL's default "CMAC" home) [deg, deg, m].
DEFAULT_SIM_HOME = GeoPoint(lat=-35.363261, lon=149.165230, alt=584.0)


def enu_offset_m(origin: GeoPoint, point: GeoPoint) -> Vec3:
    """Position of ``point`` relative to ``origin`` in metres, (east, north, up).

    Flat earth, as mavlink-protocol.md allows at swarm scale:
    north = dlat * R, east = dlon * R * cos(lat), up = dalt.
    """
    north = math.radians(point.lat - origin.lat) * EARTH_RADIUS_M
    east = (
        math.radians(point.lon - origin.lon) * EARTH_RADIUS_M * math.cos(math.radians(origin.lat))
    )
    return (east, north, point.alt - origin.alt)


def geodetic_at(origin: GeoPoint, offset_enu_m: Vec3) -> GeoPoint:
    """The geodetic point at ``offset_enu_m`` (east, north, up) [m] from ``origin``;
    the inverse of ``enu_offset_m``."""
    east, north, up = offset_enu_m
    lat = origin.lat + math.degrees(north / EARTH_RADIUS_M)
    lon = origin.lon + math.degrees(east / (EARTH_RADIUS_M * math.cos(math.radians(origin.lat))))
    return GeoPoint(lat=lat, lon=lon, alt=origin.alt + up)


@dataclass(frozen=True)
class Startup:
    """Start-up sequence settings (mavlink-protocol.md "Start-up sequence").

    takeoff_alt [m] above each vehicle's home; ready_timeout [s] for every
    vehicle (reserves too) to be armed, airborne and at its start; guid_timeout
    [s] the GUID_TIMEOUT parameter the station sets before the formation
    starts; start_tolerance [m] and start_speed_tolerance [m/s]: a vehicle is
    at its start (READY) within this distance of it and below this speed;
    read_envelope: read each vehicle's position-controller limits
    (WPNAV_*, PSC_JERK_*, ANGLE_MAX) at start-up; None: for ``ardupilot``
    vehicles, not for ``sim`` ones; command_attempts: each command is sent at
    most this many times, 1 s apart, before the vehicle fails;
    handshakes_per_network: at most this many vehicles of one network in their
    start-up handshake (CONFIGURING) at once, None: no bound
    (``gcs_swarm.swarm.handshakes``). These defaults
    are the station's too (``ProtocolConfig``, ``StationConfig`` take theirs
    from here: one place for each).
    """

    takeoff_alt: float = 5.0
    ready_timeout: float = 90.0
    guid_timeout: float = 0.5
    start_tolerance: float = 0.3
    start_speed_tolerance: float = 0.3
    read_envelope: bool | None = None
    command_attempts: int = 10
    handshakes_per_network: int | None = None


@dataclass(frozen=True)
class VelocityBias:
    """The ``mission.velocity_bias`` block (docs/velocity-bias.md): estimate a
    constant bias in each vehicle's reported velocity from its own positions
    over ``window`` [s] of telemetry and, with ``correct``, take it out of the
    velocity the law damps (Eq. 1); estimates longer than ``max`` [m/s] are
    held at ``max`` and reported. Defaults: the estimator's own."""

    correct: bool = BiasSettings.correct
    window: float = BiasSettings.window_s
    max: float = BiasSettings.max_mps


@dataclass(frozen=True)
class Failsafe:
    """The ``mission.failsafe`` block: what the station sets on each vehicle
    itself, so that a vehicle that loses the station comes down on its own
    (docs/vehicle-safety.md).

    gcs: set the GCS-loss failsafe (FS_GCS_ENABLE from ``mission.end``: rtl
    -> RTL, land and hold -> Land; FS_GCS_TIMEOUT; SYSID_MYGCS 255);
    timeout [s] FS_GCS_TIMEOUT; fence: set the vehicle's fence (max altitude
    and circle) around ``limits.geofence``, ``fence_margin`` [m] beyond it;
    restore: put every changed parameter back when the vehicle has ended.
    ``gcs`` and ``fence`` None: on for ``ardupilot`` vehicles, off for
    ``sim`` ones (the fence only where a geofence is given).
    """

    gcs: bool | None = None
    timeout: float = 5.0
    fence: bool | None = None
    fence_margin: float = 5.0
    restore: bool = True

    def gcs_for(self, autopilot: str) -> bool:
        """Whether the GCS-loss failsafe is set on a vehicle of ``autopilot``
        (the mission's: ardupilot, px4 or sim): ``gcs``, or when it is None,
        on for a real autopilot's and off for a sim one's."""
        return autopilot in ("ardupilot", "px4") if self.gcs is None else self.gcs


@dataclass(frozen=True)
class Signing:
    """The ``mission.signing`` block: MAVLink 2 message signing, both ways.

    Exactly one of ``key_file`` (a path, relative to the mission file, holding
    the 32-byte key raw or as 64 hex digits) or ``key_env`` (the name of an
    environment variable holding 64 hex digits). The key itself is never in
    the mission and never logged. ``allow_rebind``: a vehicle silent for 5 s
    may be taken over by a new address whose frames are well signed
    (otherwise, and always without signing, a system id stays bound to the
    address it was first heard from for the whole run).
    """

    key_file: str | None = None
    key_env: str | None = None
    allow_rebind: bool = False


@dataclass(frozen=True)
class Settings:
    """The ``mission:`` block.

    duration [s] of the formation phase; rate [Hz] of the control loop and of
    the telemetry asked for; origin of the mission frame (a geodetic point, or
    ``"first-vehicle"``: see ``Mission.origin_geo``); end action; stale_timeout
    [s] after which a silent vehicle is dropped from the formation;
    link_budget [setpoints/s] that one link may carry (vehicles on it x rate);
    delay_compensation: predict each vehicle's state to the time its setpoint
    will land, from TIMESYNC round trips (for real-time radio links);
    step: one control step once every flying vehicle's report is in
    ("swarm"), or one per network once that network's are ("network");
    signing: where the MAVLink 2 signing key is (None: no signing);
    failsafe: what the station sets on the vehicles themselves;
    velocity_bias: the reported velocity's bias, estimated and corrected.
    """

    name: str
    duration: float = 60.0
    rate: float = 50.0
    origin: GeoPoint | Literal["first-vehicle"] = "first-vehicle"
    end: EndAction = "hold"
    stale_timeout: float = 1.0
    link_budget: float = 2000.0
    delay_compensation: bool = False
    step: Literal["swarm", "network"] = "swarm"
    startup: Startup = field(default_factory=Startup)
    signing: Signing | None = None
    failsafe: Failsafe = field(default_factory=Failsafe)
    velocity_bias: VelocityBias = field(default_factory=VelocityBias)


@dataclass(frozen=True)
class Vehicle:
    """One vehicle of the ``vehicles:`` list.

    sysid: MAVLink system id 1..255; link: pymavlink-style connection string
    (``udpin:HOST:PORT``, ``udpout:``, ``tcp:``, ``tcpin:``) or ``"sim"`` (the
    bundled emulator); start [m] mission frame; q [C] charge (Eq. 9);
    reserve: joins on an event instead of flying from the start; origin: only
    for ``sim`` vehicles, the vehicle's EKF origin (its home, on the ground)
    either as an offset [m] in the mission frame or as a geodetic point.
    After loading, every sim vehicle has an origin (defaults filled in).
    setpoint: what its setpoints carry, the law's acceleration alone or with
    the velocity it integrates to (Eq. V1, docs/setpoints.md).
    start_velocity [m/s] mission frame: only for sim vehicles spawned in the
    air, the velocity it flies from at its first acceleration setpoint
    (None: at rest; docs/emulator.md, Eq. D9).
    """

    sysid: int
    link: str
    autopilot: Autopilot
    start: Vec3
    q: float
    reserve: bool = False
    origin: Vec3 | GeoPoint | None = None
    setpoint: Setpoint = "acceleration"
    start_velocity: Vec3 | None = None
    network: str = DEFAULT_NETWORK
    """The network it is on (its system-id space and links); ``net_index`` its
    place in the mission's ``networks`` list."""
    net_index: int = 0
    where: str = field(default="", compare=False, repr=False)
    """Its key path in the file (``vehicles[2]``, ``networks[1].vehicles[0]``)."""

    @property
    def key(self) -> int:
        """(network, system id) as one integer (``vehicle_key``)."""
        return self.net_index * KEY_STRIDE + self.sysid

    @property
    def is_sim(self) -> bool:
        """True when the bundled emulator hosts this vehicle (``link: sim``)."""
        return self.link == "sim"


@dataclass(frozen=True)
class Impairments:
    """Seeded link impairments of the emulator, applied in both directions.

    loss, duplicate: probabilities 0..1 per packet; delay, jitter [s].
    """

    loss: float = 0.0
    delay: float = 0.0
    jitter: float = 0.0
    duplicate: float = 0.0
    seed: int = 0


@dataclass(frozen=True)
class Emulator:
    """The bundled emulator, used by vehicles whose link is ``sim``.

    mode: ``lockstep`` (one step per answered telemetry) or ``realtime``
    (times ``speedup``); dynamics ``ideal`` or ``ardupilot-like``; lag [s]
    first-order acceleration lag (``None``: the emulator preset's, 0 for
    ideal, 0.1 for ardupilot-like: docs/emulator.md); ekf_ready_delay [s]
    before arming is accepted;
    ground [m] mission-frame z of the sim vehicles' homes (their EKF origins)
    unless a vehicle names its own origin; origin_spread [m] east spacing of
    the default homes (like SITL instances 5 m apart); accel_max [m/s^2]
    the emulator's clamp on the commanded acceleration (``None``: the
    emulator's own default, SIM_ACC_MAX); noise_pos [m] and noise_vel [m/s]
    standard deviations of seeded noise on LOCAL_POSITION_NED;
    velocity_bias_ned [m/s] a constant added to every reported velocity
    (``None``: the preset's, ArduCopter SITL's figure for ardupilot-like,
    none for ideal; docs/velocity-bias.md); velocity_bias_flip [s] the
    vehicles' boot time at which that bias starts to reverse (0: never;
    ``None``: the preset's, 304 s as on ArduCopter SITL for ardupilot-like);
    heartbeats: ``together`` (each vehicle's 1 Hz HEARTBEAT in the same step,
    as a SITL swarm started by one script) or ``spread`` (each at its own
    phase, as a fleet booted one by one); overrun: a real-time emulator
    held behind the wall clock takes the missed steps ``catch_up`` (each
    with its messages, as SITL's clock catches up) or ``skip`` (physics
    alone, then each stream once, as an autopilot whose loop overran:
    docs/emulator.md, "A late clock"); spawn:
    ``ground`` (landed at home, full start-up) or ``air`` (armed, GUIDED,
    hovering at the start position); host and base_port: where the
    endpoints bind (port ``base_port + 10 k`` for the k-th sim vehicle, like
    SITL instances; 0: free ports); shared: every sim vehicle on one
    endpoint, told apart by system id (like ``sim_vehicle.py --mcast``).
    """

    mode: EmulatorMode = "realtime"
    speedup: float = 1.0
    dynamics: Dynamics = "ardupilot-like"
    lag: float | None = None
    accel_max: float | None = None
    ekf_ready_delay: float = 2.0
    noise_pos: float = 0.0
    noise_vel: float = 0.0
    velocity_bias_ned: tuple[float, float, float] | None = None
    velocity_bias_flip: float | None = None
    heartbeats: Heartbeats = "together"
    overrun: Overrun = "catch_up"
    ground: float = -20.0
    origin_spread: float = 5.0
    spawn: Spawn = "ground"
    host: str = "127.0.0.1"
    base_port: int = 0
    shared: bool = False
    impairments: Impairments = field(default_factory=Impairments)


@dataclass(frozen=True)
class Event:
    """At mission time ``t`` [s] (from the formation start) vehicle ``sysid``
    of network ``network`` (index ``net_index``) joins or leaves the formation."""

    t: float
    action: EventAction
    sysid: int
    network: str = DEFAULT_NETWORK
    net_index: int = 0

    @property
    def key(self) -> int:
        """The vehicle's key (``vehicle_key``)."""
        return self.net_index * KEY_STRIDE + self.sysid


@dataclass(frozen=True)
class LogSettings:
    """Where run artefacts go: ``dir`` (relative paths are relative to the
    current directory when the station starts)."""

    dir: str = "runs"


@dataclass(frozen=True)
class Mission:
    """A validated mission file. ``law`` is what ``gcs_swarm.control`` takes."""

    source: str
    settings: Settings
    vehicles: tuple[Vehicle, ...]
    law: LawConfig = field(default_factory=LawConfig)
    emulator: Emulator = field(default_factory=Emulator)
    events: tuple[Event, ...] = ()
    log: LogSettings = field(default_factory=LogSettings)
    networks: tuple[str, ...] = (DEFAULT_NETWORK,)
    """The networks' names in file order (one ``default`` without ``networks:``)."""
    text: str = field(default="", repr=False, compare=False)
    """The YAML exactly as read and validated: a run folder's copy of the
    mission is this, not the file re-read later (it may have changed)."""

    def law_config(self) -> LawConfig:
        """The law's parameters (same object as ``self.law``)."""
        return self.law

    def vehicle(self, key: int) -> Vehicle:
        """The vehicle with key ``key`` (its system id in a mission without
        networks; KeyError if none)."""
        for v in self.vehicles:
            if v.key == key:
                return v
        raise KeyError(key)

    @property
    def multi_network(self) -> bool:
        """True when the file names its networks (``networks:``)."""
        return self.networks != (DEFAULT_NETWORK,)

    def label(self, key: int) -> str:
        """The vehicle ``key`` as people read it (``key_label``)."""
        return key_label(key, self.networks)

    def network_vehicles(self, index: int) -> tuple[Vehicle, ...]:
        """The vehicles of network ``index``, file order."""
        return tuple(v for v in self.vehicles if v.net_index == index)

    @property
    def initial(self) -> tuple[Vehicle, ...]:
        """Vehicles in the formation from the start (not reserves), file order."""
        return tuple(v for v in self.vehicles if not v.reserve)

    @property
    def reserves(self) -> tuple[Vehicle, ...]:
        """Vehicles that join on an event, file order."""
        return tuple(v for v in self.vehicles if v.reserve)

    def origin_geo(self) -> GeoPoint | None:
        """The mission origin as a geodetic point, when the file fixes it.

        - an explicit ``mission.origin`` is returned as is;
        - ``first-vehicle`` with a ``sim`` first vehicle: that vehicle's home is
          ``DEFAULT_SIM_HOME`` (or its own geodetic origin), and the mission
          origin is placed so that the home sits at the vehicle's origin offset
          (by default ``emulator.ground`` metres, i.e. 20 m below);
        - ``first-vehicle`` with a real first vehicle: ``None``; the station
          reads it from that vehicle's GPS_GLOBAL_ORIGIN.
        """
        origin = self.settings.origin
        if isinstance(origin, GeoPoint):
            return origin
        first = self.vehicles[0]
        if not first.is_sim:
            return None
        if isinstance(first.origin, GeoPoint):
            return first.origin
        offset = first.origin if first.origin is not None else (0.0, 0.0, 0.0)
        return geodetic_at(DEFAULT_SIM_HOME, (-offset[0], -offset[1], -offset[2]))

    def sim_origins(self, mission_origin: GeoPoint) -> dict[int, GeoPoint]:
        """Geodetic EKF origin (home) of every ``sim`` vehicle, by key,
        given the resolved mission origin (``origin_geo()`` or, for a real
        first vehicle, its GPS_GLOBAL_ORIGIN)."""
        out: dict[int, GeoPoint] = {}
        for v in self.vehicles:
            if not v.is_sim:
                continue
            if isinstance(v.origin, GeoPoint):
                out[v.key] = v.origin
            else:
                offset = v.origin if v.origin is not None else (0.0, 0.0, self.emulator.ground)
                out[v.key] = geodetic_at(mission_origin, offset)
        return out
