"""The emulator process: asyncio endpoints hosting many vehicles, the clock, lockstep.

Owns ``Emulator`` (an ``async with`` lifetime owning one ``asyncio.TaskGroup``
and every endpoint), ``VehicleState`` and ``EmulatorStats``. The hot path per
physics step is vectorised: one ``Fleet.step`` for every vehicle, autopilots
polled only when their deadline is due, LOCAL_POSITION_NED encoded for every
due vehicle at once (``codec``), frames batched per peer. The lockstep rule is
written in the ``sim_vehicle`` package docstring and implemented in
``_lockstep_wait`` and ``_step_now`` (the datagram that brings the last answer
takes the step at once, without waking the clock task).
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import signing
from sim_vehicle.autopilot import Autopilot, ControlTarget
from sim_vehicle.config import EmulatorConfig, Impairment, VehicleSpec
from sim_vehicle.fleet import Fleet
from sim_vehicle.link import Addr, Endpoint, Impairer, LinkStats, TcpPort, bind_udp
from sim_vehicle.params import PARAM_TABLE, ParamStore
from sim_vehicle.px4 import PX4_OVERRIDES, Px4Autopilot, Px4ParamStore
from sim_vehicle.telemetry import Kin, Vec3

__all__ = ["Emulator", "EmulatorStats", "VehicleState"]

_EPS = 1e-9
_MAX_PEERS = 8
_SMALL = 64
"""Below this many vehicles the per-step bookkeeping runs on Python lists, not numpy."""
_SETPOINT_ID = mav.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED
_GRACE_TURNS = 8
"""Event-loop turns a lockstep step still waits for its answers once the
wall-clock timeout has passed (microseconds on a quiet machine: a lost answer
still times out; after a stall of the process the answers that are on their
way get in)."""


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


@dataclass
class EmulatorStats:
    """Counters: steps taken, lockstep timeouts, late real-time steps, link counters."""

    steps: int = 0
    lockstep_timeouts: int = 0
    late_steps: int = 0
    link: LinkStats = field(default_factory=LinkStats)


@dataclass
class _Vehicle:
    spec: VehicleSpec
    ap: Autopilot
    enc: Any  # pymavlink MAVLink encoder (sysid/compid); seq kept in Fleet.seq
    ep: Endpoint
    row: int
    noise_rng: np.random.Generator
    initial: bool
    contacted: bool = False
    seen_version: int = -1
    # what _sync last wrote into the fleet row (rows move with their data on removal)
    row_deadline: float | None = None
    row_holding: bool | None = None
    row_target: ControlTarget | None = None
    # noise_pos, noise_vel, lpn_interval, velocity bias (N, E, D)
    row_dyn: tuple[float, float, float, tuple[float, float, float]] | None = None


class Emulator:
    """Many emulated ArduCopters in one process. Use as ``async with Emulator(cfg) as emu``."""

    def __init__(self, config: EmulatorConfig) -> None:
        self.config = config
        self.dt = 1.0 / config.rate_hz
        self.sim_time_s = 0.0
        self._lockstep = config.clock == "lockstep"
        self.step_count = 0
        self.stats = EmulatorStats()
        self.fleet = Fleet()
        self._vehicles: dict[int, _Vehicle] = {}
        self._rows: list[_Vehicle] = []
        self._endpoints: list[Endpoint] = []
        self._shared: Endpoint | None = None
        self._added = 0
        self._tie = itertools.count()
        self._delayed_in: list[tuple[float, int, Endpoint, list[Any]]] = []
        self._delayed_out: list[tuple[float, int, Endpoint, Addr, bytes, list[int]]] = []
        self._waiters: list[tuple[Callable[[], bool], asyncio.Future[None]]] = []
        self._out_heard: set[int] = set()
        self._wake = asyncio.Event()
        self._tg: asyncio.TaskGroup | None = None
        self._clock_task: asyncio.Task[None] | None = None
        self._kins: list[Kin] | None = None  # every row's Kin at this step (few vehicles)
        # Lockstep: while the clock waits for answers, the datagram that brings the last
        # one takes the step itself (``_step_now``); ``_last`` is the wall time of the
        # last step, ``_handed_back`` tells the clock a step was taken meanwhile.
        self._stepping = False
        self._handed_back = False
        self._last = 0.0
        self._error: BaseException | None = None

    # ------------------------------------------------------------ lifetime
    async def __aenter__(self) -> Emulator:
        self._tg = asyncio.TaskGroup()
        await self._tg.__aenter__()
        try:
            cfg = self.config
            if cfg.shared_port is not None:
                self._shared = await self._open_endpoint(cfg.shared_port, shared=True, key=0)
            for spec in cfg.vehicles:
                await self._add(spec, initial=True)
            self._clock_task = self._tg.create_task(self._clock())
        except BaseException:
            # No task runs yet (the clock starts last): close what was opened
            # and let the error out as it is (an OSError, not an ExceptionGroup).
            self._close_all()
            await self._tg.__aexit__(None, None, None)
            raise
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        assert self._tg is not None
        self._stepping = False
        try:
            if self._clock_task is not None:
                self._clock_task.cancel()
        finally:
            self._close_all()
            # An error of the body propagates as itself, not wrapped in an ExceptionGroup;
            # a cancellation is passed on so the TaskGroup can account for it.
            if exc_type is not None and issubclass(exc_type, asyncio.CancelledError):
                await self._tg.__aexit__(exc_type, exc, tb)
            else:
                await self._tg.__aexit__(None, None, None)

    def _close_all(self) -> None:
        for ep in self._endpoints:
            ep.close()
        self._endpoints.clear()
        for _pred, fut in self._waiters:
            if not fut.done():
                fut.set_exception(RuntimeError("emulator stopped"))
        self._waiters.clear()

    async def _open_endpoint(
        self, port: int, shared: bool, key: int, tcp_port: int | None = None
    ) -> Endpoint:
        cfg = self.config
        ss = np.random.SeedSequence([cfg.seed, key, 7])
        up, down = (np.random.default_rng(s) for s in ss.spawn(2))
        sock = bind_udp(cfg.host, port)
        ep = Endpoint(
            sock=sock,
            shared=shared,
            uplink=Impairer(cfg.uplink, up),
            downlink=Impairer(cfg.downlink, down),
            on_datagram=self._on_datagram,
            stats=self.stats.link,
            out=cfg.out,
            signing_key=cfg.signing_key,
        )
        loop = asyncio.get_running_loop()
        await loop.create_datagram_endpoint(lambda: ep, sock=sock)
        self._endpoints.append(ep)
        if tcp_port is not None:
            try:
                tcp = TcpPort(ep, self._on_tcp_messages, self._on_tcp_peer)
                await tcp.start(cfg.host, tcp_port)
            except BaseException:
                self._endpoints.remove(ep)
                ep.close()
                raise
            ep.tcp = tcp
        return ep

    # ------------------------------------------------------------ vehicles
    @property
    def endpoints(self) -> dict[int, Addr]:
        """Vehicle key (its system id unless ``VehicleSpec.vid`` is set) -> (host, port)."""
        return {s: v.ep.address for s, v in self._vehicles.items()}

    @property
    def tcp_endpoints(self) -> dict[int, Addr]:
        """Vehicle key -> (host, port) of its TCP server (``EmulatorConfig.tcp_base_port``);
        connect with ``tcp:HOST:PORT``."""
        return {s: v.ep.tcp.address for s, v in self._vehicles.items() if v.ep.tcp is not None}

    async def add_vehicle(self, spec: VehicleSpec) -> Addr:
        """Add a vehicle while running; returns the address it is served on."""
        return (await self._add(spec, initial=False)).ep.address

    async def _add(self, spec: VehicleSpec, initial: bool) -> _Vehicle:
        cfg = self.config
        key = spec.key
        if key in self._vehicles:
            raise ValueError(f"vehicle {key} is already hosted")
        if self._shared is not None and spec.sysid in self._shared.sysids:
            raise ValueError(f"sysid {spec.sysid} is already served on the shared endpoint")
        index = self._added
        self._added += 1
        if self._shared is not None:
            ep = self._shared
        else:
            port = spec.port
            if port is None:
                step = 1 if spec.autopilot == "px4" else 10
                port = cfg.base_port + step * index if cfg.base_port else 0
            tcp = cfg.tcp_base_port
            tcp_port = None if tcp is None else (tcp + 10 * index if tcp else 0)
            ep = await self._open_endpoint(port, shared=False, key=key, tcp_port=tcp_port)
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
        }
        px4 = spec.autopilot == "px4"
        if px4:
            overrides.update(PX4_OVERRIDES)  # its measured lag, no shaping, no end of boot
            if cfg.vel_bias_ned_m_s is None:  # the preset's bias is ArduCopter SITL's
                overrides.update({"SIM_VBIAS_N": 0.0, "SIM_VBIAS_E": 0.0, "SIM_VBIAS_D": 0.0})
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
        now = self.sim_time_s
        start = spec.start_ned_m
        ap = (Px4Autopilot if px4 else Autopilot)(
            spec.sysid,
            spec.origin,
            Px4ParamStore(overrides) if px4 else ParamStore(overrides),
            now,
            compid=spec.compid,
            airborne_at=start if spec.airborne else None,
            streams=dict(cfg.streams),
        )
        row = self.fleet.add(spec.sysid, spec.compid, start, landed=not spec.airborne)
        self._kins = None
        self.fleet.ground[row] = 0.0 if spec.airborne else start[2]
        self.fleet.boot[row] = now
        noise_rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, key, 3]))
        enc = signing.mavlink(spec.sysid, spec.compid, cfg.signing_key)
        v = _Vehicle(spec, ap, enc, ep, row, noise_rng, initial)
        self._vehicles[key] = v
        self._rows.append(v)
        ep.sysids[spec.sysid] = key
        self._sync(v, now)
        return v

    def set_impairment(self, uplink: Impairment, downlink: Impairment) -> None:
        """Change every link's impairments from now on (each keeps its seeded
        random stream), e.g. to fly lossy links after a clean start-up."""
        for ep in self._endpoints:
            ep.uplink.imp = uplink
            ep.downlink.imp = downlink

    def set_silent(self, sysid: int, silent: bool = True) -> None:
        """Switch vehicle ``sysid``'s radio off (``silent``) or on again: while
        silent it neither sends nor hears anything but keeps flying (its own
        GUID_TIMEOUT brakes it); back on, it sends a HEARTBEAT at once. Only
        for a vehicle on its own endpoint."""
        v = self._vehicle(sysid)
        if v.ep.shared:
            raise ValueError("set_silent needs a vehicle on its own endpoint, not a shared one")
        v.ep.silent = silent
        self.fleet.awaiting[v.row] = False  # an answer it cannot hear never blocks lockstep
        if not silent:  # back on the air: a HEARTBEAT at once, as to a new peer (rule 1)
            self._transmit(v.ep, [(self._pack(v, v.ap.heartbeat()), 0)])
        self._wake.set()

    def remove_vehicle(self, sysid: int) -> None:
        """Stop serving ``sysid`` (its own endpoint is closed)."""
        v = self._vehicle(sysid)
        del self._vehicles[sysid]
        self.fleet.remove(v.row)
        self._kins = None
        del self._rows[v.row]
        for i, other in enumerate(self._rows):
            other.row = i
        del v.ep.sysids[v.spec.sysid]
        if not v.ep.shared:
            v.ep.close()
            self._endpoints.remove(v.ep)
        self._wake.set()

    def _vehicle(self, sysid: int) -> _Vehicle:
        try:
            return self._vehicles[sysid]
        except KeyError:
            raise KeyError(f"no vehicle with sysid {sysid}") from None

    def _kin(self, v: _Vehicle) -> Kin:
        f, r = self.fleet, v.row
        if f.n < _SMALL:  # every row at once, kept until the state changes (next step)
            kins = self._kins
            if kins is None:
                kins = self._kins = [
                    Kin((p[0], p[1], p[2]), (q[0], q[1], q[2]), (a[0], a[1], a[2]), ld)
                    for p, q, a, ld in zip(
                        f.pos.tolist(),
                        f.vel.tolist(),
                        f.acc.tolist(),
                        f.landed.tolist(),
                        strict=True,
                    )
                ]
            return kins[r]
        px, py, pz = f.pos[r].tolist()
        vx, vy, vz = f.vel[r].tolist()
        ax, ay, az = f.acc[r].tolist()
        return Kin((px, py, pz), (vx, vy, vz), (ax, ay, az), bool(f.landed[r]))

    def vehicle_state(self, sysid: int) -> VehicleState:
        """Snapshot of one vehicle."""
        v = self._vehicle(sysid)
        k, ap = self._kin(v), v.ap
        return VehicleState(
            sysid=sysid,
            mode=ap.mode,
            mode_name=ap.mode_name,
            armed=ap.armed,
            landed=k.landed,
            ekf_ready=ap.ekf_ready,
            holding=ap.holding,
            pos_ned_m=k.pos,
            vel_ned_m_s=k.vel,
            accel_ned_m_s2=k.acc,
            sim_time_s=self.sim_time_s,
            origin=v.spec.origin,
            home_ned_m=ap.home,
            endpoint=v.ep.address,
            params=dict(ap.params.values),
            control=ap.control,
            tcp_endpoint=v.ep.tcp.address if v.ep.tcp is not None else None,
            landed_state=ap.landed_state,
        )

    def set_param(self, sysid: int, name: str, value: float) -> None:
        """Set a parameter directly (as PARAM_SET would, without a reply)."""
        v = self._vehicle(sysid)
        if not v.ap.params.set(name, value):
            raise KeyError(f"unknown parameter {name!r}")
        v.ap.refresh(self.sim_time_s, self._kin(v))
        self._sync(v, self.sim_time_s)

    # ------------------------------------------------------------- waiting
    async def wait_until(self, predicate: Callable[[], bool]) -> None:
        """Return once ``predicate()`` is true (checked now and after every step)."""
        if predicate():
            return
        fut: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._waiters.append((predicate, fut))
        await fut

    async def wait_steps(self, n: int) -> None:
        """Return after ``n`` more physics steps."""
        target = self.step_count + n
        await self.wait_until(lambda: self.step_count >= target)

    def _notify(self) -> None:
        keep = []
        for pred, fut in self._waiters:
            if fut.done():
                continue
            if pred():
                fut.set_result(None)
            else:
                keep.append((pred, fut))
        self._waiters = keep

    # ------------------------------------------------------------ inbound
    def _on_datagram(self, ep: Endpoint, data: bytes, addr: Addr) -> None:
        if not self._stepping:
            self._receive(ep, data, addr)
            return
        self._receive(ep, data, addr)
        if not self._blocked():  # lockstep rule 3: the last answer is in, step now
            self._step_now()

    def _step_now(self) -> None:
        """Take the lockstep step the clock task waits for, here (no task switch); hand
        the clock back to the task when the step leaves nobody blocking."""
        try:
            self._step()
        except BaseException as exc:  # the clock task raises it, as its own step would
            self._error = exc
            self._stepping = False
            self._wake.set()
            return
        self._last = asyncio.get_running_loop().time()
        if not self._blocked():
            self._stepping = False
            self._handed_back = True
            self._wake.set()

    def _contact(self, v: _Vehicle) -> None:
        """A station was heard by (or connected to) ``v``: lockstep rule 1, boot's end."""
        v.contacted = True
        v.ap.contact(self.sim_time_s)
        self._sync(v, self.sim_time_s)

    def _on_tcp_peer(self, ep: Endpoint, addr: Addr, up: bool) -> None:
        """A TCP client connected (a new peer: HEARTBEAT at once, lockstep rule 1, as SITL
        starts when something connects) or went away. With signing, a connection is no
        peer yet: its first well-signed frame makes it one, as on UDP (``_receive_msgs``)."""
        if not up:
            ep.peers.pop(addr, None)
            return
        if ep.signing_key is not None:
            return
        ep.peers[addr] = None
        for sysid in sorted(ep.sysids):
            v = self._vehicles[ep.sysids[sysid]]
            self._contact(v)
            self._transmit(ep, [(self._pack(v, v.ap.heartbeat()), 0)], only=addr)
        self._wake.set()

    def _on_tcp_messages(self, ep: Endpoint, msgs: list[Any], addr: Addr) -> None:
        if not self._stepping:
            self._receive_msgs(ep, msgs, addr)
            return
        self._receive_msgs(ep, msgs, addr)
        if not self._blocked():  # lockstep rule 3, as for a datagram
            self._step_now()

    def _receive(self, ep: Endpoint, data: bytes, addr: Addr) -> None:
        if ep.silent:
            return
        self._receive_msgs(ep, ep.parse(data), addr)

    def _receive_msgs(self, ep: Endpoint, msgs: list[Any], addr: Addr) -> None:
        if ep.silent:
            return
        self.stats.link.rx_datagrams += 1
        if not self._stepping:  # the clock is blocked: only a step may change that
            self._wake.set()
        # Only a peer that sent one good (with signing: well-signed) frame is
        # served: garbage or forgeries from elsewhere never evict the station.
        # With signing, the unsigned frames the parser lets through (RADIO_STATUS,
        # ArduPilot's exception) are heard but register nobody (issue 15).
        good = bool(msgs) and (ep.signing_key is None or any(m.get_signed() for m in msgs))
        new_peer = good and addr not in ep.peers
        if new_peer:
            ep.peers[addr] = None
            if len(ep.peers) > _MAX_PEERS:
                ep.peers.pop(next(iter(ep.peers)))
        for m in msgs:  # lockstep rule 3: an answer counts even if the link then loses it
            if m.get_msgId() == _SETPOINT_ID:
                ts = m.target_system
                for sysid in ep.sysids if ts == 0 else (ts,):
                    v = self._vehicles.get(ep.sysids.get(sysid, -1))
                    if v is not None and v.ep is ep:
                        self.fleet.awaiting[v.row] = False
        if new_peer:  # rule 1: a new peer gets a HEARTBEAT at once
            for sysid in sorted(ep.sysids):
                v = self._vehicles[ep.sysids[sysid]]
                self._contact(v)
                self._transmit(ep, [(self._pack(v, v.ap.heartbeat()), 0)], only=addr)
        elif good and ep.out == addr and id(ep) not in self._out_heard:
            # The fixed ``out`` peer is known from the start: its first good
            # frame is its contact (rule 1), or a lockstep clock would never start.
            self._out_heard.add(id(ep))
            for key in ep.sysids.values():
                self._contact(self._vehicles[key])
        if not ep.uplink.imp.active:  # no impairment: deliver now, no random draw
            self._deliver(ep, msgs)
            return
        delays = ep.uplink.delivery_delays()
        if not delays:
            self.stats.link.rx_lost += 1
            return
        if len(delays) > 1:
            self.stats.link.duplicated += 1
        for d in delays:
            if d <= 0.0:
                self._deliver(ep, msgs)
            else:
                item = (self.sim_time_s + d, next(self._tie), ep, msgs)
                heapq.heappush(self._delayed_in, item)

    def _deliver(self, ep: Endpoint, msgs: list[Any]) -> None:
        now = self.sim_time_s
        # lockstep: the autopilot handling it is told the wall clock (Autopilot.wall_s)
        wall = time.monotonic() if self._lockstep else None
        for m in msgs:
            ts = getattr(m, "target_system", 0)
            if ts == 0:
                targets = [ep.sysids[s] for s in sorted(ep.sysids)]
            elif ts in ep.sysids:
                targets = [ep.sysids[ts]]
            else:
                continue
            for key in targets:
                v = self._vehicles[key]
                if wall is not None:
                    v.ap.wall_s = wall
                replies = v.ap.handle(m, now, self._kin(v))
                if replies:
                    self._transmit(ep, [(self._pack(v, r), 0) for r in replies])
                self._sync(v, now)

    # ------------------------------------------------------------ outbound
    def _pack(self, v: _Vehicle, msg: Any) -> bytes:
        row = v.row
        v.enc.seq = int(self.fleet.seq[row])
        frame: bytes = msg.pack(v.enc)
        self.fleet.seq[row] = (v.enc.seq + 1) & 0xFF
        return frame

    def _transmit(
        self, ep: Endpoint, frames: list[tuple[bytes, int]], only: Addr | None = None
    ) -> None:
        """Send frames now through the downlink impairment to every peer (or ``only``)."""
        if ep.silent:
            return
        peers = [only] if only is not None else list(ep.peers)
        if len(frames) == 1:  # one frame is its own datagram (the 50 Hz case)
            frame, key = frames[0]
            batches = [(frame, [key] if key else [])]
        else:
            batches = ep.batch(frames)
        clean = not ep.downlink.imp.active  # no impairment: no random draw either
        for data, lpn in batches:
            for peer in peers:
                if clean:
                    ep.sendto(data, peer)
                    self._lpn_left(lpn)
                    continue
                delays = ep.downlink.delivery_delays()
                if not delays:
                    self.stats.link.tx_lost += 1
                    continue
                if len(delays) > 1:
                    self.stats.link.duplicated += 1
                for d in delays:
                    if d <= 0.0:
                        ep.sendto(data, peer)
                        self._lpn_left(lpn)
                    else:
                        item = (self.sim_time_s + d, next(self._tie), ep, peer, data, lpn)
                        heapq.heappush(self._delayed_out, item)

    def _lpn_left(self, keys: list[int]) -> None:
        for key in keys:
            v = self._vehicles.get(key)
            if v is not None:
                self.fleet.awaiting[v.row] = True

    def _sync(self, v: _Vehicle, now: float) -> None:
        """Copy an autopilot's published state into its fleet row (after handle/poll)."""
        ap, f, row = v.ap, self.fleet, v.row
        # Each row value is written only when it changed: a numpy item write costs
        # more than the comparison, and this runs for every setpoint.
        if ap.deadline != v.row_deadline:
            f.deadline[row] = v.row_deadline = ap.deadline
        holding = ap.holding
        if holding != v.row_holding:
            f.holding[row] = v.row_holding = holding
        if ap.version == v.seen_version:
            return
        v.seen_version = ap.version
        f.set_target(row, ap.target, v.row_target)
        v.row_target = ap.target
        iv = ap.lpn_interval_s
        prm = ap.params
        dyn = (
            prm["SIM_NOISE_POS"],
            prm["SIM_NOISE_VEL"],
            iv if iv is not None else np.inf,
            (prm["SIM_VBIAS_N"], prm["SIM_VBIAS_E"], prm["SIM_VBIAS_D"]),
        )
        if dyn != v.row_dyn:
            f.noise_pos[row], f.noise_vel[row], f.lpn_interval[row], f.vbias[row] = dyn
            v.row_dyn = dyn
        if iv is None:
            f.lpn_next[row] = np.inf
        elif ap.lpn_kick:  # rule 1: a newly enabled stream sends its first message at once
            ap.lpn_kick = False
            f.lpn_next[row] = now + iv
            if v.ep.peers:
                rows = np.array([row], dtype=np.intp)
                self._transmit(v.ep, self._lpn_frames(rows, now))

    def _lpn_frames(self, rows: NDArray[np.intp], now: float) -> list[tuple[bytes, int]]:
        f = self.fleet
        if len(rows) < _SMALL and self.config.signing_key is None:
            rl: list[int] = rows.tolist()
            npos, nvel, vb = f.noise_pos.tolist(), f.noise_vel.tolist(), f.vbias.tolist()
            if not any(npos[r] > 0 or nvel[r] > 0 or any(vb[r]) for r in rl):
                boot = f.boot.tolist()  # round() is np.rint's half-to-even
                frames = f.lpn_frames_rows(rl, [round((now - boot[r]) * 1000.0) for r in rl])
                if frames is not None:
                    return [(fr, self._rows[r].spec.key) for fr, r in zip(frames, rl, strict=True)]
        t_ms = np.rint((now - f.boot[rows]) * 1000.0).astype(np.int64)
        pos, vel = f.pos[rows], f.vel[rows] + f.vbias[rows]  # a copy: the reported velocity
        noisy = (f.noise_pos[rows] > 0) | (f.noise_vel[rows] > 0)
        if noisy.any():
            pos = pos.copy()
            for i in np.flatnonzero(noisy):
                v = self._rows[rows[i]]
                z = v.noise_rng.standard_normal(6)
                pos[i] += f.noise_pos[rows[i]] * z[:3]
                vel[i] += f.noise_vel[rows[i]] * z[3:]
        if self.config.signing_key is not None:  # signed: pymavlink packs (and signs) each
            lpn = mav.MAVLink_local_position_ned_message
            return [
                (
                    self._pack(v, lpn(int(t_ms[i]), *map(float, pos[i]), *map(float, vel[i]))),
                    v.spec.key,
                )
                for i, v in enumerate(self._rows[r] for r in rows.tolist())
            ]
        frames = f.lpn_frames(rows, t_ms, pos, vel)
        return [(fr, self._rows[r].spec.key) for fr, r in zip(frames, rows.tolist(), strict=True)]

    # --------------------------------------------------------------- clock
    def _step(self) -> None:
        """One physics step, then the telemetry due at the new sim time."""
        self.fleet.step(self.dt)
        self._kins = None
        self.step_count += 1
        self.stats.steps = self.step_count
        self.sim_time_s = now = self.step_count * self.dt
        self._emit(now)
        self._notify()

    def _emit(self, now: float) -> None:
        while self._delayed_in and self._delayed_in[0][0] <= now + _EPS:
            _t, _n, ep, msgs = heapq.heappop(self._delayed_in)
            if not ep.sysids or ep.silent:
                continue
            self._deliver(ep, msgs)
        while self._delayed_out and self._delayed_out[0][0] <= now + _EPS:
            _t, _n, ep, peer, data, lpn = heapq.heappop(self._delayed_out)
            if ep.sysids and not ep.silent:
                ep.sendto(data, peer)
                self._lpn_left(lpn)
        f = self.fleet
        if f.n < _SMALL:
            lim = now + _EPS
            polled = [r for r, d in enumerate(f.deadline.tolist()) if d <= lim]
        else:
            polled = np.flatnonzero(f.deadline <= now + _EPS).tolist()
        if f.changed:  # touched down or lifted off: the land detector looks (autopilot)
            polled = sorted(set(polled).union(f.changed))
            f.changed = []
        wall = time.monotonic() if self._lockstep and polled else None
        for row in polled:
            v = self._rows[row]
            if wall is not None:
                v.ap.wall_s = wall  # Autopilot.wall_s: lockstep's GCS failsafe clock
            out = v.ap.poll(now, self._kin(v))
            self._sync(v, now)
            if out and v.ep.peers:
                v.ep.outbox.extend((self._pack(v, m), 0) for m in out)
        if f.n < _SMALL:  # the same schedule arithmetic on lists
            lim, lnext = now + _EPS, f.lpn_next.tolist()
            rows = [r for r, t in enumerate(lnext) if t <= lim]
            if rows:
                iv = f.lpn_interval.tolist()
                for r in rows:
                    nxt = lnext[r] + iv[r]
                    lnext[r] = now + iv[r] if nxt <= lim else nxt
                f.lpn_next[:] = lnext
            due = np.array(rows, dtype=np.intp)
        else:
            due = np.flatnonzero(f.lpn_next <= now + _EPS)
            if due.size:
                nxt = f.lpn_next[due] + f.lpn_interval[due]
                f.lpn_next[due] = np.where(nxt <= now + _EPS, now + f.lpn_interval[due], nxt)
        if due.size:
            for frame, key in self._lpn_frames(due, now):
                ep = self._vehicles[key].ep
                if ep.peers:
                    ep.outbox.append((frame, key))
        for ep in self._endpoints:
            if ep.outbox:
                frames, ep.outbox = ep.outbox, []
                self._transmit(ep, frames)

    async def _clock(self) -> None:
        self._emit(0.0)
        if self.config.clock == "lockstep":
            await self._run_lockstep()
        else:
            await self._run_realtime()

    async def _run_realtime(self) -> None:
        loop = asyncio.get_running_loop()
        period = self.dt / self.config.speedup
        t0, k0 = loop.time(), self.step_count
        while True:
            delay = t0 + (self.step_count - k0 + 1) * period - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            else:
                if delay < -period:
                    self.stats.late_steps += 1
                if delay < -1.0:  # hopelessly behind: drop the backlog, keep pacing
                    t0, k0 = loop.time(), self.step_count
                await asyncio.sleep(0)
            self._step()

    async def _run_lockstep(self) -> None:
        loop = asyncio.get_running_loop()
        period = self.dt / self.config.speedup
        while not all(v.contacted for v in self._vehicles.values() if v.initial):  # rule 1
            self._wake.clear()
            await self._wake.wait()
        self._last = loop.time()
        while True:
            if self._blocked():  # _lockstep_wait yields: no extra pass of the event loop
                if not await self._lockstep_wait(blocked=True):
                    continue  # steps were taken meanwhile; the last left nobody blocking
            else:
                await asyncio.sleep(0)  # let inbound datagrams in between two steps
                if self.fleet.holding.any():
                    if not await self._lockstep_wait():
                        continue
                else:  # rule 4: nobody holds, pace at speed-up x wall clock
                    delay = self._last + period - loop.time()
                    await asyncio.sleep(max(delay, 0.0))
            self._step()
            self._last = loop.time()

    def _blocked(self) -> bool:
        """Rules 2-3: some holding vehicle blocks the next step."""
        f = self.fleet
        if f.n < _SMALL:  # twice per lockstep step: three tolist() beat four numpy calls
            isinf = math.isinf
            for h, a, iv in zip(
                f.holding.tolist(), f.awaiting.tolist(), f.lpn_interval.tolist(), strict=True
            ):
                if h and (a or isinf(iv)):
                    return True
            return False
        return bool((f.holding & (f.awaiting | np.isinf(f.lpn_interval))).any())

    async def _lockstep_wait(self, blocked: bool = False) -> bool:
        """Rules 2-3: wait until no holding vehicle blocks, or the wall-clock timeout
        (``blocked``: the caller has just found that one does). True: the caller takes
        the step. False: the datagrams that brought the answers took the steps
        (``_step_now``) and the last left nobody blocking; the caller starts over."""
        loop = asyncio.get_running_loop()
        if not blocked and not self._blocked():
            return True
        timeout = self.config.lockstep_timeout_s
        # One timer for many steps: it only wakes the loop below, which arms it again
        # from the latest step when steps were taken meanwhile.
        fired: list[bool] = []

        def expire() -> None:
            fired.append(True)
            self._wake.set()

        armed = self._last
        timer = loop.call_at(armed + timeout, expire)
        self._handed_back = False
        self._stepping = True
        try:
            while True:
                self._wake.clear()
                await self._wake.wait()
                if self._error is not None:
                    raise self._error
                if self._handed_back:
                    return False
                if not self._blocked():
                    return True
                if fired and armed != self._last:  # steps were taken: time from the last
                    fired.clear()
                    armed = self._last
                    timer = loop.call_at(armed + timeout, expire)
                elif fired or self._last + timeout - loop.time() <= 0:
                    # Before calling it a timeout, let the loop turn a few times:
                    # after a stall of the whole process (a loaded machine, a
                    # garbage collection) the answer may still be unread in a
                    # socket, or one task switch away in the station.
                    for _ in range(_GRACE_TURNS):
                        await asyncio.sleep(0)
                        if self._handed_back or not self._blocked() or self._error:
                            break
                    if self._error is not None:
                        raise self._error
                    if self._handed_back:
                        return False
                    if not self._blocked():
                        return True
                    if armed != self._last:  # steps were taken meanwhile: time from the last
                        fired.clear()
                        armed = self._last
                        timer.cancel()
                        timer = loop.call_at(armed + timeout, expire)
                        continue
                    self.stats.lockstep_timeouts += 1
                    return True
        finally:
            self._stepping = False
            timer.cancel()
