"""Telemetry scheduling on the fleet rows: who is polled, who reports, the frames. NO I/O.

After each physics step the emulator sends the 1 Hz HEARTBEAT of every row
whose ``hb_next`` is due (``due_heartbeats``; the frames from the rows'
fields, ``Fleet.heartbeat_frames``), polls the autopilots whose ``deadline``
is due (and those the step landed or lifted: the land detector looks) and,
in the same row order, sends the status-path streams of rows not polled
whose ``st_next`` is due (``due_status``, ``status_frames``: reports), then
sends LOCAL_POSITION_NED for every row whose ``lpn_next`` is due, all at
once (``codec``). Owns those pieces (``due_heartbeats``, ``due_polls``,
``due_reports``, ``report_frames``) and ``kins``, the rows'
kinematics as the autopilots read them. Each has a plain-Python side for few
vehicles (``small``), the same numbers. Driven by ``now`` (sim seconds).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import reports
from sim_vehicle.fleet import Fleet
from sim_vehicle.impairments import EPS_S
from sim_vehicle.small import few
from sim_vehicle.telemetry import Kin, Vec3

if TYPE_CHECKING:
    from sim_vehicle.autopilot import Autopilot

__all__ = [
    "bias_factor", "due_heartbeats", "due_polls", "due_reports", "due_status", "enter_accel",
    "kin", "kins", "report_frames", "status_frames",
]  # fmt: skip


def bias_factor(
    boot_s: NDArray[np.float64], flip_s: NDArray[np.float64], tau_s: NDArray[np.float64]
) -> NDArray[np.float64]:
    """How much of each row's velocity bias is reported at its boot time ``boot_s`` [s]
    (docs/emulator.md, "The reported velocity", Eq. T1): 1 until ``flip_s`` (or
    always, where ``flip_s`` is 0), then ``2 exp(-(t - flip) / tau) - 1``, from
    +1 towards -1: ArduCopter 4.5.6 SITL's EKF velocity bias reverses so, at
    304 s of boot time on every instance, with ``tau`` about 14 s."""
    after = (flip_s > 0.0) & (boot_s > flip_s)
    out = np.ones_like(boot_s)
    if after.any():
        dt = boot_s[after] - flip_s[after]
        out[after] = 2.0 * np.exp(-dt / np.maximum(tau_s[after], 1e-9)) - 1.0
    return out


def enter_accel(fleet: Fleet, row: int, now: float, reference: bool, start: Vec3 | None) -> None:
    """Eq. D9 (docs/emulator.md): the row enters GUIDED's Accel sub-mode at ``now``.
    With a ``start`` velocity (a moving spawn's, its first entry) its velocity
    becomes that; else, where the sub-mode has a velocity ``reference``
    (ArduCopter's, started at the EKF's biased velocity and flown), its velocity
    takes its reported velocity's bias at ``now`` (Eq. T1)."""
    f, r = fleet, slice(row, row + 1)
    if start is not None:
        f.vel[row] = start
        return
    if not reference or not f.vbias[row].any():  # no bias (ideal): the row's bits untouched
        return
    g = bias_factor(np.array([now - f.boot[row]]), f.vbias_flip[r], f.vbias_tau[r])
    f.vel[row] += f.vbias[row] * g[0]


def kins(fleet: Fleet) -> list[Kin]:
    """Every row's ``Kin`` (local NED, SI units), in row order."""
    f = fleet
    return [
        Kin((p[0], p[1], p[2]), (q[0], q[1], q[2]), (a[0], a[1], a[2]), ld)
        for p, q, a, ld in zip(
            f.pos.tolist(), f.vel.tolist(), f.acc.tolist(), f.landed.tolist(), strict=True
        )
    ]


def kin(fleet: Fleet, row: int) -> Kin:
    """One row's ``Kin``."""
    f, r = fleet, row
    px, py, pz = f.pos[r].tolist()
    vx, vy, vz = f.vel[r].tolist()
    ax, ay, az = f.acc[r].tolist()
    return Kin((px, py, pz), (vx, vy, vz), (ax, ay, az), bool(f.landed[r]))


def due_polls(fleet: Fleet, now: float) -> list[int]:
    """Rows whose autopilot must be polled at ``now``: deadline due, or the last step
    changed its ``landed`` flag (consumes ``fleet.changed``). Ascending."""
    f = fleet
    if few(f.n):
        lim = now + EPS_S
        polled = [r for r, d in enumerate(f.deadline.tolist()) if d <= lim]
    else:
        polled = np.flatnonzero(f.deadline <= now + EPS_S).tolist()
    if f.changed:  # touched down or lifted off: the land detector looks (autopilot)
        polled = sorted(set(polled).union(f.changed))
        f.changed = []
    return polled


def due_heartbeats(fleet: Fleet, now: float) -> list[int]:
    """Rows whose 1 Hz HEARTBEAT is due at ``now`` (``hb_next`` within 1 us), in
    order; their ``hb_next`` moves a second on, or to half a second from ``now``
    when that is due already (a clock that was held sends one, not a burst)."""
    f = fleet
    if few(f.n):
        nxt = f.hb_next.tolist()
        rows = [r for r, t in enumerate(nxt) if now >= t - 1e-6]
        for r in rows:
            f.hb_next[r] = max(nxt[r] + 1.0, now + 0.5)
        return rows
    due = np.flatnonzero(now >= f.hb_next - 1e-6)
    if due.size:
        f.hb_next[due] = np.maximum(f.hb_next[due] + 1.0, now + 0.5)
    out: list[int] = due.tolist()
    return out


def due_status(fleet: Fleet, now: float) -> list[int]:
    """Rows whose status-path streams are due at ``now`` (``st_next``, as a
    deadline is due: ``due_polls``), ascending."""
    f = fleet
    if few(f.n):
        lim = now + EPS_S
        return [r for r, d in enumerate(f.st_next.tolist()) if d <= lim]
    out: list[int] = np.flatnonzero(f.st_next <= now + EPS_S).tolist()
    return out


def status_frames(
    fleet: Fleet, ap: Autopilot, row: int, msgids: list[int], now: float
) -> list[bytes]:
    """The unsigned frames of ``msgids`` (``reports.take_fleet_streams``) of
    ``ap`` on ``row`` at ``now``; bumps the row's seq for each."""
    f = fleet
    pos, vel = f.pos[row].tolist(), f.vel[row].tolist()
    seq, sysid, compid = int(f.seq[row]), int(f.sysid[row]), int(f.compid[row])
    out = []
    for msgid in msgids:
        out.append(reports.status_frame(ap, msgid, now, pos, vel, (seq, sysid, compid)))
        seq = (seq + 1) & 0xFF
    f.seq[row] = seq
    return out


def due_reports(fleet: Fleet, now: float) -> NDArray[np.intp]:
    """Rows whose LOCAL_POSITION_NED is due at ``now``; their ``lpn_next`` moves one
    interval on (or to ``now`` + interval when that is due already: no burst)."""
    f = fleet
    if few(f.n):  # the same schedule arithmetic on lists
        lim, lnext = now + EPS_S, f.lpn_next.tolist()
        rows = [r for r, t in enumerate(lnext) if t <= lim]
        if rows:
            iv = f.lpn_interval.tolist()
            for r in rows:
                nxt = lnext[r] + iv[r]
                lnext[r] = now + iv[r] if nxt <= lim else nxt
            f.lpn_next[:] = lnext
        return np.array(rows, dtype=np.intp)
    due = np.flatnonzero(f.lpn_next <= now + EPS_S)
    if due.size:
        nxt = f.lpn_next[due] + f.lpn_interval[due]
        f.lpn_next[due] = np.where(nxt <= now + EPS_S, now + f.lpn_interval[due], nxt)
    return due


def report_frames(
    fleet: Fleet,
    rows: NDArray[np.intp],
    now: float,
    noise_rngs: Sequence[np.random.Generator],
    pack: Callable[[int, Any], bytes] | None = None,
) -> list[bytes]:
    """The LOCAL_POSITION_NED frame of each of ``rows`` at ``now`` (bumps their seq).

    Reported: position plus ``noise_pos`` x N(0, 1), velocity plus the row's bias
    (times ``bias_factor`` at the row's boot time, Eq. T1) plus ``noise_vel`` x
    N(0, 1) (each row's ``noise_rngs[row]``, six draws when noisy);
    ``time_boot_ms`` rounded half to even. ``pack(row, message)``: sign and
    pack one message (signed links); None: the unsigned encoders of ``codec``."""
    f = fleet
    if few(len(rows)) and pack is None:
        rl: list[int] = rows.tolist()
        cols = (f.noise_pos, f.noise_vel, f.vbias, f.boot)
        if few(f.n):  # a small fleet: whole columns as lists, no numpy call per row
            npos, nvel, vb, boot = (c.tolist() for c in cols)
            at: Sequence[int] = rl
        else:  # a large one: the rows' values only (a whole column is O(N) a call)
            npos, nvel, vb, boot = (c[rows].tolist() for c in cols)
            at = range(len(rl))
        if not any(npos[k] > 0 or nvel[k] > 0 or any(vb[k]) for k in at):
            # round() is np.rint's half-to-even
            frames = f.lpn_frames_rows(rl, [round((now - boot[k]) * 1000.0) for k in at])
            if frames is not None:
                return frames
    t_ms = np.rint((now - f.boot[rows]) * 1000.0).astype(np.int64)
    vb = f.vbias[rows]
    flip = f.vbias_flip[rows]
    if flip.any():
        vb = vb * bias_factor(now - f.boot[rows], flip, f.vbias_tau[rows])[:, None]
    pos, vel = f.pos[rows], f.vel[rows] + vb  # a copy: the reported velocity
    noisy = (f.noise_pos[rows] > 0) | (f.noise_vel[rows] > 0)
    if noisy.any():
        pos = pos.copy()
        for i in np.flatnonzero(noisy):
            z = noise_rngs[rows[i]].standard_normal(6)
            pos[i] += f.noise_pos[rows[i]] * z[:3]
            vel[i] += f.noise_vel[rows[i]] * z[3:]
    if pack is not None:  # signed: pymavlink packs (and signs) each
        lpn = mav.MAVLink_local_position_ned_message
        return [
            pack(r, lpn(int(t_ms[i]), *map(float, pos[i]), *map(float, vel[i])))
            for i, r in enumerate(rows.tolist())
        ]
    return f.lpn_frames(rows, t_ms, pos, vel)
