"""The repulsion with a cut-off radius (Eq. 9c, docs/formation-law.md section
3a; ``gcs_swarm.control.cutoff``) against a readable O(N^2) reference with
the same cut-off, and against the exact law when the cut-off is beyond every
distance. Seeded swarms (``numpy.random.default_rng``), no timing.

Tolerances, per vehicle n, relative to ``S_n = sum_i |F_ni|`` (the sum of
the sizes of its pair terms, so that a sum which cancels is not held to a
tighter bound than its terms allow):

- cell list against the reference with the same cut-off: the same pairs and
  the same pair terms summed in another order, so ``4 (N + 2) eps S_n``
  (eps = 2.2e-16; a few rounding errors per term, N terms).
- the exact sum (and its blocks masked at r_c, which ``repulsion_force``
  takes for a clump) against the reference: the exact sum takes
  ``|p_n - p_i|^2`` from a Gram product of the centred positions, whose
  cancellation error is about ``eps R^2`` (R the largest distance from the
  centroid) against the direct difference's ``eps r^2``; the pair term is
  then off by ``~3 eps (R / r)^2`` relatively, hence the bound
  ``(N + 8 (R / r_min)^2) 4 eps S_n``.
- a cut-off beyond every distance: from ``ALL_PAIRS_BELOW`` vehicles on every
  pair is a candidate, so the exact blocks run with nothing masked: the
  result is the exact law bit for bit. Below it the pairs are tested
  directly (the bound above). Below ``SMALL_N`` the law's float path
  (``formation_rows``) skips pairs on the same test and does the same
  arithmetic otherwise: bit-identical too.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from gcs_swarm.control.cutoff import ALL_PAIRS_BELOW, DENSE_SHARE, neighbour_pairs, pair_repulsion
from gcs_swarm.control.formation import R_MIN_M, formation_force, repulsion_force
from gcs_swarm.control.formation_rows import SMALL_N, formation_accelerations
from gcs_swarm.control.law import law_accelerations
from gcs_swarm.control.obstacles import Ellipsoids
from gcs_swarm.control.params import Gains, LawConfig, Readings
from gcs_swarm.control.supervisor import Mode

EPS = float(np.finfo(np.float64).eps)


def reference(
    pos: np.ndarray, q: np.ndarray, k_r: float, cutoff: float, *, twice: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 9c the readable way, O(N^2): for every vehicle, every other one
    closer than ``cutoff``. Returns the force ``(N, 3)`` and ``S_n (N,)``."""
    n = len(pos)
    out = np.zeros((n, 3))
    size = np.zeros(n)
    for a in range(n):
        d = pos[a] - pos  # (N, 3), p_n - p_i
        r2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
        keep = r2 < cutoff * cutoff
        keep[a] = False
        r2c = np.maximum(r2[keep], R_MIN_M * R_MIN_M)
        qq = q[a] * q[a] if twice else q[a] * q[keep]
        terms = (k_r * qq / (r2c * np.sqrt(r2c)))[:, None] * d[keep]
        out[a] = terms.sum(axis=0)
        size[a] = np.linalg.norm(terms, axis=1).sum()
    return out, size


def swarm(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, float]:
    """A random swarm: positions ``(N, 3)`` [m], charges, a cut-off [m].
    Spread, offset, charges and cut-off vary; some swarms are clumps (every
    vehicle in one cell) or hold coincident vehicles."""
    n = int(rng.integers(2, 150))
    scale = float(rng.choice([0.2, 1.0, 3.0, 10.0]))
    pos = rng.normal(size=(n, 3)) * scale + rng.uniform(-1000.0, 1000.0, size=3)
    if rng.random() < 0.2:  # a few coincident vehicles (r = 0: the clamp)
        k = int(rng.integers(1, n))
        pos[:k] = pos[rng.integers(0, n, size=k)]
    q = rng.uniform(0.5, 20.0, size=n)
    cutoff = float(rng.uniform(0.05, 3.0)) * scale * float(rng.choice([0.5, 1.0, 4.0]))
    return pos, q, cutoff


