"""Point-mass vehicle dynamics, vectorised over vehicles. PURE: numpy and math only, no I/O.

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
  horizontal velocity and downward velocity are zeroed (landed), and the
  acceleration (and the shaped command of D5) when it pushes down.
- (D5) jerk limit of ArduCopter's position controller (``AC_PosControl``
  ``shape_accel_xy`` / ``shape_accel``): the shaped command ``s`` moves towards
  the clamped command ``c`` by at most ``j dt`` per step, the horizontal part as
  a 2-D vector (``|s_h' - s_h| <= j_xy dt``), the vertical as a scalar
  (``|s_z' - s_z| <= j_z dt``); within the limit ``s' = c`` exactly.
- (D6) lean-angle cap: ``|s_h| <= a_lean = g tan(ANGLE_MAX)`` (norm clamp of the
  horizontal shaped command, stored so it does not wind up). D2 then lags ``s``.
  With ``j = a_lean = inf`` (the ideal preset) D5-D6 give ``s = c`` bit for bit.
- (D7) linear drag on vehicles that fly raw acceleration setpoints: the
  airframe's drag ``-k v`` (k in 1/s: drag coefficient over mass) is not
  cancelled by the autopilot when its velocity loop is bypassed (PX4's
  OFFBOARD acceleration; PX4 SIH's ``SIH_KDV / SIH_MASS`` = 1.0 1/s), so it
  adds to D2, evaluated at the step's start velocity:
  ``v1 -= k v0 h``, ``p1 -= k v0 h^2 / 2`` (explicit; ``k h`` <= 0.02 at 50 Hz).
  ``a`` stays the lagged thrust acceleration. ``k = 0`` rows are untouched.
  An autopilot's velocity loop leaves part of it on velocity setpoints
  (``SIM_DRAG_VEL``, fitted for PX4: docs/emulator.md); the row's ``k`` is then that part.
  (D8, a PX4's setpoint dead time, lives in ``sim_vehicle/px4.py``: it delays targets,
  not the motion.)

This module is the reference: readable, vectorised, the equations in order.
Its fast variant for few vehicles, ``dynamics_rows.advance_small`` (the same
operations on plain Python floats, the same bits), lives beside it; the
fleet switches between them at ``small.SMALL_N`` and a test runs both on the
same inputs.
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
    "shape",
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
    ``cmd_ned_m_s2``: the shaped command of D5-D6 (the jerk limiter's state,
    (N, 3) m/s^2); None = zeros.
    """

    pos_ned_m: F64
    vel_ned_m_s: F64
    acc_ned_m_s2: F64
    landed: NDArray[np.bool_]
    cmd_ned_m_s2: F64 | None = None

    @staticmethod
    def zeros(n: int) -> KinState:
        """N vehicles at rest at their origins, landed."""
        z = np.zeros((n, 3))
        return KinState(z, z.copy(), z.copy(), np.ones(n, dtype=bool), z.copy())


@dataclass(frozen=True)
class DynParams:
    """Per-vehicle dynamics limits, each shape (N,).

    ``tau_s``: lag time constant of D1 (0 = ideal); ``acc_max_m_s2``: norm
    clamp of the command; ``ground_d_m``: ground plane (down coordinate).
    ``jerk_xy_m_s3``, ``jerk_z_m_s3``: jerk limits of D5; ``lean_acc_m_s2``:
    horizontal cap of D6 (``inf`` = no limit; None = D5-D6 skipped);
    ``drag_1_s``: D7's drag over mass (None or 0 = no drag).
    """

    tau_s: F64
    acc_max_m_s2: F64
    ground_d_m: F64
    jerk_xy_m_s3: F64 | None = None
    jerk_z_m_s3: F64 | None = None
    lean_acc_m_s2: F64 | None = None
    drag_1_s: F64 | None = None


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


def shape(c: F64, s0: F64, dt: float, params: DynParams) -> F64:
    """Eqs. D5-D6: the shaped command (N,3) m/s^2 from the clamped command ``c`` and the
    previous shaped command ``s0``. Within the jerk limit the result is ``c`` itself."""
    if params.jerk_xy_m_s3 is None or params.jerk_z_m_s3 is None or params.lean_acc_m_s2 is None:
        return c
    jx = params.jerk_xy_m_s3 * dt
    jz = params.jerk_z_m_s3 * dt
    dh = c[:, :2] - s0[:, :2]
    nh = np.hypot(dh[:, 0], dh[:, 1])
    over = nh > jx  # Eq. D5, horizontal: a 2-D rate limit
    k = np.where(over, jx, 0.0) / np.where(over, nh, 1.0)
    s = np.empty_like(c)
    s[:, :2] = np.where(over[:, None], s0[:, :2] + dh * k[:, None], c[:, :2])
    dz = c[:, 2] - s0[:, 2]  # Eq. D5, vertical
    s[:, 2] = np.where(dz > jz, s0[:, 2] + jz, np.where(dz < -jz, s0[:, 2] - jz, c[:, 2]))
    cap = params.lean_acc_m_s2
    n2 = np.hypot(s[:, 0], s[:, 1])
    big = n2 > cap  # Eq. D6
    if big.any():
        q = np.where(big, cap, 1.0) / np.where(big, n2, 1.0)
        s[:, 0] *= q
        s[:, 1] *= q
    return s


def step(state: KinState, accel_cmd: F64, dt: float, params: DynParams) -> KinState:
    """Advance N point masses by ``dt`` s under ``accel_cmd`` (N,3) NED m/s^2.

    Clamps the command norm to ``acc_max_m_s2``, shapes it (Eqs. D5-D6, when
    ``params`` has the limits), applies the lag (Eq. D1/D2, exact for a command
    held over the step), then the ground plane (D4). Returns a new state;
    inputs are not modified.
    """
    c = np.asarray(accel_cmd, dtype=np.float64)
    norm = _norm(c)
    c = c * np.minimum(1.0, params.acc_max_m_s2 / np.maximum(norm, 1e-12))[:, None]
    s0 = state.cmd_ned_m_s2 if state.cmd_ned_m_s2 is not None else np.zeros_like(c)
    c = shape(c, s0, dt, params)
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
    if params.drag_1_s is not None:
        dragged = params.drag_1_s != 0.0
        if dragged.any():  # Eq. D7, only on the rows with drag (signed zeros elsewhere kept)
            kv = params.drag_1_s[dragged, None] * v0[dragged]
            v1[dragged] = v1[dragged] - kv * dt
            p1[dragged] = p1[dragged] - 0.5 * kv * (dt * dt)
    s1 = c.copy()
    # Eq. D4: ground plane.
    ground = params.ground_d_m
    below = p1[:, 2] >= ground
    if below.any():
        p1[below, 2] = ground[below]
        v1[below, :] = np.where(v1[below, 2:3] > 0.0, 0.0, v1[below, :])
        v1[below, 2] = np.minimum(v1[below, 2], 0.0)
        a1[below, :] = np.where(a1[below, 2:3] > 0.0, 0.0, a1[below, :])
        s1[below, :] = np.where(s1[below, 2:3] > 0.0, 0.0, s1[below, :])
    landed = below & (v1[:, 2] >= 0.0)
    return KinState(p1, v1, a1, landed, s1)
