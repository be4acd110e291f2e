"""The inter-vehicle repulsion with a cut-off radius (Eq. 9c of
docs/formation-law.md, section 3a), on a uniform cell list.

READING (cut-off, an option; the paper's law has none): with ``r_c`` =
``Gains.repulsion_cutoff`` [m], Eq. 9 sums only over the vehicles closer than
``r_c``,

    F_n = sum_{i != n, |p_n - p_i| < r_c} k_r q_n q_i (p_n - p_i) / |p_n - p_i|^3,

each pair term exactly Eq. 9's (same clamp of ``|p_n - p_i|`` from below at
``r_min_m``, same Eq. 10 variant). ``None`` (the default) is the exact
all-pairs sum of ``gcs_swarm.control.formation.repulsion_force``, which stays
the reference: this module is only reached when a cut-off is set.

The pairs closer than ``r_c`` are found with a uniform grid of cubic cells of
side ``r_c`` (a cell list): a pair closer than ``r_c`` lies in the same cell
or in two cells that touch, so each vehicle is compared only with the
vehicles of its own cell and of 13 of its 26 neighbours (a half shell, so
each pair of cells is visited once). Sorting the vehicles by cell is
O(N log N), finding each cell's range O(1) from a table of the cells when
the swarm is compact (at most 32 cells per vehicle), else O(log N)
(``searchsorted``), and the pair work O(N k), k the vehicles in a vehicle's
27 cells. Below ``ALL_PAIRS_BELOW`` vehicles every pair is tested instead
(cheaper there). ``pair_repulsion`` sums Eq. 9c over the pairs found.

When the cells prune little (a clump, or ``r_c`` near the swarm's size) the
pairs cost some 30 times more each than the exact sum's blocked matrix
products (N = 2000 in a clump: 290 ms against 10 ms), so
``formation.repulsion_force`` asks for at most ``DENSE_SHARE`` of all the
pairs as candidates (``max_candidates``) and otherwise takes the exact
sum's blocks with the pairs at r_c or beyond zeroed. Pure numpy, no state
between calls.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "ALL_PAIRS_BELOW",
    "DENSE_SHARE",
    "Pairs",
    "neighbour_pairs",
    "pair_repulsion",
    "row_pairs",
    "row_repulsion",
]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

#: The 13 cell offsets of a half shell (lexicographically positive); the
#: same cell, (0, 0, 0), is handled apart (the vehicles sorted after one).
_UNIT = (-1, 0, 1)
_HALF_SHELL = np.array(
    [(a, b, c) for a in _UNIT for b in _UNIT for c in _UNIT if (a, b, c) > (0, 0, 0)],
    dtype=np.int64,
)

#: At most this many cells along one axis (+ padding): the linear cell key of
#: 3 axes then stays below 2^63. A swarm wider than ``_MAX_CELLS * r_c`` gets
#: larger cells (still correct: a cell at least ``r_c`` wide is all the
#: neighbour search needs; only the candidate count grows).
_MAX_CELLS = 1 << 20

#: Up to this many cells per vehicle the ranges come from a table of every
#: cell (one gather per look-up) instead of binary searches.
_DENSE_CELLS_PER_VEHICLE = 32

DENSE_SHARE = 0.125
"""Above this share of the N (N - 1) / 2 pairs as candidates the cell list
is given up for the exact sum's blocks, masked (module docstring)."""

ALL_PAIRS_BELOW = 64
"""Below this many vehicles ``neighbour_pairs`` tests all N (N - 1) / 2 pairs
(the same test, the same pairs): the cell list's fixed cost (sorting, 28
searches) is then more than the pairs (about 150 us against 30 us at N = 12
on the development machine)."""


Pairs = tuple[I64, I64, F64, F64]


