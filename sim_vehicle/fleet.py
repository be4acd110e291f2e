"""The vectorised rows of every hosted vehicle. No I/O.

Owns the numpy arrays the hot path runs on: kinematic state, tracking targets
(dynamics Eq. D3), dynamics limits, the LOCAL_POSITION_NED and HEARTBEAT
schedules and the HEARTBEAT's fields, the
MAVLink sequence counters and the lockstep ``awaiting`` flags, one row per
vehicle. Rows are compacted on removal (rare); callers keep their row index
up to date through ``rows``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sim_vehicle import dynamics, dynamics_rows
from sim_vehicle.codec import (
    HEARTBEAT_FIELDS,
    encode_heartbeats,
    encode_local_position_ned,
    heartbeat_frames_small,
    lpn_frames_small,
)
from sim_vehicle.dynamics import DynParams, KinState, Targets
from sim_vehicle.small import few
from sim_vehicle.targets import ControlTarget

_Vec3 = tuple[float, float, float]

__all__ = ["KP_1_S", "KV_1_S", "Fleet"]

#: Gains of Eq. D3 (ArduCopter PSC_POSXY_P = 1, PSC_VELXY_P = 2).
KP_1_S = 1.0
KV_1_S = 2.0
_V3 = ("pos", "vel", "acc", "shp", "a_ff", "p_t", "v_t", "wp", "vbias")
_V1 = (
    "wv", "vmax_xy", "vmax_up", "vmax_dn", "acc_lim", "tau", "acc_max", "ground",
    "lpn_interval", "lpn_next", "noise_pos", "noise_vel", "deadline", "boot",
    "jerk_xy", "jerk_z", "lean", "drag", "vbias_flip", "vbias_tau", "hb_next", "st_next",
)  # fmt: skip
_INF_DEFAULT = ("lpn_interval", "jerk_xy", "jerk_z", "lean", "st_next")
_I1 = ("seq", "sysid", "compid")
_B1 = ("landed", "awaiting", "holding")


class Fleet:
    """Arrays of N vehicles (see module docstring). All positions local NED m."""

    pos: NDArray[np.float64]
    vel: NDArray[np.float64]
    acc: NDArray[np.float64]
    shp: NDArray[np.float64]  # shaped command of dynamics Eqs. D5-D6 (the jerk limiter's state)
    jerk_xy: NDArray[np.float64]
    jerk_z: NDArray[np.float64]
    lean: NDArray[np.float64]
    drag: NDArray[np.float64]  # Eq. D7, 1/s
    a_ff: NDArray[np.float64]
    p_t: NDArray[np.float64]
    v_t: NDArray[np.float64]
    wp: NDArray[np.float64]
    wv: NDArray[np.float64]
    vmax_xy: NDArray[np.float64]
    vmax_up: NDArray[np.float64]
    vmax_dn: NDArray[np.float64]
    acc_lim: NDArray[np.float64]
    tau: NDArray[np.float64]
    acc_max: NDArray[np.float64]
    ground: NDArray[np.float64]
    lpn_interval: NDArray[np.float64]
    lpn_next: NDArray[np.float64]
    noise_pos: NDArray[np.float64]
    noise_vel: NDArray[np.float64]
    vbias: NDArray[np.float64]  # bias of the reported velocity before its reversal (NED m/s)
    vbias_flip: NDArray[np.float64]  # boot time [s] the bias starts to reverse (0: never)
    vbias_tau: NDArray[np.float64]  # time constant [s] of that reversal
    seq: NDArray[np.int64]
    sysid: NDArray[np.int64]
    compid: NDArray[np.int64]
    deadline: NDArray[np.float64]
    boot: NDArray[np.float64]
    landed: NDArray[np.bool_]
    awaiting: NDArray[np.bool_]
    holding: NDArray[np.bool_]
    hb_next: NDArray[np.float64]  # when the row's next 1 Hz HEARTBEAT goes (sim s)
    hb_fields: NDArray[np.int64]  # its HEARTBEAT's fields (N, 6): codec.HEARTBEAT_FIELDS
    st_next: NDArray[np.float64]  # when its status-path streams are next due (reports)

    def __init__(self) -> None:
        self.n = 0
        self.changed: list[int] = []  # rows whose ``landed`` flag the last step changed
        self._views: tuple[Targets, DynParams] | None = None  # step()'s inputs over the arrays
        self._lag: tuple[list[float], float, list[tuple[float, float]]] | None = None
        self._a_ff_due: dict[int, _Vec3] = {}
        """Rows' ``a_ff`` set one at a time since the last step, written at the
        next (``_write_a_ff``)."""
        self._a_ff_batches: list[tuple[list[int], NDArray[np.float64]] | dict[int, _Vec3]] = []
        """What was set before the single rows now due: their dicts and whole
        batches (``set_a_ff_rows``), in the order they were set."""
        for name in _V3:
            setattr(self, name, np.zeros((0, 3)))
        for name in _V1:
            setattr(self, name, np.zeros(0))
        for name in _I1:
            setattr(self, name, np.zeros(0, dtype=np.int64))
        for name in _B1:
            setattr(self, name, np.zeros(0, dtype=bool))
        self.hb_fields = np.zeros((0, len(HEARTBEAT_FIELDS)), dtype=np.int64)

    def add(self, sysid: int, compid: int, pos: tuple[float, float, float], landed: bool) -> int:
        """Append a row at rest at ``pos``; returns its index."""
        self._write_a_ff()
        for name in _V3:
            arr = getattr(self, name)
            row = np.array([pos]) if name == "pos" else np.zeros((1, 3))
            setattr(self, name, np.concatenate([arr, row]))
        for name in _V1:
            setattr(
                self,
                name,
                np.append(getattr(self, name), np.inf if name in _INF_DEFAULT else 0.0),
            )
        for name, val in (("seq", 0), ("sysid", sysid), ("compid", compid)):
            setattr(self, name, np.append(getattr(self, name), np.int64(val)))
        self.landed = np.append(self.landed, landed)
        self.awaiting = np.append(self.awaiting, False)
        self.holding = np.append(self.holding, False)
        self.hb_fields = np.concatenate(
            [self.hb_fields, np.zeros((1, len(HEARTBEAT_FIELDS)), np.int64)]
        )
        self.n += 1
        self._views = None
        return self.n - 1

    def remove(self, row: int) -> None:
        """Delete a row (later rows shift down by one)."""
        self._write_a_ff()
        for name in (*_V3, *_V1, *_I1, *_B1, "hb_fields"):
            setattr(self, name, np.delete(getattr(self, name), row, axis=0))
        self.n -= 1
        self._views = None

    def set_target(self, row: int, tg: ControlTarget, prev: ControlTarget | None = None) -> None:
        """Copy one autopilot target into the row (Eq. D3 inputs, dynamics limits).

        ``prev``: the target last copied into this row, if known. When every
        field but ``a_ff`` is the very same object as in ``prev`` (a streamed
        acceleration setpoint) only ``a_ff`` is written; identity, not ``==``,
        which would take -0.0 for 0.0. ``a_ff`` reaches its array at the next
        ``step`` (or ``add``, ``remove``), whatever its row's last was."""
        self._a_ff_due[row] = tg.a_ff  # one numpy write per step, not per setpoint
        if (
            prev is not None
            and tg.p_t is prev.p_t
            and tg.v_t is prev.v_t
            and tg.wp is prev.wp
            and tg.wv is prev.wv
            and tg.vmax_xy is prev.vmax_xy
            and tg.vmax_up is prev.vmax_up
            and tg.vmax_dn is prev.vmax_dn
            and tg.acc_lim is prev.acc_lim
            and tg.acc_max is prev.acc_max
            and tg.tau_s is prev.tau_s
            and tg.jerk_xy is prev.jerk_xy
            and tg.jerk_z is prev.jerk_z
            and tg.lean_acc is prev.lean_acc
            and tg.drag is prev.drag
        ):
            return
        self.p_t[row] = tg.p_t
        self.v_t[row] = tg.v_t
        self.wp[row] = tg.wp
        self.wv[row] = tg.wv
        self.vmax_xy[row] = tg.vmax_xy
        self.vmax_up[row] = tg.vmax_up
        self.vmax_dn[row] = tg.vmax_dn
        self.acc_lim[row] = tg.acc_lim
        self.acc_max[row] = tg.acc_max
        self.tau[row] = tg.tau_s
        self.jerk_xy[row] = tg.jerk_xy
        self.jerk_z[row] = tg.jerk_z
        self.lean[row] = tg.lean_acc
        self.drag[row] = tg.drag

    def set_a_ff(self, row: int, a_ff: _Vec3) -> None:
        """The row's feed-forward acceleration alone (the deferred lane's setpoint:
        the rest of its target stays), written at the next ``step``."""
        self._a_ff_due[row] = a_ff

    def set_a_ff_rows(self, rows: list[int], a_ff: NDArray[np.float64]) -> None:
        """``set_a_ff`` of each of ``rows`` in turn, row k's ``a_ff[k]`` (K, 3)
        (the last of a row's wins): kept as the array it came in, a network's
        stream written at the next step in one assignment (a dict of tuples
        cost 83 us for 250 rows against 17 here, in process)."""
        self._seal_a_ff()  # the single rows set before this batch: written before it
        self._a_ff_batches.append((rows, a_ff))

    def _seal_a_ff(self) -> None:
        """The single rows set so far go into ``_a_ff_batches``, in their turn."""
        if self._a_ff_due:
            self._a_ff_batches.append(self._a_ff_due)
            self._a_ff_due = {}

    def _write_a_ff(self) -> None:
        """The ``a_ff`` set since the last step into its rows, in the order set
        (the last of each row's)."""
        self._seal_a_ff()
        a_ff = self.a_ff
        for batch in self._a_ff_batches:
            if isinstance(batch, dict):
                a_ff[list(batch)] = list(batch.values())
                continue
            rows, values = batch
            if len(set(rows)) < len(rows):  # a row twice: its last (numpy does not promise
                # which of a repeated index it keeps), as set_a_ff in turn gives
                last = dict(zip(rows, range(len(rows)), strict=True))
                rows, values = list(last), values[list(last.values())]
            a_ff[rows] = values
        self._a_ff_batches.clear()

    def step(self, dt: float) -> None:
        """Advance every vehicle by ``dt`` s: Eq. D3, then ``dynamics.step`` (D1, D5-7, D2, D4)."""
        if self.n == 0:
            return
        self._write_a_ff()
        before = self.landed
        small = few(self.n)  # plain floats (dynamics_rows), the same bits as numpy's
        if not (small and self._step_small(dt)):
            self.step_numpy(dt)
        if small:
            now_landed = self.landed.tolist()
            self.changed = [r for r, a in enumerate(before.tolist()) if a != now_landed[r]]
        else:
            self.changed = np.flatnonzero(before != self.landed).tolist()

    def _step_small(self, dt: float) -> bool:
        """``step`` through ``dynamics_rows.advance_small``; False (nothing changed) where it
        cannot run (a math domain error, a non-finite result): numpy decides then."""
        tau = self.tau.tolist()
        lag = self._lag
        if lag is None or lag[0] != tau or lag[1] != dt:
            lag = self._lag = (tau, dt, dynamics_rows.lag_factors(self.tau, dt))
        tg = (
            self.a_ff.tolist(), self.p_t.tolist(), self.v_t.tolist(), self.wp.tolist(),
            self.wv.tolist(), self.vmax_xy.tolist(), self.vmax_up.tolist(),
            self.vmax_dn.tolist(), self.acc_lim.tolist(),
        )  # fmt: skip
        try:
            shaping = (
                self.shp.tolist(),
                self.jerk_xy.tolist(),
                self.jerk_z.tolist(),
                self.lean.tolist(),
            )
            pos, vel, acc, landed, shp = dynamics_rows.advance_small(
                self.pos.tolist(), self.vel.tolist(), self.acc.tolist(), tg,
                self.acc_max.tolist(), self.ground.tolist(), lag[2], dt, KP_1_S, KV_1_S,
                shaping, self.drag.tolist(),
            )  # fmt: skip
        except ValueError:
            return False
        chk = 0.0
        for p, v, a, c in zip(pos, vel, acc, shp, strict=True):
            chk += p[0] + p[1] + p[2] + v[0] + v[1] + v[2] + a[0] + a[1] + a[2] + c[0] + c[1] + c[2]
        if not math.isfinite(chk):  # NaN or inf somewhere: numpy's rules for those
            return False
        self.pos, self.vel, self.acc = np.array(pos), np.array(vel), np.array(acc)
        self.shp = np.array(shp)
        self.landed = np.array(landed, dtype=bool)
        return True

    def step_numpy(self, dt: float) -> None:
        """``step`` with numpy whatever the number of vehicles (the reference of the small path)."""
        if self.n == 0:
            return
        self._write_a_ff()
        st = KinState(self.pos, self.vel, self.acc, self.landed, self.shp)
        if self._views is None:  # the arrays are written in place; only add/remove replace them
            self._views = (
                Targets(
                    self.a_ff, self.p_t, self.v_t, self.wp, self.wv,
                    self.vmax_xy, self.vmax_up, self.vmax_dn, self.acc_lim,
                ),
                DynParams(
                    self.tau, self.acc_max, self.ground, self.jerk_xy, self.jerk_z, self.lean,
                    self.drag,
                ),
            )  # fmt: skip
        tg, params = self._views
        cmd = dynamics.tracking_accel(st, tg, KP_1_S, KV_1_S)
        new = dynamics.step(st, cmd, dt, params)
        assert new.cmd_ned_m_s2 is not None
        self.pos, self.vel, self.acc, self.landed, self.shp = (
            new.pos_ned_m,
            new.vel_ned_m_s,
            new.acc_ned_m_s2,
            new.landed,
            new.cmd_ned_m_s2,
        )

    def encode_lpn(
        self,
        rows: NDArray[np.intp],
        time_boot_ms: NDArray[np.int64],
        pos: NDArray[np.float64],
        vel: NDArray[np.float64],
    ) -> tuple[NDArray[np.uint8], NDArray[np.int64]]:
        """LOCAL_POSITION_NED frames for ``rows`` (values given, e.g. with noise); bumps seq."""
        buf, lens = encode_local_position_ned(
            time_boot_ms, pos, vel, self.seq[rows], self.sysid[rows], self.compid[rows]
        )
        self.seq[rows] = (self.seq[rows] + 1) & 0xFF
        return buf, lens

    def lpn_frames_rows(self, rows: list[int], time_boot_ms: list[int]) -> list[bytes] | None:
        """``lpn_frames`` for a few rows given as a list, the state's own values (no noise):
        the same bytes from plain lists, without numpy's per-call cost. None (and no
        sequence number used) when a value does not fit a float32. ``rows``
        distinct. A small fleet's whole columns go to lists (no numpy call
        per row), a large one's rows only (a whole column is O(N) a call: a
        stream's first report, sent at once, is one row of a fleet that may
        be 250)."""
        cols = (self.pos, self.vel, self.seq, self.sysid, self.compid)
        if few(self.n):
            pos, vel, seq, sysid, compid = (c.tolist() for c in cols)
            frames = lpn_frames_small(
                time_boot_ms, [pos[r] for r in rows], [vel[r] for r in rows],
                [seq[r] for r in rows], [sysid[r] for r in rows], [compid[r] for r in rows],
            )  # fmt: skip
            if frames is not None:
                for r in rows:
                    seq[r] = (seq[r] + 1) & 0xFF
                self.seq[:] = seq
            return frames
        pos, vel, seq, sysid, compid = (c[rows].tolist() for c in cols)
        frames = lpn_frames_small(time_boot_ms, pos, vel, seq, sysid, compid)
        if frames is not None:
            self.seq[rows] = [(q + 1) & 0xFF for q in seq]
        return frames

    def lpn_frames(
        self,
        rows: NDArray[np.intp],
        time_boot_ms: NDArray[np.int64],
        pos: NDArray[np.float64],
        vel: NDArray[np.float64],
    ) -> list[bytes]:
        """The frames of ``encode_lpn`` as bytes, one per row (plain ``struct`` for a few)."""
        if few(len(rows)):
            seq = self.seq[rows]
            frames = lpn_frames_small(
                time_boot_ms.tolist(), pos.tolist(), vel.tolist(), seq.tolist(),
                self.sysid[rows].tolist(), self.compid[rows].tolist(),
            )  # fmt: skip
            if frames is not None:
                self.seq[rows] = (seq + 1) & 0xFF
                return frames
        buf, lens = self.encode_lpn(rows, time_boot_ms, pos, vel)
        return [buf[i, :e].tobytes() for i, e in enumerate(lens.tolist())]

    def set_heartbeat(self, row: int, msg: Any) -> None:
        """The row's HEARTBEAT fields from ``msg`` (its autopilot's ``heartbeat()``)."""
        self.hb_fields[row] = [getattr(msg, k) for k in HEARTBEAT_FIELDS]

    def heartbeat_frames(self, rows: list[int]) -> list[bytes]:
        """The HEARTBEAT frame of each of ``rows`` (distinct) from its
        ``hb_fields``; bumps their seq. A few rows one ``struct.pack`` each,
        more column-wise: the same bytes (``codec.encode_heartbeats``)."""
        if few(len(rows)):
            seq = [int(self.seq[r]) for r in rows]
            frames = heartbeat_frames_small(
                seq, [int(self.sysid[r]) for r in rows], [int(self.compid[r]) for r in rows],
                [self.hb_fields[r].tolist() for r in rows],
            )  # fmt: skip
            for r, q in zip(rows, seq, strict=True):
                self.seq[r] = (q + 1) & 0xFF
            return frames
        at = np.array(rows, dtype=np.intp)
        seq_col = self.seq[at]
        frames = encode_heartbeats(seq_col, self.sysid[at], self.compid[at], self.hb_fields[at])
        self.seq[at] = (seq_col + 1) & 0xFF
        return frames
