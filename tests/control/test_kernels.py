"""The compiled pair loop of the cut-off law (``control.kernels``) gives
the numpy path's floats bit for bit: ``NeighbourList.row_repulsion`` against
``cutoff.row_repulsion`` of ``NeighbourList.row_pairs``' pairs, the path it
replaced in a step of rows (docs/formation-law.md sections 3a-3b, Eq. 9c).
Equality, not a tolerance: the kernel takes each term's expression in the
same order and sums a row's terms in the order ``np.bincount`` does."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from numba import njit

from gcs_swarm.control.cutoff import _HALF_SHELL, _cells, _rank_pairs, row_repulsion
from gcs_swarm.control.formation import R_MIN_M, repulsion_rows
from gcs_swarm.control.kernels import (
    compiled,
    listed_near_min,
    listed_repulsion_sums,
    rank_pair_indices,
)
from gcs_swarm.control.neighbours import NeighbourList


def _ball(n: int, seed: int, spread: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(-spread, spread, (n, 3)), rng.uniform(5.0, 15.0, n)


def _numpy_path(nl: NeighbourList, pos: np.ndarray, rows: np.ndarray, q: np.ndarray,
                twice: bool, r_min: float) -> np.ndarray:  # fmt: skip
    pairs = nl.row_pairs(pos, rows, key="ids")
    return row_repulsion(pairs, rows, q, 0.2, q_n_twice=twice, r_min_m=r_min)


@pytest.mark.parametrize("n", [40, 300, 1500])
@pytest.mark.parametrize("twice", [False, True])
def test_the_compiled_rows_are_the_numpy_rows_bit_for_bit(n: int, twice: bool) -> None:
    pos, q = _ball(n, n, spread=0.6 * n ** (1 / 3))
    rng = np.random.default_rng(n + 1)
    nl = NeighbourList(1.5)
    for step in range(12):  # every network of six in turn, the swarm moving
        rows = np.arange(step % 6, n, 6, dtype=np.int64)
        want = _numpy_path(nl, pos, rows, q, twice, R_MIN_M)
        got = nl.row_repulsion(pos, rows, "ids", q, 0.2, q_n_twice=twice, r_min_m=R_MIN_M)
        assert got.shape == (len(rows), 3)
        assert np.array_equal(got, want)
        assert np.abs(got).max() > 0.0  # there were pairs to sum
        pos = pos + rng.normal(0.0, 0.05, pos.shape)
    assert nl.builds + nl.ahead >= 2  # the lists were replaced on the way


def test_the_clamp_and_a_vehicle_without_neighbours_are_the_numpy_path_s() -> None:
    """Pairs closer than ``r_min`` (the clamp, Eq. 9 below R_MIN_M), coincident
    vehicles (zero force), and a row with no pair within the cut-off."""
    pos, q = _ball(60, 5, spread=2.0)
    pos[1] = pos[0] + [0.003, 0.0, 0.0]  # within the clamp
    pos[2] = pos[0]  # coincident
    pos[3] = [50.0, 50.0, 50.0]  # alone
    rows = np.array([0, 1, 2, 3, 10], dtype=np.int64)
    nl = NeighbourList(1.2)
    for r_min in (R_MIN_M, 0.5):
        want = _numpy_path(nl, pos, rows, q, False, r_min)
        got = nl.row_repulsion(pos, rows, "ids", q, 0.2, q_n_twice=False, r_min_m=r_min)
        assert np.array_equal(got, want)
        assert np.array_equal(got[3], [0.0, 0.0, 0.0])
        assert np.all(np.isfinite(got))


def test_two_vehicles_by_hand() -> None:
    """Eq. 9c for a pair 2 m apart on x: each sums q_j d / r^3 = 5 * 2 / 8;
    with ``q_n_twice`` the q_j stays out; beyond the cut-off nothing."""
    pos = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    start = np.array([0, 1, 2], dtype=np.int64)  # each the other's candidate
    other = np.array([1, 0], dtype=np.int64)
    q = np.array([5.0, 5.0])
    rows = np.array([0, 1], dtype=np.int64)
    got = listed_repulsion_sums(pos, rows, start, other, q, 3.0, q_n_twice=False, r_min_m=0.01)
    assert np.array_equal(got, [[-1.25, 0.0, 0.0], [1.25, 0.0, 0.0]])
    got = listed_repulsion_sums(pos, rows, start, other, q, 3.0, q_n_twice=True, r_min_m=0.01)
    assert np.array_equal(got, [[-0.25, 0.0, 0.0], [0.25, 0.0, 0.0]])
    got = listed_repulsion_sums(pos, rows, start, other, q, 1.9, q_n_twice=False, r_min_m=0.01)
    assert np.array_equal(got, np.zeros((2, 3)))
    empty = listed_repulsion_sums(pos, rows[:0], start, other, q, 3.0, q_n_twice=False,
                                  r_min_m=0.01)  # fmt: skip
    assert empty.shape == (0, 3)


def test_the_law_s_rows_through_the_list_are_the_cells_rows_to_rounding() -> None:
    """``repulsion_rows`` with the list's ``forces_of`` against the cell
    list's pairs (another summation order: rounding only)."""
    pos, q = _ball(400, 11)
    rows = np.arange(0, 400, 3, dtype=np.int64)
    nl = NeighbourList(1.7)

    def forces_of(p, at, qq, k_r, twice, r_min):  # type: ignore[no-untyped-def]
        return nl.row_repulsion(p, at, "ids", qq, k_r, q_n_twice=twice, r_min_m=r_min)

    cells = repulsion_rows(pos, rows, q, 0.2, cutoff_m=1.7)
    listed = repulsion_rows(pos, rows, q, 0.2, cutoff_m=1.7, forces_of=forces_of)
    np.testing.assert_allclose(listed, cells, rtol=0, atol=1e-12 * np.abs(cells).max())


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_nearest_listed_pairs_are_numpy_s(seed: int) -> None:
    """``listed_near_min``: numpy's ``flatnonzero(r2 <= r2.min() (1 + rel))``
    over the same pairs, ties included; none when a position is NaN."""
    pos, _ = _ball(500, seed)
    rng = np.random.default_rng(seed)
    i = rng.integers(0, 500, 4000)
    j = (i + rng.integers(1, 500, 4000)) % 500
    pos[j[7]] = pos[i[7]] + [0.01, 0.0, 0.0]  # a nearest pair
    pos[j[99]] = pos[i[99]] + [0.0, 0.0, -0.01]  # and its tie
    d = pos[i] - pos[j]
    r2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
    for rel in (0.0, 1e-9, 0.5):
        want = np.flatnonzero(r2 <= r2.min() * (1.0 + rel))
        assert np.array_equal(listed_near_min(pos, i, j, rel), want)
    assert len(listed_near_min(pos, i, j, 1e-9)) >= 2
    pos[3] = np.nan
    assert listed_near_min(pos, i, j, 1e-9).size == 0
    assert listed_near_min(pos, i[:0], j[:0], 1e-9).size == 0


