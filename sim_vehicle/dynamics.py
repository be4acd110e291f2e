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

``advance_small`` is D3 then D1, D5, D6, D2, D7, D4 for a few vehicles in plain Python floats:
the same operations in the same order as ``tracking_accel`` then ``step``, so
the same bits (a test compares them on random cases), without numpy's cost
per call, which dominates below a few tens of vehicles.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "GRAVITY_M_S2",
    "DynParams",
    "KinState",
    "Targets",
    "advance_small",
    "lag_factors",
    "shape",
    "step",
    "tracking_accel",
]

F64 = NDArray[np.float64]
Rows = Sequence[Sequence[float]]
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


def _hypot_rows(rows: list[list[float]]) -> list[float]:
    """``np.hypot(x, y)`` of each row's first two values. Where one of them is zero the
    result is exactly the other's magnitude (C Annex F: ``hypot(x, +-0) = fabs(x)``), so
    numpy (libm, whose rounding ``math.hypot`` does not share) is called only for the
    rest: not at all for the acceleration setpoints the station streams."""
    out: list[float] = []
    rest = []
    for i, r in enumerate(rows):
        x, y = r[0], r[1]
        if y == 0.0:
            out.append(abs(x))
        elif x == 0.0:
            out.append(abs(y))
        else:
            out.append(0.0)
            rest.append(i)
    if rest:
        for i, h in zip(
            rest,
            np.hypot([rows[i][0] for i in rest], [rows[i][1] for i in rest]).tolist(),
            strict=True,
        ):
            out[i] = h
    return out


def lag_factors(tau_s: F64, dt: float) -> list[tuple[float, float]]:
    """(e, t) of Eq. D2 per vehicle, as ``step`` computes them (``e = exp(-dt / tau)``,
    ``t = tau``; both 0 for ``tau <= 0``): the inputs ``advance_small`` takes.
    numpy's ``exp`` is kept (``math.exp`` may round differently)."""
    lagged = tau_s > 0.0
    e = np.where(lagged, np.exp(-dt / np.where(lagged, tau_s, 1.0)), 0.0)
    t = np.where(lagged, tau_s, 0.0)
    return list(zip(e.tolist(), t.tolist(), strict=True))


def _shape_rows(
    cs: list[list[float]],
    s0: Rows,
    jxy: Sequence[float],
    jz: Sequence[float],
    lean: Sequence[float],
    dt: float,
) -> list[list[float]]:
    """``shape`` (Eqs. D5-D6) on rows given as lists, bit for bit (``_hypot_rows`` keeps
    numpy's hypot). Rows whose limits are all infinite keep ``c`` and cost no hypot."""
    out = [list(c) for c in cs]
    inf = math.inf
    rows = [i for i in range(len(cs)) if jxy[i] != inf or jz[i] != inf or lean[i] != inf]
    if not rows:
        return out
    dh = [[cs[i][0] - s0[i][0], cs[i][1] - s0[i][1]] for i in rows]
    nh = _hypot_rows(dh)
    for k, i in enumerate(rows):
        c, s, o = cs[i], s0[i], out[i]
        jx = jxy[i] * dt
        if nh[k] > jx:  # Eq. D5, horizontal
            q = jx / nh[k]
            o[0], o[1] = s[0] + dh[k][0] * q, s[1] + dh[k][1] * q
        j = jz[i] * dt
        dz = c[2] - s[2]  # Eq. D5, vertical
        if dz > j:
            o[2] = s[2] + j
        elif dz < -j:
            o[2] = s[2] - j
    n2 = _hypot_rows([out[i] for i in rows])
    for k, i in enumerate(rows):
        cap = lean[i]
        if n2[k] > cap:  # Eq. D6
            q = cap / n2[k]
            o = out[i]
            o[0], o[1] = o[0] * q, o[1] * q
    return out


