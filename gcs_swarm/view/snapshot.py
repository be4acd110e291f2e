"""The operator view's frames without I/O: the station now, as JSON-able data.

``SnapshotBuilder.frame(station, now)`` reads a running station through its
public figures (``Station`` or ``SwarmCore``: the vehicles' protocols, the
control loop's last step, who flies, the log) and returns one frame, a dict
of lists, numbers, strings and None only (no NaN: the browser's JSON parser
refuses it), so ``json.dumps`` takes it as it is. It is called by the view's
push task at 10-20 Hz, never inside the control path; it changes nothing it
reads. Its only state is what the last frame showed (who flew, the
behaviour, the last log line), so each frame carries the events since the
previous one. docs/operator-view.md describes every field.

Frames and units: mission frame (x east, y north, z up), metres, seconds of
mission time (vehicle time, formation-law.md s4), m/s^2. The vehicles go as
columns (one list per field, row k is vehicle ``sysid[k]``): at 250
vehicles that is a fraction of the cost of one dict per vehicle.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import numpy.typing as npt

from gcs_swarm.control.obstacles import Ellipsoids, box_signed_distance
from gcs_swarm.mavlink.states import Phase

if TYPE_CHECKING:
    from gcs_swarm.control.loop import ControlLoop, StepResult
    from gcs_swarm.control.params import LawConfig
    from gcs_swarm.mavlink.telemetry_table import TelemetryTable
    from gcs_swarm.mavlink.vehicle import VehicleProtocol
    from gcs_swarm.report.record import LinkCounts
    from gcs_swarm.runtime.config import VehiclePlan

__all__ = [
    "EVENT_KINDS",
    "SnapshotBuilder",
    "StationState",
    "float_column",
    "frame_head",
    "geometry_columns",
    "law_columns",
    "new_lines",
    "obstacles_of",
    "scene_of",
]

F64 = npt.NDArray[np.float64]

EVENT_KINDS = ("join", "leave", "lost", "switch", "note")
"""What an event in a frame is: a vehicle joined or left the formation, was
lost (left it because its link went silent or it failed), the behaviour
switched (formation <-> avoidance, Eqs. 29-30), or a line of the station's log."""

_NO_XYZ = (math.nan, math.nan, math.nan)

_LOG_SCAN = 200
"""Most log lines one frame carries (the rest were too many to read anyway)."""


class StationState(Protocol):
    """What a frame is built from: ``runtime.Station`` and ``swarm.SwarmCore``
    both have these."""

    @property
    def vehicles(self) -> Mapping[int, VehicleProtocol]: ...
    @property
    def plans(self) -> Mapping[int, VehiclePlan]: ...
    @property
    def control(self) -> ControlLoop: ...
    @property
    def flying(self) -> set[int]: ...
    @property
    def log(self) -> deque[str]: ...
    @property
    def started(self) -> bool: ...
    @property
    def ending(self) -> bool: ...
    @property
    def table(self) -> TelemetryTable: ...


def scene_of(law: LawConfig, *, name: str = "") -> dict[str, Any]:
    """What does not move during a run: the boxes (centre, half-extents [m],
    Eq. 14) with the edge of their avoidance field, ``rho = r0``: the
    ellipsoid of semi-axes ``sqrt(3) r0 v_i`` [m] (Eqs. 15-18, A = 1/(sqrt3
    v1) etc.; formation-law.md s5), Eq. 7's sphere radius alpha [m], the
    geofence (min/max corners [m], or None) and the floor ``z_floor`` [m]
    (None when unbounded)."""
    lim = law.limits
    fence = None
    if lim.geofence_min is not None and lim.geofence_max is not None:
        fence = {"min": list(lim.geofence_min), "max": list(lim.geofence_max)}
    return {
        "name": name,
        "sphere_radius": float(law.gains.alpha),
        "r0": float(law.avoidance.r0),
        "obstacles": [
            {
                "centre": list(b.centre),
                "half": list(b.half_extents),
                "field": [math.sqrt(3.0) * law.avoidance.r0 * v for v in b.half_extents],
            }
            for b in law.obstacles
        ],
        "fence": fence,
        "floor": float(lim.z_floor) if math.isfinite(lim.z_floor) else None,
    }


def float_column(values: F64, digits: int) -> list[float | None]:
    """A column of floats rounded to ``digits``, None where not finite."""
    out: list[float | None] = np.round(values, digits).tolist()
    if not np.isfinite(values).all():
        bad = np.flatnonzero(~np.isfinite(values)).tolist()
        for k in bad:
            out[k] = None
    return out


def _rows(values: F64, digits: int) -> list[list[float] | None]:
    """Rows of ``values (N, 3)`` rounded to ``digits``, None where not all finite."""
    out: list[list[float] | None] = np.round(values, digits).tolist()
    for k in np.flatnonzero(~np.isfinite(values).all(axis=1)).tolist():
        out[k] = None
    return out


