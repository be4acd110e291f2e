"""Rebuild a ``FlightRecord`` from a ``.tlog`` and the mission file alone.

Positions: each vehicle's LOCAL_POSITION_NED (north, east, down from its
own EKF origin) plus the offset of its GPS_GLOBAL_ORIGIN from the mission
origin, ``p = (e, n, -d) + o_i`` (formation-law.md s1, the station's own
conversion in ``gcs_swarm.mavlink.coordinates``). The mission origin is the
mission file's, or (``first-vehicle`` with a real first vehicle) that
vehicle's GPS_GLOBAL_ORIGIN, as the station does. Commanded accelerations:
the acceleration of each SET_POSITION_TARGET_LOCAL_NED the station (system
255) sent, acceleration-only (type_mask 3135) or with its velocity
(3079, Eq. V1), NED -> mission frame.

Two ways to find the control steps, the leader and the behaviour:

- a log written by gcs-swarm holds the station's annotations
  (``gcs_swarm.report.notes``): each ``LEADER`` note is one step with the
  leader's position; members come from ``JOIN``/``LEAVE``, the behaviour
  from ``AVOID``, the safety filter's work from ``SAFE``. The record then
  equals the station's live one.
- a log without them (another station, or a tap on the link): a step is a
  run of consecutive acceleration setpoints (no LOCAL_POSITION_NED between
  them, no vehicle twice); a vehicle joins the formation with its first
  non-zero acceleration setpoint and leaves when the station commands a
  mode other than GUIDED, a landing or a disarm, or after ``stale_timeout``
  of log time without a setpoint; the
  leader, behaviour and safety corrections are recomputed by running the
  station's own control loop (``gcs_swarm.control.loop.ControlLoop``,
  the mission's law in vehicle time) on the logged states.
"""

from __future__ import annotations

import heapq
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as _dialect

from gcs_swarm.control.loop import ControlLoop
from gcs_swarm.control.safety import filter_acts
from gcs_swarm.mavlink.builders import TYPE_MASK_ACCEL, TYPE_MASK_VEL_ACCEL
from gcs_swarm.mavlink.coordinates import GeoOrigin, origin_offset_m, vector_ned_to_mission
from gcs_swarm.mission import Mission
from gcs_swarm.mission.model import KEY_STRIDE
from gcs_swarm.report.notes import parse_note
from gcs_swarm.report.record import F64, FlightRecord, FlightRecorder
from gcs_swarm.report.tlog import TlogRecord, TlogStats, read_tlog

__all__ = ["CONTROLLER_TLOG_NAME", "ReplayStats", "record_from_tlog", "safety_applied"]

CONTROLLER_TLOG_NAME = "controller.tlog"
"""A sharded run's annotations (``gcs-swarm run --shards``): its controller
runs the law and keeps the notes; the shards log each network's frames."""

_LPN, _ORIGIN, _COMMAND_LONG, _SETPOINT, _DEBUG_VECT = 32, 49, 76, 84, 250
_MAV_CMD_NAV_LAND, _MAV_CMD_DO_SET_MODE, _MAV_CMD_ARM_DISARM = 21, 176, 400
_COPTER_GUIDED = 4
_PX4_OFFBOARD = (6, 0)


def _ends_flight(msg: Any, px4: bool = False) -> bool:
    """A command that takes a vehicle out of the formation: a mode other than
    its fly mode (ArduCopter GUIDED; PX4 OFFBOARD, main mode 6 sub 0: the
    station's ending is BRAKE, LAND, RTL or PX4's Hold, AUTO.LAND, AUTO.RTL),
    a land, a disarm."""
    cmd = int(msg.command)
    if cmd == _MAV_CMD_DO_SET_MODE:
        if px4:
            return (round(float(msg.param2)), round(float(msg.param3))) != _PX4_OFFBOARD
        return round(float(msg.param2)) != _COPTER_GUIDED
    return cmd == _MAV_CMD_NAV_LAND or (cmd == _MAV_CMD_ARM_DISARM and float(msg.param1) == 0.0)


@dataclass
class ReplayStats:
    """What the replay met: records read, frames that failed to decode,
    whether station annotations were found, and the reader's counts."""

    records: int = 0
    undecodable: int = 0
    annotated: bool = False
    tlog: TlogStats = field(default_factory=TlogStats)


def safety_applied(mission: Mission) -> bool:
    """Whether the station runs the limits/safety filter for this mission
    (``ControlLoop.filtering``)."""
    return filter_acts(mission.law.limits, mission.law.safety)


