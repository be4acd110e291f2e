"""The vehicle model (Eq. 1) and the formation force (Eqs. 7-12), vectorised over vehicles.

Shapes: ``pos_m``/``vel_mps`` are ``(N, 3)`` float64 arrays in the mission
frame (x east, y north, z up); ``charges`` is ``(N,)``; forces are newtons,
accelerations m/s^2. Every printed-variant switch is read from
``gcs_swarm.control.params.Readings``.

The all-pairs repulsion (Eqs. 8-9) never builds an ``N x N x 3`` array: with
``W_ni = 1/|p_n - p_i|^3`` (zero diagonal) it is

    F_n = k_r q_n (p_n (W q)_n - (W (q p))_n),

i.e. matrix products on blocks of ``W`` (each symmetric block computed once),
with ``|p_n - p_i|^2`` taken from an augmented Gram product of the centred
positions. N = 1000 takes about 3 ms on one core (benchmarks/README.md).

With ``Gains.repulsion_cutoff`` set (an option, docs/formation-law.md section
3a) the repulsion sums only the pairs closer than the cut-off, found with a
cell list (``gcs_swarm.control.cutoff``, Eq. 9c): O(N log N). Unset (the
default) nothing here changes: the exact sum below, bit for bit.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from gcs_swarm.control.cutoff import (
    ALL_PAIRS_BELOW,
    DENSE_SHARE,
    neighbour_pairs,
    pair_repulsion,
    row_pairs,
    row_repulsion,
)
from gcs_swarm.control.params import Gains, Readings

__all__ = [
    "R_MIN_M",
    "eq1_acceleration",
    "formation_force",
    "repulsion_force",
    "repulsion_rows",
    "sphere_attraction",
]

F64 = NDArray[np.float64]
RowForces = Callable[[F64, NDArray[np.int64], F64, float, bool, float], F64]
"""``(pos_m, rows, charges, k_r, q_n_twice, r_min_m) -> (R, 3)``: Eq. 9c for
``rows``, as ``row_repulsion(row_pairs(pos_m, rows, r_c), ...)`` gives it
(``neighbours.NeighbourList.row_repulsion``: the same floats)."""

#: Lower clamp of the inter-vehicle distance in Eq. 9 [m]. Below it the pair
#: force grows linearly with the distance (like the field inside a uniformly
#: charged ball of this radius) instead of as 1/r^2, and coincident vehicles
#: (r = 0) push each other with exactly zero force: finite, never NaN. Any two
#: real vehicles this close have already collided.
R_MIN_M = 0.01

#: Rows of the N x N weight matrix processed at once (keeps the block in cache).
_BLOCK_ROWS = 256


def eq1_acceleration(force_n: F64, vel_mps: F64, gains: Gains) -> F64:
    """Eq. 1: ``a = (f - (D + k) v) / M`` [m/s^2] from force ``f`` [N] and
    measured velocity ``v`` [m/s]; any shape ``(..., 3)``.

    READING (time scale, ``Gains.time_scale`` = lambda): M and D + k are
    flown as ``lambda^2 M`` and ``lambda (D + k)`` (``Gains.mass_scaled``,
    ``damping_scaled``): the same solutions lambda times slower. lambda = 1
    multiplies by 1.0, so the paper's law is unchanged bit for bit."""
    out: F64 = (force_n - gains.damping_scaled * vel_mps) / gains.mass_scaled
    return out


def sphere_attraction(pos_m: F64, centre_m: F64, gains: Gains, readings: Readings) -> F64:
    """Eq. 7: ``f_s,n = -k_s (p_n - c)(|p_n - c|^2 - alpha^2)`` [N], ``(N, 3)``.

    READING: alpha^2 is kept. ``readings.eq12_printed`` gives Eq. 12 as
    printed, ``-k_s (p_n - c)|p_n - c|^2``. A vehicle at the centre gets zero.
    """
    d = pos_m - centre_m
    r2 = np.einsum("ni,ni->n", d, d)
    if not readings.eq12_printed:
        r2 = r2 - gains.alpha**2
    out: F64 = -gains.k_s * d * r2[:, None]
    return out


