"""The station's core against the emulator's autopilots, in one process, on
one hand-advanced clock (aioquic's client/server ``transfer`` in its tests).

Station side: ``gcs_swarm.swarm.SwarmCore`` behind one listening
``LinkState`` (every vehicle on one ``udpin`` link, each from its own
address, as MAVProxy or a radio bridge would). Vehicle side: one
``sim_vehicle.Autopilot`` per vehicle (its own pymavlink encoder and parser:
the emulator never shares the station's codec) and one ``sim_vehicle.Fleet``
for the point masses. Between them, datagrams as bytes, which a test may
drop (seeded), forge or silence. No sockets, no event loop, no sleeps: a
second of flight is 50 physics steps and whatever the core asks for.

The wiring follows ``sim_vehicle/server.py`` (``_deliver``, ``_sync``,
``_emit``) and ``runtime/station.py`` (``_after``, ``_on_timer``,
``_control_task``), reduced to what an ideal, unimpaired emulator does.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.states import Phase
from gcs_swarm.mission import Mission, load_mission
from gcs_swarm.runtime import emulator_config, station_config
from gcs_swarm.swarm import LinkState, SetpointBatch, SwarmCore
from sim_vehicle import signing
from sim_vehicle.autopilot import Autopilot, ControlTarget
from sim_vehicle.fleet import Fleet
from sim_vehicle.params import ParamStore
from sim_vehicle.telemetry import Kin

MISSIONS = Path(__file__).resolve().parents[2] / "config" / "missions"
LINK = "udpin:0.0.0.0:14550"
GCS: tuple[str, int] = ("10.0.0.1", 14550)
"""The station's address as the vehicles see it."""
_LPN = mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED
_SETPOINT = mav.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED

Datagram = tuple[tuple[str, int], bytes]
"""(sender address, bytes)."""


def mission_from(name: str, *, duration: float) -> Mission:
    """A shipped mission given a ``duration`` [s] of formation flight."""
    m = load_mission(MISSIONS / name)
    return dataclasses.replace(m, settings=dataclasses.replace(m.settings, duration=duration))


def address(sysid: int) -> tuple[str, int]:
    """Vehicle ``sysid``'s own address."""
    return ("10.0.1.1", 5760 + 10 * sysid)


@dataclasses.dataclass(eq=False)
class SimVehicle:
    """One emulated vehicle: its autopilot, its fleet row, its radio."""

    ap: Autopilot
    row: int
    enc: Any
    parser: Any
    addr: tuple[str, int]
    target: ControlTarget | None = None
    version: int = -1
    lpn_next: float = float("inf")
    contacted: bool = False
    silent: bool = False
    setpoints_heard: int = 0