class _State:
    """Latest telemetry per vehicle and the mission-frame offsets."""

    def __init__(self, mission: Mission) -> None:
        geo = mission.origin_geo()
        self.reference = None if geo is None else GeoOrigin(geo.lat, geo.lon, geo.alt)
        self.first = mission.vehicles[0].key
        self.origins: dict[int, GeoOrigin] = {}
        self.lpn: dict[int, Any] = {}
        self.mav: Any = _dialect.MAVLink(None)
        self.mav.robust_parsing = True

    def decode(self, rec: TlogRecord) -> Any | None:
        try:
            return self.mav.decode(bytearray(rec.frame))
        except (_dialect.MAVError, ValueError, IndexError, KeyError, TypeError):
            return None

    def take(self, msg: Any, base: int = 0) -> None:
        sysid = int(msg.get_srcSystem()) + base  # the vehicle's key
        if msg.get_msgId() == _LPN:
            self.lpn[sysid] = msg
        else:
            origin = GeoOrigin.from_mavlink(int(msg.latitude), int(msg.longitude),
                                           int(msg.altitude))  # fmt: skip
            self.origins[sysid] = origin
            if self.reference is None and sysid == self.first:
                self.reference = origin

    def state(self, sysid: int) -> tuple[F64, F64] | None:
        """Mission-frame (position [m], velocity [m/s]), as the station computes it."""
        p = self.lpn.get(sysid)
        origin = self.origins.get(sysid)
        if p is None or origin is None or self.reference is None:
            return None
        o = origin_offset_m(origin, self.reference)
        # Same arithmetic as VehicleProtocol.state_mission: p = (e, n, -d) + o_i.
        x, y, z = float(p.x), float(p.y), float(p.z)
        return (
            np.array((y + o[0], x + o[1], -z + o[2])),
            np.array((float(p.vy), float(p.vx), -float(p.vz))),
        )


def _accel(msg: Any) -> F64 | None:
    if int(msg.type_mask) not in (TYPE_MASK_ACCEL, TYPE_MASK_VEL_ACCEL):
        return None  # not the law's (a position setpoint: the go-to of the start-up)
    return vector_ned_to_mission((float(msg.afx), float(msg.afy), float(msg.afz)))


def record_from_tlog(
    path: str | os.PathLike[str], mission: Mission, *, stats: ReplayStats | None = None
) -> FlightRecord:
    """The flight record of the run logged in ``path`` (see the module docstring)."""
    st = stats if stats is not None else ReplayStats()
    records = _network_records(path, mission, st)
    st.records = len(records)
    st.annotated = any(r.direction == "note" for r, _ in records)
    law = mission.law
    recorder = FlightRecorder(
        name=mission.settings.name,
        source="tlog",
        boxes=law.obstacles,
        r0=law.avoidance.r0,
        rate_hz=mission.settings.rate,
        safety=safety_applied(mission),
    )
    state = _State(mission)
    if st.annotated:
        _replay_notes(records, state, recorder, st)
    else:
        _replay_law(records, state, recorder, st, mission)
    return recorder.record()


_Keyed = tuple[TlogRecord, int]
"""A record and the base of its network's keys (``mission.vehicle_key``)."""


def _network_records(
    path: str | os.PathLike[str], mission: Mission, st: ReplayStats
) -> list[_Keyed]:
    """The records of the run: ``path`` alone for a mission without networks;
    else every network's ``.tlog`` beside it (``flight-<name>.tlog``), each
    record with its network's key base, merged in time order (the first
    network's first on a tie: it holds the station's notes); and a sharded
    run's ``controller.tlog`` when there is one beside (the notes: first on
    a tie). The processes of a sharded run stamp records with one machine's
    clock: a step's notes precede the setpoints it sent."""
    folder = Path(path).parent
    # A sharded run's controller logs the annotations apart (its notes name
    # vehicles by key): first on a tie, as the station's notes come first.
    notes = folder / CONTROLLER_TLOG_NAME
    streams = [[(r, 0) for r in read_tlog(notes, st.tlog)]] if notes.is_file() else []
    if not mission.multi_network:
        streams.append([(r, 0) for r in read_tlog(path, st.tlog)])
    else:
        streams += [
            [(r, j * KEY_STRIDE) for r in read_tlog(folder / f"flight-{name}.tlog", st.tlog)]
            for j, name in enumerate(mission.networks)
        ]
    if len(streams) == 1:
        return streams[0]
    return list(heapq.merge(*streams, key=lambda kr: kr[0].t_us))


def _inbound(
    rec: TlogRecord, base: int, state: _State, recorder: FlightRecorder, st: ReplayStats
) -> bool:
    """Count an inbound frame; take LOCAL_POSITION_NED / GPS_GLOBAL_ORIGIN.
    True when it was a LOCAL_POSITION_NED."""
    h = rec.header
    if h.msgid not in (_LPN, _ORIGIN):
        recorder.inbound(h.sysid + base, h.compid, h.seq, h.msgid)
        return False
    msg = state.decode(rec)
    if msg is None:
        st.undecodable += 1
        return False
    recorder.inbound(h.sysid + base, h.compid, h.seq, h.msgid)
    state.take(msg, base)
    return h.msgid == _LPN


