"""What one hosted vehicle is, to the emulator. NO I/O.

Owns ``HostedVehicle`` (spec, autopilot, fleet row, encoder, port, noise
stream, and what was last copied into its row), ``Port`` (what the core uses
of the endpoint it is served on: ``link.Endpoint``, or a test's radio),
``VehicleState`` (a snapshot), ``autopilot_for`` (the ArduCopter or PX4
autopilot of a spec with the emulator's parameter overrides) and
``heartbeat_phase_s`` (when in its second a vehicle's HEARTBEAT goes).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from sim_vehicle.autopilot import Autopilot, ControlTarget
from sim_vehicle.config import EmulatorConfig, VehicleSpec
from sim_vehicle.impairments import Impairer
from sim_vehicle.params import PARAM_TABLE, ParamStore
from sim_vehicle.px4 import PX4_OVERRIDES, Px4Autopilot, Px4ParamStore
from sim_vehicle.telemetry import Kin, Vec3

__all__ = [
    "Addr", "HostedVehicle", "Port", "VehicleState", "autopilot_for", "heartbeat_phase_s",
    "state_of",
]  # fmt: skip

Addr = tuple[str, int]


class Port(Protocol):
    """What the core uses of one endpoint (``link.Endpoint``; a test's radio): its
    bookkeeping and a non-blocking ``sendto``."""

    shared: bool
    uplink: Impairer
    downlink: Impairer
    out: Addr | None
    sysids: dict[int, int]  # system id -> vehicle key
    peers: dict[Addr, None]
    outbox: list[tuple[bytes, int]]
    signing_key: bytes | None
    silent: bool

    def sendto(self, data: bytes, addr: Addr) -> None: ...

    def close(self) -> None: ...  # the shell's: the core never closes a port


@dataclass(frozen=True)
class VehicleState:
    """Snapshot of one vehicle (local NED relative to its origin; SI units)."""

    sysid: int
    mode: int
    mode_name: str
    armed: bool
    landed: bool
    ekf_ready: bool
    holding: bool
    pos_ned_m: Vec3
    vel_ned_m_s: Vec3
    accel_ned_m_s2: Vec3
    sim_time_s: float
    origin: Vec3
    home_ned_m: Vec3
    endpoint: Addr
    params: dict[str, float]
    control: str = ""  # what GUIDED tracks now: "accel" once the station's law flies it
    tcp_endpoint: Addr | None = None  # (host, port) of its TCP server, if served over TCP
    landed_state: int = 0  # EXTENDED_SYS_STATE.landed_state (1 ground, 2 air, 3 up, 4 down)


@dataclass(eq=False)
class HostedVehicle:
    """One hosted vehicle: spec, autopilot, fleet row, encoder, port."""

    spec: VehicleSpec
    ap: Autopilot
    enc: Any  # pymavlink MAVLink encoder (sysid/compid); seq kept in Fleet.seq
    ep: Port
    row: int
    noise_rng: np.random.Generator
    initial: bool
    contacted: bool = False
    seen_version: int = -1
    # The deferred lane (EmulatorCore._deliver): open while the autopilot's
    # ``stream_deferrable``; the last setpoint it held (local NED m/s^2, None: none)
    # and the sim time it was heard, for the autopilot's ``stream_accel`` at ``_fold``.
    lane: bool = False
    lane_a: Vec3 | None = None
    lane_t: float = 0.0
    # the velocity it flies from at its first GUIDED Accel entry (Eq. D9), until then
    moving_start: Vec3 | None = None
    # what sync wrote into the fleet row last (rows move with their data on removal)
    row_deadline: float | None = None
    row_holding: bool | None = None
    row_target: ControlTarget | None = None
    row_heartbeat: tuple[int, bool] | None = None  # (mode, armed) its HEARTBEAT fields are of
    # noise_pos, noise_vel, lpn_interval, velocity bias (N, E, D), its reversal, time constant
    row_dyn: tuple[float, float, float, tuple[float, float, float], float, float] | None = field(
        default=None
    )
    # (parameter store, its generation, the report interval) row_dyn was read at
    row_dyn_key: tuple[object, int, float | None] | None = None

    def __post_init__(self) -> None:
        self.moving_start = self.spec.start_vel_ned_m_s


def state_of(
    v: HostedVehicle, k: Kin, sim_time_s: float, endpoint: Addr, tcp: Addr | None
) -> VehicleState:
    """``v``'s snapshot with kinematics ``k`` at ``sim_time_s``, served on
    ``endpoint`` (and TCP ``tcp``)."""
    ap = v.ap
    return VehicleState(
        sysid=v.spec.key, mode=ap.mode, mode_name=ap.mode_name, armed=ap.armed,
        landed=k.landed, ekf_ready=ap.ekf_ready, holding=ap.holding, pos_ned_m=k.pos,
        vel_ned_m_s=k.vel, accel_ned_m_s2=k.acc, sim_time_s=sim_time_s, origin=v.spec.origin,
        home_ned_m=ap.home, endpoint=endpoint, params=dict(ap.params.values),
        control=ap.control, tcp_endpoint=tcp, landed_state=ap.landed_state,
    )  # fmt: skip


def autopilot_for(cfg: EmulatorConfig, spec: VehicleSpec, now: float) -> Autopilot:
    """The autopilot of ``spec`` (ArduCopter or PX4) with the emulator's parameter overrides."""
    overrides: dict[str, float] = {
        "SIM_ACC_TAU": cfg.tau_s,
        "SIM_EKF_DELAY": cfg.ekf_ready_s,
        "SIM_BOOT_S": cfg.boot_s,
        "SIM_ACC_SHAPE": 1.0 if cfg.shaping else 0.0,
        "SIM_NOISE_POS": cfg.noise_pos_m,
        "SIM_NOISE_VEL": cfg.noise_vel_m_s,
        "SIM_VBIAS_N": cfg.vel_bias[0],
        "SIM_VBIAS_E": cfg.vel_bias[1],
        "SIM_VBIAS_D": cfg.vel_bias[2],
        "SIM_VBIAS_FLIP": cfg.vel_bias_flip,
    }
    px4 = spec.autopilot == "px4"
    if px4:
        overrides.update(PX4_OVERRIDES)  # its measured lag, no shaping, no end of boot
        if cfg.vel_bias_ned_m_s is None:  # the preset's bias is ArduCopter SITL's
            overrides.update({"SIM_VBIAS_N": 0.0, "SIM_VBIAS_E": 0.0, "SIM_VBIAS_D": 0.0})
        if cfg.vel_bias_flip_s is None:
            overrides["SIM_VBIAS_FLIP"] = 0.0
        if cfg.accel_tau_s is not None or cfg.dynamics == "ideal":
            overrides["SIM_ACC_TAU"] = cfg.tau_s
        if cfg.accel_shaping is not None:
            overrides["SIM_ACC_SHAPE"] = 1.0 if cfg.accel_shaping else 0.0
    # A mixed fleet's overrides may name the other autopilot's parameters.
    table = Px4ParamStore().table if px4 else PARAM_TABLE
    other = PARAM_TABLE if px4 else Px4ParamStore().table
    for name, value in cfg.params.items():
        if name in table or name not in other:
            overrides[name] = value  # an unknown name fails in the store
    start = spec.start_ned_m
    return (Px4Autopilot if px4 else Autopilot)(
        spec.sysid,
        spec.origin,
        Px4ParamStore(overrides) if px4 else ParamStore(overrides),
        now,
        compid=spec.compid,
        airborne_at=start if spec.airborne else None,
        streams=dict(cfg.streams),
    )


def heartbeat_phase_s(cfg: EmulatorConfig, spec: VehicleSpec) -> float:
    """When in the second after it is hosted ``spec``'s periodic 1 Hz HEARTBEAT
    first goes [s], in [0, 1). ``cfg.heartbeats`` ``"together"``: at once, so
    an emulator's vehicles send theirs in one step, as a SITL swarm started by
    one script does (measured: docs/mavlink-protocol.md). ``"spread"``: a
    phase of its own, as a fleet's vehicles booted one by one keep theirs
    (at 1,500 in networks of 250, "together" puts 250 HEARTBEATs in one
    period at the station; the emulator's step that sends them, a stream
    of the fleet since the eighteenth session, costs 0.72-0.84 ms against
    0.49: docs/emulator.md), drawn from
    the emulator's seed and the vehicle's key: the same in every run,
    lockstep included. The HEARTBEAT a new peer gets at once (docs/emulator.md,
    rule 1) goes as before."""
    if cfg.heartbeats == "together":
        return 0.0
    rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, spec.key, 4]))
    return float(rng.random())