class _Cells(NamedTuple):
    """A cell list over all N vehicles (module docstring): each vehicle's
    cell ``key``, the vehicles sorted by it (``order``, stable; ``skey`` =
    ``key[order]``), the key offset of one cell along each axis (``stride``)
    and, for a compact swarm, ``start[c]`` the first sorted index of cell c
    (``ncell + 1`` long; None: binary searches instead)."""

    key: I64
    order: I64
    skey: I64
    stride: I64
    start: I64 | None


def _cells(pos_m: F64, cutoff_m: float) -> _Cells:
    """The cell list of side ``cutoff_m`` (larger for a swarm wider than
    ``_MAX_CELLS`` cells) of ``pos_m (N, 3)``, padded by one cell each side
    (no key of a neighbour wraps into another row)."""
    n = pos_m.shape[0]
    lo = pos_m.min(axis=0)
    span = float((pos_m.max(axis=0) - lo).max())
    side = max(float(cutoff_m), span / _MAX_CELLS)
    cell = np.floor((pos_m - lo) / side).astype(np.int64) + 1  # >= 1: padding for -1 offsets
    dims = cell.max(axis=0) + 2  # padding for +1 offsets: no key wraps into another row
    stride = np.array([dims[1] * dims[2], dims[2], 1], dtype=np.int64)
    key = cell @ stride
    order = np.argsort(key, kind="stable")
    skey = key[order]
    ncell = int(dims[0]) * int(dims[1]) * int(dims[2])
    start = None
    if ncell <= _DENSE_CELLS_PER_VEHICLE * n:  # a compact swarm: a table of every cell
        start = np.zeros(ncell + 1, dtype=np.int64)
        np.cumsum(np.bincount(skey, minlength=ncell), out=start[1:])
    return _Cells(key, order, skey, stride, start)


def _first(c: _Cells, keys: I64) -> I64:
    """The first sorted index of each cell of ``keys``."""
    if c.start is not None:
        return c.start[keys]
    return np.searchsorted(c.skey, keys, side="left")  # a sparse swarm: binary search


def _after(c: _Cells, keys: I64) -> I64:
    """The sorted index after the last vehicle of each cell of ``keys``."""
    if c.start is not None:
        return c.start[keys + 1]
    return np.searchsorted(c.skey, keys, side="right")


def _expand(owner: I64, first: I64, count: I64, total: int) -> tuple[I64, I64]:
    """The candidate pairs of ranges: ``owner[k]`` with each index of
    ``first[k], first[k] + 1, ... first[k] + count[k] - 1``; ``total`` is
    ``count.sum()``."""
    starts = np.cumsum(count) - count
    index = np.arange(total, dtype=np.int64) + np.repeat(first - starts, count)
    return np.repeat(owner, count), index


def _near_rows(pos_m: F64, rows: I64, r_s: I64, j_s: I64, rc2: float) -> Pairs:
    """The candidates (row ``rows[r_s]``, vehicle ``j_s``) closer than
    ``sqrt(rc2)``, as ``row_pairs`` returns them."""
    x, y, z = np.ascontiguousarray(pos_m.T)
    own = rows[r_s]
    dx, dy, dz = x[own] - x[j_s], y[own] - y[j_s], z[own] - z[j_s]
    r2 = dx * dx + dy * dy + dz * dz
    near = np.flatnonzero(r2 < rc2)
    d = np.stack((dx[near], dy[near], dz[near]), axis=1)
    return r_s[near], j_s[near], d, r2[near]


