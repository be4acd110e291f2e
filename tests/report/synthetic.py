"""A synthetic station run written to a .tlog the way the wired station
writes it: vehicle telemetry in, the station's annotations at each control
step, then its setpoints out. Known trajectories, a leave and a rejoin, an
avoidance episode, safety-filter corrections and lost telemetry."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.codec import Codec, MessageSpec
from gcs_swarm.mavlink.coordinates import GeoOrigin, origin_offset_m
from gcs_swarm.mission import Mission, geodetic_at, load_mission
from gcs_swarm.report import FlightRecord, FlightRecorder
from gcs_swarm.runtime.tlog import TlogWriter

MISSIONS = Path(__file__).resolve().parents[2] / "config" / "missions"
T0_US = 1_700_000_000_000_000
STEPS = 400
DT = 0.02
LOST = {(2, 50), (2, 51), (3, 300)}  # (sysid, step): telemetry lost on the way


def mission() -> Mission:
    """Scenario 3 (a box on the leader's path), safety filter on."""
    m = load_mission(MISSIONS / "scenario3_obstacle.yaml")
    law = dataclasses.replace(m.law, safety=dataclasses.replace(m.law.safety, enabled=True))
    return dataclasses.replace(m, law=law)


def _plan(k: int, j: int) -> np.ndarray:
    """Vehicle j's mission-frame position [m] at step k: through the box region."""
    t = k * DT
    return np.array([2.0 + 2.5 * t + 0.3 * j, 13.0 + 0.8 * j, 5.0 + 0.1 * j * np.sin(t)])


def write_run(path: Path, m: Mission) -> FlightRecord:
    """Write the log of the run to ``path``; return the live record."""
    ref_geo = m.origin_geo()
    assert ref_geo is not None
    ref = GeoOrigin(ref_geo.lat, ref_geo.lon, ref_geo.alt)
    ids = [v.sysid for v in m.vehicles]
    codecs = {s: Codec(sysid=s, compid=1) for s in ids}
    station = Codec()
    offsets: dict[int, np.ndarray] = {}
    clock = [T0_US]

    def stamp() -> int:
        clock[0] += 37
        return clock[0]

    with TlogWriter(path) as w:
        rec = FlightRecorder(name=m.settings.name, boxes=m.law.obstacles, r0=m.law.avoidance.r0,
                             rate_hz=m.settings.rate, safety=True,
                             sink=lambda f: w.write(f, t_us=stamp()))  # fmt: skip

        def receive(sysid: int, spec: MessageSpec) -> None:
            frame = codecs[sysid].encode(spec)
            w.write(frame, t_us=stamp())
            rec.inbound(sysid, 1, frame[4], (spec.name == "LOCAL_POSITION_NED" and 32) or 49)

        for j, sysid in enumerate(ids):
            home = geodetic_at(ref_geo, (5.0 * j, 1.0, -20.0))
            lat, lon, alt = round(home.lat * 1e7), round(home.lon * 1e7), round(home.alt * 1e3)
            fields = {"latitude": lat, "longitude": lon, "altitude": alt, "time_usec": 0}
            receive(sysid, MessageSpec("GPS_GLOBAL_ORIGIN", fields))
            offsets[sysid] = origin_offset_m(GeoOrigin.from_mavlink(lat, lon, alt), ref)
            rec.member(0.0, sysid, True)
        members = set(ids)
        latest: dict[int, np.ndarray] = {}
        for k in range(STEPS):
            t = k * DT
            if k == 100:
                members.discard(4)
                rec.member(t, 4, False)
            if k == 200:
                members.add(4)
                rec.member(t, 4, True)
            for j, sysid in enumerate(ids):
                ned = np.float32(_plan(k, j) - offsets[sysid])[[1, 0, 2]] * np.float32([1, 1, -1])
                spec = MessageSpec("LOCAL_POSITION_NED", {"time_boot_ms": 1000 + 20 * k,
                                   "x": ned[0], "y": ned[1], "z": ned[2],
                                   "vx": 2.5, "vy": 0.0, "vz": 0.0})  # fmt: skip
                if (sysid, k) in LOST:
                    codecs[sysid].encode(spec)  # sent by the vehicle, never arrives
                    continue
                receive(sysid, spec)
                o = offsets[sysid]
                # The station's arithmetic (VehicleProtocol.state_mission).
                x, y, z = float(ned[0]), float(ned[1]), float(ned[2])
                latest[sysid] = np.array((y + o[0], x + o[1], -z + o[2]))
            step_ids = sorted(members)
            pos = np.array([latest[s] for s in step_ids])
            leader = pos.mean(axis=0) + np.array([0.0, 0.1, 0.0])
            avoid = 150 <= k < 250
            acc = np.array([[0.1 * j, -0.05 * k / STEPS, 1.0 + (k == 210)] for j in step_ids])
            cor = np.array([0.25 if (avoid and s == 1 and k % 10 == 0) else 0.0 for s in step_ids])
            rec.step(t, step_ids, pos, leader, "avoidance" if avoid else "formation",
                     1 if k >= 150 else 0, accel_mps2=acc, correction_mps2=cor)  # fmt: skip
            for i, sysid in enumerate(step_ids):
                a = acc[i]
                spec = b.accel_setpoint(sysid, 1, k, (a[1], a[0], -a[2]))
                w.write(station.encode(spec), t_us=stamp())
            if k % 50 == 0:
                w.write(station.encode(b.heartbeat()), t_us=stamp())
        for sysid in sorted(members):
            rec.member(STEPS * DT, sysid, False)
    return rec.record()