def _replay_notes(
    records: list[_Keyed], state: _State, recorder: FlightRecorder, st: ReplayStats
) -> None:
    members: set[int] = set()
    behaviour, episode = "formation", 0
    stepped = False
    for rec, base in records:
        direction, msgid = rec.direction, rec.header.msgid
        if direction == "in":
            _inbound(rec, base, state, recorder, st)
            continue
        if msgid not in (_SETPOINT, _DEBUG_VECT):
            continue
        msg = state.decode(rec)
        if msg is None:
            st.undecodable += 1
            continue
        if direction == "out":
            a = _accel(msg) if msgid == _SETPOINT else None
            if a is not None and stepped:
                recorder.set_accel(int(msg.target_system) + base, a)
            continue
        note = parse_note(msg)
        if note is None:
            continue
        if note.name == "JOIN" or note.name == "LEAVE":
            sysid = round(note.x)
            joined = note.name == "JOIN"
            (members.add if joined else members.discard)(sysid)
            recorder.member(note.t_s, sysid, joined)
        elif note.name == "AVOID":
            behaviour = "avoidance" if note.x > 0.5 else "formation"
            episode = round(note.y)
        elif note.name == "SAFE" and stepped:
            recorder.set_correction(round(note.x), note.y)
        elif note.name == "LEADER":
            ids, pos = [], []
            for sysid in sorted(members):
                s = state.state(sysid)
                if s is not None:
                    ids.append(sysid)
                    pos.append(s[0])
            cor = np.zeros(len(ids)) if recorder.safety else None
            recorder.step(note.t_s, ids, np.array(pos).reshape(-1, 3), (note.x, note.y, note.z),
                          behaviour, episode, sent=(), correction_mps2=cor)  # fmt: skip
            stepped = True


def _replay_law(
    records: list[_Keyed],
    state: _State,
    recorder: FlightRecorder,
    st: ReplayStats,
    mission: Mission,
) -> None:
    px4 = {v.key for v in mission.vehicles if v.autopilot == "px4"}
    loop = ControlLoop(mission.law, {v.key: v.q for v in mission.vehicles},
                       mission.settings.rate, defer=False)  # fmt: skip
    stale_us = mission.settings.stale_timeout * 1e6
    last_sent: dict[int, int] = {}
    members: set[int] = set()
    group: dict[int, F64] = {}
    group_t = 0

    def flush() -> None:
        if not group:
            return
        for sysid in [s for s in members if group_t - last_sent[s] > stale_us]:
            members.discard(sysid)
            recorder.member(loop.t_s, sysid, False)
            loop.forget(sysid)
        fresh = {s: int(state.lpn[s].time_boot_ms) for s in group if s in state.lpn}
        t = loop.advance_clock(fresh)
        for sysid in sorted(group):
            if sysid not in members:
                members.add(sysid)
                recorder.member(t, sysid, True)
        ids: list[int] = []
        pos, vel = [], []
        for sysid in sorted(members):
            s = state.state(sysid)
            if s is not None:
                ids.append(sysid)
                pos.append(s[0])
                vel.append(s[1])
        if ids:
            res = loop.step(ids, np.array(pos), np.array(vel))
            cor = None if res.safety is None else res.safety.correction_mps2
            recorder.step(t, ids, res.pos_m, res.law.leader_pos_m, res.law.behaviour,
                          res.law.episode, sent=(), correction_mps2=cor)  # fmt: skip
            for sysid, a in group.items():
                recorder.set_accel(sysid, a)
        group.clear()

    for rec, base in records:
        h = rec.header
        if rec.direction == "in":
            if h.msgid == _LPN:
                flush()  # the step used the positions before this one
            _inbound(rec, base, state, recorder, st)
            continue
        if rec.direction != "out" or h.msgid not in (_SETPOINT, _COMMAND_LONG):
            continue
        msg = state.decode(rec)
        if msg is None:
            st.undecodable += 1
            continue
        target = int(msg.target_system) + base
        if h.msgid == _COMMAND_LONG:
            if target in members and _ends_flight(msg, target in px4):
                flush()
                members.discard(target)
                recorder.member(loop.t_s, target, False)
                loop.forget(target)
            continue
        a = _accel(msg)
        if a is None or target not in state.lpn or (target not in members and not a.any()):
            continue  # a zero command to a non-member: the ending's, not the law's
        if target in group:
            flush()
        if not group:
            group_t = rec.t_us
        group[target] = a
        last_sent[target] = rec.t_us
    flush()
    t_end = loop.t_s
    for sysid in sorted(members):
        recorder.member(t_end, sysid, False)
