"""``ControlLoop``'s minimum separation (``loop._min_separation``): from
``_GRAM_FROM_N`` vehicles it searches candidates with an augmented Gram
product, and must still give exactly the float of the direct all-pairs
minimum, on spread, jittered, tied (exact grids), clustered and far-off
swarms."""

from __future__ import annotations

import math

import numpy as np

from gcs_swarm.control.loop import _GRAM_FROM_N, _min_separation


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
    for n in (_GRAM_FROM_N, 100, 250, 400):
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
