"""The dynamics of dynamics.py on plain Python floats, for few vehicles. PURE: no I/O.

The fast variant of the reference ``dynamics`` (Eqs. D1-D7 of docs/emulator.md):
``advance_small`` is D3 then D1, D5, D6, D2, D7, D4 for rows given as Python
lists, the same operations in the same order as ``dynamics.tracking_accel``
then ``dynamics.step``, so the same bits (tests/sim_vehicle/test_sv_dynamics.py
runs both on the same random inputs and asserts 0 ulp apart), without
numpy's cost per call, which dominates below a few tens of vehicles
(``small.SMALL_N``; ``fleet.Fleet.step`` switches). numpy's elementwise rules
are copied where Python's differ; numpy's ``hypot`` and ``exp`` are kept.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = ["advance_small", "lag_factors"]

Rows = Sequence[Sequence[float]]


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


def lag_factors(tau_s: NDArray[np.float64], dt: float) -> list[tuple[float, float]]:
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
