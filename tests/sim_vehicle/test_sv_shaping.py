"""The position controller's limits on the command (dynamics Eqs. D5-D6), stepped by hand.

Pure: ``dynamics.step`` and ``Fleet`` advanced in a loop, no sockets, no clock. Lag
``tau = 0`` where the shaped command itself is observed (then the achieved
acceleration equals it exactly, Eq. D2).
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle.autopilot import Autopilot
from sim_vehicle.config import DEFAULT_ORIGIN
from sim_vehicle.dynamics import GRAVITY_M_S2, DynParams, KinState, step
from sim_vehicle.fleet import Fleet
from sim_vehicle.params import ParamStore
from sim_vehicle.telemetry import Kin

DT = 0.02
LEAN_30 = GRAVITY_M_S2 * math.tan(math.radians(30.0))  # 5.662 m/s^2
HOVER = Kin((0.0, 0.0, -10.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), False)


def _air(n: int = 1) -> KinState:
    pos = np.zeros((n, 3))
    pos[:, 2] = -50.0
    z = np.zeros((n, 3))
    return KinState(pos, z.copy(), z.copy(), np.zeros(n, dtype=bool), z.copy())


def _par(tau: float = 0.0, jxy: float = 5.0, jz: float = 5.0, lean: float = LEAN_30) -> DynParams:
    one = np.ones(1)
    return DynParams(tau * one, 50.0 * one, 0.0 * one, jxy * one, jz * one, lean * one)


def _run(cmd: tuple[float, float, float], steps: int, par: DynParams) -> list[np.ndarray]:
    st, out = _air(), []
    for _ in range(steps):
        st = step(st, np.array([cmd]), DT, par)
        out.append(st.acc_ned_m_s2[0].copy())
    return out


def test_a_4_m_s2_step_north_takes_0_8_s_at_5_m_s3() -> None:
    acc = _run((4.0, 0.0, 0.0), 60, _par())
    # 5 m/s^3 x 0.02 s = 0.1 m/s^2 per step: 3.9 after 39 steps (0.78 s), 4 at 40 (0.8 s);
    # 1e-12 is float rounding of forty additions of 0.1
    assert abs(acc[38][0] - 3.9) < 1e-12 and acc[38][0] < 4.0
    assert abs(acc[39][0] - 4.0) < 1e-12
    assert all(a[0] == 4.0 for a in acc[41:])  # within the limit the command itself, exactly
    steps = np.diff([a[0] for a in acc[:40]])
    assert np.all(steps <= 0.1 + 1e-12)  # never faster than the jerk limit
    assert all(a[1] == 0.0 and a[2] == 0.0 for a in acc)


def test_horizontal_jerk_is_a_2d_vector_limit() -> None:
    (a1, *_rest) = _run((3.0, 4.0, 0.0), 1, _par())
    # |delta| = 0.1 along (3, 4) / 5: (0.06, 0.08), not 0.1 on each axis
    np.testing.assert_allclose(a1[:2], [0.06, 0.08], rtol=0, atol=1e-15)


def test_horizontal_norm_is_capped_at_the_lean_angle() -> None:
    acc = _run((10.0, 0.0, 0.0), 200, _par())
    assert abs(acc[-1][0] - LEAN_30) < 1e-12  # g tan(30 deg) = 5.662 m/s^2
    assert max(a[0] for a in acc) <= LEAN_30 + 1e-12
    acc = _run((8.0, 8.0, -3.0), 200, _par())
    assert abs(math.hypot(acc[-1][0], acc[-1][1]) - LEAN_30) < 1e-12
    assert abs(acc[-1][0] - acc[-1][1]) < 1e-12  # direction kept
    assert acc[-1][2] == -3.0  # the vertical is not capped by the lean angle


def test_vertical_jerk_is_limited_separately() -> None:
    acc = _run((1.0, 0.0, -1.0), 5, _par(jxy=5.0, jz=2.0))
    # after 5 steps: x 5 x 0.1 = 0.5, z 5 x 0.04 = 0.2 (up is negative)
    np.testing.assert_allclose(acc[-1], [0.5, 0.0, -0.2], rtol=0, atol=1e-12)


def test_shaping_then_lag_reaches_the_measured_step() -> None:
    acc = _run((1.0, 0.0, 0.0), 150, _par(tau=0.2))
    # sheet: +1 m/s^2 for 3 s reached 0.985-0.989 m/s^2 (drag unmodelled: 0.02 covers it)
    assert abs(acc[-1][0] - 0.987) < 0.02


def test_ideal_preset_is_untouched_bit_for_bit() -> None:
    """Infinite limits (the ideal preset) and no limits at all give the same bits."""
    rng = np.random.default_rng(11)
    n = 9
    inf = np.full(n, np.inf)
    for tau in (0.0, 0.2):
        base = DynParams(np.full(n, tau), np.full(n, 5.0), np.zeros(n))
        unl = DynParams(base.tau_s, base.acc_max_m_s2, base.ground_d_m, inf, inf, inf)
        a = b = KinState(rng.normal(size=(n, 3)), rng.normal(size=(n, 3)),
                         rng.normal(size=(n, 3)), np.zeros(n, dtype=bool))  # fmt: skip
        for _ in range(50):
            cmd = rng.normal(size=(n, 3)) * 4
            a, b = step(a, cmd, DT, base), step(b, cmd, DT, unl)
            for x, y in ((a.pos_ned_m, b.pos_ned_m), (a.vel_ned_m_s, b.vel_ned_m_s),
                         (a.acc_ned_m_s2, b.acc_ned_m_s2)):  # fmt: skip
                assert x.tobytes() == y.tobytes()


def _ap(**params: float) -> Autopilot:
    return Autopilot(1, DEFAULT_ORIGIN, ParamStore(params), 0.0, airborne_at=HOVER.pos)


def _param_set(ap: Autopilot, name: str, value: float) -> None:
    msg = mav.MAVLink_param_set_message(1, 1, name.encode(), value, mav.MAV_PARAM_TYPE_REAL32)
    (reply,) = ap.handle(msg, 0.0, HOVER)
    assert reply.get_type() == "PARAM_VALUE" and reply.param_id == name


def test_limits_come_from_arducopter_parameters() -> None:
    ap = _ap()
    t = ap.target
    assert (t.jerk_xy, t.jerk_z) == (5.0, 5.0) and abs(t.lean_acc - LEAN_30) < 1e-12
    _param_set(ap, "ANGLE_MAX", 4500)  # 45 deg: g tan 45 = g
    _param_set(ap, "PSC_JERK_Z", 2.0)
    assert abs(ap.target.lean_acc - GRAVITY_M_S2) < 1e-12 and ap.target.jerk_z == 2.0
    # Eq. D5a: 0.5 sqrt(WPNAV_ACCEL * snap), snap = radians(1100) g: 4.85 m/s^3 at 50 cm/s^2
    _param_set(ap, "WPNAV_ACCEL", 50)
    expect = 0.5 * math.sqrt(0.5 * math.radians(1100) * GRAVITY_M_S2)
    assert abs(ap.target.jerk_xy - expect) < 1e-12 and expect < 5.0
    ideal = _ap(SIM_ACC_SHAPE=0)
    assert ideal.target.jerk_xy == ideal.target.jerk_z == ideal.target.lean_acc == math.inf


def test_guid_timeout_braking_is_jerk_limited() -> None:
    """A vehicle accelerating at +2 m/s^2 north for 3 s brakes after GUID_TIMEOUT (WPNAV_ACCEL
    2.5 m/s^2, Eq. D3), its shaped command changing by at most 0.1 m/s^2 a step."""
    ap = _ap(GUID_TIMEOUT=3.0, SIM_ACC_TAU=0.0)
    f = Fleet()
    f.add(1, 1, HOVER.pos, landed=False)
    sp = mav.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, 1, 3135, 0, 0, 0, 0, 0, 0, 2.0, 0.0, 0.0, 0, 0
    )
    ap.handle(sp, 0.0, HOVER)
    f.set_target(0, ap.target)
    hist, t = [], 0.0
    for _ in range(400):
        f.step(DT)
        t += DT
        kin = Kin(tuple(f.pos[0]), tuple(f.vel[0]), tuple(f.acc[0]), bool(f.landed[0]))
        if ap.deadline <= t + 1e-9:
            ap.poll(t, kin)
            f.set_target(0, ap.target)
        hist.append(f.acc[0].copy())
    jumps = np.abs(np.diff(np.array(hist)[:, 0]))
    assert jumps.max() <= 0.1 + 1e-12
    assert min(a[0] for a in hist) >= -2.5 - 1e-12  # WPNAV_ACCEL
    assert min(a[0] for a in hist) < -2.4  # and it does use it
    assert np.linalg.norm(f.vel[0]) < 0.05 and ap.control == "hold"


def test_config_shaping_presets() -> None:
    from sim_vehicle import EmulatorConfig

    assert EmulatorConfig().shaping is True  # the ardupilot preset's, by default
    assert EmulatorConfig().tau_s == 0.05  # the lag fitted on SITL with the ramp modelled
    assert EmulatorConfig(accel_shaping=None).shaping is True  # the ardupilot preset's
    assert EmulatorConfig(dynamics="ideal", accel_shaping=None).shaping is False
    assert EmulatorConfig(dynamics="ideal", accel_shaping=True).shaping is True
