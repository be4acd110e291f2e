"""The formation law in floats for a few vehicles (``formation_rows``)
against the readable reference, ``eq1_acceleration(formation_force(...))``,
on seeded random swarms in every reading."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from gcs_swarm.control import Gains, Readings
from gcs_swarm.control.formation import R_MIN_M, eq1_acceleration, formation_force
from gcs_swarm.control.formation_rows import SMALL_N, formation_accelerations
from gcs_swarm.control.law import law_accelerations
from gcs_swarm.control.obstacles import Ellipsoids
from gcs_swarm.control.params import LawConfig
from gcs_swarm.control.supervisor import Mode

READINGS = [
    Readings(eq10_printed=a, eq11_printed=b, eq12_printed=c)
    for a, b, c in itertools.product((False, True), repeat=3)
]


def _case(
    rng: np.random.Generator, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, Gains]:
    scale = 10.0 ** rng.uniform(-1.0, 2.5)
    pos = rng.normal(size=(n, 3)) * scale + rng.normal(size=3) * 10.0 * scale
    vel = rng.normal(size=(n, 3)) * rng.uniform(0.0, 5.0)
    q = rng.uniform(0.5, 20.0, n)
    centre = pos.mean(axis=0) + rng.normal(size=3) * scale if n else rng.normal(size=3)
    gains = Gains(
        M=rng.uniform(0.5, 3.0), D=rng.uniform(0.0, 3.0), k=rng.uniform(0.0, 20.0),
        k_s=rng.uniform(0.1, 3.0), k_r=rng.uniform(0.05, 2.0), alpha=rng.uniform(0.5, 5.0),
        time_scale=float(rng.choice([1.0, 1.0, 1.7, 3.0])),
    )  # fmt: skip
    return pos, vel, q, centre, gains


def _reference(pos, vel, q, centre, gains, rd):  # type: ignore[no-untyped-def]
    return eq1_acceleration(formation_force(pos, q, centre, gains, rd), vel, gains)


@pytest.mark.parametrize("rd", READINGS, ids=lambda r: f"{r.eq10_printed:d}{r.eq11_printed:d}"
                         f"{r.eq12_printed:d}")  # fmt: skip
def test_matches_the_reference_on_random_swarms(rd: Readings) -> None:
    # The repulsion's pair distances differ by rounding only: the reference takes
    # |p_n - p_i|^2 from a Gram product of centred positions c (absolute error
    # ~8 eps (|c_n|^2 + |c_i|^2)), this module from the differences (~2 eps r^2);
    # the pair term ~ r^-2 moves by 1.5 times the relative error. Allowed: that
    # bound x 3 of each vehicle's gross repulsion, plus 1e-13 of the sizes of
    # the other terms (Eq. 7 and Eq. 1 are the same operations: see below).
    rng = np.random.default_rng(20261203)
    eps = np.finfo(np.float64).eps
    for _ in range(400):
        n = int(rng.integers(0, SMALL_N + 4))
        pos, vel, q, centre, gains = _case(rng, n)
        got = formation_accelerations(pos, vel, q, centre, gains, rd)
        ref = _reference(pos, vel, q, centre, gains, rd)
        assert got.shape == ref.shape == (n, 3)
        if n < 2:
            np.testing.assert_array_equal(got, ref)
            continue
        d = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(n) * 1e150
        qi = np.ones(n) if rd.eq10_printed else q
        qn = q * q if rd.eq10_printed else q
        gross = gains.k_r * qn * (qi[None, :] / np.maximum(d, R_MIN_M) ** 2).sum(axis=1)
        c2 = float(np.max(np.sum((pos - pos.mean(axis=0)) ** 2, axis=1)))
        rel = 3.0 * 1.5 * 16.0 * eps * c2 / max(float(d.min()), R_MIN_M) ** 2 + 1e-13
        others = np.abs(ref).max() * gains.mass_scaled + np.abs(pos - centre).max() ** 3
        tol = (rel * gross + 1e-13 * others) / gains.mass_scaled
        np.testing.assert_array_less(np.abs(got - ref).max(axis=1), tol + 1e-300)


@pytest.mark.parametrize("rd", READINGS[:1] + READINGS[-1:], ids=["paper", "printed"])
def test_without_repulsion_it_is_the_reference_bit_for_bit(rd: Readings) -> None:
    # k_r = 0: Eq. 7, Eqs. 11-12 and Eq. 1 alone, the reference's operations in its order.
    rng = np.random.default_rng(7)
    for _ in range(400):
        pos, vel, q, centre, gains = _case(rng, int(rng.integers(1, SMALL_N)))
        gains = Gains(M=gains.M, D=gains.D, k=gains.k, k_s=gains.k_s, k_r=0.0,
                      alpha=gains.alpha, time_scale=gains.time_scale)  # fmt: skip
        np.testing.assert_array_equal(
            formation_accelerations(pos, vel, q, centre, gains, rd),
            _reference(pos, vel, q, centre, gains, rd),
        )


def test_coincident_vehicles_are_clamped_as_in_the_reference() -> None:
    rng = np.random.default_rng(3)
    gains, rd = Gains(), Readings()
    pos = rng.normal(size=(5, 3))
    pos[3] = pos[1]
    pos[4] = pos[1] + 1e-4  # closer than R_MIN_M
    vel, q, centre = rng.normal(size=(5, 3)), np.full(5, 10.0), np.zeros(3)
    got = formation_accelerations(pos, vel, q, centre, gains, rd)
    assert np.isfinite(got).all()
    np.testing.assert_allclose(got, _reference(pos, vel, q, centre, gains, rd), rtol=1e-9)


def test_law_accelerations_flies_formation_through_it_below_small_n() -> None:
    rng = np.random.default_rng(11)
    config = LawConfig()
    for n in (1, 2, 6, SMALL_N - 1, SMALL_N, SMALL_N + 3):
        pos, vel = rng.normal(size=(n, 3)) * 3.0, rng.normal(size=(n, 3))
        q, lead = np.full(n, 10.0), rng.normal(size=3)
        empty = np.zeros((n, 0))
        mode = Mode("formation", 0, tuple(range(n)), None, empty.astype(bool), empty, empty, True)
        got = law_accelerations(config, mode, pos, vel, q, lead, Ellipsoids.from_boxes(()))
        fast = formation_accelerations(pos, vel, q, lead, config.gains, config.readings)
        ref = _reference(pos, vel, q, lead, config.gains, config.readings)
        np.testing.assert_array_equal(got, fast if n < SMALL_N else ref)
