"""Plane selection by look-ahead (rule after Eq. 25), batched over vehicles and planes.

When an avoidance episode meets an obstacle, each vehicle's path to its slot
target is predicted twice, once with the horizontal and once with the
vertical rotational field, with a single-vehicle model: Eq. 1 driven by
Eqs. 26-28 for THIS obstacle only, no other vehicle, sense latched at field
entry by the same rule as the live law. The shorter path wins; READING (the
paper prints the same branch twice): ``L_yz >= L_xy`` gives horizontal.

All ``2 N`` predictions run as one fixed-step RK4 integration of a
``(2N, 3)`` state (discrete sense latching once per step, held within it).
A prediction ends when the vehicle is within :data:`ARRIVE_M` of its target;
one that never arrives within the horizon has length ``inf``. Cost is
measured in ``benchmarks/README.md``.

:class:`LookaheadJob` is a pure, picklable-in-spirit callable holding copies
of its inputs, so a caller may run it in a worker thread and hand the
:class:`LookaheadResult` back to the law later.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gcs_swarm.control.fields import (
    avoidance_force,
    desired_force,
    heading,
    horizontal_tangent_cw,
    sense_rule,
    vertical_tangent_up,
)
from gcs_swarm.control.obstacles import Ellipsoids, rho, rho_gradient
from gcs_swarm.control.params import Avoidance, Gains, Readings

__all__ = [
    "ARRIVE_M",
    "LOOKAHEAD_DT_S",
    "LookaheadJob",
    "LookaheadResult",
    "entry_senses",
    "forced_senses",
    "predict_plane_lengths",
]

F64 = NDArray[np.float64]

#: A predicted path ends when the vehicle is this close to its target [m].
ARRIVE_M = 0.5
#: Fixed RK4 step of the look-ahead [s] (the model's time constant is M/(D+k) = 0.1 s).
LOOKAHEAD_DT_S = 0.05
#: Longest predicted time [s].
MAX_HORIZON_S = 300.0


def forced_senses(avoidance: Avoidance) -> tuple[float | None, float | None]:
    """``(horizontal, vertical)`` sense forced by ``Avoidance.sense``, or None for
    the automatic rule: cw/ccw force the horizontal, up/down the vertical sense."""
    forced = {"cw": (1.0, None), "ccw": (-1.0, None), "up": (None, 1.0), "down": (None, -1.0)}
    return forced.get(avoidance.sense, (None, None))


def entry_senses(
    pos_m: F64, vel_mps: F64, f_des_n: F64, obs: Ellipsoids, avoidance: Avoidance
) -> tuple[F64, F64]:
    """The senses ``(sense_h, sense_v)``, each ``(N, K)``, that the rule (or
    the forced setting) gives in the current state: what is latched at entry."""
    d, _, _ = rho_gradient(pos_m, obs)
    coeffs = obs.coeffs_per_m[None, :, :]
    fh, fv = forced_senses(avoidance)
    n, k = pos_m.shape[0], obs.count
    if fh is None:
        sh = sense_rule(horizontal_tangent_cw(d, coeffs), vel_mps, f_des_n)
    else:
        sh = np.full((n, k), fh)
    if fv is None:
        phi = heading(vel_mps, f_des_n, from_velocity=avoidance.heading == "velocity")
        tv = vertical_tangent_up(d, coeffs, phi)
        sv = sense_rule(tv, vel_mps, f_des_n)
    else:
        sv = np.full((n, k), fv)
    return sh, sv


@dataclass(frozen=True)
class LookaheadResult:
    """Outcome of one look-ahead: per vehicle (in the job's ``ids`` order) the
    predicted path lengths [m] and whether the vertical plane was chosen."""

    ids: tuple[int, ...]
    length_h_m: F64
    length_v_m: F64
    vertical: NDArray[np.bool_]


def predict_plane_lengths(
    pos_m: F64,
    vel_mps: F64,
    targets_m: F64,
    obs: Ellipsoids,
    gains: Gains,
    avoidance: Avoidance,
    readings: Readings,
    *,
    dt_s: float = LOOKAHEAD_DT_S,
    horizon_s: float | None = None,
) -> tuple[F64, F64]:
    """Predicted path lengths ``(L_xy, L_yz)`` [m], each ``(N,)``, of every
    vehicle to its target with the horizontal and the vertical field around the
    single obstacle ``obs`` (K = 1). ``inf`` where the target is not reached.

    READING (time scale, ``Gains.time_scale`` = lambda): the paths are the
    same lambda times slower, so the step and the horizon cap are lambda times
    longer (the same RK4 iterates, the same cost); lambda = 1 is unchanged."""
    lam = gains.time_scale
    dt_s = dt_s * lam
    n = pos_m.shape[0]
    if n == 0:
        return np.zeros(0), np.zeros(0)
    p = np.concatenate([pos_m, pos_m])
    v = np.concatenate([vel_mps, vel_mps])
    tgt = np.concatenate([targets_m, targets_m])
    vertical = np.zeros((2 * n, 1), dtype=bool)
    vertical[n:] = True
    v_term = avoidance.F_D / gains.damping_scaled  # READING (time scale): Eq. 1 as flown
    if horizon_s is None:
        dist = float(np.max(np.linalg.norm(targets_m - pos_m, axis=1)))
        horizon_s = 20.0 + 4.0 * dist / max(v_term, 1e-6)
    steps = max(1, math.ceil(min(horizon_s, MAX_HORIZON_S * lam) / dt_s))
    length = np.zeros(2 * n)
    arrived = np.linalg.norm(p - tgt, axis=1) <= ARRIVE_M
    latched = np.zeros((2 * n, 1), dtype=bool)
    sh = np.ones((2 * n, 1))
    sv = np.ones((2 * n, 1))
    r0 = avoidance.r0
    inv_m = 1.0 / gains.mass_scaled
    c = gains.damping_scaled

    def accel(pp: F64, vv: F64) -> F64:
        f_des = desired_force(pp, tgt, avoidance.F_D)
        f = avoidance_force(
            pp,
            vv,
            f_des,
            obs,
            method="rotational",
            r0=r0,
            vertical=vertical,
            sense_h=sh,
            sense_v=sv,
            printed_eq27=readings.eq27_printed,
            heading_from_velocity=avoidance.heading == "velocity",
        )
        return (f - c * vv) * inv_m

    for _ in range(steps):
        if arrived.all():
            break
        # Discrete logic once per step: latch senses at field entry, release on exit.
        inside = rho(p, obs) <= r0
        entering = np.flatnonzero((inside & ~latched)[:, 0])
        if entering.size:
            pe = p[entering]
            f_e = desired_force(pe, tgt[entering], avoidance.F_D)
            sh[entering], sv[entering] = entry_senses(pe, v[entering], f_e, obs, avoidance)
        latched = inside
        # RK4 of Eq. 1 for every row; arrived rows are frozen.
        a1 = accel(p, v)
        a2 = accel(p + 0.5 * dt_s * v, v + 0.5 * dt_s * a1)
        v2 = v + 0.5 * dt_s * a1
        v3 = v + 0.5 * dt_s * a2
        a3 = accel(p + 0.5 * dt_s * v2, v3)
        v4 = v + dt_s * a3
        a4 = accel(p + dt_s * v3, v4)
        p_new = p + (dt_s / 6.0) * (v + 2.0 * v2 + 2.0 * v3 + v4)
        v_new = v + (dt_s / 6.0) * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        keep = arrived[:, None]
        step_len = np.linalg.norm(p_new - p, axis=1)
        length += np.where(arrived, 0.0, step_len)
        p = np.where(keep, p, p_new)
        v = np.where(keep, v, v_new)
        arrived |= np.linalg.norm(p - tgt, axis=1) <= ARRIVE_M
    length = np.where(arrived, length, np.inf)
    return length[:n], length[n:]


@dataclass(frozen=True, eq=False)
class LookaheadJob:
    """A pure look-ahead for one episode and one obstacle; call it (in any
    thread) to get a :class:`LookaheadResult`, then hand that to
    ``SwarmController.resolve_lookahead``. Holds its own copies of the inputs."""

    episode: int
    obstacle: int
    ids: tuple[int, ...]
    pos_m: F64
    vel_mps: F64
    targets_m: F64
    obstacle_set: Ellipsoids
    gains: Gains
    avoidance: Avoidance
    readings: Readings

    def __call__(self) -> LookaheadResult:
        lh, lv = predict_plane_lengths(
            self.pos_m,
            self.vel_mps,
            self.targets_m,
            self.obstacle_set,
            self.gains,
            self.avoidance,
            self.readings,
        )
        # READING (rule after Eq. 25): L_yz >= L_xy -> horizontal.
        return LookaheadResult(self.ids, lh, lv, lv < lh)
