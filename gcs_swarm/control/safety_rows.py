"""The safety filter's constraint set: every half-space row n.a >= b that one
control cycle asks of each vehicle, and the distances they come from.

Barriers on the box clearance (a), the pair separation (b), the floor and
fence planes (c) and the keep-out boxes (e: where a vehicle that left the
formation unheard may be, Eq. K1 of ``keep_out``, kept at the separation)
are (B1)-(B2) (``limits.braking_bound``), or within a bounded
vehicle envelope (B1')-(B2') (``reaction.reaction_bound``); the speed rows (d)
are ``limits.speed_rows``; the envelope's acceleration caps are
``reaction.cap_rows``. The readings are in ``safety``'s module docstring and
docs/vehicle-safety.md; ``SafetyFilter`` projects onto these rows. Pure
numpy, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gcs_swarm.control.limits import (
    BoolArray,
    FloatArray,
    box_signed_distance,
    braking_bound,
    speed_rows,
)
from gcs_swarm.control.params import Box, Envelope, Limits, Safety
from gcs_swarm.control.reaction import POLYGON_SIDES, cap_rows, radial_extent, reaction_bound

__all__ = ["CAP", "ENV", "PAIR", "SPEED", "Geometry", "SafetyRows", "SafetyTuning"]

#: Row classes, in the order the best effort keeps them (``SafetyFilter``).
CAP, ENV, PAIR, SPEED = -1, 0, 1, 2
_BIG_MPS2 = 1e6  # stands in for an unbounded closing acceleration in (B0')


def _planning(envelope: Envelope) -> bool:
    """Whether the filter must plan within ``envelope`` (a finite acceleration
    or jerk bound, or a lag); speeds alone are checked, not filtered."""
    e = envelope
    finite = any(math.isfinite(x) for x in (e.accel_xy, e.accel_z, e.jerk_xy, e.jerk_z))
    return finite or e.lag_s > 0.0


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
class Geometry:
    """Per-cycle distances: box clearance (N, K) [m] and normals (N, K, 3),
    nearest-vehicle distance (N,) [m], pair distances (N, N) [m] (inf on the
    diagonal and for unusable vehicles) and unit directions j -> i (N, N, 3),
    and the keep-out boxes' signed distances (N, L) [m] and normals (N, L, 3)
    (not obstacles: they are not in ``clearance``)."""

    clearance: FloatArray
    box_n: FloatArray
    separation: FloatArray
    pair_d: FloatArray
    pair_n: FloatArray
    keep_d: FloatArray
    keep_n: FloatArray


class SafetyRows:
    """The rows of one filter (its limits, safety settings, boxes, period
    ``dt`` [s] and tuning), with the sets they live in: ``plan`` (plan within
    a bounded envelope), ``jerk`` [m/s^3], ``ball`` (the radius of the
    acceleration ball [m/s^2], around the last command when the jerk is
    finite), ``cap_n``/``cap_b`` (the envelope's caps as rows)."""

    def __init__(
        self,
        limits: Limits,
        safety: Safety,
        boxes: Sequence[Box],
        *,
        dt: float,
        tuning: SafetyTuning,
    ) -> None:
        self.limits = limits
        self.safety = safety
        self.dt = dt
        self.tuning = tuning
        self._centres = np.array([b.centre for b in boxes], dtype=np.float64).reshape(-1, 3)
        self._halves = np.array([b.half_extents for b in boxes], dtype=np.float64).reshape(-1, 3)
        self.set_keep_out(())
        a_max = limits.a_max
        self._a_b = (
            tuning.brake_fraction * a_max if math.isfinite(a_max) else tuning.brake_unbounded_mps2
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
        self.plan = _planning(env)
        self.jerk = min(env.jerk_xy, env.jerk_z)
        self._r_xy = min(a_max, env.accel_xy)  # horizontal radius of the set [m/s^2]
        self._z_cap = env.accel_z  # vertical bound of the set [m/s^2]
        if self.plan and math.isfinite(self.jerk):
            # Jerk step ball around the last command; caps as half-spaces.
            self.ball = self.jerk * dt
            self._z_cap = min(a_max, env.accel_z)
            self.cap_n, self.cap_b = cap_rows(self._r_xy, self._z_cap)
            self._r_in = self._r_xy * math.cos(math.pi / POLYGON_SIDES)  # inscribed
        elif self.plan:
            self.ball = self._r_xy
            self.cap_n, self.cap_b = cap_rows(math.inf, env.accel_z)
            self._r_in = self._r_xy
        else:
            self.ball = a_max
            self.cap_n, self.cap_b = np.zeros((0, 3)), np.zeros(0)
            self._r_in = a_max
        if self.plan:
            budget = min(self._r_in, self._z_cap)
            if math.isfinite(budget):
                self._a_b = tuning.brake_fraction * budget

    def set_keep_out(self, boxes: Sequence[Box]) -> None:
        """The keep-out boxes from now on (e): each vehicle keeps the safety
        separation from each box, with the filter on (``Safety.enabled``)."""
        self.keep_out = tuple(boxes)
        self._keep_centres = np.array([b.centre for b in boxes], dtype=np.float64).reshape(-1, 3)
        halves = [b.half_extents for b in boxes]
        self._keep_halves = np.array(halves, dtype=np.float64).reshape(-1, 3)

    def geometry(self, pos: FloatArray, ok: BoolArray) -> Geometry:
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
        if self._keep_centres.shape[0]:
            keep_d, keep_n = box_signed_distance(pos, self._keep_centres, self._keep_halves)
        else:  # the usual case: nobody left unheard
            keep_d, keep_n = np.zeros((nv, 0)), np.zeros((nv, 0, 3))
        return Geometry(clearance, box_n, pair_d.min(axis=1, initial=math.inf), pair_d, direction,
                        keep_d, keep_n)  # fmt: skip

    def rows(
        self,
        pos: FloatArray,
        vel: FloatArray,
        a0: FloatArray,
        geo: Geometry,
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
        # (a) boxes at the clearance and (e) keep-out boxes at the vehicle
        # separation: (B1)-(B2) on the signed distance, supporting-plane normal.
        boxes = ((geo.box_n, geo.clearance, self.safety.clearance),
                 (geo.keep_n, geo.keep_d, self.safety.separation))  # fmt: skip
        for box_n, dist, margin in boxes if self.safety.enabled else ():
            if not box_n.shape[1]:
                continue
            closing = -np.einsum("nkj,nj->nk", box_n, vel)
            gap = dist - margin
            normals.append(box_n)
            if self.plan:
                fams.append((box_n, gap, closing, -np.einsum("nkj,nj->nk", box_n, prev)))
                bounds.append(gap)  # placeholder, replaced below
            else:
                bounds.append(braking_bound(gap, closing, a_b, dt, self.tuning.gamma_per_s))
            classes += [ENV] * box_n.shape[1]
        if self._plane_axis.size:
            # (c) floor and fence planes: (B1)-(B2), exact for a plane, margin 0.
            gap = self._plane_sign * pos[:, self._plane_axis] - self._plane_offset
            closing = -self._plane_sign * vel[:, self._plane_axis]
            plane_n = np.broadcast_to(self._plane_n, (nv, *self._plane_n.shape))
            normals.append(plane_n)
            if self.plan:
                fams.append((plane_n, gap, closing, -self._plane_sign * prev[:, self._plane_axis]))
                bounds.append(gap)
            else:
                bounds.append(braking_bound(gap, closing, a_b, dt, self.tuning.gamma_per_s))
            classes += [ENV] * self._plane_axis.size
        if self.safety.enabled and nv > 1:
            # (b) pairs: relative barrier with 2 a_b, each vehicle takes half.
            off = ~np.eye(nv, dtype=bool)
            rel_v = vel[:, None, :] - vel[None, :, :]
            closing = -np.einsum("ijk,ijk->ij", geo.pair_n, rel_v)
            real = np.isfinite(geo.pair_d)
            gap = np.where(real, geo.pair_d, 0.0) - self.safety.separation
            pair_n = geo.pair_n[off].reshape(nv, nv - 1, 3)
            normals.append(pair_n)
            if self.plan:
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
            classes += [PAIR] * (nv - 1)
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
            if self.plan and math.isfinite(self.jerk):
                # No more than one jerk step from the last command (else it only conflicts).
                b = np.minimum(b, np.einsum("nkj,nj->nk", n, prev) + 0.999 * self.ball)
            normals.append(n)
            bounds.append(b)
            classes += [SPEED, SPEED]
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
            gap, closing, c_prev, a_b, cap, jerk=self.jerk, lag=self.envelope.lag_s,
            dt=self.dt, gamma=self.tuning.gamma_per_s,
        )  # fmt: skip
