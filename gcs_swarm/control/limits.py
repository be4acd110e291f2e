"""The admissible-acceleration set and the exact least-squares projection onto it.

Pure numpy, no I/O. This module owns the geometry under the safety filter
(``gcs_swarm.control.safety``): signed distance to a box and its gradient, the
braking barrier and the speed limit written as half-spaces in a, the |a|
clamp, and the small convex problem solved every control cycle, vectorised
over vehicles:

    minimise |a - a_des|^2   over a in R^3 [m/s^2, mission frame]
    subject to  n_i . a >= b_i   (half-spaces, unit normals n_i)
                |a| <= a_max     (the acceleration ball)

The problem is three-dimensional, so the optimum is the projection of ``a_des``
onto the affine set of at most three linearly independent active constraints
(with or without the sphere |a| = a_max). ``project`` enumerates exactly those
candidates, keeps the feasible ones and returns the closest: the answer is the
exact optimum, not an iterate. Constraint generation (start from the row
``a_des`` violates most, add the row the current answer violates most, repeat)
keeps the enumeration to the few rows that matter and finds a conflicting
subset early; it is exact because the optimum of a relaxation that is
feasible for every row is the optimum of the full problem.
"""

from __future__ import annotations

import math
from functools import cache
from itertools import combinations

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "FEAS_TOL",
    "box_signed_distance",
    "braking_bound",
    "clamp_norm",
    "project",
    "speed_rows",
]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

FEAS_TOL = 1e-9
"""Feasibility tolerance [m/s^2] (scaled by max(1, |a_des|, a_max)): a constraint
counts as met when violated by less than this. It absorbs rounding only."""

_DEGENERATE = 1e-12  # Gram determinant / triple product below which normals are dependent
_EX = np.array([1.0, 0.0, 0.0])
_EY = np.array([0.0, 1.0, 0.0])


def clamp_norm(vec: FloatArray, limit: float) -> FloatArray:
    """Scale each row of ``vec`` (N, 3) down to norm <= ``limit`` (direction kept).

    Rows already inside are returned bit-exactly; ``limit = inf`` is the identity.
    """
    out = np.array(vec, dtype=np.float64, copy=True)
    if not math.isfinite(limit):
        return out
    norm = np.linalg.norm(out, axis=-1)
    over = norm > limit
    if np.any(over):
        out[over] *= (limit / norm[over])[:, None]
    return out


def speed_rows(
    vel_mps: FloatArray, accel_des_mps2: FloatArray, v_max: float, dt: float, brake_mps2: float
) -> tuple[FloatArray, FloatArray]:
    """Speed limiter as two half-spaces per vehicle: normals (N, 2, 3), bounds (N, 2).

    Each row is a tangent plane of the sphere |v_next| = v_max (ZOH:
    v_next = v + a dt), ``e . (v + a dt) <= v_max``, written ``-e . a >= b``:
    one at the current velocity's direction (so with |a| <= a_max the next
    speed exceeds v_max by at most ``(a_max dt)^2 / (2 v_max)``, the
    tangential part, removed on the next cycle), one at the direction the
    desired command would reach, ``v + a_des dt`` (so a speed-only correction
    lands exactly on v_max). Tangent planes contain the sphere, so neither row
    excludes an admissible velocity. Above v_max the required deceleration is
    capped at ``brake_mps2`` so the rows stay compatible with |a| <= a_max.
    A zero direction falls back to the other one, then to +x.
    """
    along_v = _unit_rows(vel_mps, fallback=_unit_rows(accel_des_mps2, fallback=None))
    along_next = _unit_rows(vel_mps + accel_des_mps2 * dt, fallback=along_v)
    e = np.stack([along_v, along_next], axis=1)
    rhs = np.maximum((v_max - np.einsum("nkj,nj->nk", e, vel_mps)) / dt, -brake_mps2)
    return -e, -rhs