def gram_bound(
    pos: np.ndarray,
    size: np.ndarray,
    q: np.ndarray | None = None,
    cutoff: float = math.inf,
    *,
    twice: bool = False,
) -> np.ndarray:
    """The exact sum's rounding bound per vehicle (module docstring); with
    ``q``, also that of its two sums ``p_n sum_i w q_i - sum_i w q_i p_i``
    (centred p), which do not cancel exactly where a pair's term is zero
    but its weight is not (coincident vehicles, w = 1 / R_MIN_M^3)."""
    n = len(pos)
    c = pos - pos.mean(axis=0)
    r_far = float(np.linalg.norm(c, axis=1).max())
    d2 = ((pos[:, None] - pos[None]) ** 2).sum(axis=-1)
    np.fill_diagonal(d2, np.inf)
    r_min = max(float(np.sqrt(d2.min())), R_MIN_M)
    out = (n + 8 * (r_far / r_min) ** 2) * 4 * EPS * size
    if q is not None:
        w = np.where(d2 < cutoff * cutoff, np.maximum(d2, R_MIN_M**2) ** -1.5, 0.0)
        qq = np.outer(q, np.ones(n)) * q[:, None] if twice else np.outer(q, q)
        norm = np.linalg.norm(c, axis=1)
        out = out + 4 * (n + 2) * EPS * 0.2 * (qq * w * (norm[:, None] + norm[None])).sum(axis=1)
    return np.asarray(out)


