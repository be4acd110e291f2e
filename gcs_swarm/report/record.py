"""The flight record: what a run did at every control step, as arrays.

``FlightRecord`` is the one input of the run summary and the report picture,
whatever produced it: the station while flying (``FlightRecorder``, fed at
each control step), a ``.tlog`` replayed afterwards (``gcs_swarm.report.replay``)
or the in-process simulator (``from_sim_result``). Pure numpy, no I/O.

Frames and units: mission frame (x east, y north, z up), metres, seconds
(mission time, i.e. vehicle time from the formation start, formation-law.md
s4), m/s^2. Values that a ``.tlog`` carries as float32 (positions, leader,
commanded accelerations, safety corrections) are stored at float32
precision and times at whole microseconds, so that the record rebuilt from
the log equals the live one exactly.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from gcs_swarm.control.params import Box

__all__ = ["FlightRecord", "FlightRecorder", "LinkCounts", "TelemetryCounter"]

F64 = npt.NDArray[np.float64]
Sink = Callable[[bytes], None]


def _f32(x: npt.ArrayLike) -> F64:
    """Round to float32 precision (what a MAVLink float field carries), as float64."""
    return np.asarray(np.asarray(x, dtype=np.float32), dtype=np.float64)


def _t_us(t_s: float) -> float:
    return round(t_s * 1e6) * 1e-6


@dataclass
class LinkCounts:
    """Inbound MAVLink traffic of one system id (whole run, every message).

    ``lost`` is the number of sequence numbers skipped and never heard
    (MAVLink's per-sender ``seq`` counts every message it sends, per
    component); ``duplicates`` numbers heard again; ``late`` frames that
    came after a newer one (reordered: up to half the sequence space behind,
    taken back out of ``lost``); ``local_position`` the LOCAL_POSITION_NED
    messages among ``received``."""

    received: int = 0
    lost: int = 0
    duplicates: int = 0
    late: int = 0
    local_position: int = 0

    @property
    def loss_fraction(self) -> float:
        total = self.received + self.lost
        return self.lost / total if total else 0.0


_MSG_LOCAL_POSITION_NED = 32
_WINDOW = (1 << 128) - 1
"""Sequence numbers remembered behind the newest: half of MAVLink's 256."""


class TelemetryCounter:
    """Counts inbound frames per system id from their header fields."""

    def __init__(self) -> None:
        self.counts: dict[int, LinkCounts] = {}
        self._seen: dict[tuple[int, int], tuple[int, int]] = {}
        """Per sender (sysid, compid): its newest sequence number ``last`` and a
        mask whose bit d says ``last - d`` was heard (d < 128)."""

    def add(self, sysid: int, compid: int, seq: int, msgid: int) -> None:
        c = self.counts.setdefault(sysid, LinkCounts())
        c.received += 1
        if msgid == _MSG_LOCAL_POSITION_NED:
            c.local_position += 1
        key = (sysid, compid)
        seen = self._seen.get(key)
        if seen is None:
            self._seen[key] = (seq, 1)
            return
        last, heard = seen
        ahead = (seq - last) % 256
        if ahead == 0 or ahead >= 128:  # the newest again, or one behind it
            behind = (last - seq) % 256
            bit = 1 << behind
            if heard & bit:
                c.duplicates += 1
            else:  # skipped when a newer one came (counted lost then): reordered
                self._seen[key] = (last, heard | bit)
                c.late += 1
                if behind < 128 and c.lost > 0:  # 128 behind: outside the window
                    c.lost -= 1
            return
        c.lost += ahead - 1
        self._seen[key] = (seq, ((heard << ahead) | 1) & _WINDOW)


