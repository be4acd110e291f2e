"""``ControlLoop``'s minimum separation (``loop._min_separation``): from
``_GRAM_FROM_N`` vehicles it searches candidates with an augmented Gram
product, from ``_CELLS_FROM_N`` on a cell list, and must still give exactly
the float of the direct all-pairs minimum, on spread, jittered, tied (exact
grids), clustered, coincident and far-off swarms."""

from __future__ import annotations

import math

import numpy as np

from gcs_swarm.control.formation_rows import SMALL_N
from gcs_swarm.control.loop import (
    _CELLS_FROM_N,
    _GRAM_FROM_N,
    _min_separation,
    _min_separation_cells,
)


def _direct(pos: np.ndarray) -> float:
    d = pos[:, None, :] - pos[None, :, :]
    d2 = np.einsum("ijk,ijk->ij", d, d)
    np.fill_diagonal(d2, np.inf)
    return math.sqrt(float(d2.min()))


def _grid(n: int, step: float) -> np.ndarray:
    side = math.ceil(n ** (1 / 3))
    i = np.arange(n)
    return step * np.stack([i % side, (i // side) % side, i // (side * side)], axis=1).astype(float)


def test_the_gram_search_gives_the_direct_minimum_bit_for_bit() -> None:
    rng = np.random.default_rng(16)
    cases = []
    for n in (_GRAM_FROM_N, 100, 250, _CELLS_FROM_N, 700):
        cases.append(rng.uniform(-50, 50, (n, 3)))
        cases.append(_grid(n, 3.0))  # every nearest pair tied
        cases.append(_grid(n, 3.0) + rng.normal(0, 0.3, (n, 3)))
        cases.append(_grid(n, 0.1) + 1.0e5)  # far from the origin: rounding matters
        pts = rng.normal(0, 20, (n, 3))
        pts[n // 2] = pts[n // 3] + rng.normal(0, 1e-7, 3)  # one pair nearly on top
        cases.append(pts)
        cases.append(np.repeat(rng.normal(0, 5, (n // 4 + 1, 3)), 4, axis=0)[:n])  # zeros
    for pos in cases:
        assert _min_separation(pos) == _direct(pos)


def test_a_sphere_and_a_clump_on_the_cell_list_give_the_direct_minimum() -> None:
    """A formation's shape (a sphere shell: the probes' bound is the spacing),
    and a clump whose probes all fly far apart from it and from each other
    (their bound, 100 m, takes in every pair of the clump: the cells would
    test most pairs, and the Gram product takes over)."""
    rng = np.random.default_rng(19)
    n = _CELLS_FROM_N + 50
    shell = rng.normal(size=(n, 3))
    shell *= 12.0 / np.linalg.norm(shell, axis=1)[:, None]
    clump = rng.normal(0, 0.5, (n, 3))
    probes = np.arange(0, n, n // 8)[:8]  # the rows _min_separation_cells probes
    clump[probes] = 100.0 * np.arange(1, 9)[:, None] * np.array([1.0, 0.0, 0.0])
    assert _min_separation_cells(shell) is not None  # the cells answered
    assert _min_separation_cells(clump) is None  # the Gram product did
    for pos in (shell, clump):
        assert _min_separation(pos) == _direct(pos)


def test_a_few_vehicles_in_floats_give_the_direct_minimum_bit_for_bit() -> None:
    """Below ``SMALL_N`` the search runs pair by pair in Python floats;
    it must give the direct search's float (its squares summed in einsum's
    order), also far from the origin, with ties and coincident vehicles, and
    NaN where a position is NaN, as numpy gives."""
    rng = np.random.default_rng(61)
    for n in range(2, SMALL_N):
        for scale, offset in ((1e-3, 0.0), (1.0, 0.0), (50.0, 3.0), (0.1, 1.0e5)):
            for _ in range(200):
                pos = rng.normal(0.0, scale, (n, 3)) + offset
                assert _min_separation(pos) == _direct(pos)
        grid = _grid(n, 3.0)  # tied pairs
        assert _min_separation(grid) == _direct(grid) == 3.0
        same = np.repeat(rng.normal(0.0, 5.0, (1, 3)), n, axis=0)  # all on one point
        assert _min_separation(same) == _direct(same) == 0.0
        bad = rng.normal(0.0, 5.0, (n, 3))
        bad[n - 1, 1] = math.nan
        assert math.isnan(_min_separation(bad)) and math.isnan(_direct(bad))