def _nearest_m(pos: F64) -> F64:
    """Each row's distance [m] to the nearest other row of ``pos (N, 3)``
    (inf when alone, NaN rows ignored)."""
    n = pos.shape[0]
    out = np.full(n, np.inf)
    ok = np.flatnonzero(np.isfinite(pos).all(axis=1))
    if ok.size < 2:
        return out
    p = pos[ok]
    sq = np.einsum("ij,ij->i", p, p)
    d2 = sq[:, None] + sq[None, :] - 2.0 * (p @ p.T)
    np.fill_diagonal(d2, np.inf)
    out[ok] = np.sqrt(np.maximum(d2.min(axis=1), 0.0))
    return out


def geometry_columns(
    pos_m: F64, leader_m: F64 | None, obstacles: Ellipsoids
) -> dict[str, list[Any]]:
    """The columns a frame derives from positions ``pos_m (N, 3)`` (NaN rows:
    no position): ``pos``, ``radius`` to ``leader_m``, ``nearest`` neighbour,
    ``clearance`` (signed distance to the nearest box, Eq. 14's boxes)."""
    n = pos_m.shape[0]
    radius = np.full(n, np.nan)
    if leader_m is not None:
        radius = np.linalg.norm(pos_m - leader_m, axis=1)
    clearance = np.full(n, np.nan)
    if obstacles.count and n:
        clearance = box_signed_distance(pos_m, obstacles).min(axis=1)
    return {
        "pos": _rows(pos_m, 3),
        "radius": float_column(radius, 3),
        "nearest": float_column(_nearest_m(pos_m), 3),
        "clearance": float_column(clearance, 3),
    }


def law_columns(last: StepResult | None, ids: list[int]) -> tuple[F64, F64]:
    """Each of ``ids``' commanded acceleration |a| [m/s^2] and safety
    correction [m/s^2] at the law's last step ``last``; NaN for a vehicle
    not in it (and for the correction without a filter)."""
    accel = np.full(len(ids), np.nan)
    correction = np.full(len(ids), np.nan)
    if last is not None:
        col = {s: k for k, s in enumerate(ids)}
        rows = [col[s] for s in last.ids if s in col]
        have = [i for i, s in enumerate(last.ids) if s in col]
        accel[rows] = np.linalg.norm(last.accel_mps2[have], axis=1)
        if last.safety is not None:
            correction[rows] = last.safety.correction_mps2[have]
    return accel, correction


def frame_head(seq: int, t: float, stage: str, last: StepResult | None) -> dict[str, Any]:
    """A live frame's fields before its vehicles: number ``seq``, mission
    time ``t`` [s], ``stage``, and the law's behaviour, episode and leader
    at its last step ``last``."""
    leader = None if last is None else last.law.leader_pos_m
    return {
        "type": "frame",
        "seq": seq,
        "t": round(t, 3),
        "stage": stage,
        "behaviour": None if last is None else str(last.law.behaviour),
        "episode": None if last is None else int(last.law.episode),
        "leader": None if leader is None else float_column(np.asarray(leader), 3),
    }


def obstacles_of(scene: Mapping[str, Any]) -> Ellipsoids:
    """The scene's boxes as the law's arrays (Eqs. 14-17)."""
    from gcs_swarm.control.params import Box

    boxes = [Box(tuple(b["centre"]), tuple(b["half"])) for b in scene["obstacles"]]
    return Ellipsoids.from_boxes(boxes)