class Sky:
    """Station core and emulated vehicles wired together (module docstring).

    ``drop_down``/``drop_up``: the chance [0, 1) that a datagram to the
    station (telemetry) / to a vehicle (setpoints, commands) is lost, drawn
    from ``numpy.random.default_rng(seed)``."""

    def __init__(
        self,
        mission: Mission,
        *,
        drop_down: float = 0.0,
        drop_up: float = 0.0,
        seed: int = 0,
    ) -> None:
        cfg = station_config(mission, {v.sysid: LINK for v in mission.vehicles})
        self.core = SwarmCore(cfg)
        self.notices: list[str] = []
        self.now = 0.0
        self.link = LinkState(
            LINK,
            unix_clock=lambda: 1.7e9 + self.now,
            sysids=[v.sysid for v in mission.vehicles],
            telemetry=self.core.table,
            on_notice=self.notices.append,
        )
        emu = emulator_config(mission, airborne=True)
        self.dt = 1.0 / emu.rate_hz
        self.fleet = Fleet()
        self.vehicles: dict[int, SimVehicle] = {}
        self.drop_down, self.drop_up = drop_down, drop_up
        self.rng = np.random.default_rng(seed)
        self.lost_down = self.lost_up = 0
        self.steps = 0
        self.answered: Counter[int] = Counter()
        """Setpoints of the control steps per vehicle (the station's answers)."""
        self._next_hb = 0.0
        self._next_status = 1.0
        self._to_station: list[Datagram] = []
        for spec in emu.vehicles:
            params = ParamStore(
                {"SIM_EKF_DELAY": 0.0, "SIM_BOOT_S": 0.0, "SIM_ACC_TAU": emu.tau_s,
                 "SIM_ACC_SHAPE": 0.0}
            )  # fmt: skip
            start = spec.start_ned_m
            ap = Autopilot(
                spec.sysid,
                spec.origin,
                params,
                0.0,
                compid=spec.compid,
                airborne_at=start if spec.airborne else None,
                streams=dict(emu.streams),
            )
            row = self.fleet.add(spec.sysid, spec.compid, start, landed=not spec.airborne)
            self.fleet.ground[row] = 0.0 if spec.airborne else start[2]
            parser = mav.MAVLink(None)
            parser.robust_parsing = True
            v = SimVehicle(ap, row, signing.mavlink(spec.sysid, spec.compid, None), parser,
                           address(spec.sysid))  # fmt: skip
            self.vehicles[spec.sysid] = v
            self._sync(v)

    # ----------------------------------------------------------- vehicles
    def _kin(self, v: SimVehicle) -> Kin:
        f, r = self.fleet, v.row
        return Kin(tuple(f.pos[r].tolist()), tuple(f.vel[r].tolist()),  # type: ignore[arg-type]
                   tuple(f.acc[r].tolist()), bool(f.landed[r]))  # type: ignore[arg-type]  # fmt: skip

    def _sync(self, v: SimVehicle) -> None:
        """The autopilot's published state into its fleet row (server ``_sync``)."""
        ap = v.ap
        if ap.version != v.version:
            v.version = ap.version
            self.fleet.set_target(v.row, ap.target, v.target)
            v.target = ap.target
        iv = ap.lpn_interval_s
        if iv is None:
            v.lpn_next = float("inf")
        elif ap.lpn_kick:  # a newly enabled stream sends its first report at once
            ap.lpn_kick = False
            v.lpn_next = self.now + iv
            self._radio(v, [self._lpn(v)])
        elif v.lpn_next == float("inf"):
            v.lpn_next = self.now + iv

    def _lpn(self, v: SimVehicle) -> bytes:
        f, r = self.fleet, v.row
        t_ms = round((self.now - v.ap.boot) * 1000.0)
        msg = mav.MAVLink_local_position_ned_message(t_ms, *f.pos[r].tolist(), *f.vel[r].tolist())
        return bytes(msg.pack(v.enc))

    def _radio(self, v: SimVehicle, frames: list[bytes]) -> None:
        if frames and not v.silent:
            self._to_station.append((v.addr, b"".join(frames)))

    def _to_vehicle(self, v: SimVehicle, data: bytes) -> None:
        """A datagram from the station arrives at ``v`` (server ``_deliver``)."""
        if v.silent:
            return
        ap = v.ap
        msgs = v.parser.parse_buffer(data) or []
        if msgs and not v.contacted:
            v.contacted = True
            ap.contact(self.now)
        replies: list[bytes] = []
        for m in msgs:
            ts = getattr(m, "target_system", 0)
            if ts not in (0, ap.sysid):
                continue
            if m.get_msgId() == _SETPOINT:
                v.setpoints_heard += 1
            replies.extend(bytes(r.pack(v.enc)) for r in ap.handle(m, self.now, self._kin(v)))
        self._radio(v, replies)
        self._sync(v)

    def set_silent(self, sysid: int, silent: bool = True) -> None:
        """Vehicle ``sysid``'s radio off (it keeps flying) or on again."""
        self.vehicles[sysid].silent = silent

    def inject(self, sender: tuple[str, int], data: bytes) -> None:
        """A datagram to the station from ``sender`` (a forger, a stray port)."""
        self._to_station.append((sender, data))

    # ------------------------------------------------------------ station
    def _write(self, link: str, batch: SetpointBatch | None) -> None:
        if batch is not None:
            self.answered.update(batch.sysids)
        writes = (
            self.link.datagrams_to_send() if batch is None else self.link.accel_setpoints(*batch)
        )
        self._deliver(writes)

    def _deliver(self, writes: list[tuple[Any, bytes, list[float | None]]]) -> None:
        by_addr = {v.addr: v for v in self.vehicles.values()}
        for peer, data, _since in writes:
            v = by_addr.get(peer)
            if v is None:
                continue  # to the forger: nobody listens there
            if self.drop_up and self.rng.random() < self.drop_up:
                self.lost_up += 1
                continue
            self._to_vehicle(v, data)

    def _station_sends(self) -> None:
        core = self.core
        if core.outbound:
            out, core.outbound = core.outbound, []
            for _link, spec, sysid in out:
                self.link.send(spec, sysid)
        self._deliver(self.link.datagrams_to_send())

    def transfer(self) -> None:
        """Pass datagrams both ways until nobody has anything to say (at ``now``)."""
        core, link = self.core, self.link
        for _ in range(100):
            self._station_sends()
            if core.step_wanted:
                core.control_step(self.now, self._write)
                self.steps += 1
                core.lookahead.clear()  # the look-ahead is not exercised here
                continue
            if not self._to_station:
                return
            batch, self._to_station = self._to_station, []
            for sender, data in batch:
                if self.drop_down and self.rng.random() < self.drop_down:
                    self.lost_down += 1
                    continue
                for msg in link.receive(data, sender, self.now, datagram=True):
                    core.receive(msg, LINK, self.now, self.now)
                if link.positions_written:
                    core.telemetry_written(self.now)
        raise AssertionError("the two sides kept talking at one instant")

    # -------------------------------------------------------------- clock
    def advance(self, seconds: float) -> None:
        """Fly ``seconds`` [s]: physics steps of ``dt``, each followed by the
        vehicles' timers and telemetry; the core's timers at their own times."""
        end = self.now + seconds - 1e-9
        while self.now < end:
            tick = self.now + self.dt
            while (due := self.core.get_timer()) is not None and due <= tick:
                self.now = max(self.now, due)
                self.core.handle_timer(self.now)
                self.transfer()
            if self._next_hb <= tick:  # the station's 1 Hz HEARTBEAT (its shell's task)
                self._next_hb += 1.0
                self.link.send(b.heartbeat())
            self.fleet.step(self.dt)
            self.now = tick
            changed, self.fleet.changed = set(self.fleet.changed), []
            for v in self.vehicles.values():
                ap = v.ap
                if ap.deadline <= self.now + 1e-9 or v.row in changed:
                    frames = [bytes(m.pack(v.enc)) for m in ap.poll(self.now, self._kin(v))]
                    self._radio(v, frames)
                    self._sync(v)
                if v.lpn_next <= self.now + 1e-9:
                    iv = ap.lpn_interval_s or float("inf")
                    v.lpn_next = max(v.lpn_next + iv, self.now + 0.5 * iv)
                    self._radio(v, [self._lpn(v)])
            self.transfer()
            if self._next_status <= self.now:  # the shell's status task, every second
                self._next_status += 1.0
                self.core.check_alive(self.now)
                self.transfer()

    def run_until(self, done: Callable[[], bool], limit_s: float) -> None:
        """Advance a step at a time until ``done()``; fail after ``limit_s`` [s]."""
        end = self.now + limit_s
        while not done():
            assert self.now < end, f"not done after {limit_s} s: {self.phases()}"
            self.advance(self.dt)

    # ------------------------------------------------------------ phases
    def phases(self) -> dict[int, Phase]:
        return {s: vp.phase for s, vp in self.core.vehicles.items()}

    def ready(self, limit_s: float = 30.0) -> None:
        """Until every vehicle is READY (``Station.ready``), then the envelope."""
        self.run_until(lambda: all(p is Phase.READY for p in self.phases().values()), limit_s)
        self.core.apply_envelope()

    def start(self) -> None:
        """The formation starts (``Station.fly``)."""
        self.core.start(self.now)
        self.transfer()

    def end(self, limit_s: float = 10.0) -> None:
        """Zero acceleration and the end mode for everyone, until each vehicle
        has settled (``Station.end``)."""
        self.core.finish_all(self.now)
        self.transfer()
        settled = {Phase.ENDED, Phase.FAILED, Phase.LOST, Phase.CONNECTING}
        vps = list(self.core.vehicles.values())
        self.run_until(lambda: all(v.phase in settled and not v.restoring for v in vps), limit_s)
