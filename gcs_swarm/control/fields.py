"""Rotational fields (Eqs. 19-26), the sense rule, the avoidance force (Eq. 27),
the desired force (Eq. 28) and the classic radial baseline field.

Shapes: N vehicles, K obstacles. ``pos_m``, ``vel_mps``, ``f_des_n`` are
``(N, 3)`` in the mission frame (x east, y north, z up); per-obstacle arrays
are ``(N, K)`` or ``(N, K, 3)``. Senses are ``+1`` (clockwise / upward) or
``-1`` (counterclockwise / downward). "Clockwise" is as seen from +z.

Readings (formation-law.md s6-7):

- Horizontal field, READING (Eq. 21 is the tangent field, Eq. 19's saddle is
  a misprint): ``t_cw = (B/A dy, -A/B dx, 0)``; counterclockwise is ``-t_cw``.
- Vertical field in the vertical plane of heading phi, READING (Eq. 20's
  ``+ sin(phi)`` is ``-``, as in Eq. 23):
  ``t_up = (kappa dz cos(phi), kappa dz sin(phi), -s / kappa)``.
  REFINEMENT (reported to the lead): with the sheet's ``kappa = C /
  sqrt(A^2 + B^2)`` and ``s = dx cos(phi) + dy sin(phi)`` this vector is not
  tangent to the level sets (``t . grad rho = dz s (kappa A^2 - C^2/kappa)``
  for A = B, non-zero). We use ``kappa = C / E`` with ``E^2 = A^2 cos^2(phi) +
  B^2 sin^2(phi)`` (the ellipse of the level set cut by that vertical plane)
  and ``s = (A^2 dx cos(phi) + B^2 dy sin(phi)) / E^2``. In the plane through
  the centre this is exactly the sheet's form, it is a rotation in that plane,
  and it is tangent everywhere: ``t . grad rho = 0``.
- phi = atan2(v_y, v_x) of the vehicle's velocity; when the horizontal speed is
  below :data:`V_REST_MPS`, the azimuth of the desired force (0 if that is
  vertical or zero too).
- Sense rule: the sense whose tangent makes an acute angle with the velocity,
  ``t . v >= 0`` (the desired force when ``|v| < V_REST_MPS``); a tie gives
  clockwise / upward. Latching at field entry is done by the supervisor.
- Eq. 26: ``t_hat = t / |t|``; on the field's axis (``|t| = 0``) there is no
  rotational term (``t_hat = 0``), finite.
- Eq. 27, READING (vector form): for ``rho <= r0``,
  ``f = f_des + |f_des| t_hat g(rho)``, ``g(rho) = (1/rho^2)(1/rho - 1/r0)``;
  otherwise ``f = f_des``. Printed variant (``Readings.eq27_printed``),
  per component: ``f_i = f_des,i + |f_des,i| t_hat_i g(rho)``. Several
  obstacles in range add their terms.
- Classic field: the same gain law along the outward normal of the
  ellipsoid level set, ``grad rho / |grad rho|`` (zero at the centre).
- Eq. 28: ``f_des = F_D (p_t - p) / |p_t - p|``; zero exactly at the target.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gcs_swarm.control.obstacles import RHO_MIN, Ellipsoids, rho_gradient

__all__ = [
    "V_REST_MPS",
    "avoidance_force",
    "desired_force",
    "field_gain",
    "heading",
    "horizontal_tangent_cw",
    "sense_rule",
    "unit_or_zero",
    "vertical_tangent_up",
]

F64 = NDArray[np.float64]

#: Below this speed [m/s] a vehicle counts as at rest: the sense rule and the
#: vertical field's heading use the desired force instead of the velocity.
V_REST_MPS = 1e-3


def horizontal_tangent_cw(d_m: F64, coeffs: F64) -> F64:
    """Eq. 21 (READING): clockwise horizontal tangent ``(B/A dy, -A/B dx, 0)``.

    ``d_m (..., 3)`` offsets from the obstacle centre, ``coeffs (..., 3)`` =
    (A, B, C) broadcastable to it. Returns ``(..., 3)``.
    """
    a, b = coeffs[..., 0], coeffs[..., 1]
    out = np.zeros(np.broadcast_shapes(d_m.shape, coeffs.shape))
    out[..., 0] = (b / a) * d_m[..., 1]
    out[..., 1] = -(a / b) * d_m[..., 0]
    return out


def heading(vel_mps: F64, f_des_n: F64, *, from_velocity: bool = True) -> F64:
    """phi [rad] of the vertical field: azimuth of the velocity, or of the
    desired force when the horizontal speed is below ``V_REST_MPS`` (or always,
    ``from_velocity=False``: ``Avoidance.heading == "desired"``). ``(N,)``."""
    vh = np.hypot(vel_mps[:, 0], vel_mps[:, 1])
    use_v = (vh >= V_REST_MPS) & from_velocity
    x = np.where(use_v, vel_mps[:, 0], f_des_n[:, 0])
    y = np.where(use_v, vel_mps[:, 1], f_des_n[:, 1])
    return np.arctan2(y, x)  # atan2(0, 0) = 0


def vertical_tangent_up(d_m: F64, coeffs: F64, phi: F64) -> F64:
    """Eqs. 20/23 (READING + tangency refinement, see the module docstring):
    upward tangent in the vertical plane of heading ``phi``.

    ``d_m (N, K, 3)``, ``coeffs (K, 3)`` or broadcastable, ``phi (N,)`` [rad].
    """
    c, s = np.cos(phi)[:, None], np.sin(phi)[:, None]
    a2 = coeffs[..., 0] ** 2
    b2 = coeffs[..., 1] ** 2
    cc = coeffs[..., 2]
    e = np.sqrt(a2 * c * c + b2 * s * s)  # > 0: A, B > 0
    kappa = cc / e
    proj = (a2 * d_m[..., 0] * c + b2 * d_m[..., 1] * s) / (e * e)
    dz = d_m[..., 2]
    out = np.empty(np.broadcast_shapes(d_m.shape, np.shape(coeffs)))
    out[..., 0] = kappa * dz * c
    out[..., 1] = kappa * dz * s
    out[..., 2] = -proj / kappa
    return out


def sense_rule(tangent: F64, vel_mps: F64, f_des_n: F64) -> F64:
    """Sense rule after Eq. 25 (READING): ``+1`` if ``t . v >= 0`` else ``-1``,
    with ``v`` the velocity, or the desired force when ``|v| < V_REST_MPS``.

    ``tangent (N, K, 3)`` of the +1 sense; returns ``(N, K)``.
    """
    speed = np.linalg.norm(vel_mps, axis=-1)
    ref = np.where((speed >= V_REST_MPS)[:, None], vel_mps, f_des_n)
    dot = np.einsum("nki,ni->nk", tangent, ref)
    return np.where(dot >= 0.0, 1.0, -1.0)


def unit_or_zero(v: F64) -> F64:
    """Eq. 26: ``v / |v|`` along the last axis, and 0 where ``|v| = 0``."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    out: F64 = np.divide(v, n, out=np.zeros_like(v), where=n > 0.0)
    return out