def _gram_operands(pos_m: F64, q: F64, q_n_twice: bool) -> tuple[F64, F64, F64, F64]:
    """The exact sum's operands: the centred positions ``p`` (smaller Gram
    cancellation error), ``left``/``right`` with ``|p_n - p_i|^2 = [p_n,
    |p_n|^2, 1] . [-2 p_i, 1, |p_i|^2]`` (one product per block), and
    ``rhs = [q_i, q_i p_i]`` (ones for Eq. 10 as printed)."""
    n = pos_m.shape[0]
    p = pos_m - pos_m.mean(axis=0)
    sq = np.einsum("ni,ni->n", p, p)
    left = np.empty((n, 5))
    left[:, :3] = p
    left[:, 3] = sq
    left[:, 4] = 1.0
    right = np.empty((n, 5))
    right[:, :3] = -2.0 * p
    right[:, 3] = 1.0
    right[:, 4] = sq
    qw = np.ones(n) if q_n_twice else q
    rhs = np.empty((n, 4))
    rhs[:, 0] = qw
    rhs[:, 1:] = qw[:, None] * p
    return p, left, right, rhs


def repulsion_force(
    pos_m: F64,
    charges: F64,
    k_r: float,
    *,
    q_n_twice: bool = False,
    r_min_m: float = R_MIN_M,
    cutoff_m: float | None = None,
) -> F64:
    """Eqs. 8-9: ``F_n = sum_{i != n} k_r q_n q_i (p_n - p_i) / |p_n - p_i|^3`` [N].

    READING: one q_n (Eqs. 8-9). ``q_n_twice=True`` is Eq. 10 as printed
    (``q_n q_n`` in place of ``q_n q_i``). Distances are clamped from below at
    ``r_min_m`` (see :data:`R_MIN_M`). ``pos_m (N, 3)``, ``charges (N,)`` ->
    ``(N, 3)``. Cost: O(N^2) scalar work in blocks of rows, O(N * block) memory.

    ``cutoff_m`` (``Gains.repulsion_cutoff``, [m]): when set, Eq. 9c (section
    3a of docs/formation-law.md): only the pairs closer than it, found with
    a cell list (``cutoff.neighbour_pairs``, ``cutoff.pair_repulsion``),
    O(N log N); where the cells would leave more than ``cutoff.DENSE_SHARE``
    of the pairs to test (a clump), these blocks with every pair at r_c or
    beyond zeroed (the test then on the Gram form's ``|p_n - p_i|^2``, which
    differs from the direct one by rounding, about eps times the squared
    size of the swarm). None (the default) is the exact sum.
    """
    n = pos_m.shape[0]
    out = np.zeros((n, 3))
    if n < 2:
        return out
    r2_cut = None
    if cutoff_m is not None:
        most = None if n < ALL_PAIRS_BELOW else int(DENSE_SHARE * (n * (n - 1) // 2))
        pairs = neighbour_pairs(pos_m, cutoff_m, max_candidates=most)
        if pairs is not None:
            return pair_repulsion(pairs, charges, k_r, q_n_twice=q_n_twice, r_min_m=r_min_m)
        r2_cut = cutoff_m * cutoff_m  # a clump: the blocks below, masked
    q = np.asarray(charges, dtype=np.float64)
    p, left, right, rhs = _gram_operands(pos_m, q, q_n_twice)
    acc = np.zeros((n, 4))
    r2_min = r_min_m * r_min_m
    nb = -(-n // _BLOCK_ROWS)
    # W is symmetric: each off-diagonal block is computed once and used for both
    # its rows and its columns, so the pair forces are exactly equal and opposite.
    for bi in range(nb):
        i0, i1 = bi * _BLOCK_ROWS, min(n, (bi + 1) * _BLOCK_ROWS)
        for bj in range(bi, nb):
            j0, j1 = bj * _BLOCK_ROWS, min(n, (bj + 1) * _BLOCK_ROWS)
            w = left[i0:i1] @ right[j0:j1].T  # |r|^2, (bi, bj)
            far = None if r2_cut is None else w >= r2_cut  # Eq. 9c: pairs at r >= r_c
            np.maximum(w, r2_min, out=w)  # clamp |r| from below at r_min_m
            s = np.sqrt(w)
            w *= s  # |r|^3
            np.divide(1.0, w, out=w)
            if far is not None:
                w[far] = 0.0
            if bi == bj:
                np.fill_diagonal(w, 0.0)  # no self-interaction
                acc[i0:i1] += w @ rhs[j0:j1]
            else:
                acc[i0:i1] += w @ rhs[j0:j1]
                acc[j0:j1] += w.T @ rhs[i0:i1]
    qn = q * q if q_n_twice else q
    np.multiply(p, acc[:, 0:1], out=out)
    out -= acc[:, 1:]
    out *= (k_r * qn)[:, None]
    return out


def repulsion_rows(
    pos_m: F64,
    rows: NDArray[np.int64],
    charges: F64,
    k_r: float,
    *,
    q_n_twice: bool = False,
    r_min_m: float = R_MIN_M,
    cutoff_m: float | None = None,
    forces_of: RowForces | None = None,
) -> F64:
    """Eqs. 8-9 (or Eq. 9c with ``cutoff_m``) for the vehicles ``rows`` only,
    against all N: ``(R, 3)`` [N], row k the force on vehicle ``rows[k]``
    (a step that answers some vehicles, docs/formation-law.md section 3b).

    The same pair terms as ``repulsion_force`` (one q_n, or Eq. 10 as
    printed with ``q_n_twice``; the clamp at ``r_min_m``); the sums run in
    another order, so the rows agree with ``repulsion_force``'s to rounding
    (about 1e-15 relative), not bit for bit. Exact law: one ``(R, N)``
    block of the augmented Gram product (in blocks of columns),
    O(R N). Cut-off: ``cutoff.row_pairs``
    on the cells of all N, O(N log N + R k), or ``forces_of`` when given
    (the same floats from a Verlet list: ``neighbours.NeighbourList.row_repulsion``).
    """
    rows = np.asarray(rows, dtype=np.int64)
    q = np.asarray(charges, dtype=np.float64)
    if cutoff_m is not None:
        if forces_of is not None:
            return forces_of(pos_m, rows, q, k_r, q_n_twice, r_min_m)
        pairs = row_pairs(pos_m, rows, cutoff_m)
        return row_repulsion(pairs, rows, q, k_r, q_n_twice=q_n_twice, r_min_m=r_min_m)
    n, m = pos_m.shape[0], rows.shape[0]
    out = np.zeros((m, 3))
    if n < 2 or m == 0:
        return out
    p, left_all, right, rhs = _gram_operands(pos_m, q, q_n_twice)
    left = left_all[rows]
    acc = np.zeros((m, 4))
    r2_min = r_min_m * r_min_m
    for j0 in range(0, n, _BLOCK_ROWS):  # blocks of columns, as repulsion_force's
        j1 = min(n, j0 + _BLOCK_ROWS)
        w = left @ right[j0:j1].T  # |r|^2, (R, block)
        np.maximum(w, r2_min, out=w)
        w *= np.sqrt(w)
        np.divide(1.0, w, out=w)
        own = np.flatnonzero((rows >= j0) & (rows < j1))
        w[own, rows[own] - j0] = 0.0  # no self-interaction
        acc += w @ rhs[j0:j1]
    qn = q[rows] * q[rows] if q_n_twice else q[rows]
    np.multiply(p[rows], acc[:, 0:1], out=out)
    out -= acc[:, 1:]
    out *= (k_r * qn)[:, None]
    return out


def formation_force(
    pos_m: F64,
    charges: F64,
    centre_m: F64,
    gains: Gains,
    readings: Readings,
    *,
    with_repulsion: bool = True,
) -> F64:
    """Eqs. 11-12: the formation force ``f_n(vs) = F_n + f_s,n`` [N], ``(N, 3)``,
    around the virtual leader ``centre_m (3,)``.

    READING: ``F + f_s`` (Eq. 7's minus sign already pulls inward).
    ``readings.eq11_printed`` gives Eq. 11 literally, ``F - f_s`` (diverges).
    ``F`` is Eq. 9, or Eq. 9c with ``gains.repulsion_cutoff`` set.
    """
    fs = sphere_attraction(pos_m, centre_m, gains, readings)
    if readings.eq11_printed:
        fs = -fs
    if not with_repulsion:
        return fs
    return fs + repulsion_force(
        pos_m,
        charges,
        gains.k_r,
        q_n_twice=readings.eq10_printed,
        cutoff_m=gains.repulsion_cutoff,
    )