def box_signed_distance(
    pos_m: FloatArray, centres_m: FloatArray, half_extents_m: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Signed distance [m] from points to axis-aligned boxes, and its unit gradient.

    pos_m (N, 3); centres_m, half_extents_m (K, 3). Returns d (N, K), negative
    inside, and n (N, K, 3), the outward unit normal at the closest boundary
    point (outside: (p - closest point)/d, exact). Inside or on the surface, n
    is the normalised sum of the nearest faces' normals: one face in general,
    the bisector on an edge or corner; a coordinate exactly on a box's mid
    plane counts as the + side, so the result is deterministic.
    """
    rel = pos_m[:, None, :] - centres_m[None, :, :]
    sgn = np.where(rel >= 0.0, 1.0, -1.0)
    q = np.abs(rel) - half_extents_m[None, :, :]
    qo = np.maximum(q, 0.0)
    out = np.linalg.norm(qo, axis=-1)
    qmax = q.max(axis=-1)
    outside = out > 0.0
    dist = np.where(outside, out, qmax)
    faces = np.where(q >= qmax[..., None] - 1e-12, sgn, 0.0)
    face_n = faces / np.linalg.norm(faces, axis=-1, keepdims=True)
    out_n = sgn * qo / np.where(outside, out, 1.0)[..., None]
    return dist, np.where(outside[..., None], out_n, face_n)


def braking_bound(
    dist: FloatArray, closing: FloatArray, a_b: float, dt: float, gamma: float
) -> FloatArray:
    """u_min: the least outward acceleration [m/s^2] that keeps the braking barrier.

    The barrier is H = D - max(s, 0)^2 / (2 a_b) (B1 in ``safety``) and the
    condition H(next) >= (1 - gamma dt) H over one ZOH step (B2).
    dist = D = d - d_min [m], closing = s [m/s] (positive approaching), any shape.
    With w = s+ the next closing speed, (B2) reads
    D - (s + w) dt/2 - max(w, 0)^2/(2 a_b) >= R, R = (1 - gamma dt) H:
    for Q = D - s dt/2 - R >= 0 the largest w is the root of
    w^2/(2 a_b) + w dt/2 = Q, else w < 0 and the kinematic term alone binds.

    Whenever H >= 0, u = a_b already gives H(d+, s+) >= H, so u_min <= a_b.
    Only a violated barrier (H < 0: started inside, or after a conflict) can
    ask for more; that demand is capped at a_b (recover at the braking
    budget), because a one-step exponential recovery would ask for O(H/dt^2).
    """
    h = dist - np.maximum(closing, 0.0) ** 2 / (2.0 * a_b)
    r = (1.0 - min(gamma * dt, 1.0)) * h
    q = dist - closing * dt / 2.0 - r
    qp = np.maximum(q, 0.0)
    w = 2.0 * qp / (np.sqrt(dt * dt / 4.0 + 2.0 * qp / a_b) + dt / 2.0)  # stable root
    u = np.where(q >= 0.0, (closing - w) / dt, closing / dt - 2.0 * q / (dt * dt))
    return np.minimum(u, a_b)


def _unit_rows(vec: FloatArray, fallback: FloatArray | None) -> FloatArray:
    norm = np.linalg.norm(vec, axis=-1, keepdims=True)
    ok = norm > 1e-12
    base = np.broadcast_to(_EX, vec.shape) if fallback is None else fallback
    return np.where(ok, vec / np.where(ok, norm, 1.0), base)


@cache
def _index_sets(k: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """All pairs (P, 2) and triples (T, 3) of k row indices (cached, read-only)."""
    pairs = np.array(list(combinations(range(k), 2)), dtype=np.intp).reshape(-1, 2)
    triples = np.array(list(combinations(range(k), 3)), dtype=np.intp).reshape(-1, 3)
    pairs.flags.writeable = False
    triples.flags.writeable = False
    return pairs, triples


def _cross(u: FloatArray, v: FloatArray) -> FloatArray:
    """Row-wise cross product over the last axis (np.cross without its overhead)."""
    u0, u1, u2 = u[..., 0], u[..., 1], u[..., 2]
    v0, v1, v2 = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0], axis=-1)


def _perpendicular(n: FloatArray) -> FloatArray:
    """A deterministic unit vector perpendicular to each unit row of ``n``."""
    c = _cross(n, np.broadcast_to(_EX, n.shape))
    small = np.linalg.norm(c, axis=-1, keepdims=True) < 1e-6
    c = np.where(small, _cross(n, np.broadcast_to(_EY, n.shape)), c)
    out: FloatArray = c / np.linalg.norm(c, axis=-1, keepdims=True)
    return out


def _candidates(
    a0: FloatArray, n: FloatArray, b: FloatArray, w: BoolArray, a_max: float
) -> tuple[FloatArray, BoolArray]:
    """Every KKT candidate of the projection: (N, C, 3) points and validity (N, C).

    Rows with ``w`` False do not exist. Candidates: a0; the projection onto each
    plane, each line (two planes) and each vertex (three planes); and, if a_max
    is finite, the nearest point of the sphere, of each plane's circle on it and
    both points of each line's chord.
    """
    nv, k = b.shape
    pairs, triples = _index_sets(k)
    pts: list[FloatArray] = [a0[:, None, :]]
    ok: list[BoolArray] = [np.ones((nv, 1), dtype=bool)]

    na0 = np.einsum("nkj,nj->nk", n, a0)
    pts.append(a0[:, None, :] + (b - na0)[..., None] * n)  # Eq. of a plane projection
    ok.append(w.copy())

    n1, n2 = n[:, pairs[:, 0]], n[:, pairs[:, 1]]
    b1, b2 = b[:, pairs[:, 0]], b[:, pairs[:, 1]]
    c12 = np.einsum("npj,npj->np", n1, n2)
    det2 = 1.0 - c12 * c12
    ok2 = w[:, pairs[:, 0]] & w[:, pairs[:, 1]] & (det2 > _DEGENERATE)
    inv2 = 1.0 / np.where(ok2, det2, 1.0)

    def line_point(base: FloatArray, r1: FloatArray, r2: FloatArray) -> FloatArray:
        lam1 = (r1 - c12 * r2) * inv2
        lam2 = (r2 - c12 * r1) * inv2
        point: FloatArray = base + lam1[..., None] * n1 + lam2[..., None] * n2
        return point

    pts.append(line_point(a0[:, None, :], b1 - na0[:, pairs[:, 0]], b2 - na0[:, pairs[:, 1]]))
    ok.append(ok2)

    t1, t2, t3 = (n[:, triples[:, i]] for i in range(3))
    x23, x31, x12 = _cross(t2, t3), _cross(t3, t1), _cross(t1, t2)
    det3 = np.einsum("ntj,ntj->nt", t1, x23)
    ok3 = w[:, triples].all(axis=-1) & (np.abs(det3) > _DEGENERATE)
    inv3 = 1.0 / np.where(ok3, det3, 1.0)
    bt = b[:, triples]
    pts.append((bt[..., 0:1] * x23 + bt[..., 1:2] * x31 + bt[..., 2:3] * x12) * inv3[..., None])
    ok.append(ok3)

    if math.isfinite(a_max):
        norm0 = np.linalg.norm(a0, axis=-1)
        pts.append((a0 * (a_max / np.where(norm0 > 0.0, norm0, 1.0))[:, None])[:, None, :])
        ok.append((norm0 > 0.0)[:, None])
        # Circle: plane n.x = b cut by the sphere; centre b n, radius sqrt(a_max^2 - b^2).
        rad2 = a_max * a_max - b * b
        perp = a0[:, None, :] - na0[..., None] * n
        pnorm = np.linalg.norm(perp, axis=-1, keepdims=True)
        alt = _perpendicular(n.reshape(-1, 3)).reshape(n.shape)
        direction = np.where(pnorm > 1e-12, perp / np.where(pnorm > 1e-12, pnorm, 1.0), alt)
        rad = np.sqrt(np.maximum(rad2, 0.0))
        pts.append(b[..., None] * n + rad[..., None] * direction)
        ok.append(w & (rad2 >= 0.0))
        # Chord: the line of two planes cut by the sphere (two points).
        x0 = line_point(np.zeros_like(n1), b1, b2)
        axis = _cross(n1, n2)
        axis /= np.where(ok2, np.linalg.norm(axis, axis=-1), 1.0)[..., None]
        half2 = a_max * a_max - np.einsum("npj,npj->np", x0, x0)
        half = np.sqrt(np.maximum(half2, 0.0))[..., None]
        pts.extend([x0 + half * axis, x0 - half * axis])
        ok.extend([ok2 & (half2 >= 0.0)] * 2)

    return np.concatenate(pts, axis=1), np.concatenate(ok, axis=1)


def _solve_subset(
    a0: FloatArray, n: FloatArray, b: FloatArray, w: BoolArray, a_max: float, tol: FloatArray
) -> tuple[FloatArray, BoolArray]:
    """Exact projection onto the rows in ``w`` (N, k) and the ball; (x, feasible)."""
    pts, valid = _candidates(a0, n, b, w, a_max)
    slack = np.einsum("nkj,ncj->nck", n, pts) - b[:, None, :]
    feas = valid & np.all((slack >= -tol[:, None, None]) | ~w[:, None, :], axis=-1)
    if math.isfinite(a_max):
        feas &= np.linalg.norm(pts, axis=-1) <= a_max + tol[:, None]
    dist = np.where(feas, np.sum((pts - a0[:, None, :]) ** 2, axis=-1), np.inf)
    best = np.argmin(dist, axis=1)
    x = np.take_along_axis(pts, best[:, None, None], axis=1)[:, 0, :]
    return x, feas.any(axis=1)


def _most_violated(
    rows: BoolArray, n: FloatArray, b: FloatArray, x: FloatArray, tol: FloatArray
) -> BoolArray:
    """Mask (N, m) of each vehicle's most violated row at ``x`` (none if all met).

    Adding one row per round (a cutting-plane step) keeps the enumerated
    working set at the few rows that matter, and finds an infeasible subset
    early when the rows conflict.
    """
    slack = np.where(rows, np.einsum("nkj,nj->nk", n, x) - b, np.inf)
    worst = np.argmin(slack, axis=1) if slack.shape[1] else np.zeros(len(x), dtype=np.intp)
    mask = np.zeros(rows.shape, dtype=bool)
    hit = np.take_along_axis(slack, worst[:, None], axis=1)[:, 0] < -tol
    mask[np.flatnonzero(hit), worst[hit]] = True
    return mask


def project(
    a0: FloatArray, n: FloatArray, b: FloatArray, rows: BoolArray, a_max: float
) -> tuple[FloatArray, BoolArray]:
    """Closest point to each ``a0`` row in {n_i . a >= b_i for rows, |a| <= a_max}.

    a0 (N, 3) [m/s^2]; n (N, m, 3) unit normals; b (N, m) [m/s^2]; rows (N, m)
    which rows exist; a_max [m/s^2] (may be inf). Returns ``(a, feasible)``:
    where feasible, ``a`` is the exact optimum (within ``FEAS_TOL`` scaled) and a
    row of ``a0`` that already meets every row is returned bit-exactly; where
    infeasible, ``a`` is ``a0`` clamped to the ball and the caller decides.
    """
    nv, m = b.shape
    if m == 0:
        return clamp_norm(a0, a_max), np.ones(nv, dtype=bool)
    scale = np.maximum(1.0, np.linalg.norm(a0, axis=-1))
    if math.isfinite(a_max):
        scale = np.maximum(scale, a_max)
    tol = FEAS_TOL * scale
    out = clamp_norm(a0, a_max)
    feasible = np.ones(nv, dtype=bool)
    work = _most_violated(rows, n, b, a0, tol)
    todo = work.any(axis=1) | (np.linalg.norm(a0, axis=-1) > a_max + tol)  # ball: False if inf
    while np.any(todo):
        idx = np.flatnonzero(todo)
        wk = work[idx]
        k = max(int(wk.sum(axis=1).max()), 1)
        order = np.argsort(~wk, axis=1, kind="stable")[:, :k]
        sub_w = np.take_along_axis(wk, order, axis=1)
        sub_n = np.take_along_axis(n[idx], order[..., None], axis=1)
        sub_b = np.where(sub_w, np.take_along_axis(b[idx], order, axis=1), 0.0)  # no inf padding
        x, ok = _solve_subset(a0[idx], sub_n, sub_b, sub_w, a_max, tol[idx])
        out[idx[ok]] = x[ok]
        feasible[idx[~ok]] = False
        new = _most_violated(rows[idx] & ~wk & ok[:, None], n[idx], b[idx], x, tol[idx])
        work[idx] |= new
        todo[:] = False
        todo[idx] = new.any(axis=1)
    return out, feasible