@dataclass(frozen=True, eq=False)
class FlightRecord:
    """A run, sampled at its control steps (T steps, N vehicles seen).

    - ``times_s (T,)`` mission time; ``ids (N,)`` system ids, ascending;
    - ``pos_m (T, N, 3)`` positions the law used, NaN where a vehicle was not
      in the formation at that step; ``leader_pos_m (T, 3)``;
    - ``accel_mps2 (T, N, 3)`` commanded acceleration where a setpoint was
      sent at that step (``sent (T, N)``), NaN elsewhere;
    - ``behaviour (T,)`` "formation" | "avoidance", ``episode (T,)``
      avoidance episodes started so far;
    - ``correction_mps2 (T, N)`` |a - a_des| of the safety filter (0 when it
      left the command alone, NaN when not applied), or None (no filter);
    - ``events`` ``(t_s, "join" | "leave", sysid)`` formation membership;
    - ``telemetry`` inbound counts per system id (None: not known, e.g. a
      simulation); ``boxes``, ``r0`` the obstacles and field range
      (formation-law.md s5); ``rate_hz`` the intended control rate.
    """

    name: str
    source: str
    times_s: F64
    ids: npt.NDArray[np.int64]
    pos_m: F64
    leader_pos_m: F64
    accel_mps2: F64
    sent: npt.NDArray[np.bool_]
    behaviour: npt.NDArray[np.str_]
    episode: npt.NDArray[np.int64]
    correction_mps2: F64 | None = None
    events: tuple[tuple[float, str, int], ...] = ()
    telemetry: dict[int, LinkCounts] | None = None
    boxes: tuple[Box, ...] = ()
    r0: float = 2.0
    rate_hz: float | None = None
    extra: dict[str, object] = field(default_factory=dict)

    @property
    def steps(self) -> int:
        return int(self.times_s.shape[0])

    def column(self, sysid: int) -> int:
        """Index of ``sysid`` along the vehicle axis (KeyError if never seen)."""
        hits = np.flatnonzero(self.ids == sysid)
        if hits.size == 0:
            raise KeyError(sysid)
        return int(hits[0])

    def switches(self) -> list[tuple[float, str, int]]:
        """Behaviour switches ``(t_s, "start" | "end", episode)`` (Eqs. 29-30)."""
        out: list[tuple[float, str, int]] = []
        beh = self.behaviour
        for k in range(1, beh.shape[0]):
            if beh[k] != beh[k - 1]:
                what = "start" if beh[k] == "avoidance" else "end"
                out.append((float(self.times_s[k]), what, int(self.episode[k])))
        return out


