"""What the station needs from a mission: the vehicles and the settings
(``gcs_swarm.runtime.run.station_config`` builds them from a loaded mission)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from gcs_swarm.control.params import LawConfig, Vec3
from gcs_swarm.control.velocity_bias import BiasSettings
from gcs_swarm.mavlink.coordinates import GeoOrigin
from gcs_swarm.mavlink.states import ProtocolConfig
from gcs_swarm.mavlink.vehicle_params import ParamSettings
from gcs_swarm.mission.model import KEY_STRIDE, Startup

__all__ = ["StationConfig", "VehiclePlan"]


@dataclass(frozen=True)
class VehiclePlan:
    """One vehicle as the station sees it: ``sysid`` its key (its system id,
    plus network index * 256 on a later network: ``mission.vehicle_key``),
    ``link`` a connection string, ``start_m`` mission frame [m], ``q``
    charge [C] (Eq. 9), ``params`` what the station reads and sets among its
    parameters (envelope, failsafe, fence)."""

    sysid: int
    link: str
    start_m: Vec3
    q: float
    reserve: bool = False
    params: ParamSettings = field(default_factory=ParamSettings)
    autopilot: str = "ardupilot"
    """The mission's ``autopilot`` (ardupilot, sim or px4): its personality."""
    setpoint: str = "acceleration"
    """The mission's ``setpoint``: ``acceleration`` (type_mask 3135) or
    ``velocity+acceleration`` (3079, Eq. V1 of docs/setpoints.md)."""
    label: str = ""
    """How people read its identity (``blue:7``; empty: the key as a number)."""

    @property
    def base(self) -> int:
        """Its key less its system id: its network index * 256."""
        return self.sysid - self.sysid % KEY_STRIDE


@dataclass(frozen=True)
class StationConfig:
    """What the station needs from a mission. Times in seconds: ``duration_s``
    and event times are mission (vehicle) time from the formation start;
    ``ready_timeout_s`` and ``end_timeout_s`` are station (wall) time.
    What it shares with ``ProtocolConfig`` defaults to ``ProtocolConfig``'s
    value (one place); the mission's own defaults are kept equal to these by
    ``tests/mission/test_defaults_agree.py``."""

    vehicles: tuple[VehiclePlan, ...]
    law: LawConfig
    rate_hz: float = ProtocolConfig.control_rate_hz
    duration_s: float = 60.0
    end_mode: int = ProtocolConfig.end_mode
    stale_timeout_s: float = ProtocolConfig.stale_timeout_s
    ready_timeout_s: float = Startup.ready_timeout
    end_timeout_s: float = 15.0
    guid_timeout_s: float = ProtocolConfig.guid_timeout_s
    takeoff_alt_m: float = ProtocolConfig.takeoff_min_alt_m
    start_tolerance_m: float = ProtocolConfig.goto_tolerance_m
    start_speed_tolerance_mps: float = ProtocolConfig.goto_speed_tolerance_mps
    """At its start (READY) within this distance [m] and below this speed [m/s]."""
    mission_origin: GeoOrigin | None = None
    events: tuple[tuple[float, str, int], ...] = ()
    lockstep: bool = False
    delay_compensation: bool = False
    step_per_network: bool = False
    """A step per network whose reports are all in (``mission.step: network``,
    docs/formation-law.md section 3b), instead of one once every report is."""
    predict_accel_max_mps2: float = 5.0
    """Acceleration a vehicle is taken to follow when its state is predicted
    over the commands in flight (the emulator's SIM_ACC_MAX default)."""
    signing_key: bytes | None = field(default=None, repr=False)
    """MAVLink 2 signing key (32 bytes) of every link; never shown."""
    velocity_bias: BiasSettings = field(default_factory=BiasSettings)
    """The reported velocity's bias: estimated, and corrected (docs/velocity-bias.md)."""
    command_attempts: int = ProtocolConfig.command_attempts
    """Each command sent at most this many times (``mission.startup.command_attempts``)."""
    handshakes_per_network: int | None = Startup.handshakes_per_network
    """At most this many vehicles of one network in their start-up handshake
    (CONFIGURING) at once, the others waiting in the order heard; None: no
    bound (``mission.startup.handshakes_per_network``, ``swarm.handshakes``)."""
    allow_rebind: bool = False
    """A well-signed new address may take over a vehicle silent for
    ``links.REBIND_S`` (needs ``signing_key``; ``mission.signing.allow_rebind``)."""

    def step_groups(self) -> list[int] | None:
        """Each vehicle's network as 0, 1, ... in ``vehicles`` order when
        ``step_per_network`` (the telemetry table's groups), else None."""
        if not self.step_per_network:
            return None
        bases = sorted({p.base for p in self.vehicles})
        return [bases.index(p.base) for p in self.vehicles]

    def status_phases(self) -> dict[int, float]:
        """Each vehicle's ``VehicleProtocol.status_phase``: the k-th of a
        network's n vehicles (``vehicles`` order) k / n. An autopilot sends
        its status streams together, on the phase the first ask set, so
        vehicles readied together would all send theirs in one control
        period: 875 frames at once from a network of 250, a burst of three
        times a period's traffic on its radio, and a 6-7 ms step of the
        emulator's loop (benchmarks/README.md, "Scale, 2026-12-06 (eleventh
        session)": no clear change of the station's own latency).
        All 0 in ``lockstep``: the emulator's clock waits for the station
        there, and a wait on the station's clock would make the start-up's
        steps depend on the wall clock, the run no longer repeatable."""
        if self.lockstep:
            return {p.sysid: 0.0 for p in self.vehicles}
        count, before = Counter(p.base for p in self.vehicles), Counter[int]()
        phases = {}
        for p in self.vehicles:
            phases[p.sysid] = before[p.base] / count[p.base]
            before[p.base] += 1
        return phases

    def protocol_config(self) -> ProtocolConfig:
        return ProtocolConfig(
            control_rate_hz=self.rate_hz,
            guid_timeout_s=self.guid_timeout_s,
            takeoff_min_alt_m=self.takeoff_alt_m,
            goto_tolerance_m=self.start_tolerance_m,
            goto_speed_tolerance_mps=self.start_speed_tolerance_mps,
            stale_timeout_s=self.stale_timeout_s,
            end_mode=self.end_mode,
            mission_origin=self.mission_origin,
            velocity_bias=self.velocity_bias,
            command_attempts=self.command_attempts,
        )
