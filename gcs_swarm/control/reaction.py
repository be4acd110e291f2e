"""The braking barrier of a jerk-limited, lagged vehicle: (B1') and (B2').

Pure numpy, no I/O. Used by ``gcs_swarm.control.safety`` when the vehicle
envelope (``params.Envelope``) is bounded; docs/vehicle-envelope.md derives
it. Along one barrier's unit normal n (a box face, a floor, a pair), with
closing speed s [m/s] and c [m/s^2] the closing part of the last command
sent (c = -n.a'), the vehicle cannot brake at once: its acceleration is the
command of lag_s ago (tau, a pure delay), and the command changes by at most
the jerk j [m/s^3] per second. So what is already in flight is bounded by
c + j (tau - t) at time t in [0, tau], and the fastest braking plan from now
continues that line: the closing acceleration of the plan is

    c_plan(t) = clip(c + j (tau - t), -a_b, c_cap)                     (B0')

(c_cap: the largest closing acceleration any command can have; a_b: the
braking budget). The plan's stopping distance S(s, c) is the largest
displacement towards the barrier along (B0') (its first phase may still
close in; the vehicle stops on the -a_b phase). The barrier is

    H'(d, s, c) = d - d_min - S(s, c)                                  (B1')

For tau = 0 and j = inf, S = max(s, 0)^2 / (2 a_b): (B1) of ``safety``.
The filter asks, for the new command's closing part c+ = -n.a,

    H'(d+, s+, c+) >= (1 - gamma dt) H'(d, s, c)                       (B2')

with (d+, s+) the plan's own state after one step dt (the vehicle moves on
what is in flight, not on the new command). S grows with c+, so (B2') is one
half-space ``n.a >= u_min`` (a bracketed root, Illinois regula falsi, whose
feasible end is kept: never less conservative than the root). (B0') is time
consistent: the plan from (d+, s+, c - j dt) is the rest of the plan from (d, s, c), so
the plan's own step keeps H' and (B2') never asks more than one jerk step,
u_min <= n.a' + j dt; it is also capped at a_b, like (B2).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "POLYGON_SIDES",
    "cap_rows",
    "radial_extent",
    "reaction_bound",
    "stop_distance",
]

FloatArray = NDArray[np.float64]

_ROOT_STEPS = 12  # Illinois (regula falsi) steps on the bracket; then its feasible end
POLYGON_SIDES = 16  # horizontal acceleration disk as an inscribed 16-gon (98 % of the radius)


def radial_extent(normal: FloatArray, r_ball: float, a_z: float) -> FloatArray:
    """Largest lambda [m/s^2] with lambda n in {|a| <= r_ball, |a_z| <= a_z}."""
    nz = np.abs(normal[..., 2])
    vert = np.where(nz > 1e-12, a_z / np.where(nz > 1e-12, nz, 1.0), math.inf)
    return np.minimum(r_ball, vert)


def cap_rows(r_xy: float, a_z: float) -> tuple[FloatArray, FloatArray]:
    """The acceleration caps as half-spaces ``n.a >= b``: an inscribed
    ``POLYGON_SIDES``-gon of the disk |a_xy| <= r_xy and -a_z <= a_z_acc <= a_z.
    Normals (m, 3), bounds (m,); infinite caps give no rows."""
    normals: list[FloatArray] = []
    bounds: list[float] = []
    if math.isfinite(r_xy):
        ang = 2.0 * math.pi * np.arange(POLYGON_SIDES) / POLYGON_SIDES
        inner = r_xy * math.cos(math.pi / POLYGON_SIDES)
        for a in ang:
            normals.append(np.array([-math.cos(a), -math.sin(a), 0.0]))
            bounds.append(-inner)
    if math.isfinite(a_z):
        normals += [np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, 1.0])]
        bounds += [-a_z, -a_z]
    if not normals:
        return np.zeros((0, 3)), np.zeros(0)
    return np.array(normals), np.array(bounds)


def _phases(
    c: FloatArray, a_b: FloatArray, c_cap: FloatArray, jerk: float, lag: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """(B0') as phases: flat at c_cap for t_f, a ramp from c0 at -jerk for
    t_r, then -a_b. Returns (t_f, c0, t_r, j) with j finite (unused if t_r = 0)."""
    if math.isfinite(jerk):
        peak = c + jerk * lag
        t_f = np.maximum(lag - (c_cap - c) / jerk, 0.0)
        c0 = np.minimum(peak, c_cap)
        t_r = np.maximum((c0 + a_b) / jerk, 0.0)
        return t_f, c0, t_r, np.full(c.shape, jerk)
    t_f = np.full(c.shape, lag)
    c0 = c_cap if lag > 0.0 else c
    return t_f, np.asarray(c0, dtype=np.float64), np.zeros(c.shape), np.ones(c.shape)


def _state_at(
    s: FloatArray, phases: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
    c_cap: FloatArray, a_b: FloatArray, t: float,
) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """Displacement towards the barrier [m] and closing speed [m/s] at time t
    along the plan (B0') (not stopped at standstill)."""
    t_f, c0, t_r, j = phases
    t1 = np.minimum(t, t_f)
    x = s * t1 + 0.5 * c_cap * t1 * t1
    v = s + c_cap * t1
    t2 = np.clip(t - t_f, 0.0, t_r)
    x = x + v * t2 + 0.5 * c0 * t2 * t2 - j * t2**3 / 6.0
    v = v + c0 * t2 - 0.5 * j * t2 * t2
    t3 = np.maximum(t - t_f - t_r, 0.0)
    return x + v * t3 - 0.5 * a_b * t3 * t3, v - a_b * t3


def stop_distance(
    s: FloatArray, c: FloatArray, a_b: FloatArray, c_cap: FloatArray, jerk: float, lag: float
) -> FloatArray:
    """S(s, c) of (B1') [m]: the largest displacement towards the barrier along
    the plan (B0') from closing speed ``s`` and commanded closing acceleration
    ``c``; >= 0. Arrays broadcast together; ``jerk`` [m/s^3] may be inf,
    ``lag`` [s] >= 0."""
    if not (np.shape(s) == np.shape(c) == np.shape(a_b) == np.shape(c_cap)):
        s, c, a_b, c_cap = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64) for x in
                                                 (s, c, a_b, c_cap)))  # fmt: skip
    t_f, c0, t_r, j = _phases(c, a_b, c_cap, jerk, lag)
    # Flat phase: c_cap > 0, so the displacement is convex there: ends only.
    x1 = s * t_f + 0.5 * c_cap * t_f * t_f
    v1 = s + c_cap * t_f
    best = np.maximum(x1, 0.0)
    # Ramp: v(t) = v1 + c0 t - j t^2 / 2 is concave; x peaks at its larger root.
    disc = c0 * c0 + 2.0 * j * v1
    root = (c0 + np.sqrt(np.maximum(disc, 0.0))) / j
    inside = (disc >= 0.0) & (root > 0.0) & (root < t_r)
    rt = np.where(inside, root, t_r)
    x_root = x1 + v1 * rt + 0.5 * c0 * rt * rt - j * rt**3 / 6.0
    best = np.maximum(best, x_root)
    x2 = x1 + v1 * t_r + 0.5 * c0 * t_r * t_r - j * t_r**3 / 6.0
    v2 = v1 + c0 * t_r - 0.5 * j * t_r * t_r
    best = np.maximum(best, x2 + np.maximum(v2, 0.0) ** 2 / (2.0 * a_b))
    out: FloatArray = best
    return out


