"""Safety filter between the formation law and the setpoint (issue 10).

Pure numpy, no I/O, no logging. Every control cycle, per vehicle, it returns the
acceleration closest (least squares) to the law's ``a_des`` [m/s^2, mission
frame x east / y north / z up] that keeps

  (a) signed distance to every box >= ``Safety.clearance``,
  (b) distance to every other vehicle >= ``Safety.separation``,
  (e) distance to every keep-out box >= ``Safety.separation`` (where a
      vehicle that left the formation unheard may be: ``set_keep_out``),
  (c) z >= ``Limits.z_floor`` and the position inside the geofence,
  (d) |a| <= ``Limits.a_max`` and |v| <= ``Limits.v_max``.

(a), (b) and (e) are the filter proper (``Safety.enabled``); (c) and (d) are
``Limits`` and apply always, also in the paper mode, so an infinite-limits,
disabled filter is the identity, bit for bit.

Barrier. For a distance d(p) with unit gradient n, margin d_min, closing speed
s = -n.v and a braking budget a_b, the braking-distance barrier is

    H(d, s) = d - d_min - max(s, 0)^2 / (2 a_b)                       (B1)

i.e. "the vehicle can still stop before the margin while braking at a_b". The
filter demands, for the exact zero-order-hold step of a double integrator
(d+ = d - s dt + u dt^2/2, s+ = s - u dt, u = n.a),

    H(d+, s+) >= (1 - gamma dt) H(d, s)                                (B2)

H(d+, s+) is concave and increasing in u, so (B2) is exactly one half-space
``n.a >= u_min`` (``limits.braking_bound``). At the boundary (H = 0, s > 0) it asks
for u = a_b, never more, so with a_b = brake_fraction * a_max the constraint
set stays inside the |a| <= a_max ball, unlike an ordinary second-order CBF
whose demand grows with speed. For a plane (floor, fence) (B2) is exact; for a
box or a pair the distance is convex, so the supporting plane used here
under-estimates the next distance (conservative); only the turning of n within
one step (O(dt^2)) is not modelled.

Pairs share the work: the relative barrier uses 2 a_b and each vehicle takes
half of u_min (n_ij.a_i >= u_min/2, n_ji.a_j >= u_min/2). Coincident vehicles
use the fixed direction +x (the lower index is pushed to -x).

Vehicle envelope (``Limits.envelope``, docs/vehicle-envelope.md). When it is
bounded the filter plans within what the vehicle can deliver:

- the acceleration set is the envelope's: the ball |a| <= min(a_max,
  accel_xy) and the two vertical half-spaces |a_z| <= accel_z; with a finite
  jerk, the horizontal disk becomes an inscribed 16-gon of half-spaces, the
  ball is the jerk step |a - a'| <= min(jerk_xy, jerk_z) dt around the last
  command a' (the projection stays exact: it is solved for a - a'), and
  |a| <= a_max is clamped after;
- each barrier's braking budget is a_b = brake_fraction x the envelope's
  extent along its normal (0.5 m/s^2 against a floor for ArduCopter's 1 m/s^2
  vertical), and (B1)-(B2) become (B1')-(B2') of
  ``gcs_swarm.control.reaction``: the stopping distance of a vehicle whose
  acceleration is its command of lag_s ago and whose command ramps at the
  jerk, so clearance and separation hold on that vehicle, not only on a
  point mass. The unbounded envelope keeps (B1)-(B2), bit for bit.
  Several barriers braking at once may need more than one jerk step
  together: then the best effort's last resort is a full jerk step down the
  environment rows' total violation (cheap; conflicts are common there).

The rows (barriers, speed, the envelope's caps) are built by
``gcs_swarm.control.safety_rows.SafetyRows``; this module projects onto them.
The per-vehicle projection is ``gcs_swarm.control.limits.project`` (exact).
When the rows conflict the filter returns a best effort and flags the vehicle
infeasible: it drops the speed row, then the separation rows, then relaxes the
environment rows uniformly by the least amount that is feasible, and always
keeps |a| <= a_max. ``strict=True`` raises ``InfeasibleError`` instead.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from gcs_swarm.control.limits import (
    FEAS_TOL,
    BoolArray,
    FloatArray,
    box_signed_distance,
    clamp_norm,
    project,
)
from gcs_swarm.control.params import Box, Limits, Safety
from gcs_swarm.control.safety_rows import CAP, ENV, PAIR, SafetyRows, SafetyTuning
from gcs_swarm.control.safety_stats import SafetyReport, SafetyStats, SafetyTotals
from gcs_swarm.errors import InfeasibleError

__all__ = [
    "SafetyFilter",
    "SafetyHook",
    "SafetyReport",
    "SafetyStats",
    "SafetyTotals",
    "SafetyTuning",
    "box_signed_distance",
    "filter_acts",
]


def filter_acts(limits: Limits, safety: Safety) -> bool:
    """Whether the filter can change anything: enabled, or any finite limit.
    Otherwise it is the identity (module docstring) and callers skip it."""
    return safety.enabled or not (
        math.isinf(limits.a_max) and math.isinf(limits.v_max) and math.isinf(limits.z_floor)
        and limits.geofence_min is None and limits.geofence_max is None
    )  # fmt: skip


_RELAX_STEPS = 40  # bisection steps of the best-effort relaxation (2^-40 of the range)


class SafetyFilter:
    """Per-vehicle projection of the law's acceleration onto the safe set.

    limits, safety: the mission's ``Limits`` and ``Safety``; boxes: the
    obstacles; dt [s]: the control period (one zero-order-hold step).
    ``strict=True`` raises ``InfeasibleError`` when any vehicle's constraints
    conflict (after computing the best effort).
    """

    def __init__(
        self,
        limits: Limits,
        safety: Safety,
        boxes: Sequence[Box],
        *,
        dt: float,
        tuning: SafetyTuning | None = None,
        strict: bool = False,
    ) -> None:
        if not 0.0 < dt < math.inf:
            raise ValueError(f"dt must be a positive period in seconds, got {dt}")
        if not limits.a_max > 0.0 or not limits.v_max > 0.0:
            raise ValueError(f"a_max and v_max must be > 0, got {limits.a_max}, {limits.v_max}")
        if not (safety.clearance >= 0.0 and safety.separation >= 0.0):
            raise ValueError("clearance and separation must be >= 0")
        self.limits = limits
        self.safety = safety
        self.dt = dt
        self.tuning = tuning if tuning is not None else SafetyTuning()
        self.strict = strict
        self._constraints = SafetyRows(limits, safety, boxes, dt=dt, tuning=self.tuning)
        self.envelope = limits.envelope

    @property
    def keep_out(self) -> tuple[Box, ...]:
        """The keep-out boxes in force (e)."""
        return self._constraints.keep_out

    def set_keep_out(self, boxes: Sequence[Box]) -> None:
        """Keep every vehicle ``Safety.separation`` from each of ``boxes``
        [m, mission frame] from the next ``filter`` on (e); empty: none.
        Nothing with the filter off (``Safety.enabled`` False)."""
        self._constraints.set_keep_out(boxes)

    def filter(
        self,
        pos_m: FloatArray,
        vel_mps: FloatArray,
        accel_des_mps2: FloatArray,
        *,
        ids: Sequence[object] | None = None,
        prev_accel_mps2: FloatArray | None = None,
    ) -> tuple[FloatArray, SafetyReport]:
        """Filter one cycle. pos_m, vel_mps, accel_des_mps2: (N, 3), mission frame.

        Returns the safe accelerations (N, 3) [m/s^2] and a ``SafetyReport``.
        Never returns NaN: a non-finite ``a_des`` row is treated as zero; a
        vehicle with a non-finite position or velocity gets a = 0 and is
        flagged infeasible. ``ids`` only names vehicles in ``InfeasibleError``.
        ``prev_accel_mps2 (N, 3)``: the last command sent to each vehicle
        (zero if None), used only when the envelope is bounded.
        """
        c = self._constraints
        pos = np.asarray(pos_m, dtype=np.float64).reshape(-1, 3)
        vel = np.asarray(vel_mps, dtype=np.float64).reshape(-1, 3)
        a_des = np.asarray(accel_des_mps2, dtype=np.float64).reshape(-1, 3)
        if not pos.shape == vel.shape == a_des.shape:
            raise ValueError(f"shape mismatch: {pos.shape}, {vel.shape}, {a_des.shape}")
        prev = np.zeros_like(pos)
        if c.plan and prev_accel_mps2 is not None:
            prev = np.asarray(prev_accel_mps2, dtype=np.float64).reshape(pos.shape)
            prev = np.where(np.isfinite(prev), prev, 0.0)
        state_ok: BoolArray = np.asarray(
            np.isfinite(pos).all(axis=1) & np.isfinite(vel).all(axis=1)
        )
        des_ok: BoolArray = np.asarray(np.isfinite(a_des).all(axis=1))
        a0 = np.where(des_ok[:, None], a_des, 0.0)
        pos = np.where(state_ok[:, None], pos, 0.0)
        vel = np.where(state_ok[:, None], vel, 0.0)
        geo = c.geometry(pos, state_ok)
        normals, bounds, classes = c.rows(pos, vel, a0, geo, state_ok, prev)
        if c.cap_b.size:
            nv = pos.shape[0]
            caps_n = np.broadcast_to(c.cap_n, (nv, *c.cap_n.shape))
            normals = np.concatenate([normals, caps_n], axis=1)
            bounds = np.concatenate([bounds, np.broadcast_to(c.cap_b, (nv, c.cap_b.size))], axis=1)
            classes = np.concatenate([classes, np.full(c.cap_b.size, CAP)])
        rows = np.ones(bounds.shape, dtype=bool)
        ball = c.ball
        if c.plan and math.isfinite(c.jerk):
            # The ball is the jerk step around the last command: solve for a - a'.
            shift = bounds - np.einsum("nkj,nj->nk", normals, prev)
            delta, feasible = project(a0 - prev, normals, shift, rows, ball)
            if not feasible.all():
                delta = self._best_effort(delta, feasible, a0 - prev, normals, shift, classes)
            accel = prev + delta
        else:
            accel, feasible = project(a0, normals, bounds, rows, ball)
            if not feasible.all():
                accel = self._best_effort(accel, feasible, a0, normals, bounds, classes)
        a_max = self.limits.a_max
        if c.plan and math.isfinite(a_max) and ball != a_max:
            accel = clamp_norm(accel, a_max)
        accel[~state_ok] = 0.0
        infeasible = ~feasible | ~state_ok

        scale = np.maximum(1.0, np.linalg.norm(a0, axis=-1))
        if math.isfinite(ball):
            scale = np.maximum(scale, ball)
        resid = bounds - np.einsum("nkj,nj->nk", normals, accel)
        active = np.count_nonzero(np.abs(resid) <= FEAS_TOL * scale[:, None], axis=1)
        if math.isfinite(ball):
            active += np.abs(np.linalg.norm(accel - prev, axis=-1) - ball) <= FEAS_TOL * scale
        violation = np.where(infeasible, np.maximum(resid.max(axis=1, initial=0.0), 0.0), 0.0)
        report = SafetyReport(
            correction_mps2=np.linalg.norm(accel - a0, axis=-1),
            active=active.astype(np.int64),
            infeasible=infeasible,
            violation_mps2=violation,
            # A vehicle whose position is unknown has no clearance figure.
            min_clearance_m=np.where(
                state_ok, geo.clearance.min(axis=1, initial=math.inf), math.inf
            ),
            min_separation_m=geo.separation,
            min_keep_out_m=np.where(state_ok, geo.keep_d.min(axis=1, initial=math.inf), math.inf),
        )
        if self.strict and infeasible.any():
            bad = np.flatnonzero(infeasible)
            names = [ids[int(i)] if ids is not None else int(i) for i in bad]
            raise InfeasibleError(
                f"safety filter: constraints conflict for vehicle(s) {names} "
                f"(worst residual {float(violation.max()):.3g} m/s^2)"
            )
        return accel, report

    def _best_effort(
        self,
        accel: FloatArray,
        feasible: BoolArray,
        a0: FloatArray,
        normals: FloatArray,
        bounds: FloatArray,
        classes: NDArray[np.int64],
    ) -> FloatArray:
        """Best command for infeasible vehicles: drop speed, then pairs, then
        relax the environment rows by the least uniform amount t >= 0 (the
        acceleration caps are never dropped nor relaxed); within a finite
        jerk, a full jerk step down the environment rows' violation instead."""
        c = self._constraints
        a_max = c.ball
        out = accel.copy()
        bad = np.flatnonzero(~feasible)
        for keep in (PAIR, ENV):
            rows = np.broadcast_to(classes <= keep, bounds[bad].shape)
            x, ok = project(a0[bad], normals[bad], bounds[bad], rows, a_max)
            out[bad[ok]] = x[ok]
            bad = bad[~ok]
            if bad.size == 0:
                return out
        if c.plan and math.isfinite(c.jerk):
            # Within a jerk step (a - a' here): the whole step down the environment
            # rows' total violation, one cheap answer (a bisection of projections
            # would cost tens of ms in the conflicts that are common there).
            env = np.broadcast_to(classes == ENV, bounds[bad].shape)
            viol = np.where(env, np.maximum(bounds[bad], 0.0), 0.0)
            g = np.einsum("nk,nkj->nj", viol, normals[bad])
            size = np.linalg.norm(g, axis=1, keepdims=True)
            out[bad] = np.where(size > 0.0, a_max * g / np.where(size > 0.0, size, 1.0), 0.0)
            return out
        rows = np.broadcast_to(classes <= ENV, bounds[bad].shape)
        env_b = np.where(rows, bounds[bad], -math.inf)
        relax = np.broadcast_to(classes == ENV, env_b.shape)
        lo = np.zeros(bad.size)
        hi = np.maximum(np.where(relax, env_b, -math.inf).max(axis=1), 0.0)
        hi = hi * (1.0 + 1e-12) + 1e-12  # a = 0 meets b - hi
        for _ in range(_RELAX_STEPS):
            mid = 0.5 * (lo + hi)
            _, ok = project(a0[bad], normals[bad], env_b - relax * mid[:, None], rows, a_max)
            hi = np.where(ok, mid, hi)
            lo = np.where(ok, lo, mid)
        x, _ = project(a0[bad], normals[bad], env_b - relax * hi[:, None], rows, a_max)
        out[bad] = x
        return out


@dataclass
class SafetyHook:
    """Adaptor for the simulator's acceleration hook: ``hook(t, ids, p, v, a) -> a``.

    Filters every call. A simulator may call it several times per step (RK4
    stages), so ``stats`` and ``last_report`` take one report per control
    period ``dt``: the first call at or after each period boundary (a time
    going back by more than dt starts a new run).
    """

    safety_filter: SafetyFilter
    stats: SafetyStats = field(default_factory=SafetyStats)
    last_report: SafetyReport | None = None
    _next_t: float = -math.inf
    _last_t: float = -math.inf

    def __call__(
        self,
        t: float,
        ids: Sequence[object],
        pos_m: FloatArray,
        vel_mps: FloatArray,
        accel_mps2: FloatArray,
    ) -> FloatArray:
        """Return the filtered accelerations (N, 3); ``t`` [s] only paces ``stats``."""
        accel, report = self.safety_filter.filter(pos_m, vel_mps, accel_mps2, ids=ids)
        dt = self.safety_filter.dt
        if t >= self._next_t - 1e-6 * dt or t < self._last_t - dt:
            self.last_report = report
            self.stats.update(report)
            self._next_t = t + dt
        self._last_t = t
        return accel