def neighbour_pairs(
    pos_m: F64, cutoff_m: float, *, max_candidates: int | None = None
) -> Pairs | None:
    """Every unordered pair of vehicles closer than ``cutoff_m`` [m], once.

    ``pos_m (N, 3)`` mission frame, finite. Returns ``(i, j, d, r2)``: indices
    ``(P,)`` into ``pos_m`` (``i != j``), ``d (P, 3) = p_i - p_j`` [m] and
    ``r2 (P,) = |d|^2`` [m^2] (summed x, y, z in that order), every pair with
    ``r2 < cutoff_m^2``; the order of the pairs is unspecified. Cell list of
    side ``cutoff_m`` (module docstring): O(N log N + N k). None, without
    building them, when the cell list has more than ``max_candidates``
    candidate pairs to test (only when that is given; from
    ``ALL_PAIRS_BELOW`` vehicles on).
    """
    n = pos_m.shape[0]
    rc2 = float(cutoff_m) * float(cutoff_m)
    if n < ALL_PAIRS_BELOW:  # every pair, then the same test: cheaper than sorting
        a, b = np.triu_indices(n, k=1)
        d = pos_m[a] - pos_m[b]
        r2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
        close = r2 < rc2
        return a[close].astype(np.int64), b[close].astype(np.int64), d[close], r2[close]
    c = _cells(pos_m, cutoff_m)
    xyz = np.ascontiguousarray(pos_m[c.order].T)  # (3, N): one contiguous row per axis
    return _rank_pairs(c, xyz, 0, n, rc2, max_candidates)


def _rank_pairs(
    c: _Cells, xyz: F64, lo: int, hi: int, rc2: float, max_candidates: int | None = None
) -> Pairs | None:
    """``neighbour_pairs``' pairs whose first vehicle has sorted rank ``lo`` to
    ``hi - 1`` in the cell list ``c`` (``xyz (3, N)``: the positions in
    sorted order, one row per axis): over the ranks 0 .. N - 1 in slices,
    every pair once, as the whole range finds them."""
    skey = c.skey[lo:hi]
    rank = np.arange(lo, hi, dtype=np.int64)
    # Neighbouring cells (13 offsets x the ranks): the sorted range of each.
    nkey = (skey[None, :] + (_HALF_SHELL @ c.stride)[:, None]).reshape(-1)
    first = _first(c, nkey)
    # The same cell: the vehicles sorted after this one (each pair once).
    count = np.concatenate((_after(c, nkey) - first, _after(c, skey) - rank - 1))
    first = np.concatenate((first, rank + 1))
    owner = np.tile(rank, _HALF_SHELL.shape[0] + 1)
    total = int(count.sum())
    if max_candidates is not None and total > max_candidates:
        return None
    i_s, j_s = _expand(owner, first, count, total)
    x, y, z = xyz
    dx, dy, dz = x[i_s] - x[j_s], y[i_s] - y[j_s], z[i_s] - z[j_s]
    r2 = dx * dx + dy * dy + dz * dz
    near = np.flatnonzero(r2 < rc2)
    d = np.stack((dx[near], dy[near], dz[near]), axis=1)
    order = c.order
    return order[i_s[near]], order[j_s[near]], d, r2[near]


def pair_repulsion(
    pairs: Pairs,
    charges: F64,
    k_r: float,
    *,
    q_n_twice: bool,
    r_min_m: float,
) -> F64:
    """Eq. 9c (Eqs. 8-9 with a cut-off, docs/formation-law.md section 3a) over
    the given pairs (``neighbour_pairs``): ``F_n = sum_{i != n, |p_n - p_i| <
    r_c} k_r q_n q_i (p_n - p_i) / |p_n - p_i|^3`` [N], ``(N, 3)``, N =
    ``len(charges)``.

    READING: one q_n (Eqs. 8-9); ``q_n_twice=True`` is Eq. 10 as printed.
    ``|p_n - p_i|`` is clamped from below at ``r_min_m`` as in the exact sum
    (``formation.R_MIN_M``). ``charges (N,)`` [C]. Each pair's term is
    computed once and added to both vehicles with opposite signs, so the pair
    forces are equal and opposite. O(P).
    """
    q = np.asarray(charges, dtype=np.float64)
    n = q.shape[0]
    out = np.zeros((n, 3))
    i, j, d, r2 = pairs
    if i.size == 0:
        return out
    qw = np.ones(n) if q_n_twice else q
    r2 = np.maximum(r2, r_min_m * r_min_m)  # clamp |r| from below at r_min_m
    w = 1.0 / (r2 * np.sqrt(r2))  # 1 / |p_i - p_j|^3
    wi, wj = w * qw[j], w * qw[i]  # on i: q_j (p_i - p_j) w; on j: -q_i (p_i - p_j) w
    idx = np.concatenate((i, j))
    for axis in range(3):
        col = d[:, axis]
        out[:, axis] = np.bincount(idx, weights=np.concatenate((wi * col, -wj * col)), minlength=n)
    qn = q * q if q_n_twice else q
    out *= (k_r * qn)[:, None]
    return out