def reaction_bound(
    dist: FloatArray,
    closing: FloatArray,
    c_prev: FloatArray,
    a_b: FloatArray,
    c_cap: FloatArray,
    *,
    jerk: float,
    lag: float,
    dt: float,
    gamma: float,
) -> FloatArray:
    """u_min [m/s^2] of (B2'): the least n.a that keeps the barrier (B1').

    dist = d - d_min [m], closing = s [m/s] (positive approaching), c_prev
    [m/s^2] the last command's closing part -n.a', a_b and c_cap [m/s^2] the
    braking budget and the largest closing acceleration along n (arrays of one
    shape). Returns -inf where no command of closing part <= c_cap can break
    (B2'); otherwise the bracketed bound, capped at a_b and at one jerk step
    n.a' + jerk dt (what the vehicle can reach)."""
    arrays = np.broadcast_arrays(
        *(np.asarray(x, dtype=np.float64) for x in (dist, closing, c_prev, a_b, c_cap))
    )
    shape = arrays[0].shape
    dist, closing, c_prev, a_b, c_cap = (x.reshape(-1) for x in arrays)
    out = np.full(dist.shape, -math.inf)
    if dist.size == 0:
        return out.reshape(shape)
    h = dist - stop_distance(closing, c_prev, a_b, c_cap, jerk, lag)
    r = (1.0 - min(gamma * dt, 1.0)) * h
    ph = _phases(c_prev, a_b, c_cap, jerk, lag)
    x_dt, s_next = _state_at(closing, ph, c_cap, a_b, dt)
    d_next = dist - x_dt

    def margin(c_new: FloatArray, sel: NDArray[np.bool_]) -> FloatArray:
        """H'(d+, s+, c_new) - (1 - gamma dt) H' [m]: >= 0 meets (B2'); decreasing."""
        s_new = stop_distance(s_next[sel], c_new, a_b[sel], c_cap[sel], jerk, lag)
        res: FloatArray = d_next[sel] - s_new - r[sel]
        return res

    every = np.ones(dist.shape, dtype=bool)
    sel = margin(c_cap, every) < 0.0
    if not sel.any():
        return out.reshape(shape)
    reach = c_prev[sel] - jerk * dt if math.isfinite(jerk) else -c_cap[sel]
    lo = np.minimum(reach, c_cap[sel])  # the most braking the vehicle can command now
    hi = c_cap[sel]
    g_lo = margin(lo, sel)
    g_hi = margin(hi, sel)
    feasible = g_lo >= 0.0
    # Illinois regula falsi on the bracket [lo (margin >= 0), hi (margin < 0)].
    side = np.zeros(lo.shape)
    for _ in range(_ROOT_STEPS):
        denom = np.where(feasible, g_lo - g_hi, 1.0)
        mid = np.where(feasible, lo + (hi - lo) * g_lo / np.where(denom > 0.0, denom, 1.0), lo)
        mid = np.clip(mid, np.minimum(lo, hi), np.maximum(lo, hi))
        g_mid = margin(mid, sel)
        good = g_mid >= 0.0
        lo, g_lo = np.where(good, mid, lo), np.where(good, g_mid, g_lo)
        hi, g_hi = np.where(good, hi, mid), np.where(good, g_hi, g_mid)
        # Illinois: halve the weight of the end that stayed twice in a row.
        g_hi = np.where(good & (side > 0), 0.5 * g_hi, g_hi)
        g_lo = np.where(~good & (side < 0), 0.5 * g_lo, g_lo)
        side = np.where(good, 1.0, -1.0)
    u = np.where(feasible, -lo, -reach)
    out[sel] = np.minimum(np.minimum(u, a_b[sel]), -reach)
    return out.reshape(shape)