@pytest.mark.parametrize("seed", range(60))
def test_cell_list_matches_the_all_pairs_reference_with_the_same_cut_off(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pos, q, cutoff = swarm(rng)
    twice = seed % 5 == 0  # Eq. 10 as printed on some
    pairs = neighbour_pairs(pos, cutoff)
    assert pairs is not None
    got = pair_repulsion(pairs, q, 0.2, q_n_twice=twice, r_min_m=R_MIN_M)
    want, size = reference(pos, q, 0.2, cutoff, twice=twice)
    n = len(pos)
    err = np.abs(got - want).max(axis=1)
    assert (err <= 4 * (n + 2) * EPS * size).all(), (err / np.maximum(size, 1e-300)).max()
    # and the law's entry point, by the cell list or (a clump) the masked blocks
    law = repulsion_force(pos, q, 0.2, q_n_twice=twice, cutoff_m=cutoff)
    bound = gram_bound(pos, size, q, cutoff, twice=twice)
    assert (np.abs(law - want).max(axis=1) <= bound).all()


@pytest.mark.parametrize("n", [64, 300, 1000])
def test_a_clump_takes_the_exact_sums_blocks_masked(n: int) -> None:
    """Every vehicle within r_c of the others: the cell list would test all
    the pairs one by one, so the candidates exceed DENSE_SHARE and the
    blocked sum runs with the far pairs zeroed; the same forces."""
    rng = np.random.default_rng(n)
    pos = rng.normal(size=(n, 3)) * 0.3 + 50.0
    q = rng.uniform(1.0, 10.0, size=n)
    cutoff = 1.0  # most pairs inside, some (the tails) outside
    most = int(DENSE_SHARE * (n * (n - 1) // 2))
    assert neighbour_pairs(pos, cutoff, max_candidates=most) is None
    got = repulsion_force(pos, q, 0.2, cutoff_m=cutoff)
    want, size = reference(pos, q, 0.2, cutoff)
    assert (np.abs(got - want).max(axis=1) <= gram_bound(pos, size, q, cutoff)).all()
    exact = repulsion_force(pos, q, 0.2)
    assert not np.array_equal(got, exact)  # some pairs were dropped


@pytest.mark.parametrize("seed", range(20))
def test_the_pairs_are_exactly_those_closer_than_the_cut_off(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    pos, _, cutoff = swarm(rng)
    pairs = neighbour_pairs(pos, cutoff)
    assert pairs is not None
    i, j, d, r2 = pairs
    got = {(min(a, b), max(a, b)) for a, b in zip(i.tolist(), j.tolist(), strict=True)}
    assert len(got) == len(i)  # each pair once
    a, b = np.triu_indices(len(pos), k=1)
    dd = pos[a] - pos[b]
    near = dd[:, 0] * dd[:, 0] + dd[:, 1] * dd[:, 1] + dd[:, 2] * dd[:, 2] < cutoff * cutoff
    assert got == set(zip(a[near].tolist(), b[near].tolist(), strict=True))
    np.testing.assert_array_equal(d, pos[i] - pos[j])
    np.testing.assert_array_equal(r2, (d * d).sum(axis=1))


def test_a_pair_at_exactly_the_cut_off_is_dropped_on_both_paths() -> None:
    pos = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 0.5, 0.0]])
    q = np.full(3, 10.0)
    got = repulsion_force(pos, q, 0.2, cutoff_m=1.0)
    want, _ = reference(pos, q, 0.2, 1.0)
    np.testing.assert_allclose(got, want, rtol=1e-15)
    pairs = neighbour_pairs(pos, 1.0)
    assert pairs is not None
    i, j, _, _ = pairs
    pairs = {(min(a, b), max(a, b)) for a, b in zip(i.tolist(), j.tolist(), strict=True)}
    assert pairs == {(0, 2), (1, 2)}  # not (0, 1), at r = r_c exactly
    # vehicle 0 feels vehicle 2 alone: straight away from it
    np.testing.assert_allclose(got[0], 0.2 * 100 * (pos[0] - pos[2]) / 0.5**1.5, rtol=1e-15)
    g = Gains(repulsion_cutoff=1.0)
    rows = formation_accelerations(pos, np.zeros((3, 3)), q, np.zeros(3), g, Readings())
    vec = formation_force(pos, q, np.zeros(3), g, Readings())
    np.testing.assert_allclose(rows, vec, rtol=1e-14, atol=1e-14)


def test_a_swarm_wider_than_the_cell_limit_gets_larger_cells_and_the_same_pairs() -> None:
    rng = np.random.default_rng(7)
    centres = np.array([[-90_000.0, 0.0, 0.0], [90_000.0, 5_000.0, -100.0]])
    pos = np.concatenate([c + rng.normal(size=(30, 3)) * 0.05 for c in centres])
    q = np.full(60, 10.0)
    cutoff = 0.06  # span / cutoff = 3e6 cells > 2^20: cells of span / 2^20
    got = repulsion_force(pos, q, 0.2, cutoff_m=cutoff)
    want, size = reference(pos, q, 0.2, cutoff)
    assert (np.abs(got - want).max(axis=1) <= 4 * 62 * EPS * size).all()
    assert (size > 0).any()


def test_no_pair_within_the_cut_off_gives_zero_and_tiny_swarms_are_fine() -> None:
    pos = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    assert not repulsion_force(pos, np.ones(2), 0.2, cutoff_m=1.0).any()
    assert repulsion_force(pos[:1], np.ones(1), 0.2, cutoff_m=1.0).shape == (1, 3)
    assert repulsion_force(np.zeros((0, 3)), np.ones(0), 0.2, cutoff_m=1.0).shape == (0, 3)


def test_coincident_vehicles_give_finite_zero_forces() -> None:
    pos = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [1.0, 2.0, 3.5]])
    f = repulsion_force(pos, np.full(3, 10.0), 0.2, cutoff_m=2.0)
    assert np.isfinite(f).all()
    want, _ = reference(pos, np.full(3, 10.0), 0.2, 2.0)
    np.testing.assert_allclose(f, want, rtol=1e-14)


