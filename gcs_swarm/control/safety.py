"""Safety filter between the formation law and the setpoint (issue 10).

Pure numpy, no I/O, no logging. Every control cycle, per vehicle, it returns the
acceleration closest (least squares) to the law's ``a_des`` [m/s^2, mission
frame x east / y north / z up] that keeps

  (a) signed distance to every box >= ``Safety.clearance``,
  (b) distance to every other vehicle >= ``Safety.separation``,
  (c) z >= ``Limits.z_floor`` and the position inside the geofence,
  (d) |a| <= ``Limits.a_max`` and |v| <= ``Limits.v_max``.

(a) and (b) are the filter proper (``Safety.enabled``); (c) and (d) are
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
    braking_bound,
    clamp_norm,
    project,
    speed_rows,
)
from gcs_swarm.control.params import Box, Envelope, Limits, Safety
from gcs_swarm.control.reaction import POLYGON_SIDES, cap_rows, radial_extent, reaction_bound
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


_CAP, _ENV, _PAIR, _SPEED = -1, 0, 1, 2  # row classes, in the order the best effort keeps them
_BIG_MPS2 = 1e6  # stands in for an unbounded closing acceleration in (B0')


def _planning(envelope: Envelope) -> bool:
    """Whether the filter must plan within ``envelope`` (a finite acceleration
    or jerk bound, or a lag); speeds alone are checked, not filtered."""
    e = envelope
    finite = any(math.isfinite(x) for x in (e.accel_xy, e.accel_z, e.jerk_xy, e.jerk_z))
    return finite or e.lag_s > 0.0


_RELAX_STEPS = 40  # bisection steps of the best-effort relaxation (2^-40 of the range)


@dataclass(frozen=True)
class SafetyTuning:
    """Filter settings not in the mission contract (``params.Safety``/``Limits``).

    brake_fraction: a_b = brake_fraction * a_max, the deceleration each barrier
    may count on (0.5 leaves room for three orthogonal walls at once:
    sqrt(3) * 0.5 < 1). brake_unbounded_mps2: a_b when a_max is infinite.
    gamma_per_s [1/s]: how fast a barrier may be approached (B2); larger is
    later and harder; gamma*dt is capped at 1 (one-step invariance).
    """

    brake_fraction: float = 0.5
    brake_unbounded_mps2: float = 5.0
    gamma_per_s: float = 2.0

    def __post_init__(self) -> None:
        if not 0.0 < self.brake_fraction <= 1.0:
            raise ValueError(f"brake_fraction must be in (0, 1], got {self.brake_fraction}")
        if not 0.0 < self.brake_unbounded_mps2 < math.inf:
            raise ValueError(f"brake_unbounded_mps2 must be > 0, got {self.brake_unbounded_mps2}")
        if not 0.0 < self.gamma_per_s < math.inf:
            raise ValueError(f"gamma_per_s must be > 0, got {self.gamma_per_s}")


@dataclass(frozen=True, eq=False)
class _Geometry:
    """Per-cycle distances: box clearance (N, K) [m] and normals (N, K, 3),
    nearest-vehicle distance (N,) [m], pair distances (N, N) [m] (inf on the
    diagonal and for unusable vehicles) and unit directions j -> i (N, N, 3)."""

    clearance: FloatArray
    box_n: FloatArray
    separation: FloatArray
    pair_d: FloatArray
    pair_n: FloatArray


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
        self._centres = np.array([b.centre for b in boxes], dtype=np.float64).reshape(-1, 3)
        self._halves = np.array([b.half_extents for b in boxes], dtype=np.float64).reshape(-1, 3)
        a_max = limits.a_max
        self._a_b = (
            self.tuning.brake_fraction * a_max
            if math.isfinite(a_max)
            else self.tuning.brake_unbounded_mps2
        )
        # (c) as planes sign * p[axis] >= offset [m].
        planes: list[tuple[int, float, float]] = []
        if math.isfinite(limits.z_floor):
            planes.append((2, 1.0, limits.z_floor))
        if limits.geofence_min is not None:
            planes.extend((k, 1.0, float(limits.geofence_min[k])) for k in range(3))
        if limits.geofence_max is not None:
            planes.extend((k, -1.0, -float(limits.geofence_max[k])) for k in range(3))
        self._plane_axis = np.array([p[0] for p in planes], dtype=np.intp)
        self._plane_sign = np.array([p[1] for p in planes], dtype=np.float64)
        self._plane_offset = np.array([p[2] for p in planes], dtype=np.float64)
        self._plane_n = np.zeros((len(planes), 3))
        self._plane_n[np.arange(len(planes)), self._plane_axis] = self._plane_sign
        env = limits.envelope
        self.envelope = env
        self._plan = _planning(env)
        self._jerk = min(env.jerk_xy, env.jerk_z)
        self._r_xy = min(a_max, env.accel_xy)  # horizontal radius of the set [m/s^2]
        self._z_cap = env.accel_z  # vertical bound of the set [m/s^2]
        if self._plan and math.isfinite(self._jerk):
            # Jerk step ball around the last command; caps as half-spaces.
            self._ball = self._jerk * dt
            self._z_cap = min(a_max, env.accel_z)
            self._cap_n, self._cap_b = cap_rows(self._r_xy, self._z_cap)
            self._r_in = self._r_xy * math.cos(math.pi / POLYGON_SIDES)  # inscribed
        elif self._plan:
            self._ball = self._r_xy
            self._cap_n, self._cap_b = cap_rows(math.inf, env.accel_z)
            self._r_in = self._r_xy
        else:
            self._ball = a_max
            self._cap_n, self._cap_b = np.zeros((0, 3)), np.zeros(0)
            self._r_in = a_max
        if self._plan:
            budget = min(self._r_in, self._z_cap)
            if math.isfinite(budget):
                self._a_b = self.tuning.brake_fraction * budget

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
        pos = np.asarray(pos_m, dtype=np.float64).reshape(-1, 3)
        vel = np.asarray(vel_mps, dtype=np.float64).reshape(-1, 3)
        a_des = np.asarray(accel_des_mps2, dtype=np.float64).reshape(-1, 3)
        if not pos.shape == vel.shape == a_des.shape:
            raise ValueError(f"shape mismatch: {pos.shape}, {vel.shape}, {a_des.shape}")
        prev = np.zeros_like(pos)
        if self._plan and prev_accel_mps2 is not None:
            prev = np.asarray(prev_accel_mps2, dtype=np.float64).reshape(pos.shape)
            prev = np.where(np.isfinite(prev), prev, 0.0)
        state_ok: BoolArray = np.asarray(
            np.isfinite(pos).all(axis=1) & np.isfinite(vel).all(axis=1)
        )
        des_ok: BoolArray = np.asarray(np.isfinite(a_des).all(axis=1))
        a0 = np.where(des_ok[:, None], a_des, 0.0)
        pos = np.where(state_ok[:, None], pos, 0.0)
        vel = np.where(state_ok[:, None], vel, 0.0)
        geo = self._geometry(pos, state_ok)
        normals, bounds, classes = self._rows(pos, vel, a0, geo, state_ok, prev)
        if self._cap_b.size:
            nv = pos.shape[0]
            normals = np.concatenate(
                [normals, np.broadcast_to(self._cap_n, (nv, *self._cap_n.shape))], axis=1
            )
            bounds = np.concatenate(
                [bounds, np.broadcast_to(self._cap_b, (nv, self._cap_b.size))], axis=1
            )
            classes = np.concatenate([classes, np.full(self._cap_b.size, _CAP)])
        rows = np.ones(bounds.shape, dtype=bool)
        ball = self._ball
        if self._plan and math.isfinite(self._jerk):
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
        if self._plan and math.isfinite(a_max) and ball != a_max:
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
        )
        if self.strict and infeasible.any():
            bad = np.flatnonzero(infeasible)
            names = [ids[int(i)] if ids is not None else int(i) for i in bad]
            raise InfeasibleError(
                f"safety filter: constraints conflict for vehicle(s) {names} "
                f"(worst residual {float(violation.max()):.3g} m/s^2)"
            )
        return accel, report

    def _geometry(self, pos: FloatArray, ok: BoolArray) -> _Geometry:
        """Distances and normals at the current positions (vehicles not ``ok`` have
        no pairs)."""
        nv = pos.shape[0]
        clearance, box_n = box_signed_distance(pos, self._centres, self._halves)
        rel = pos[:, None, :] - pos[None, :, :]
        dist = np.linalg.norm(rel, axis=-1)
        coincident = dist < 1e-9
        # Coincident vehicles: fixed direction +x, antisymmetric (lower index to -x).
        upper = np.triu(np.ones((nv, nv), dtype=bool), 1)
        fixed = np.where(upper, -1.0, 1.0)[..., None] * np.array([1.0, 0.0, 0.0])
        direction = np.where(
            coincident[..., None], fixed, rel / np.where(coincident, 1.0, dist)[..., None]
        )
        other = ~np.eye(nv, dtype=bool) & ok[:, None] & ok[None, :]
        pair_d = np.where(other, dist, math.inf)
        return _Geometry(clearance, box_n, pair_d.min(axis=1, initial=math.inf), pair_d, direction)

    def _rows(
        self,
        pos: FloatArray,
        vel: FloatArray,
        a0: FloatArray,
        geo: _Geometry,
        ok: BoolArray,
        prev: FloatArray,
    ) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
        """All half-space rows n.a >= b: normals (N, m, 3), bounds (N, m), class (m,)."""
        nv = pos.shape[0]
        dt, a_b = self.dt, self._a_b
        normals: list[FloatArray] = []
        bounds: list[FloatArray] = []
        classes: list[int] = []
        # Barrier families (normals, gap, closing, c_prev); a pair's is halved:
        # (B1')-(B2') are homogeneous in lengths, so half the relative problem
        # with one vehicle's budget, caps and jerk is each vehicle's half share.
        fams: list[tuple[FloatArray, FloatArray, FloatArray, FloatArray]] = []
        if self.safety.enabled and self._centres.shape[0]:
            # (a) boxes: (B1)-(B2) on the signed distance, supporting-plane normal.
            closing = -np.einsum("nkj,nj->nk", geo.box_n, vel)
            gap = geo.clearance - self.safety.clearance
            normals.append(geo.box_n)
            if self._plan:
                fams.append((geo.box_n, gap, closing, -np.einsum("nkj,nj->nk", geo.box_n, prev)))
                bounds.append(gap)  # placeholder, replaced below
            else:
                bounds.append(braking_bound(gap, closing, a_b, dt, self.tuning.gamma_per_s))
            classes += [_ENV] * geo.box_n.shape[1]
        if self._plane_axis.size:
            # (c) floor and fence planes: (B1)-(B2), exact for a plane, margin 0.
            gap = self._plane_sign * pos[:, self._plane_axis] - self._plane_offset
            closing = -self._plane_sign * vel[:, self._plane_axis]
            plane_n = np.broadcast_to(self._plane_n, (nv, *self._plane_n.shape))
            normals.append(plane_n)
            if self._plan:
                fams.append((plane_n, gap, closing, -self._plane_sign * prev[:, self._plane_axis]))
                bounds.append(gap)
            else:
                bounds.append(braking_bound(gap, closing, a_b, dt, self.tuning.gamma_per_s))
            classes += [_ENV] * self._plane_axis.size
        if self.safety.enabled and nv > 1:
            # (b) pairs: relative barrier with 2 a_b, each vehicle takes half.
            off = ~np.eye(nv, dtype=bool)
            rel_v = vel[:, None, :] - vel[None, :, :]
            closing = -np.einsum("ijk,ijk->ij", geo.pair_n, rel_v)
            real = np.isfinite(geo.pair_d)
            gap = np.where(real, geo.pair_d, 0.0) - self.safety.separation
            pair_n = geo.pair_n[off].reshape(nv, nv - 1, 3)
            normals.append(pair_n)
            if self._plan:
                c_prev = -np.einsum("ijk,ijk->ij", geo.pair_n, prev[:, None, :] - prev[None, :, :])

                def half(x: FloatArray) -> FloatArray:
                    out: FloatArray = 0.5 * x[off].reshape(nv, nv - 1)
                    return out

                fams.append((pair_n, half(gap), half(closing), half(c_prev)))
                bounds.append(np.where(real[off].reshape(nv, nv - 1), 0.0, -math.inf))
            else:
                u = braking_bound(gap, closing, 2.0 * a_b, dt, self.tuning.gamma_per_s)
                u = np.where(real, 0.5 * u, -math.inf)
                bounds.append(u[off].reshape(nv, nv - 1))
            classes += [_PAIR] * (nv - 1)
        if fams:
            flat = [np.concatenate([f[i].reshape(nv, -1) for f in fams], axis=1) for i in (1, 2, 3)]
            normal = np.concatenate([f[0].reshape(nv, -1, 3) for f in fams], axis=1)
            u_all = self._reaction(normal, *flat)
            col = 0
            for slot, b in enumerate(bounds):
                width = b.shape[1]
                # Pairs' placeholder is 0 (real) or -inf (unusable): -inf stays.
                bounds[slot] = np.where(np.isneginf(b), -math.inf, u_all[:, col : col + width])
                col += width
        if math.isfinite(self.limits.v_max):
            # (d) speed: tangent planes of |v_next| = v_max (limits.speed_rows).
            n, b = speed_rows(vel, a0, self.limits.v_max, dt, a_b)
            if self._plan and math.isfinite(self._jerk):
                # No more than one jerk step from the last command (else it only conflicts).
                b = np.minimum(b, np.einsum("nkj,nj->nk", n, prev) + 0.999 * self._ball)
            normals.append(n)
            bounds.append(b)
            classes += [_SPEED, _SPEED]
        if not normals:
            return np.zeros((nv, 0, 3)), np.zeros((nv, 0)), np.zeros(0, dtype=np.int64)
        bnd = np.concatenate(bounds, axis=1)
        bnd[~ok] = -math.inf
        return np.concatenate(normals, axis=1), bnd, np.array(classes, dtype=np.int64)

    def _reaction(
        self, normal: FloatArray, gap: FloatArray, closing: FloatArray, c_prev: FloatArray
    ) -> FloatArray:
        """u_min of (B1')-(B2') (``reaction.reaction_bound``) within the bounded
        envelope, for rows with unit normals ``normal (N, m, 3)``: the budget is
        brake_fraction x the envelope's extent along n, the closing cap its
        support along n."""
        frac = self.tuning.brake_fraction
        a_b = frac * radial_extent(normal, self._r_in, self._z_cap)
        a_b = np.where(np.isfinite(a_b), a_b, self.tuning.brake_unbounded_mps2)
        nz = np.abs(normal[..., 2])
        nxy = np.sqrt(np.maximum(1.0 - nz * nz, 0.0))
        r_xy, z_cap = min(self._r_xy, _BIG_MPS2), min(self._z_cap, _BIG_MPS2)  # no inf * 0
        cap = np.minimum(r_xy * nxy + z_cap * nz, _BIG_MPS2)
        return reaction_bound(
            gap, closing, c_prev, a_b, cap, jerk=self._jerk, lag=self.envelope.lag_s,
            dt=self.dt, gamma=self.tuning.gamma_per_s,
        )  # fmt: skip

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
        a_max = self._ball
        out = accel.copy()
        bad = np.flatnonzero(~feasible)
        for keep in (_PAIR, _ENV):
            rows = np.broadcast_to(classes <= keep, bounds[bad].shape)
            x, ok = project(a0[bad], normals[bad], bounds[bad], rows, a_max)
            out[bad[ok]] = x[ok]
            bad = bad[~ok]
            if bad.size == 0:
                return out
        if self._plan and math.isfinite(self._jerk):
            # Within a jerk step (a - a' here): the whole step down the environment
            # rows' total violation, one cheap answer (a bisection of projections
            # would cost tens of ms in the conflicts that are common there).
            env = np.broadcast_to(classes == _ENV, bounds[bad].shape)
            viol = np.where(env, np.maximum(bounds[bad], 0.0), 0.0)
            g = np.einsum("nk,nkj->nj", viol, normals[bad])
            size = np.linalg.norm(g, axis=1, keepdims=True)
            out[bad] = np.where(size > 0.0, a_max * g / np.where(size > 0.0, size, 1.0), 0.0)
            return out
        rows = np.broadcast_to(classes <= _ENV, bounds[bad].shape)
        env_b = np.where(rows, bounds[bad], -math.inf)
        relax = np.broadcast_to(classes == _ENV, env_b.shape)
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
