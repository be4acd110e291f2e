"""Eq. 1 and the formation force (Eqs. 7-12): repulsion properties against a
naive reference, printed variants, and degenerate inputs."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gcs_swarm.control import Gains, Readings, formation_force
from gcs_swarm.control.formation import (
    R_MIN_M,
    eq1_acceleration,
    repulsion_force,
    sphere_attraction,
)


def _naive(p: np.ndarray, q: np.ndarray, k_r: float, q_twice: bool = False) -> np.ndarray:
    """Reference Eqs. 8-9 by broadcasting (N x N x 3): the slow obvious form."""
    d = p[:, None, :] - p[None, :, :]
    r = np.linalg.norm(d, axis=-1)
    np.fill_diagonal(r, np.inf)
    qi = q[:, None] if q_twice else q[None, :]
    return k_r * q[:, None] * np.sum((qi / r**3)[..., None] * d, axis=1)


positions = arrays(
    np.float64,
    st.tuples(st.integers(2, 12), st.just(3)),
    elements=st.floats(-100.0, 100.0, allow_nan=False),
)


@settings(max_examples=200, deadline=None)
@given(p=positions, seed=st.integers(0, 2**32 - 1))
def test_repulsion_matches_reference_and_sums_to_zero(p: np.ndarray, seed: int) -> None:
    rng = np.random.default_rng(seed)
    q = rng.uniform(0.5, 20.0, p.shape[0])
    r = np.linalg.norm(p[:, None] - p[None], axis=-1) + np.eye(p.shape[0]) * 1e9
    f = repulsion_force(p, q, 0.2)
    assert np.all(np.isfinite(f))
    if r.min() <= R_MIN_M:
        return  # clamped pairs: finiteness is the property (test_coincident_vehicles...)
    # Scale: the largest gross force sum_i k q_n q_i / r^2 on one vehicle. The
    # matrix form p_n (W q)_n - (W q p)_n cancels terms of size |p| / r^3, so
    # its rounding error relative to that scale is ~ eps |p| / r <= 2e-16 * 1.8e4
    # here: 1e-9 leaves a wide margin and still catches any real error. The
    # Gram form of r^2 (centred positions c) errs by ~8 eps (|c_n|^2 + |c_i|^2)
    # absolute, i.e. relatively 16 eps max|c|^2 / r^2 for a close pair far from
    # the centroid, and the force by 1.5 times that: allowed on top (3x margin).
    gross = float(np.max(0.2 * q[:, None] * q[None, :] / r**2 @ np.ones(len(q))))
    c2 = float(np.max(np.sum((p - p.mean(axis=0)) ** 2, axis=1)))
    gram = 3.0 * 1.5 * 16.0 * np.finfo(np.float64).eps * c2 / float(r.min()) ** 2
    np.testing.assert_allclose(f, _naive(p, q, 0.2), rtol=0, atol=(1e-9 + gram) * gross)
    # Newton's third law, summed: total repulsion ~ 0 (rounding only).
    assert np.all(np.abs(f.sum(axis=0)) <= 1e-9 * gross)


@settings(max_examples=200, deadline=None)
@given(a=st.tuples(*[st.floats(-50, 50)] * 3), b=st.tuples(*[st.floats(-50, 50)] * 3))
def test_pair_forces_are_equal_and_opposite(
    a: tuple[float, float, float], b: tuple[float, float, float]
) -> None:
    f = repulsion_force(np.array([a, b]), np.array([3.0, 7.0]), 0.2)
    # Equal and opposite to rounding: both rows share the one weight W_12, but
    # F_n = k q_n (p_n W q - W q p) rounds differently per row (few ulp).
    np.testing.assert_allclose(f[0], -f[1], rtol=0, atol=1e-12 * np.abs(f).max())


def test_eq10_printed_uses_q_n_twice() -> None:
    rng = np.random.default_rng(7)
    p, q = rng.normal(size=(8, 3)) * 5.0, rng.uniform(1.0, 10.0, 8)
    np.testing.assert_allclose(
        repulsion_force(p, q, 0.2, q_n_twice=True), _naive(p, q, 0.2, q_twice=True), rtol=1e-10
    )


def test_blocked_path_matches_reference_for_many_vehicles() -> None:
    rng = np.random.default_rng(11)
    p, q = rng.normal(size=(600, 3)) * 30.0, rng.uniform(1.0, 10.0, 600)  # > one block
    f = repulsion_force(p, q, 0.2)
    np.testing.assert_allclose(f, _naive(p, q, 0.2), rtol=1e-7, atol=1e-9 * np.abs(f).max())


def test_coincident_vehicles_are_finite() -> None:
    p = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [1.0, 2.0, 3.0 + 1e-9], [4.0, 0.0, 0.0]])
    f = repulsion_force(p, np.full(4, 10.0), 0.2)
    assert np.all(np.isfinite(f))
    # Below the clamp a pair pushes as k q q r / R_MIN^3: bounded by k q q / R_MIN^2.
    assert np.max(np.linalg.norm(f, axis=1)) < 0.2 * 100.0 * 3 / R_MIN_M**2
    f2 = formation_force(p, np.full(4, 10.0), np.array([1.0, 2.0, 3.0]), Gains(), Readings())
    assert np.all(np.isfinite(f2))  # a vehicle exactly at the leader is fine too


def test_single_and_empty_swarm() -> None:
    np.testing.assert_array_equal(repulsion_force(np.zeros((1, 3)), np.ones(1), 0.2), 0.0)
    assert repulsion_force(np.zeros((0, 3)), np.ones(0), 0.2).shape == (0, 3)


def test_sphere_attraction_and_variants() -> None:
    g = Gains(k_s=2.0, alpha=2.0)
    c = np.array([1.0, 1.0, 1.0])
    p = np.array([[3.0, 1.0, 1.0], [4.0, 1.0, 1.0], [1.0, 1.0, 1.0]])
    fs = sphere_attraction(p, c, g, Readings())
    # On the alpha-sphere: zero; outside: -k_s d (|d|^2 - alpha^2); centre: zero.
    np.testing.assert_allclose(fs, [[0.0, 0, 0], [-2.0 * 3 * 5, 0, 0], [0, 0, 0]])
    fs12 = sphere_attraction(p, c, g, Readings(eq12_printed=True))
    np.testing.assert_allclose(fs12[:2], [[-2.0 * 2 * 4, 0, 0], [-2.0 * 3 * 9, 0, 0]])
    q = np.ones(3)
    f11 = formation_force(p, q, c, g, Readings(eq11_printed=True), with_repulsion=False)
    np.testing.assert_allclose(f11, -fs)  # Eq. 11 literal flips Eq. 7's sign


def test_eq1_acceleration() -> None:
    g = Gains(M=2.0, D=1.0, k=9.0)
    a = eq1_acceleration(np.array([[10.0, 0.0, -4.0]]), np.array([[1.0, 0.5, 0.0]]), g)
    np.testing.assert_allclose(a, [[0.0, -2.5, -2.0]])