def test_pair_forces_are_equal_and_opposite() -> None:
    rng = np.random.default_rng(3)
    pos = rng.normal(size=(300, 3)) * 4.0
    q = np.full(300, 10.0)
    f = repulsion_force(pos, q, 0.2, cutoff_m=2.0)
    _, size = reference(pos, q, 0.2, 2.0)
    assert np.abs(f.sum(axis=0)).max() <= 300 * 4 * EPS * size.sum()


@pytest.mark.parametrize("seed", range(20))
def test_a_cut_off_beyond_every_distance_is_the_exact_law(seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    n = int(rng.integers(SMALL_N, 250)) if seed % 2 else int(rng.integers(SMALL_N, ALL_PAIRS_BELOW))
    pos = rng.normal(size=(n, 3)) * float(rng.uniform(0.5, 20.0)) + rng.uniform(-50, 50, 3)
    q = rng.uniform(1.0, 10.0, size=n)
    span = float(np.linalg.norm(pos.max(axis=0) - pos.min(axis=0)))
    for cutoff in (1.01 * span, 1e5):
        got = repulsion_force(pos, q, 0.2, cutoff_m=cutoff)
        exact = repulsion_force(pos, q, 0.2)
        pairs = neighbour_pairs(pos, cutoff)
        assert pairs is not None and len(pairs[0]) == n * (n - 1) // 2
        if n >= ALL_PAIRS_BELOW:  # every pair a candidate: the exact blocks, nothing masked
            np.testing.assert_array_equal(got, exact)
        else:  # every pair tested directly: the same terms, rounded differently
            _, size = reference(pos, q, 0.2, math.inf)
            assert (np.abs(got - exact).max(axis=1) <= gram_bound(pos, size)).all()


@pytest.mark.parametrize("seed", range(10))
def test_below_small_n_a_cut_off_beyond_every_distance_is_bit_identical(seed: int) -> None:
    rng = np.random.default_rng(300 + seed)
    n = int(rng.integers(2, SMALL_N))
    pos = rng.normal(size=(n, 3)) * 3.0
    vel = rng.normal(size=(n, 3))
    q = rng.uniform(1.0, 10.0, size=n)
    centre = rng.normal(size=3)
    rd = Readings(eq10_printed=bool(seed % 2))
    exact = formation_accelerations(pos, vel, q, centre, Gains(), rd)
    far = formation_accelerations(pos, vel, q, centre, Gains(repulsion_cutoff=1e5), rd)
    np.testing.assert_array_equal(far, exact)


@pytest.mark.parametrize("n", [3, 6, 9, 10, 40, 100])
def test_the_law_applies_the_cut_off_on_both_of_its_paths(n: int) -> None:
    """``law_accelerations`` takes the float rows below SMALL_N and the
    vectorised path from it on (every pair tested below ALL_PAIRS_BELOW, the
    cell list from it): all give Eq. 1 of Eq. 9c with the same pairs."""
    rng = np.random.default_rng(n)
    pos = rng.normal(size=(n, 3)) * 2.0
    vel = rng.normal(size=(n, 3))
    q = np.full(n, 10.0)
    g = Gains(repulsion_cutoff=2.5)
    cfg = LawConfig(gains=g)
    obs = Ellipsoids.from_boxes(())
    got = law_accelerations(cfg, Mode.formation(tuple(range(n))), pos, vel, q, np.zeros(3), obs)
    rep, size = reference(pos, q, g.k_r, 2.5)
    fs = formation_force(pos, q, np.zeros(3), g, Readings(), with_repulsion=False)
    want = (fs + rep - g.damping_scaled * vel) / g.mass_scaled
    scale = size + np.abs(fs).sum(axis=1) + g.damping_scaled * np.abs(vel).sum(axis=1)
    bound = 4 * (n + 8) * EPS * scale + gram_bound(pos, size, q, 2.5)  # N = 100: a clump
    assert (np.abs(got - want).max(axis=1) <= bound).all()
    exact = law_accelerations(
        LawConfig(), Mode.formation(tuple(range(n))), pos, vel, q, np.zeros(3), obs
    )
    assert not np.array_equal(got, exact)  # the cut-off did drop some pairs


def _even_sphere(n: int, radius_m: float) -> np.ndarray:
    """N points spread evenly on a sphere (a Fibonacci lattice), ``(N, 3)`` [m]."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5**0.5) * k
    s = np.sqrt(1.0 - z * z)
    return radius_m * np.stack((s * np.cos(phi), s * np.sin(phi), z), axis=1)


@pytest.mark.parametrize("n", [500, 1000])
def test_on_a_charged_sphere_the_cut_off_keeps_about_rc_over_2r_of_the_outward_push(
    n: int,
) -> None:
    """Section 3a's shell model: on a uniformly charged sphere of radius R the
    vehicles within chord r_c give r_c / 2R of the outward push. On N point
    charges the near field has a hole of about one neighbour distance, so the
    share kept lies between (r_c - d_nn) / 2R and r_c / 2R; and the exact
    push is the continuum's k_r q^2 N / (2 R^2) within 5 %."""
    radius = 6.0
    pos = _even_sphere(n, radius)
    q = np.full(n, 10.0)
    u = pos / radius
    d2 = ((pos[:, None] - pos[None]) ** 2).sum(axis=-1)
    np.fill_diagonal(d2, np.inf)
    d_nn = float(np.sqrt(d2.min(axis=1)).mean())
    exact = float((repulsion_force(pos, q, 0.2) * u).sum(axis=1).mean())
    assert exact == pytest.approx(0.2 * 100 * n / (2 * radius**2), rel=0.05)
    for factor in (2.0, 3.0, 5.0, 8.0):
        rc = factor * d_nn
        kept = float((repulsion_force(pos, q, 0.2, cutoff_m=rc) * u).sum(axis=1).mean())
        assert (rc - d_nn) / (2 * radius) < kept / exact < rc / (2 * radius)


def test_avoidance_with_repulsion_takes_the_cut_off_too() -> None:
    """With ``repulsion_in_avoidance`` (Mode.repulsion) Eq. 9c is added to
    Eq. 27's force: the law with and without the cut-off differ by exactly
    the repulsion the cut-off drops (over M)."""
    n = 80
    rng = np.random.default_rng(5)
    pos = rng.normal(size=(n, 3)) * 3.0
    vel = rng.normal(size=(n, 3))
    q = np.full(n, 10.0)
    mode = Mode(
        behaviour="avoidance",
        episode=1,
        ids=tuple(range(n)),
        targets_m=pos + 5.0,
        vertical=np.zeros((n, 0), dtype=bool),
        sense_h=np.ones((n, 0)),
        sense_v=np.ones((n, 0)),
        repulsion=True,
    )
    obs = Ellipsoids.from_boxes(())
    g = Gains(repulsion_cutoff=2.0)
    cut = law_accelerations(LawConfig(gains=g), mode, pos, vel, q, np.zeros(3), obs)
    exact = law_accelerations(LawConfig(), mode, pos, vel, q, np.zeros(3), obs)
    rep_cut, _ = reference(pos, q, g.k_r, 2.0)
    rep_all, size = reference(pos, q, g.k_r, math.inf)
    # the exact sum's Gram rounding (module docstring), |f_des| = F_D = 10 N, (D + k) |v|
    d2 = ((pos[:, None] - pos[None]) ** 2).sum(axis=-1)
    np.fill_diagonal(d2, np.inf)
    spread = (np.linalg.norm(pos - pos.mean(axis=0), axis=1).max() ** 2) / d2.min()
    tol = (n + 8 * spread) * 4 * EPS * (size + 10.0 + 10.0 * np.abs(vel).sum(axis=1))
    assert (np.abs((cut - exact) - (rep_cut - rep_all) / g.M).max(axis=1) <= tol).all()
    assert not np.array_equal(cut, exact)