def field_gain(rho: F64, r0: float) -> F64:
    """Eq. 27's gain ``g(rho) = (1/rho^2)(1/rho - 1/r0)`` for ``rho <= r0``,
    0 outside the field; rho clamped below at ``RHO_MIN`` (finite at the centre)."""
    r = np.maximum(rho, RHO_MIN)
    out: F64 = np.where(rho <= r0, (1.0 / (r * r)) * (1.0 / r - 1.0 / r0), 0.0)
    return out


def desired_force(pos_m: F64, target_m: F64, f_d: float) -> F64:
    """Eq. 28: ``f_des = F_D (p_t - p) / |p_t - p|`` [N], ``(N, 3)``; zero at the target."""
    return f_d * unit_or_zero(target_m - pos_m)


def avoidance_force(
    pos_m: F64,
    vel_mps: F64,
    f_des_n: F64,
    obs: Ellipsoids,
    *,
    method: str,
    r0: float,
    vertical: NDArray[np.bool_] | None = None,
    sense_h: F64 | None = None,
    sense_v: F64 | None = None,
    printed_eq27: bool = False,
    heading_from_velocity: bool = True,
) -> F64:
    """Eq. 27 with the rotational fields (``method="rotational"``) or the classic
    radial field (``method="classic"``); ``"none"`` returns ``f_des``.

    ``vertical (N, K)`` picks the vertical plane per vehicle and obstacle
    (default all horizontal); ``sense_h``/``sense_v (N, K)`` are the latched
    senses (+1 cw/up, -1 ccw/down; default +1); ``heading_from_velocity``
    selects phi's source (see :func:`heading`). Returns ``(N, 3)`` [N].
    """
    if method == "none" or obs.count == 0 or pos_m.shape[0] == 0:
        return f_des_n.copy()
    d, r, grad = rho_gradient(pos_m, obs)
    gain = field_gain(r, r0)  # (N, K), zero outside the field
    if method == "classic":
        direction = unit_or_zero(grad)
    elif method == "rotational":
        n, k = r.shape
        sh = np.ones((n, k)) if sense_h is None else sense_h
        th = horizontal_tangent_cw(d, obs.coeffs_per_m[None, :, :]) * sh[:, :, None]
        if vertical is not None and np.any(vertical):
            sv = np.ones((n, k)) if sense_v is None else sense_v
            phi = heading(vel_mps, f_des_n, from_velocity=heading_from_velocity)
            tv = vertical_tangent_up(d, obs.coeffs_per_m[None, :, :], phi)
            th = np.where(vertical[:, :, None], tv * sv[:, :, None], th)
        direction = unit_or_zero(th)
    else:
        raise ValueError(f"unknown avoidance method {method!r}")
    term = np.einsum("nki,nk->ni", direction, gain)  # sum of t_hat g over obstacles
    scale = np.abs(f_des_n) if printed_eq27 else np.linalg.norm(f_des_n, axis=-1, keepdims=True)
    out: F64 = f_des_n + scale * term
    return out