class SnapshotBuilder:
    """Frames of one run (module docstring). ``scene`` is ``scene_of``'s."""

    def __init__(self, scene: Mapping[str, Any], obstacles: Ellipsoids | None = None) -> None:
        self.scene = dict(scene)
        self._obstacles = obstacles_of(scene) if obstacles is None else obstacles
        self._flying: set[int] = set()
        self._behaviour: str | None = None
        self._last_line: str | None = None
        self._modes: dict[int, tuple[object, str, bool]] = {}
        """Per vehicle: the HEARTBEAT last read, and its mode name and arming."""
        self.seq = 0
        self._slot_ids: list[int] = []
        self._slot_rows: npt.NDArray[np.intp] = np.zeros(0, dtype=np.intp)

    def frame(
        self,
        station: StationState,
        now: float,
        *,
        telemetry: Mapping[int, LinkCounts] | None = None,
    ) -> dict[str, Any]:
        """One frame at wall time ``now`` [s] (the station's clock). ``telemetry``:
        inbound counts per system id (the flight recorder's), for the loss column."""
        control = station.control
        last = control.last
        vps = [station.vehicles[s] for s in sorted(station.vehicles)]
        ids = [vp.sysid for vp in vps]
        n = len(vps)
        # state_mission's position, p = (e, n, -d) + o_i (formation-law.md s1), in one go:
        # a flying vehicle's from the telemetry table's columns, the others' one by one.
        ned, attached = station.table.ned_positions(self._slots(station, ids))
        for i in np.flatnonzero(~attached).tolist():
            p = vps[i].position
            ned[i] = _NO_XYZ if p is None else p[3:6]
        off = np.array([_NO_XYZ if vp.offset_m is None else vp.offset_m for vp in vps],
                       dtype=np.float64).reshape(n, 3)  # fmt: skip
        pos = np.empty((n, 3))
        if n:
            pos[:, 0] = ned[:, 1] + off[:, 0]
            pos[:, 1] = ned[:, 0] + off[:, 1]
            pos[:, 2] = off[:, 2] - ned[:, 2]
        modes, armed = self._mode_columns(vps)
        leader = None if last is None else last.law.leader_pos_m
        accel, correction = law_columns(last, ids)
        flying = station.flying
        heard = np.array([now - vp.position_at for vp in vps], dtype=np.float64)
        rate = np.array([math.nan if vp.telemetry_rate_hz is None else vp.telemetry_rate_hz
                         for vp in vps], dtype=np.float64)  # fmt: skip
        loss = np.full(n, np.nan)
        if telemetry is not None:
            for k, s in enumerate(ids):
                c = telemetry.get(s)
                if c is not None:
                    loss[k] = c.loss_fraction
        behaviour = None if last is None else str(last.law.behaviour)
        t = float(control.t_s)
        events = self._events(station, t, behaviour)
        self.seq += 1
        stage = "ending" if station.ending else "flying" if station.started else "starting"
        return {
            **frame_head(self.seq, t, stage, last),
            "vehicles": {
                "sysid": ids,
                "label": [vp.label for vp in vps],
                "autopilot": [station.plans[s].autopilot for s in ids],
                "phase": [vp.phase._value_ for vp in vps],  # ._value_: no enum descriptor
                "mode": modes,
                "armed": armed,
                "rate_hz": float_column(rate, 1),
                "loss": float_column(loss, 4),
                "heard_s": float_column(heard, 2),
                **geometry_columns(pos, leader, self._obstacles),
                "accel": float_column(accel, 3),
                "correction": float_column(correction, 3),
                "in_formation": [s in flying for s in ids],
            },
            "scene": self.scene,
            "events": events,
        }

    def _slots(self, station: StationState, ids: list[int]) -> npt.NDArray[np.intp]:
        """The table rows of ``ids`` (kept while the vehicles are the same)."""
        if self._slot_ids != ids:
            self._slot_ids, self._slot_rows = list(ids), station.table.slots(ids)
        return self._slot_rows

    def _mode_columns(self, vps: list[VehicleProtocol]) -> tuple[list[str], list[bool]]:
        """Each vehicle's mode name and arming, read again only when a new
        HEARTBEAT has come (1 Hz: most frames reuse the last reading)."""
        modes, armed = [], []
        cache = self._modes
        for vp in vps:
            hb = vp.heartbeat
            seen = cache.get(vp.sysid)
            if seen is None or seen[0] is not hb:
                seen = (hb, vp.mode_name, vp.armed)
                cache[vp.sysid] = seen
            modes.append(seen[1])
            armed.append(seen[2])
        return modes, armed

    def _events(self, station: StationState, t: float, behaviour: str | None) -> list[Any]:
        """What happened since the last frame: membership and behaviour by
        difference, then the log's new lines."""
        out: list[dict[str, Any]] = []
        flying = set(station.flying)
        for s in sorted(flying - self._flying):
            text = f"vehicle {station.vehicles[s].label} joins"
            out.append({"t": t, "kind": "join", "sysid": s, "text": text})
        for s in sorted(self._flying - flying):
            vp = station.vehicles[s]
            kind = "lost" if vp.phase in (Phase.LOST, Phase.FAILED) else "leave"
            text = f"vehicle {vp.label} out of the formation ({vp.phase.value})"
            out.append({"t": t, "kind": kind, "sysid": s, "text": text})
        self._flying = flying
        if behaviour is not None and self._behaviour is not None and behaviour != self._behaviour:
            out.append({"t": t, "kind": "switch", "sysid": None, "text": f"{behaviour}"})
        if behaviour is not None:
            self._behaviour = behaviour
        for line in self._new_lines(station.log):
            out.append({"t": t, "kind": "note", "sysid": None, "text": line})
        return out

    def _new_lines(self, log: deque[str]) -> list[str]:
        lines, self._last_line = new_lines(log, self._last_line)
        return lines


def new_lines(log: deque[str], mark: str | None) -> tuple[list[str], str | None]:
    """The log's lines after ``mark``, the line the last frame ended on, and
    the new mark (the log is a bounded deque: the mark is that line object,
    looked for from the end, at most ``_LOG_SCAN`` back)."""
    if not log:
        return [], mark
    lines: list[str] = []
    for line in itertools.islice(reversed(log), _LOG_SCAN):
        if line is mark:
            break
        lines.append(line)
    lines.reverse()
    return lines, log[-1]