def test_a_kernel_without_a_place_for_its_cache_is_compiled_all_the_same() -> None:
    """``compiled`` where numba finds nowhere to cache (here: source with no
    file, as an unwritable install has no cache place): numba refuses
    ``cache=True``; the kernel is compiled without its cache and works."""
    namespace: dict[str, object] = {}
    code = compile("def twice(x):\n    return 2.0 * x\n", "<no file>", "exec")
    exec(code, namespace)  # a function whose source file does not exist
    with pytest.raises(RuntimeError, match="cannot cache"):
        njit("float64(float64)", cache=True)(namespace["twice"])
    kernel = compiled("float64(float64)")(namespace["twice"])
    assert kernel(1.5) == 3.0


def _sorted_cells(pos: np.ndarray, side: float):  # type: ignore[no-untyped-def]
    c = _cells(pos, side)
    return c, np.ascontiguousarray(pos[c.order].T), _HALF_SHELL @ c.stride


@pytest.mark.parametrize(
    ("n", "spread", "sparse"),
    [(64, 2.0, False), (300, 4.0, False), (1500, 7.0, False), (400, 4.0, True)],
)
def test_the_compiled_rank_pairs_are_numpy_s_in_its_order(n: int, spread: float,
                                                          sparse: bool) -> None:  # fmt: skip
    """``kernels.rank_pair_indices`` against ``cutoff._rank_pairs``: the same
    index arrays, element for element, over the whole range and over the six
    slices the Verlet list searches (their concatenation is the whole), on
    a compact swarm (the cells' table) and a sparse one (binary searches)."""
    pos = np.random.default_rng(n).uniform(-spread, spread, (n, 3))
    if sparse:  # a few far away: more than 32 cells a vehicle, no table
        pos[: n // 10] *= 400.0
    side = 1.3
    c, xyz, shell = _sorted_cells(pos, side)
    assert (c.start is None) == sparse
    want = _rank_pairs(c, xyz, 0, n, side * side)
    assert want is not None and want[0].size > n  # pairs to find
    i, j = rank_pair_indices(c.skey, c.start, shell, c.order, xyz, 0, n, side * side)
    assert np.array_equal(i, want[0]) and np.array_equal(j, want[1])
    cuts = list(itertools.pairwise([min(n, k * -(-n // 6)) for k in range(7)]))
    found = []
    for lo, hi in cuts:
        pi, pj = rank_pair_indices(c.skey, c.start, shell, c.order, xyz, lo, hi, side * side)
        ref = _rank_pairs(c, xyz, lo, hi, side * side)
        assert ref is not None
        assert np.array_equal(pi, ref[0]) and np.array_equal(pj, ref[1])
        found += zip(pi.tolist(), pj.tolist(), strict=True)
    assert sorted(found) == sorted(zip(i.tolist(), j.tolist(), strict=True))  # the slices: all


def test_a_pair_on_the_cut_off_is_left_out_as_numpy_leaves_it() -> None:
    """Exactly at the radius (``r2 == rc2``) is not closer: both leave it out."""
    pos = np.zeros((70, 3))
    pos[:, 0] = np.arange(70) * 10.0  # far apart: no pair but the next
    pos[1] = [1.0, 0.0, 0.0]  # exactly 1 m from vehicle 0
    pos[2] = [0.0, 0.5, 0.0]  # within
    c, xyz, shell = _sorted_cells(pos, 1.0)
    i, j = rank_pair_indices(c.skey, c.start, shell, c.order, xyz, 0, 70, 1.0)
    ref = _rank_pairs(c, xyz, 0, 70, 1.0)
    assert ref is not None
    assert np.array_equal(i, ref[0]) and np.array_equal(j, ref[1])
    assert sorted(zip(np.minimum(i, j).tolist(), np.maximum(i, j).tolist(),
                      strict=True)) == [(0, 2)]  # fmt: skip