def advance_small(
    pos: Rows,
    vel: Rows,
    acc: Rows,
    tg: tuple[
        Rows,
        Rows,
        Rows,
        Rows,
        Sequence[float],
        Sequence[float],
        Sequence[float],
        Sequence[float],
        Sequence[float],
    ],
    acc_max: Sequence[float],
    ground: Sequence[float],
    lag: Sequence[tuple[float, float]],
    dt: float,
    kp_1_s: float,
    kv_1_s: float,
    shaping: tuple[Rows, Sequence[float], Sequence[float], Sequence[float]] | None = None,
    drag: Sequence[float] | None = None,
) -> tuple[list[list[float]], list[list[float]], list[list[float]], list[bool], list[list[float]]]:
    """``tracking_accel`` then ``step`` for rows given as Python lists, bit for bit.

    ``tg`` holds the ``Targets`` fields in their order, ``acc_max`` and
    ``ground`` the ``DynParams`` ones, ``lag`` is ``lag_factors(tau, dt)``,
    ``shaping`` is (shaped command rows, jerk_xy, jerk_z, lean_acc) for D5-D6
    (None: skipped), ``drag`` the D7 coefficients (None: none).
    Returns (pos, vel, acc, landed, shaped command) as lists.
    numpy's elementwise rules are
    copied where Python's differ: ``np.maximum(a, b)`` is ``a if a > b else b``
    (``b`` on a tie, which matters for signed zeros), ``np.minimum`` likewise,
    ``np.clip(x, lo, hi)`` with array bounds is ``np.minimum(np.maximum(x, lo), hi)``
    with those rules; ``np.hypot`` is kept (libm's rounding, not ``math.hypot``'s)
    where a zero does not make it exact (``_hypot_rows``). For finite inputs;
    ``math.sqrt`` raises ``ValueError`` where numpy would warn and give NaN (e.g.
    a negative acceleration limit), and the caller then takes the numpy path.
    """
    a_ff, p_t, v_t, wp, wv, vmax_xy, vmax_up, vmax_dn, acc_lim = tg
    sqrt = math.sqrt
    n = len(pos)
    err = [
        [w[0] * (t[0] - p[0]), w[1] * (t[1] - p[1]), w[2] * (t[2] - p[2])]
        for w, t, p in zip(wp, p_t, pos, strict=True)
    ]
    e_h = _hypot_rows(err)
    kk = kp_1_s * kp_1_s
    v_des = []
    for i in range(n):  # Eq. D3a, horizontal then vertical
        er, vt = err[i], v_t[i]
        a_plan = 0.5 * acc_lim[i]
        lin = a_plan / kk
        e = e_h[i]
        m = e - 0.5 * lin
        far = sqrt(2.0 * a_plan * (m if m > 0.0 else 0.0))
        sh = (far if e > lin else kp_1_s * e) / (e if e > 1e-12 else 1e-12)
        e = abs(er[2])
        m = e - 0.5 * lin
        far = sqrt(2.0 * a_plan * (m if m > 0.0 else 0.0))
        sv = (far if e > lin else kp_1_s * e) / (e if e > 1e-12 else 1e-12)
        v_des.append([vt[0] + er[0] * sh, vt[1] + er[1] * sh, vt[2] + er[2] * sv])
    hs = _hypot_rows(v_des)
    cs = []
    for i in range(n):
        vd, v0, af = v_des[i], vel[i], a_ff[i]
        h = hs[i]
        q = vmax_xy[i] / (h if h > 1e-12 else 1e-12)
        scale = 1.0 if 1.0 < q else q
        lo, hi, z = -vmax_up[i], vmax_dn[i], vd[2]
        z = z if z > lo else lo
        z = z if z < hi else hi
        k = kv_1_s * wv[i]
        c0 = af[0] + k * (vd[0] * scale - v0[0])
        c1 = af[1] + k * (vd[1] * scale - v0[1])
        c2 = af[2] + k * (z - v0[2])
        norm = sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        q = acc_lim[i] / (norm if norm > 1e-12 else 1e-12)
        lim = 1.0 if 1.0 < q else q
        c0, c1, c2 = c0 * lim, c1 * lim, c2 * lim  # tracking_accel's output
        norm = sqrt(c0 * c0 + c1 * c1 + c2 * c2)  # step: Eq. D1 clamp
        q = acc_max[i] / (norm if norm > 1e-12 else 1e-12)
        lim = 1.0 if 1.0 < q else q
        cs.append([c0 * lim, c1 * lim, c2 * lim])
    if shaping is not None:  # Eqs. D5-D6
        cs = _shape_rows(cs, *shaping, dt)
    p1s, v1s, a1s, landed, s1s = [], [], [], [], []
    for i in range(n):
        v0, p0, a0 = vel[i], pos[i], acc[i]
        c0, c1, c2 = cs[i]
        e, t = lag[i]  # Eq. D2
        d0, d1, d2 = a0[0] - c0, a0[1] - c1, a0[2] - c2
        a1 = [c0 + d0 * e, c1 + d1 * e, c2 + d2 * e]
        u, w = 1.0 - e, dt - t * (1.0 - e)
        hh = dt * dt
        v1 = [
            v0[0] + c0 * dt + d0 * t * u,
            v0[1] + c1 * dt + d1 * t * u,
            v0[2] + c2 * dt + d2 * t * u,
        ]
        p1 = [
            p0[0] + v0[0] * dt + 0.5 * c0 * hh + d0 * t * w,
            p0[1] + v0[1] * dt + 0.5 * c1 * hh + d1 * t * w,
            p0[2] + v0[2] * dt + 0.5 * c2 * hh + d2 * t * w,
        ]
        k = drag[i] if drag is not None else 0.0
        if k != 0.0:  # Eq. D7
            kv0, kv1, kv2 = k * v0[0], k * v0[1], k * v0[2]
            v1 = [v1[0] - kv0 * dt, v1[1] - kv1 * dt, v1[2] - kv2 * dt]
            p1 = [p1[0] - 0.5 * kv0 * hh, p1[1] - 0.5 * kv1 * hh, p1[2] - 0.5 * kv2 * hh]
        s1 = [c0, c1, c2]
        g = ground[i]
        below = p1[2] >= g
        if below:  # Eq. D4
            p1[2] = g
            if v1[2] > 0.0:
                v1 = [0.0, 0.0, 0.0]
            v1[2] = v1[2] if v1[2] < 0.0 else 0.0
            if a1[2] > 0.0:
                a1 = [0.0, 0.0, 0.0]
            if c2 > 0.0:
                s1 = [0.0, 0.0, 0.0]
        p1s.append(p1)
        v1s.append(v1)
        a1s.append(a1)
        s1s.append(s1)
        landed.append(below and v1[2] >= 0.0)
    return p1s, v1s, a1s, landed, s1s
