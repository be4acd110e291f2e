"""The fast variant of the dynamics (``dynamics_rows``) against the reference
(``dynamics``), through their public functions only, on the same inputs.

Stated tolerance: none. ``advance_small`` is built to give the reference's
bits, so the comparison is ``tobytes()`` equality (0 ulp, signed zeros
included) rather than an ``allclose``; an agreement to rounding would hide
a reordered operation that changes lockstep runs."""

from __future__ import annotations

import numpy as np

from sim_vehicle import dynamics, dynamics_rows
from sim_vehicle.dynamics import DynParams, KinState, Targets
from sim_vehicle.fleet import KP_1_S, KV_1_S
from sim_vehicle.small import SMALL_N

DT = 0.02


def _vals(rng: np.random.Generator, shape: tuple[int, ...], scale: float) -> np.ndarray:
    """Random values with exact zeros of both signs and repeats (numpy's tie rules)."""
    x = rng.standard_normal(shape) * scale * 10.0 ** rng.uniform(-3, 1, shape)
    pick = rng.integers(0, 8, shape)
    x = np.where(pick == 0, 0.0, np.where(pick == 1, -0.0, x))
    return np.where(pick == 2, np.round(x), x)


def _case(rng: np.random.Generator, n: int) -> tuple[KinState, Targets, DynParams]:
    def lim(lo: float, hi: float) -> np.ndarray:
        v = rng.uniform(lo, hi, n)
        return np.where(rng.integers(0, 5, n) == 0, 0.0, v)

    def cap(hi: float) -> np.ndarray:
        pick = rng.integers(0, 4, n)
        return np.where(pick == 0, np.inf, np.where(pick == 1, 0.0, rng.uniform(0.0, hi, n)))

    ground = rng.uniform(-1, 1, n)
    pos = _vals(rng, (n, 3), 5.0)
    pos[:, 2] = np.where(rng.integers(0, 4, n) == 0, ground + 1e-3, pos[:, 2])
    st = KinState(
        pos, _vals(rng, (n, 3), 5.0), _vals(rng, (n, 3), 5.0),
        rng.integers(0, 2, n).astype(bool), _vals(rng, (n, 3), 5.0),
    )  # fmt: skip
    tg = Targets(
        _vals(rng, (n, 3), 5.0), _vals(rng, (n, 3), 5.0), _vals(rng, (n, 3), 5.0),
        rng.integers(0, 2, (n, 3)).astype(float), rng.integers(0, 2, n).astype(float),
        lim(0.0, 12.0), lim(0.0, 3.0), lim(0.0, 2.0), lim(0.0, 8.0),
    )  # fmt: skip
    drag = np.where(rng.integers(0, 2, n) == 0, 0.0, rng.uniform(0.0, 2.0, n))
    prm = DynParams(lim(-0.1, 0.4), lim(0.0, 8.0), ground, cap(20.0), cap(20.0), cap(8.0), drag)
    return st, tg, prm


def _rows(a: np.ndarray) -> list:
    return a.tolist()  # type: ignore[no-any-return]


def test_fast_variant_agrees_with_the_reference_bit_for_bit() -> None:
    rng = np.random.default_rng(16)
    for case in range(1500):
        n = case % (SMALL_N - 1) + 1
        st, tg, prm = _case(rng, n)
        # reference: Eq. D3, then D1, D5-D6, D2, D7, D4
        cmd = dynamics.tracking_accel(st, tg, KP_1_S, KV_1_S)
        want = dynamics.step(st, cmd, DT, prm)
        assert prm.jerk_xy_m_s3 is not None and prm.jerk_z_m_s3 is not None
        assert prm.lean_acc_m_s2 is not None and prm.drag_1_s is not None
        assert st.cmd_ned_m_s2 is not None
        targets = (
            _rows(tg.a_ff_ned_m_s2), _rows(tg.p_t_ned_m), _rows(tg.v_t_ned_m_s), _rows(tg.wp),
            _rows(tg.wv), _rows(tg.vmax_xy_m_s), _rows(tg.vmax_up_m_s), _rows(tg.vmax_dn_m_s),
            _rows(tg.acc_lim_m_s2),
        )  # fmt: skip
        shaping = (
            _rows(st.cmd_ned_m_s2), _rows(prm.jerk_xy_m_s3), _rows(prm.jerk_z_m_s3),
            _rows(prm.lean_acc_m_s2),
        )  # fmt: skip
        try:
            got = dynamics_rows.advance_small(
                _rows(st.pos_ned_m), _rows(st.vel_ned_m_s), _rows(st.acc_ned_m_s2), targets,
                _rows(prm.acc_max_m_s2), _rows(prm.ground_d_m),
                dynamics_rows.lag_factors(prm.tau_s, DT), DT, KP_1_S, KV_1_S, shaping,
                _rows(prm.drag_1_s),
            )  # fmt: skip
        except ValueError:  # a math domain error: the fleet takes the reference then
            assert (tg.acc_lim_m_s2 < 0).any(), case
            continue
        pos, vel, acc, landed, shp = got
        assert want.cmd_ned_m_s2 is not None
        for name, g, w in (
            ("pos", np.array(pos), want.pos_ned_m),
            ("vel", np.array(vel), want.vel_ned_m_s),
            ("acc", np.array(acc), want.acc_ned_m_s2),
            ("shp", np.array(shp), want.cmd_ned_m_s2),
            ("landed", np.array(landed, dtype=bool), want.landed),
        ):
            assert g.shape == w.shape and g.tobytes() == w.tobytes(), (case, name, g, w)
