"""The emulator without its sockets: vehicles, sim time, delivery, telemetry. NO I/O.

Owns ``EmulatorCore``: the hosted vehicles (``vehicles``: autopilot, fleet
row, encoder, noise stream), the physics step and what follows it
(``schedule``: HEARTBEATs, polls, the status path of ``reports``, the
LOCAL_POSITION_NED stream), inbound messages
(peer rules, lockstep answers, the uplink impairment, delivery to the
autopilots) and outbound frames (sequence numbers, datagram joining, the
downlink impairment, ``impairments``). It is driven by ``step()`` and
``receive(port, msgs, addr, wall_s)``; it hands datagrams to each
``Port.sendto`` and never waits. The asyncio shell (``server.Emulator``)
owns the sockets, the clock task and the lockstep wait (``lockstep``).
``wall_s``: the wall clock, which only the GCS failsafe reads in lockstep
(``Autopilot.wall_s``); the shell passes it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import ardupilotmega as mav

from mavwire.datagrams import join_frames
from sim_vehicle import lockstep, reports, schedule
from sim_vehicle.codec import RawSetpoint, pack_frame
from sim_vehicle.commands import stream_accel, stream_accel_fields, streamed_accel
from sim_vehicle.config import EmulatorConfig, VehicleSpec
from sim_vehicle.fleet import Fleet
from sim_vehicle.impairments import DelayLine, impair
from sim_vehicle.small import few
from sim_vehicle.stats import EmulatorStats
from sim_vehicle.targets import NO_KIN
from sim_vehicle.telemetry import Kin
from sim_vehicle.vehicles import (
    Addr,
    HostedVehicle,
    Port,
    VehicleState,
    autopilot_for,
    heartbeat_phase_s,
    state_of,
)

__all__ = ["MAX_PEERS", "EmulatorCore"]

MAX_PEERS = 8
"""Peers one port serves at most (the oldest goes first)."""
_SETPOINT_CLASS = mav.MAVLink_set_position_target_local_ned_message
_HB = mav.MAVLink_heartbeat_message


class EmulatorCore:
    """Every hosted vehicle and the sim clock (module docstring)."""

    def __init__(self, config: EmulatorConfig, stats: EmulatorStats | None = None) -> None:
        self.config = config
        self.dt = 1.0 / config.rate_hz
        self.lockstep = config.clock == "lockstep"
        self.sim_time_s = 0.0
        self.step_count = 0
        self.stats = stats if stats is not None else EmulatorStats()
        self.fleet = Fleet()
        self.vehicles: dict[int, HostedVehicle] = {}
        self.rows: list[HostedVehicle] = []
        self._row_keys: list[int] = []  # each row's vehicle key and noise generator
        self._row_rngs: list[np.random.Generator] = []
        self.ports: list[Port] = []
        self._delayed_in: DelayLine[tuple[Port, list[Any]]] = DelayLine()
        self._delayed_out: DelayLine[tuple[Port, Addr, bytes, list[int]]] = DelayLine()
        self.out_heard: set[int] = set()
        """The ports (by ``id``) whose fixed ``out`` peer has been heard (rule 1)."""
        self._kins: list[Kin] | None = None  # every row's Kin at this step (few vehicles)
        self.defer_stream = True
        """The deferred lane (``_deliver``); False: every setpoint calls its
        autopilot at once (what the lane is tested against)."""
        self.status_path = True
        """ArduCopter's status streams without a poll (``reports``); False: each
        from its autopilot's poll (what the path is tested against)."""

    # ------------------------------------------------------------ vehicles
    def add(self, spec: VehicleSpec, ep: Port, initial: bool, enc: Any) -> HostedVehicle:
        """Host ``spec`` on port ``ep`` from now on; ``enc``: its pymavlink encoder
        (``signing.mavlink``: signing starts from the wall clock, the shell's)."""
        cfg, key = self.config, spec.key
        now = self.sim_time_s
        ap = autopilot_for(cfg, spec, now)
        if self.status_path:
            ap.fleet_streams = ap.FLEET_STREAMS
        start = spec.start_ned_m
        row = self.fleet.add(spec.sysid, spec.compid, start, landed=not spec.airborne)
        self._kins = None
        self.fleet.ground[row] = 0.0 if spec.airborne else start[2]
        self.fleet.boot[row] = now
        self.fleet.hb_next[row] = now + heartbeat_phase_s(cfg, spec)
        noise_rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, key, 3]))
        v = HostedVehicle(spec, ap, enc, ep, row, noise_rng, initial)
        self.vehicles[key] = v
        self.rows.append(v)
        self._row_keys.append(key)
        self._row_rngs.append(noise_rng)
        ep.sysids[spec.sysid] = key
        self.sync(v, now)
        return v

    def remove(self, key: int) -> HostedVehicle:
        """Stop hosting vehicle ``key``; returns it (its port is the caller's to close)."""
        v = self.vehicle(key)
        self._fold(v)
        del self.vehicles[key]
        self.fleet.remove(v.row)
        self._kins = None
        del self.rows[v.row], self._row_keys[v.row], self._row_rngs[v.row]
        for i, other in enumerate(self.rows):
            other.row = i
        del v.ep.sysids[v.spec.sysid]
        return v

    def vehicle(self, key: int) -> HostedVehicle:
        try:
            return self.vehicles[key]
        except KeyError:
            raise KeyError(f"no vehicle with sysid {key}") from None

    def set_silent(self, v: HostedVehicle, silent: bool) -> None:
        """``v``'s radio off or on (its own port): back on, a HEARTBEAT at once (rule 1)."""
        v.ep.silent = silent
        self.fleet.awaiting[v.row] = False  # an answer it cannot hear never blocks lockstep
        if not silent:
            self.transmit(v.ep, [(self.pack(v, v.ap.heartbeat()), 0)])

    def set_param(self, v: HostedVehicle, name: str, value: float) -> None:
        """Set a parameter directly (as PARAM_SET would, without a reply)."""
        self._fold(v)
        if not v.ap.params.set(name, value):
            raise KeyError(f"unknown parameter {name!r}")
        v.ap.refresh(self.sim_time_s, self.kin(v))
        self.sync(v, self.sim_time_s)

    def kin(self, v: HostedVehicle) -> Kin:
        """``v``'s kinematics now (few vehicles: every row's at once, kept until the next step)."""
        f = self.fleet
        if few(f.n):
            kins = self._kins
            if kins is None:
                kins = self._kins = schedule.kins(f)
            return kins[v.row]
        return schedule.kin(f, v.row)

    def snapshot(self, v: HostedVehicle, endpoint: Addr, tcp: Addr | None) -> VehicleState:
        """``v`` now, served on ``endpoint`` (and TCP ``tcp``)."""
        self._fold(v)
        return state_of(v, self.kin(v), self.sim_time_s, endpoint, tcp)

    def contact(self, v: HostedVehicle) -> None:
        """A station was heard by (or connected to) ``v``: lockstep rule 1, boot's end."""
        v.contacted = True
        self._fold(v)
        v.ap.contact(self.sim_time_s)
        self.sync(v, self.sim_time_s)

    def greet(self, ep: Port, addr: Addr) -> None:
        """A new peer ``addr`` of ``ep``: every vehicle there is in contact and sends it a
        HEARTBEAT at once (rule 1)."""
        for sysid in sorted(ep.sysids):
            v = self.vehicles[ep.sysids[sysid]]
            self.contact(v)
            self.transmit(ep, [(self.pack(v, v.ap.heartbeat()), 0)], only=addr)

    # ------------------------------------------------------------ inbound
    def receive(self, ep: Port, msgs: list[Any], addr: Addr, wall_s: float | None) -> None:
        """Decoded messages from ``addr`` arrive at port ``ep`` (sim time: now)."""
        if ep.silent:
            return
        stats = self.stats.link
        stats.rx_datagrams += 1
        # Only a peer that sent one good (with signing: well-signed) frame is
        # served: garbage or forgeries from elsewhere never evict the station.
        # With signing, the unsigned frames the parser lets through (RADIO_STATUS,
        # ArduPilot's exception) are heard but register nobody (issue 15).
        good = bool(msgs) and (ep.signing_key is None or any(m.get_signed() for m in msgs))
        new_peer = good and addr not in ep.peers
        if new_peer:
            ep.peers[addr] = None
            if len(ep.peers) > MAX_PEERS:
                ep.peers.pop(next(iter(ep.peers)))
        if self.lockstep:  # the ``awaiting`` flags block only a lockstep clock
            lockstep.answered(self.fleet, lockstep.setpoint_rows(self.vehicles, ep, msgs))
        if new_peer:  # rule 1: a new peer gets a HEARTBEAT at once
            self.greet(ep, addr)
        elif good and ep.out == addr and id(ep) not in self.out_heard:
            # The fixed ``out`` peer is known from the start: its first good
            # frame is its contact (rule 1), or a lockstep clock would never start.
            self.out_heard.add(id(ep))
            for key in ep.sysids.values():
                self.contact(self.vehicles[key])
        fate = impair(ep.uplink, self._delayed_in, self.sim_time_s, (ep, msgs))
        if fate.copies == 0:
            stats.rx_lost += 1
        elif fate.copies > 1:
            stats.duplicated += 1
        for _ in range(fate.now):
            self._deliver(ep, msgs, wall_s)

    def _deliver(self, ep: Port, msgs: list[Any], wall_s: float | None) -> None:
        """Each message to the autopilots it is for, in order; a setpoint
        may come as a ``codec.RawSetpoint`` (``Endpoint.parse(raw=True)``),
        read by the 50 Hz lane and made a message only if the lane declines.

        The deferred lane: a streamed acceleration setpoint for a vehicle
        whose autopilot is ``stream_deferrable`` (already flying the stream)
        and is not landed writes its a_ff into the fleet row and is held;
        the autopilot's own ``stream_accel`` runs once, for the last one
        held, when anything else is asked of it (``_fold``) but a HEARTBEAT,
        which commutes with it: the GCS failsafe's clock moves and the
        deadline is lowered to its check, as a setpoint lowers it to
        GUID_TIMEOUT (``Autopilot.gcs_heartbeat``; the HEARTBEAT reads no
        ``Kin``: ``commands.dispatch``). Its ``wall_s``
        is not set: only the GCS failsafe reads it, at a poll or a HEARTBEAT,
        each of which sets it first."""
        now = self.sim_time_s
        fleet = self.fleet
        landed, set_a_ff = fleet.landed, fleet.set_a_ff
        vehicles, sysids = self.vehicles, ep.sysids
        defer = self.defer_stream
        for m in msgs:
            cls = m.__class__
            f = m.f if cls is RawSetpoint else None
            ts = f[13] if f is not None else getattr(m, "target_system", 0)
            if ts == 0:
                targets = [vehicles[sysids[s]] for s in sorted(sysids)]
            elif ts in sysids:
                v = vehicles[sysids[ts]]
                if v.lane and defer and not landed[v.row]:
                    if f is not None:
                        a = streamed_accel(f[12], f[15], f[14], v.spec.compid, f[7], f[8], f[9])
                    elif cls is _SETPOINT_CLASS:
                        a = streamed_accel(m.type_mask, m.coordinate_frame, m.target_component,
                                           v.spec.compid, m.afx, m.afy, m.afz)  # fmt: skip
                    else:
                        a = None
                    if a is not None:
                        v.lane_a, v.lane_t = a, now
                        set_a_ff(v.row, a)
                        continue
                targets = [v]
            else:
                continue
            msg = m
            for v in targets:
                if v.lane_a is not None and cls is not _HB:  # a HEARTBEAT commutes with it
                    self._fold(v)
                ap = v.ap
                if wall_s is not None:
                    ap.wall_s = wall_s  # lockstep: the GCS failsafe's clock
                # the 50 Hz case, without a Kin (commands.stream_accel); a row in
                # sync before takes only what the lane moves (_sync_target)
                in_sync = v.seen_version == ap.version
                if f is not None:
                    if stream_accel_fields(ap, f[12], f[15], ts, f[14], f[7], f[8], f[9],
                                           now, bool(landed[v.row])):  # fmt: skip
                        if in_sync:
                            self._sync_target(v, holding_may_change=not v.row_holding)
                        else:
                            self.sync(v, now)
                        continue
                    if msg is m:
                        msg = m.message()
                elif cls is _SETPOINT_CLASS and stream_accel(ap, m, now, bool(landed[v.row])):
                    if in_sync:
                        self._sync_target(v, holding_may_change=not v.row_holding)
                    else:
                        self.sync(v, now)
                    continue
                # a HEARTBEAT (commands.dispatch: the GCS failsafe's clock) reads no Kin
                replies = ap.handle(msg, now, NO_KIN if cls is _HB else self.kin(v))
                if replies:
                    self.transmit(ep, [(self.pack(v, r), 0) for r in replies])
                self.sync(v, now)

    def _fold(self, v: HostedVehicle) -> None:
        """The deferred lane's last setpoint for ``v`` into its autopilot
        (``Autopilot.stream_accel``) and row: before anything else reads or
        changes the autopilot."""
        a = v.lane_a
        if a is not None:
            v.lane_a = None
            v.ap.stream_accel(a, v.lane_t)
            self._sync_target(v, holding_may_change=False)

    def fold(self) -> None:
        """Every held setpoint into its autopilot (``_deliver``): each autopilot's state
        as if it had taken every setpoint at once (for a reader of ``vehicles``)."""
        for v in self.rows:
            if v.lane_a is not None:
                self._fold(v)

    # ------------------------------------------------------------ outbound
    def pack(self, v: HostedVehicle, msg: Any) -> bytes:
        """One frame of ``v`` (its sequence number from the fleet row)."""
        row, enc = v.row, v.enc
        enc.seq = seq = int(self.fleet.seq[row])
        # Unsigned, a plain message's frame without pymavlink's framing (the same bytes).
        frame = None if enc.signing.sign_outgoing else pack_frame(msg, seq, enc.srcSystem,
                                                                   enc.srcComponent)  # fmt: skip
        if frame is None:
            frame = msg.pack(enc)
        self.fleet.seq[row] = (seq + 1) & 0xFF
        return frame

    def transmit(self, ep: Port, frames: list[tuple[bytes, int]], only: Addr | None = None) -> None:
        """Send (frame, key) pairs now through the downlink impairment to every peer (or
        ``only``); a nonzero key names the vehicle whose LOCAL_POSITION_NED it is."""
        if ep.silent:
            return
        peers = [only] if only is not None else list(ep.peers)
        if len(frames) == 1:  # one frame is its own datagram (the 50 Hz case)
            frame, key = frames[0]
            batches = [(frame, [key] if key else [])]
        else:
            batches = join_frames(frames)
        stats, now, line = self.stats.link, self.sim_time_s, self._delayed_out
        clean = not ep.downlink.imp.active  # the hot case: no impairment, no random draw
        for data, lpn in batches:
            for peer in peers:
                if clean:
                    ep.sendto(data, peer)
                    self._sent_reports(lpn)
                    continue
                fate = impair(ep.downlink, line, now, (ep, peer, data, lpn))
                if fate.copies == 0:
                    stats.tx_lost += 1
                elif fate.copies > 1:
                    stats.duplicated += 1
                for _ in range(fate.now):
                    ep.sendto(data, peer)
                    self._sent_reports(lpn)

    def _sent_reports(self, keys: list[int]) -> None:
        """Rule 3: a LOCAL_POSITION_NED left towards these vehicles; they await an answer
        (a lockstep clock's flags: a real-time one keeps none)."""
        if not self.lockstep:
            return
        for key in keys:
            v = self.vehicles.get(key)
            if v is not None:
                self.fleet.awaiting[v.row] = True

    def _sync_target(self, v: HostedVehicle, holding_may_change: bool = True) -> bool:
        """The first part of ``sync``: the deadline, the holding flag (unless it cannot
        have changed) and, when the version moved, the target; True in that case.

        All of ``sync`` after the setpoint lane (``commands.stream_accel_fields``)
        took a setpoint for a vehicle whose row was in sync before: the lane moves
        only the deadline, the holding flag (to True: a holding row stays so), the
        version and the target, not the parameters, the report interval or the
        stream kick that the rest of ``sync`` copies."""
        ap, f, row = v.ap, self.fleet, v.row
        # Each row value is written only when it changed: a numpy item write costs
        # more than the comparison, and this runs for every setpoint.
        if ap.deadline != v.row_deadline:
            f.deadline[row] = v.row_deadline = ap.deadline
        if holding_may_change:
            holding = ap.holding
            if holding != v.row_holding:
                f.holding[row] = v.row_holding = holding
        v.lane = ap.stream_deferrable()
        if ap.version == v.seen_version:
            return False
        v.seen_version = ap.version
        f.set_target(row, ap.target, v.row_target)
        v.row_target = ap.target
        if ap.accel_entry is not None:  # Eq. D9
            schedule.enter_accel(f, row, ap.accel_entry, ap.VEL_REFERENCE, v.moving_start)
            ap.accel_entry = v.moving_start = None
        return True

    def sync(self, v: HostedVehicle, now: float) -> None:
        """Copy an autopilot's published state into its fleet row (after handle/poll)."""
        ap = v.ap
        if (ap.mode, ap.armed) != v.row_heartbeat:  # new (or first): its HEARTBEAT's fields,
            v.row_heartbeat = (ap.mode, ap.armed)  # and a poll at the next step, whose land
            self.fleet.set_heartbeat(v.row, ap.heartbeat())  # detector looks (ArduCopter's
            ap.deadline = min(ap.deadline, now)  # every loop; nothing else acts if not due)
        if ap.fleet_streams:
            self.fleet.st_next[v.row] = reports.first_due(ap, status_path=True)
        if not self._sync_target(v):
            return
        ap, f, row = v.ap, self.fleet, v.row
        iv = ap.lpn_interval_s
        prm = ap.params
        # The row's telemetry values come from the parameters and the interval only:
        # read again when one of them changed (a setpoint bumps the version, 50 Hz).
        dyn_key = (prm, prm.generation, iv)
        if dyn_key != v.row_dyn_key:
            v.row_dyn_key = dyn_key
            dyn = (
                prm["SIM_NOISE_POS"],
                prm["SIM_NOISE_VEL"],
                iv if iv is not None else np.inf,
                (prm["SIM_VBIAS_N"], prm["SIM_VBIAS_E"], prm["SIM_VBIAS_D"]),
                prm["SIM_VBIAS_FLIP"],
                prm["SIM_VBIAS_TAU"],
            )
            if dyn != v.row_dyn:
                (f.noise_pos[row], f.noise_vel[row], f.lpn_interval[row], f.vbias[row],
                 f.vbias_flip[row], f.vbias_tau[row]) = dyn  # fmt: skip
                v.row_dyn = dyn
        if iv is None:
            f.lpn_next[row] = np.inf
        elif ap.lpn_kick:  # rule 1: a newly enabled stream sends its first message at once
            ap.lpn_kick = False
            f.lpn_next[row] = now + iv
            if v.ep.peers:
                self.transmit(v.ep, self._report_frames(np.array([row], dtype=np.intp), now))

    def _status(self, v: HostedVehicle, now: float) -> None:
        """``v``'s status-path streams due at ``now``, without a poll (reports)."""
        ap, f = v.ap, self.fleet
        ids, f.st_next[v.row] = reports.take_fleet_streams(ap, now)
        if not ids or not v.ep.peers:
            return
        if self.config.signing_key is None:
            frames = schedule.status_frames(f, ap, v.row, ids, now)
        else:
            frames = [self.pack(v, ap.build(m, now, self.kin(v))) for m in ids]
        v.ep.outbox.extend((frame, 0) for frame in frames)

    def _report_frames(self, rows: NDArray[np.intp], now: float) -> list[tuple[bytes, int]]:
        by_row = self.rows
        signed: Callable[[int, Any], bytes] | None = None
        if self.config.signing_key is not None:

            def signed(row: int, msg: Any) -> bytes:
                return self.pack(by_row[row], msg)

        frames = schedule.report_frames(self.fleet, rows, now, self._row_rngs, signed)
        return list(zip(frames, map(self._row_keys.__getitem__, rows.tolist()), strict=True))

    # --------------------------------------------------------------- clock
    def step(self, wall: Callable[[], float] | None = None, *, emit: bool = True) -> None:
        """One physics step, then what is due at the new sim time (``emit``).
        ``wall``: reads the wall clock (lockstep), None in real time. ``emit=False``:
        the physics alone (``server.Emulator``'s overrun: ``overrun_steps``)."""
        self.fleet.step(self.dt)
        self._kins = None
        self.step_count += 1
        self.stats.steps = self.step_count
        self.sim_time_s = now = self.step_count * self.dt
        if emit:
            return self.emit(now, wall)
        self.stats.overrun_steps += 1

    def emit(self, now: float, wall: Callable[[], float] | None = None) -> None:
        """The delayed datagrams due by ``now``, the autopilots' polls, the telemetry."""
        while (item := self._delayed_in.pop_due(now)) is not None:
            ep, msgs = item
            if ep.sysids and not ep.silent:
                self._deliver(ep, msgs, wall() if wall is not None else None)
        while (out := self._delayed_out.pop_due(now)) is not None:
            ep, peer, data, lpn = out
            if ep.sysids and not ep.silent:
                ep.sendto(data, peer)
                self._sent_reports(lpn)
        f, rows = self.fleet, self.rows
        # The 1 Hz HEARTBEATs first (of the state before the polls); signed: one by one
        beats = [r for r in schedule.due_heartbeats(f, now) if rows[r].ep.peers]
        if beats:
            hbs = (f.heartbeat_frames(beats) if self.config.signing_key is None
                   else [self.pack(rows[r], rows[r].ap.heartbeat()) for r in beats])  # fmt: skip
            for frame, r in zip(hbs, beats, strict=True):
                rows[r].ep.outbox.append((frame, 0))
        polled = schedule.due_polls(f, now)
        only = set(schedule.due_status(f, now)).difference(polled)  # no poll: reports
        wall_s = wall() if wall is not None and polled else None
        for row in sorted(only.union(polled)) if only else polled:
            v = self.rows[row]
            if row in only:  # its status-path streams alone are due
                self._status(v, now)
                continue
            if v.lane_a is not None:
                self._fold(v)
            if wall_s is not None:
                v.ap.wall_s = wall_s  # Autopilot.wall_s: lockstep's GCS failsafe clock
            out_msgs = v.ap.poll(now, self.kin(v))
            self.sync(v, now)
            if out_msgs and v.ep.peers:
                v.ep.outbox.extend((self.pack(v, m), 0) for m in out_msgs)
        due = schedule.due_reports(f, now)
        if due.size:
            for pair, r in zip(self._report_frames(due, now), due.tolist(), strict=True):
                ep = rows[r].ep
                if ep.peers:
                    ep.outbox.append(pair)
        for ep in self.ports:
            if ep.outbox:
                frames, ep.outbox = ep.outbox, []
                self.transmit(ep, frames)
