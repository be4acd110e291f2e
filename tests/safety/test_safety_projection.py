"""Unit tests of the safety filter's pieces: the exact projection (limits.py),
box signed distance, the braking barrier bound, the speed rows, and the filter's
single-cycle behaviour (identity, NaN, coincident vehicles, infeasibility)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gcs_swarm.control import limits as limits_mod
from gcs_swarm.control import safety as safety_mod
from gcs_swarm.control.limits import braking_bound, clamp_norm, project, speed_rows
from gcs_swarm.control.params import Box, Limits, Safety
from gcs_swarm.control.safety import (
    SafetyFilter,
    SafetyHook,
    SafetyStats,
    SafetyTuning,
    box_signed_distance,
)
from gcs_swarm.errors import InfeasibleError

DT = 0.02


def _unit(v: list[float]) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    return a / np.linalg.norm(a)


def test_exported_names_exist() -> None:
    for mod in (safety_mod, limits_mod):
        for name in mod.__all__:
            assert hasattr(mod, name), name


# --- projection ---------------------------------------------------------------


def test_inactive_constraints_leave_a_des_bit_exact() -> None:
    a0 = np.array([[0.1234567891234, -2.0, 0.3], [1.0, 1.0, 1.0]])
    n = np.array([[[1.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]]])
    b = np.array([[-5.0], [0.5]])  # both rows met by a0
    out, ok = project(a0, n, b, np.ones_like(b, dtype=bool), a_max=10.0)
    assert ok.all()
    assert np.array_equal(out, a0)  # bit-exact, not merely close


def test_single_half_space_matches_closed_form() -> None:
    rng = np.random.default_rng(7)
    for _ in range(50):
        nrm = _unit(list(rng.normal(size=3)))
        a0 = rng.normal(size=3) * 3.0
        b = float(nrm @ a0) + rng.uniform(0.1, 2.0)  # violated by construction
        out, ok = project(
            a0[None], nrm[None, None], np.array([[b]]), np.ones((1, 1), bool), math.inf
        )
        assert ok[0]
        # Closed form of the projection onto {n.a >= b}: a0 + (b - n.a0) n.
        np.testing.assert_allclose(out[0], a0 + (b - nrm @ a0) * nrm, rtol=0, atol=1e-12)


def test_ball_is_respected_and_ball_plane_matches_circle_point() -> None:
    a0 = np.array([[10.0, 0.0, 0.0]])
    out, ok = project(a0, np.zeros((1, 0, 3)), np.zeros((1, 0)), np.zeros((1, 0), bool), 3.0)
    np.testing.assert_allclose(out, [[3.0, 0.0, 0.0]], atol=1e-15)
    # Plane z >= 2 and |a| <= 3: the optimum is on the circle z = 2, radius sqrt(5),
    # in the direction of a0's in-plane part (+x).
    n = np.array([[[0.0, 0.0, 1.0]]])
    out, ok = project(a0, n, np.array([[2.0]]), np.ones((1, 1), bool), 3.0)
    assert ok[0]
    np.testing.assert_allclose(out, [[math.sqrt(5.0), 0.0, 2.0]], atol=1e-12)
    # Plane z >= 4 lies outside the ball: infeasible, answer stays in the ball.
    out, ok = project(a0, n, np.array([[4.0]]), np.ones((1, 1), bool), 3.0)
    assert not ok[0]
    assert np.linalg.norm(out) <= 3.0 + 1e-12


def test_projection_is_optimal_against_sampled_feasible_points() -> None:
    # Variational inequality of a projection onto a convex set C:
    # x = P(a0) iff (a0 - x).(y - x) <= 0 for every y in C. Sample y near x.
    rng = np.random.default_rng(11)
    checked = 0
    for _ in range(150):
        m = int(rng.integers(1, 6))
        nrm = rng.normal(size=(1, m, 3))
        nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
        b = rng.normal(size=(1, m)) * 1.5
        a0 = rng.normal(size=(1, 3)) * 4.0
        a_max = float(rng.choice([2.5, math.inf]))
        x, ok = project(a0, nrm, b, np.ones((1, m), bool), a_max)
        if not ok[0]:
            continue
        checked += 1
        x0 = x[0]
        tol = 1e-8  # scaled feasibility tolerance (FEAS_TOL * max(1, |a0|, a_max))
        assert np.all(nrm[0] @ x0 >= b[0] - tol)
        assert np.linalg.norm(x0) <= a_max + tol
        y = x0 + rng.normal(size=(400, 3)) * rng.choice([0.01, 0.3, 2.0])
        feas = np.all(y @ nrm[0].T >= b[0], axis=1) & (np.linalg.norm(y, axis=1) <= a_max)
        # 1e-9: rounding of the enumerated candidate, the products are O(10).
        assert np.all((y[feas] - x0) @ (a0[0] - x0) <= 1e-9)
    assert checked > 60  # the sample really exercised feasible problems


def test_clamp_norm_keeps_direction_and_inside_rows() -> None:
    a = np.array([[3.0, 4.0, 0.0], [0.1, 0.0, 0.0]])
    out = clamp_norm(a, 2.5)
    np.testing.assert_allclose(out[0], [1.5, 2.0, 0.0], atol=1e-15)
    assert np.array_equal(out[1], a[1])
    assert np.array_equal(clamp_norm(a, math.inf), a)


# --- geometry and barrier -------------------------------------------------------


def test_box_signed_distance_faces_edges_corners_inside() -> None:
    c = np.array([[0.0, 0.0, 0.0]])
    h = np.array([[1.0, 2.0, 3.0]])
    pts = np.array(
        [
            [3.0, 0.0, 0.0],  # face +x, d = 2
            [2.0, 3.0, 0.0],  # edge, d = sqrt(2)
            [-2.0, -3.0, -4.0],  # corner, d = sqrt(3)
            [0.5, 0.0, 0.0],  # inside, nearest face +x at 0.5
            [0.0, 0.0, 0.0],  # centre: nearest face +-x; + side by convention
            [1.0, 2.0, 0.0],  # on an edge: bisector of +x and +y
        ]
    )
    d, n = box_signed_distance(pts, c, h)
    np.testing.assert_allclose(d[:, 0], [2.0, math.sqrt(2), math.sqrt(3), -0.5, -1.0, 0.0])
    np.testing.assert_allclose(n[0, 0], [1, 0, 0])
    np.testing.assert_allclose(n[1, 0], _unit([1, 1, 0]))
    np.testing.assert_allclose(n[2, 0], _unit([-1, -1, -1]))
    np.testing.assert_allclose(n[3, 0], [1, 0, 0])
    np.testing.assert_allclose(n[4, 0], [1, 0, 0])
    np.testing.assert_allclose(n[5, 0], _unit([1, 1, 0]))
    assert np.all(np.isfinite(n))


def test_box_gradient_matches_finite_differences_outside() -> None:
    rng = np.random.default_rng(3)
    c = np.array([[1.0, -2.0, 0.5]])
    h = np.array([[1.5, 0.5, 2.0]])
    p = rng.uniform(-6, 6, size=(200, 3))
    d, n = box_signed_distance(p, c, h)
    p, n = p[d[:, 0] > 0.05], n[d[:, 0] > 0.05, 0]
    eps = 1e-6
    fd = np.stack(
        [
            (box_signed_distance(p + eps * e, c, h)[0] - box_signed_distance(p - eps * e, c, h)[0])[
                :, 0
            ]
            / (2 * eps)
            for e in np.eye(3)
        ],
        axis=1,
    )
    np.testing.assert_allclose(n, fd, atol=1e-6)  # central difference error O(eps)


def test_braking_bound_asks_exactly_a_b_on_the_boundary() -> None:
    a_b, gamma = 2.5, 2.0
    s = np.array([0.3, 1.0, 4.0])
    dist = s**2 / (2 * a_b)  # H = 0: just able to stop
    u = braking_bound(dist, s, a_b, DT, gamma)
    # On the boundary the exact ZOH step needs u = a_b (derivation in safety.py).
    np.testing.assert_allclose(u, a_b, rtol=1e-12)
    assert np.all(u <= a_b + 1e-12)


def test_braking_bound_is_exact_for_a_plane_step() -> None:
    rng = np.random.default_rng(5)
    a_b, gamma = 3.0, 2.0
    dist = rng.uniform(0.0, 5.0, 300)
    s = rng.uniform(-3.0, 3.0, 300)
    u = braking_bound(dist, s, a_b, DT, gamma)

    def barrier(d: np.ndarray, sp: np.ndarray) -> np.ndarray:
        return d - np.maximum(sp, 0.0) ** 2 / (2 * a_b)

    d1 = dist - s * DT + u * DT**2 / 2
    s1 = s - u * DT
    h0, h1 = barrier(dist, s), barrier(d1, s1)
    safe = h0 >= 0.0
    assert 50 < safe.sum() < 300  # both branches exercised
    # From a safe state (B2) holds with equality at u_min (1e-9: rounding of
    # the root formula at distances O(1) m).
    np.testing.assert_allclose(h1[safe], (1 - gamma * DT) * h0[safe], atol=1e-9)
    # From a violated state the demand is capped at a_b and never worsens H.
    np.testing.assert_array_equal(u[~safe], a_b)
    assert np.all(h1[~safe] >= h0[~safe] - 1e-12)


def test_speed_rows_bring_speed_to_v_max_exactly_when_alone() -> None:
    v = np.array([[3.0, 0.0, 0.0]])
    a_des = np.array([[5.0, 0.0, 0.0]])
    f = SafetyFilter(Limits(v_max=3.05), Safety(), [], dt=DT)
    a, rep = f.filter(np.zeros((1, 3)), v, a_des)
    np.testing.assert_allclose(np.linalg.norm(v + a * DT), 3.05, rtol=1e-12)
    assert rep.correction_mps2[0] > 0
    n, b = speed_rows(v, a_des, 3.05, DT, 1.0)
    assert n.shape == (1, 2, 3) and b.shape == (1, 2)


# --- the filter, one cycle ------------------------------------------------------


@settings(max_examples=40, deadline=None, derandomize=True)
@given(
    st.lists(
        st.tuples(*[st.floats(-1e6, 1e6, allow_nan=False)] * 9),
        min_size=1,
        max_size=6,
    )
)
def test_disabled_with_infinite_limits_is_identity(rows: list[tuple[float, ...]]) -> None:
    arr = np.array(rows).reshape(-1, 9)
    p, v, a = arr[:, 0:3], arr[:, 3:6], arr[:, 6:9]
    f = SafetyFilter(Limits(), Safety(enabled=False), [Box((0, 0, 0), (1, 1, 1))], dt=DT)
    out, rep = f.filter(p, v, a)
    assert np.array_equal(out, a)
    assert not rep.intervened.any() and not rep.infeasible.any()


def test_far_box_leaves_a_des_bit_exact() -> None:
    f = SafetyFilter(
        Limits(a_max=5.0, v_max=5.0), Safety(enabled=True), [Box((100, 0, 0), (1, 1, 1))], dt=DT
    )
    a = np.array([[1.1, -0.7, 0.3]])
    out, rep = f.filter(np.zeros((1, 3)), np.array([[1.0, 0.0, 0.0]]), a)
    assert np.array_equal(out, a)
    assert rep.active[0] == 0 and rep.correction_mps2[0] == 0.0


def test_nan_inputs_give_finite_outputs_and_a_flag() -> None:
    f = SafetyFilter(Limits(a_max=4.0), Safety(enabled=True), [Box((5, 0, 0), (1, 1, 1))], dt=DT)
    p = np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0], [0.0, 5.0, 0.0]])
    v = np.zeros((3, 3))
    a = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [np.inf, 0.0, np.nan]])
    out, rep = f.filter(p, v, a)
    assert np.all(np.isfinite(out))
    assert list(rep.infeasible) == [False, True, False]
    assert np.array_equal(out[1], [0.0, 0.0, 0.0])  # unknown state: no command
    assert np.array_equal(out[2], [0.0, 0.0, 0.0])  # non-finite wish treated as zero
    assert rep.min_clearance_m[1] == np.inf  # no figure for an unknown position
    assert rep.min_clearance_m[0] == pytest.approx(4.0)


def test_coincident_vehicles_are_pushed_apart_deterministically() -> None:
    f = SafetyFilter(Limits(a_max=4.0), Safety(enabled=True, separation=1.0), [], dt=DT)
    p = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]])
    out, rep = f.filter(p, np.zeros((2, 3)), np.zeros((2, 3)))
    assert np.all(np.isfinite(out))
    assert out[0, 0] < 0.0 < out[1, 0]  # lower index to -x, fixed convention
    np.testing.assert_allclose(out[0], -out[1], atol=1e-12)
    assert rep.min_separation_m[0] == 0.0


def test_conflict_is_flagged_best_effort_and_strict_raises() -> None:
    # brake_fraction = 1: each wall may ask for all of a_max. Racing into the
    # corner of the floor and the fence's x = 0 wall, both ask for a_max at
    # once: |(2, 0, 2)| > 2, no admissible command.
    lim = Limits(a_max=2.0, z_floor=0.0, geofence_min=(0.0, -50.0, -50.0))
    tuning = SafetyTuning(brake_fraction=1.0)
    p = np.array([[0.05, 0.0, 0.05]])
    v = np.array([[-1.0, 0.0, -1.0]])
    a_des = np.array([[0.0, 1.0, 0.0]])
    out, rep = SafetyFilter(lim, Safety(), [], dt=DT, tuning=tuning).filter(p, v, a_des)
    assert rep.infeasible[0] and rep.violation_mps2[0] > 0
    # Best effort: the least uniform relaxation t of a_x >= 2 - t, a_z >= 2 - t
    # inside |a| <= 2 is a = (sqrt2, 0, sqrt2). Bisection to 2^-40 of the
    # range, and the circle's radius grows like sqrt(t): 1e-5 is ample.
    np.testing.assert_allclose(out[0], [math.sqrt(2), 0.0, math.sqrt(2)], atol=1e-5)
    assert np.linalg.norm(out[0]) <= 2.0 + 1e-9
    strict = SafetyFilter(lim, Safety(), [], dt=DT, tuning=tuning, strict=True)
    with pytest.raises(InfeasibleError, match="vehicle\\(s\\) \\['uav7'\\]"):
        strict.filter(p, v, a_des, ids=["uav7"])


def test_best_effort_keeps_the_floor_before_separation() -> None:
    # Vehicle 0 rests on the floor; vehicle 1 drops onto it. Vehicle 0's half of
    # the pair row wants it to go down, the floor forbids it: vehicle 0 is
    # flagged and keeps the floor; vehicle 1 takes its own half (up, a_b).
    lim = Limits(a_max=4.0, z_floor=0.0)
    f = SafetyFilter(lim, Safety(enabled=True, separation=1.0), [], dt=DT)
    p = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.9]])
    v = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    out, rep = f.filter(p, v, np.zeros((2, 3)))
    assert list(rep.infeasible) == [True, False]
    assert out[0, 2] >= 0.0
    assert out[1, 2] >= 2.0 - 1e-9  # a_b = 0.5 * a_max


def test_hook_accumulates_stats_and_summary_text() -> None:
    f = SafetyFilter(Limits(a_max=1.0), Safety(), [], dt=DT)
    hook = SafetyHook(f)
    a = hook(0.0, [1, 2], np.zeros((2, 3)), np.zeros((2, 3)), np.array([[3.0, 0, 0], [0.5, 0, 0]]))
    np.testing.assert_allclose(a, [[1.0, 0, 0], [0.5, 0, 0]])
    hook(DT / 2, [1, 2], np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 3)))  # RK4 stage
    hook(DT, [1, 2], np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 3)))
    # The next step's first stage at the same time, one ulp earlier: same period.
    hook(float(np.nextafter(DT, 0.0)), [1, 2], np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 3)))
    summ = hook.stats.totals()
    assert (summ.cycles, summ.vehicle_cycles, summ.interventions) == (2, 4, 1)
    assert summ.max_correction_mps2 == pytest.approx(2.0)
    assert "intervened 1/4" in str(summ)
    assert isinstance(hook.stats, SafetyStats)


def test_tuning_and_constructor_validation() -> None:
    with pytest.raises(ValueError, match="brake_fraction"):
        SafetyTuning(brake_fraction=0.0)
    with pytest.raises(ValueError, match="dt"):
        SafetyFilter(Limits(), Safety(), [], dt=0.0)