#: All 27 cell offsets: a row's own cell and every neighbour (``row_pairs``).
_FULL_SHELL = np.array([(a, b, c) for a in _UNIT for b in _UNIT for c in _UNIT], dtype=np.int64)


def row_pairs(pos_m: F64, rows: I64, cutoff_m: float) -> Pairs:
    """Every vehicle closer than ``cutoff_m`` [m] to each of ``rows``.

    The rows' side of ``neighbour_pairs`` (a step that answers only some
    vehicles, docs/formation-law.md section 3b): ``pos_m (N, 3)`` mission
    frame, finite; ``rows (R,)`` distinct indices into it. Returns
    ``(r, j, d, r2)``: ``r (P,)`` positions in ``rows`` (0 .. R - 1), ``j
    (P,)`` indices into ``pos_m`` (``j != rows[r]``), ``d = p_rows[r] - p_j``
    [m] and ``r2 = |d|^2`` [m^2] (x, y, z summed in that order), every such
    pair with ``r2 < cutoff_m^2``, once per row (a pair of two rows appears
    twice, once from each). The cells of ``neighbour_pairs`` over all N
    (the sort is O(N log N)); the work is O(R k) with a full shell of 27
    cells per row.
    """
    n = pos_m.shape[0]
    rows = np.asarray(rows, dtype=np.int64)
    rc2 = float(cutoff_m) * float(cutoff_m)
    m = rows.shape[0]
    if n < ALL_PAIRS_BELOW or m == 0:  # every (row, vehicle), then the same test
        r_s = np.repeat(np.arange(m, dtype=np.int64), n)
        j_s = np.tile(np.arange(n, dtype=np.int64), m)
    else:
        c = _cells(pos_m, cutoff_m)
        nkey = (c.key[rows][None, :] + (_FULL_SHELL @ c.stride)[:, None]).reshape(-1)
        first = _first(c, nkey)
        count = _after(c, nkey) - first
        owner = np.tile(np.arange(m, dtype=np.int64), _FULL_SHELL.shape[0])
        r_s, sorted_j = _expand(owner, first, count, int(count.sum()))
        j_s = c.order[sorted_j]
    keep = j_s != rows[r_s]
    return _near_rows(pos_m, rows, r_s[keep], j_s[keep], rc2)


def row_repulsion(
    pairs: Pairs,
    rows: I64,
    charges: F64,
    k_r: float,
    *,
    q_n_twice: bool,
    r_min_m: float,
) -> F64:
    """Eq. 9c on ``rows`` only: ``F_n`` [N] ``(R, 3)`` for ``n`` in ``rows``
    over ``row_pairs``' pairs (each pair's term as ``pair_repulsion``
    computes it: the same clamp at ``r_min_m``, the same Eq. 10 variant with
    ``q_n_twice``). ``charges (N,)`` [C] of every vehicle."""
    q = np.asarray(charges, dtype=np.float64)
    m = len(rows)
    out = np.zeros((m, 3))
    r, j, d, r2 = pairs
    if r.size == 0:
        return out
    r2 = np.maximum(r2, r_min_m * r_min_m)
    w = 1.0 / (r2 * np.sqrt(r2))
    w = w if q_n_twice else w * q[j]
    for axis in range(3):
        out[:, axis] = np.bincount(r, weights=w * d[:, axis], minlength=m)
    qn = q[rows] * q[rows] if q_n_twice else q[rows]
    out *= (k_r * qn)[:, None]
    return out
