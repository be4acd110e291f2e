"""Point-mass vehicle dynamics, vectorised over vehicles. PURE: numpy only, no I/O.

Owns the kinematic state of every vehicle and the one step function
``step(state, accel_cmd, dt, params) -> state`` plus the vectorised tracking
law ``tracking_accel`` that turns per-vehicle targets into acceleration
commands (ArduCopter's cascaded position -> velocity -> acceleration loop,
reduced to two proportional gains). Frame: local NED metres relative to each
vehicle's EKF origin (x north, y east, z down); ground plane at
``params.ground_d_m`` (down coordinate, normally 0).

Equations (named where used):

- (D1) first-order lag of the achieved acceleration ``a`` on the clamped
  command ``c``: ``da/dt = (c - a) / tau``; ``tau = 0`` means ``a = c``.
- (D2) its exact discretisation for ``c`` constant over a step ``h``
  (``e = exp(-h / tau)``)::

      a1 = c + (a0 - c) e
      v1 = v0 + c h + (a0 - c) tau (1 - e)
      p1 = p0 + v0 h + c h^2 / 2 + (a0 - c) tau (h - tau (1 - e))

  With ``tau = 0`` this is ``v1 = v0 + c h``, ``p1 = p0 + v0 h + c h^2 / 2``:
  exact for a constant acceleration, so ideal-mode runs match the closed form
  ``p = p0 + v0 t + a t^2 / 2`` to rounding.
- (D3) tracking: ``v_des = v_t + wp sqrt_ctrl(p_t - p)`` (D3a, ArduPilot's
  square-root controller, linear with gain ``kp`` near the target) (horizontal norm clamped to
  ``vmax_xy``, vertical to ``[-vmax_up, vmax_dn]``), ``c = a_ff + kv wv (v_des - v)``,
  then ``|c| <= acc_max`` (norm clamp).
- (D4) ground: a vehicle may not go below ``ground_d_m``; on the ground its
  horizontal velocity and downward velocity are zeroed (landed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "GRAVITY_M_S2",
    "DynParams",
    "KinState",
    "Targets",
    "step",
    "tracking_accel",
]

F64 = NDArray[np.float64]
GRAVITY_M_S2 = 9.80665


@dataclass(frozen=True)
class KinState:
    """Kinematic state of N vehicles (local NED, per vehicle origin).

    ``pos_ned_m``, ``vel_ned_m_s``, ``acc_ned_m_s2`` (achieved acceleration,
    the lag state of D1): shape (N, 3). ``landed``: shape (N,), on the ground.
    """

    pos_ned_m: F64
    vel_ned_m_s: F64
    acc_ned_m_s2: F64
    landed: NDArray[np.bool_]

    @staticmethod
    def zeros(n: int) -> KinState:
        """N vehicles at rest at their origins, landed."""
        z = np.zeros((n, 3))
        return KinState(z, z.copy(), z.copy(), np.ones(n, dtype=bool))


@dataclass(frozen=True)
class DynParams:
    """Per-vehicle dynamics limits, each shape (N,).

    ``tau_s``: lag time constant of D1 (0 = ideal); ``acc_max_m_s2``: norm
    clamp of the command; ``ground_d_m``: ground plane (down coordinate).
    """

    tau_s: F64
    acc_max_m_s2: F64
    ground_d_m: F64


@dataclass(frozen=True)
class Targets:
    """Per-vehicle tracking targets for D3 (NED, shapes (N,3) or (N,)).

    ``wp`` (N,3) in {0,1} selects position-tracked axes; ``wv`` (N,) in {0,1}
    enables velocity tracking at all (0 = pure acceleration feed-forward).
    """

    a_ff_ned_m_s2: F64
    p_t_ned_m: F64
    v_t_ned_m_s: F64
    wp: F64
    wv: F64
    vmax_xy_m_s: F64
    vmax_up_m_s: F64
    vmax_dn_m_s: F64
    acc_lim_m_s2: F64


def _norm(v: F64) -> F64:
    """Euclidean norm of each row of (N, 3) ``v``: what ``np.linalg.norm(v, axis=1)``
    computes (sqrt of the row sum of squares), without its argument handling."""
    out: F64 = np.sqrt(np.add.reduce(v * v, axis=1))
    return out


def _sqrt_speed(err_m: F64, kp_1_s: float, acc_m_s2: F64) -> F64:
    """Eq. D3a: ArduPilot's square-root controller, speed (m/s) towards a target ``err_m`` away.

    Linear ``kp e`` near the target, ``sqrt(2 a (e - a / (2 kp^2)))`` beyond
    ``a / kp^2``, so a vehicle limited to deceleration ``a`` stops without
    overshoot.
    """
    lin = acc_m_s2 / (kp_1_s * kp_1_s)
    far = np.sqrt(2.0 * acc_m_s2 * np.maximum(err_m - 0.5 * lin, 0.0))
    out: F64 = np.where(err_m > lin, far, kp_1_s * err_m)
    return out


def tracking_accel(state: KinState, tg: Targets, kp_1_s: float, kv_1_s: float) -> F64:
    """Acceleration command (N,3) NED m/s^2 from targets (Eq. D3, cascaded P-P loop).

    The position error is turned into a speed by Eq. D3a, separately for the
    horizontal plane and the vertical, with half the vehicle's acceleration
    limit as the planned deceleration (margin for the lag of D1).
    """
    err = tg.wp * (tg.p_t_ned_m - state.pos_ned_m)
    a_plan = 0.5 * tg.acc_lim_m_s2
    # row 0 horizontal, row 1 vertical: one pass of Eq. D3a for both (elementwise, so
    # the same numbers as two passes, in half the numpy calls)
    e2 = np.stack([np.hypot(err[:, 0], err[:, 1]), np.abs(err[:, 2])])
    s2 = _sqrt_speed(e2, kp_1_s, a_plan) / np.maximum(e2, 1e-12)
    v_des = tg.v_t_ned_m_s + err * s2[[0, 0, 1]].T
    hs = np.hypot(v_des[:, 0], v_des[:, 1])
    scale = np.minimum(1.0, tg.vmax_xy_m_s / np.maximum(hs, 1e-12))
    v_des[:, 0] *= scale
    v_des[:, 1] *= scale
    v_des[:, 2] = np.clip(v_des[:, 2], -tg.vmax_up_m_s, tg.vmax_dn_m_s)
    cmd = tg.a_ff_ned_m_s2 + (kv_1_s * tg.wv)[:, None] * (v_des - state.vel_ned_m_s)
    norm = _norm(cmd)
    lim = np.minimum(1.0, tg.acc_lim_m_s2 / np.maximum(norm, 1e-12))
    out: F64 = cmd * lim[:, None]
    return out


def step(state: KinState, accel_cmd: F64, dt: float, params: DynParams) -> KinState:
    """Advance N point masses by ``dt`` s under ``accel_cmd`` (N,3) NED m/s^2.

    Clamps the command norm to ``acc_max_m_s2``, applies the lag (Eq. D1/D2,
    exact for a command held over the step), then the ground plane (D4).
    Returns a new state; inputs are not modified.
    """
    c = np.asarray(accel_cmd, dtype=np.float64)
    norm = _norm(c)
    c = c * np.minimum(1.0, params.acc_max_m_s2 / np.maximum(norm, 1e-12))[:, None]
    p0, v0, a0 = state.pos_ned_m, state.vel_ned_m_s, state.acc_ned_m_s2
    tau = params.tau_s
    lagged = tau > 0.0
    safe_tau = np.where(lagged, tau, 1.0)
    e = np.where(lagged, np.exp(-dt / safe_tau), 0.0)[:, None]
    t = np.where(lagged, tau, 0.0)[:, None]
    d = a0 - c
    # Eq. D2 (with tau = 0 the lag terms vanish: t = 0, e = 0).
    a1 = c + d * e
    v1 = v0 + c * dt + d * t * (1.0 - e)
    p1 = p0 + v0 * dt + 0.5 * c * (dt * dt) + d * t * (dt - t * (1.0 - e))
    # Eq. D4: ground plane.
    ground = params.ground_d_m
    below = p1[:, 2] >= ground
    if below.any():
        p1[below, 2] = ground[below]
        v1[below, :] = np.where(v1[below, 2:3] > 0.0, 0.0, v1[below, :])
        v1[below, 2] = np.minimum(v1[below, 2], 0.0)
        a1[below, :] = np.where(a1[below, 2:3] > 0.0, 0.0, a1[below, :])
    landed = below & (v1[:, 2] >= 0.0)
    return KinState(p1, v1, a1, landed)