class FlightRecorder:
    """Builds a ``FlightRecord`` step by step (the station's and the replay's).

    ``sink``, when given, receives the station's log annotations as raw
    MAVLink frames (``gcs_swarm.report.notes``) for the ``.tlog``; they are
    never sent to a vehicle.
    """

    def __init__(
        self,
        *,
        name: str = "",
        source: str = "run",
        boxes: Sequence[Box] = (),
        r0: float = 2.0,
        rate_hz: float | None = None,
        safety: bool = False,
        sink: Sink | None = None,
    ) -> None:
        self.name, self.source = name, source
        self.boxes, self.r0, self.rate_hz = tuple(boxes), r0, rate_hz
        self.safety = safety
        self.telemetry = TelemetryCounter()
        self.events: list[tuple[float, str, int]] = []
        self._t: list[float] = []
        self._rows: list[dict[int, tuple[F64, F64 | None, float]]] = []
        self._leader: list[F64] = []
        self._beh: list[str] = []
        self._ep: list[int] = []
        self._notes = None
        if sink is not None:
            from gcs_swarm.report.notes import NoteWriter

            self._notes = NoteWriter(sink)

    # ------------------------------------------------------------- feeding
    def step(
        self,
        t_s: float,
        ids: Sequence[int],
        pos_m: npt.ArrayLike,
        leader_pos_m: npt.ArrayLike,
        behaviour: str,
        episode: int,
        *,
        accel_mps2: npt.ArrayLike | None = None,
        sent: Iterable[int] | None = None,
        correction_mps2: npt.ArrayLike | None = None,
    ) -> None:
        """One control step: ``pos_m (N, 3)`` of ``ids``, the commanded
        ``accel_mps2 (N, 3)`` of which only the vehicles in ``sent`` (default
        all) were sent a setpoint, the safety filter's ``correction_mps2 (N,)``."""
        t = _t_us(float(t_s))
        pos = np.asarray(pos_m, dtype=np.float64).reshape(-1, 3)
        acc = None if accel_mps2 is None else _f32(accel_mps2).reshape(-1, 3)
        cor = None if correction_mps2 is None else _f32(correction_mps2).reshape(-1)
        sent_set = set(ids) if sent is None else set(sent)
        row: dict[int, tuple[F64, F64 | None, float]] = {}
        for i, sysid in enumerate(ids):
            a = acc[i] if acc is not None and sysid in sent_set else None
            c = float(cor[i]) if cor is not None else math.nan
            row[int(sysid)] = (pos[i].copy(), a, c)
        leader = _f32(leader_pos_m).reshape(3)
        self._t.append(t)
        self._rows.append(row)
        self._leader.append(leader)
        self._beh.append(behaviour)
        self._ep.append(int(episode))
        if self._notes is not None:
            self._notes.step(t, leader, behaviour, int(episode), ids, cor)

    def set_accel(self, sysid: int, accel_mps2: npt.ArrayLike) -> None:
        """The setpoint sent to ``sysid`` at the last step (a replay learns it
        after the step); the first one per step counts."""
        row = self._rows[-1]
        if sysid in row and row[sysid][1] is None:
            p, _, c = row[sysid]
            row[sysid] = (p, _f32(accel_mps2).reshape(3), c)

    def set_correction(self, sysid: int, correction_mps2: float) -> None:
        """The safety correction of ``sysid`` at the last step (replay)."""
        row = self._rows[-1]
        if sysid in row:
            p, a, _ = row[sysid]
            row[sysid] = (p, a, float(np.float32(correction_mps2)))

    def member(self, t_s: float, sysid: int, joined: bool) -> None:
        """``sysid`` joined (True) or left the formation at mission time ``t_s``."""
        t = _t_us(float(t_s))
        self.events.append((t, "join" if joined else "leave", int(sysid)))
        if self._notes is not None:
            self._notes.member(t, int(sysid), joined)

    def inbound(self, sysid: int, compid: int, seq: int, msgid: int) -> None:
        """One received MAVLink message (header fields), for telemetry counts."""
        self.telemetry.add(sysid, compid, seq, msgid)

    # ------------------------------------------------------------- result
    def record(self) -> FlightRecord:
        """The record so far (arrays are copies)."""
        ids = sorted({s for row in self._rows for s in row} | {e[2] for e in self.events})
        col = {s: j for j, s in enumerate(ids)}
        t_n, n = len(self._t), len(ids)
        pos = np.full((t_n, n, 3), np.nan)
        acc = np.full((t_n, n, 3), np.nan)
        sent = np.zeros((t_n, n), dtype=bool)
        cor = np.full((t_n, n), np.nan)
        for k, row in enumerate(self._rows):
            for sysid, (p, a, c) in row.items():
                j = col[sysid]
                pos[k, j] = p
                cor[k, j] = c
                if a is not None:
                    acc[k, j] = a
                    sent[k, j] = True
        return FlightRecord(
            name=self.name,
            source=self.source,
            times_s=np.array(self._t, dtype=np.float64),
            ids=np.array(ids, dtype=np.int64),
            pos_m=pos,
            leader_pos_m=np.array(self._leader, dtype=np.float64).reshape(t_n, 3),
            accel_mps2=acc,
            sent=sent,
            behaviour=np.array(self._beh, dtype="<U9"),
            episode=np.array(self._ep, dtype=np.int64),
            correction_mps2=cor if self.safety else None,
            events=tuple(self.events),
            telemetry={s: LinkCounts(**vars(c)) for s, c in self.telemetry.counts.items()},
            boxes=self.boxes,
            r0=self.r0,
            rate_hz=self.rate_hz,
        )
