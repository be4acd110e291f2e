"""The station's per-report loops compiled (numba): Eq. 9c for the rows of
a step from the Verlet list's candidates, in one pass and the same floats
as numpy's ``cutoff.row_repulsion(cutoff._near_rows(...))``; the listed
pairs nearest to each other (the swarm's separation, once a period); the
next Verlet list's pairs, a slice of the cell list's ranks at a time
(``rank_pair_indices``: at 1,500 vehicles 0.03-0.05 ms a slice against
numpy's 0.20-0.38 ms); and the velocity-bias bank's common report
(``bias_common_reports``).

A network's step at 1,500 vehicles tests about 40 candidates for each of
its 250 rows. In numpy that is some twenty passes over arrays of 10,000
(gathers, the distance, the filter, the weights, three ``bincount``s):
0.38 ms a step, the largest single cost of the station's step
(benchmarks/README.md, "Scale, 2026-12-06 (thirteenth session)"). Compiled,
one loop over the candidates, 0.04 ms. numba is used because it compiles
this loop where it is written, for every platform with a wheel, with no
compiler on the machine (a C extension would need one at install), and
the loop stays readable beside the numpy reference it must equal.

The same floats: each term is the numpy path's expression in its order
(``d = p_i - p_j``, ``r2 = dx*dx + dy*dy + dz*dz``, the clamp, ``w = 1 /
(r2 sqrt(r2))``, times ``q_j``), summed per row in the candidates' order,
which is the order ``np.bincount`` adds them in; no fast-math (no fused or
reordered operations). ``tests/control/test_kernels.py`` holds the two to
bit equality. Compiled when this module is imported (an explicit
signature), cached beside it after the first time (``compiled``), so no
step pays for it. No I/O.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = [
    "bias_common_reports",
    "compiled",
    "listed_near_min",
    "listed_repulsion_sums",
    "rank_pair_indices",
]


def compiled(signature: str) -> Callable[[Callable[..., Any]], Any]:
    """numba's ``njit(signature, nogil=True)``, its machine code cached
    beside the module (``cache=True``) where a cache can be written: else
    (an install without a writable ``__pycache__`` nor home, no
    ``NUMBA_CACHE_DIR``) compiled again in each process rather than refused
    (numba raises at import then). Measured here: importing this module
    1.59 s when it compiles, 0.66 s from the cache."""

    def wrap(func: Callable[..., Any]) -> Any:
        try:
            return njit(signature, cache=True, nogil=True)(func)
        except RuntimeError:  # "cannot cache function ...: no locator available"
            return njit(signature, nogil=True)(func)

    return wrap


@compiled(
    "void(float64[:, :], int64[:], int64[:], int64[:], float64[:], float64, float64,"
    " boolean, float64[:, :])"
)
def _sums(
    pos: NDArray[np.float64],
    rows: NDArray[np.int64],
    start: NDArray[np.int64],
    other: NDArray[np.int64],
    charges: NDArray[np.float64],
    rc2: float,
    r2_min: float,
    q_n_twice: bool,
    out: NDArray[np.float64],
) -> None:  # pragma: no cover - compiled; tested through listed_repulsion_sums
    for k in range(rows.shape[0]):
        i = rows[k]
        xi, yi, zi = pos[i, 0], pos[i, 1], pos[i, 2]
        sx = sy = sz = 0.0
        for c in range(start[i], start[i + 1]):
            j = other[c]
            dx = xi - pos[j, 0]
            dy = yi - pos[j, 1]
            dz = zi - pos[j, 2]
            r2 = dx * dx + dy * dy + dz * dz
            if r2 < rc2:
                rr = r2 if r2 > r2_min else r2_min  # np.maximum(r2, r2_min)
                w = 1.0 / (rr * np.sqrt(rr))
                if not q_n_twice:
                    w = w * charges[j]
                sx += w * dx
                sy += w * dy
                sz += w * dz
        out[k, 0] = sx
        out[k, 1] = sy
        out[k, 2] = sz


def listed_repulsion_sums(
    pos_m: NDArray[np.float64],
    rows: NDArray[np.int64],
    start: NDArray[np.int64],
    other: NDArray[np.int64],
    charges: NDArray[np.float64],
    cutoff_m: float,
    *,
    q_n_twice: bool,
    r_min_m: float,
) -> NDArray[np.float64]:
    """Eq. 9c's sum for each of ``rows`` before its ``k_r q_n`` factor:
    ``(R, 3)``, row k = sum over the candidates ``j`` of vehicle
    ``rows[k]`` (``other[start[i]:start[i + 1]]``, a Verlet list) closer
    than ``cutoff_m`` of ``w d`` with ``d = p_i - p_j``, ``w = q_j /
    max(r, r_min)^3`` (``q_j`` left out with ``q_n_twice``: Eq. 10 as
    printed). ``cutoff.row_repulsion`` of ``cutoff._near_rows``' pairs
    divided by ``k_r q_n``, bit for bit."""
    out = np.empty((rows.shape[0], 3))
    _sums(
        np.asarray(pos_m, dtype=np.float64),
        np.asarray(rows, dtype=np.int64),
        start,
        other,
        np.asarray(charges, dtype=np.float64),
        float(cutoff_m) * float(cutoff_m),
        float(r_min_m) * float(r_min_m),
        bool(q_n_twice),
        out,
    )
    return out


@compiled("int64[:](float64[:, :], int64[:], int64[:], float64)")
def _near_min(
    pos: NDArray[np.float64], i: NDArray[np.int64], j: NDArray[np.int64], rel: float
) -> NDArray[np.int64]:  # pragma: no cover - compiled; tested through listed_near_min
    n = i.shape[0]
    r2 = np.empty(n)
    least = np.inf
    for c in range(n):
        a, b = i[c], j[c]
        dx = pos[a, 0] - pos[b, 0]
        dy = pos[a, 1] - pos[b, 1]
        dz = pos[a, 2] - pos[b, 2]
        v = dx * dx + dy * dy + dz * dz
        if v != v:  # a NaN position: numpy's min is NaN, and nothing is near it
            return np.empty(0, dtype=np.int64)
        r2[c] = v
        if v < least:
            least = v
    bound = least * (1.0 + rel)
    near = np.empty(n, dtype=np.int64)
    k = 0
    for c in range(n):
        if r2[c] <= bound:
            near[k] = c
            k += 1
    return near[:k]


def listed_near_min(
    pos_m: NDArray[np.float64], i: NDArray[np.int64], j: NDArray[np.int64], rel: float
) -> NDArray[np.int64]:
    """The pairs ``(i[c], j[c])`` whose squared distance (``dx*dx + dy*dy +
    dz*dz`` of ``p_i - p_j``) is within ``1 + rel`` times the smallest, in
    order: ``np.flatnonzero(r2 <= r2.min() * (1 + rel))`` of the same floats
    in one pass, without the arrays of every pair (none when a position is
    NaN, as numpy's NaN minimum gives none)."""
    pos = np.asarray(pos_m, dtype=np.float64)
    near: NDArray[np.int64] = _near_min(pos, np.asarray(i, dtype=np.int64),
                                        np.asarray(j, dtype=np.int64), float(rel))  # fmt: skip
    return near


@compiled(
    "UniTuple(int64[:], 2)(int64[:], int64[:], int64[:], int64[:], float64[:, :], int64, int64,"
    " float64)"
)
def _rank_pairs(
    skey: NDArray[np.int64],
    start: NDArray[np.int64],
    shell: NDArray[np.int64],
    order: NDArray[np.int64],
    xyz: NDArray[np.float64],
    lo: int,
    hi: int,
    rc2: float,
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:  # pragma: no cover - compiled
    blocks = shell.shape[0] + 1  # the half shell's cells, then the same cell
    firsts = np.empty((blocks, hi - lo), dtype=np.int64)
    afters = np.empty((blocks, hi - lo), dtype=np.int64)
    table = start.shape[0] > 0
    total = 0
    for k in range(blocks):
        for r in range(lo, hi):
            own = k == blocks - 1
            key = skey[r] if own else skey[r] + shell[k]
            if table:
                first, after = start[key], start[key + 1]
            else:  # binary searches (``cutoff._first``, ``cutoff._after``)
                first = np.searchsorted(skey, key, side="left")
                after = np.searchsorted(skey, key, side="right")
            if own:  # the same cell: the vehicles sorted after this one
                first = r + 1
            firsts[k, r - lo] = first
            afters[k, r - lo] = after
            total += after - first
    out_i = np.empty(total, dtype=np.int64)
    out_j = np.empty(total, dtype=np.int64)
    x, y, z = xyz[0], xyz[1], xyz[2]
    m = 0
    for k in range(blocks):
        for r in range(lo, hi):
            for s in range(firsts[k, r - lo], afters[k, r - lo]):
                dx = x[r] - x[s]
                dy = y[r] - y[s]
                dz = z[r] - z[s]
                if dx * dx + dy * dy + dz * dz < rc2:
                    out_i[m] = order[r]
                    out_j[m] = order[s]
                    m += 1
    return out_i[:m].copy(), out_j[:m].copy()


def rank_pair_indices(
    skey: NDArray[np.int64],
    start: NDArray[np.int64] | None,
    shell: NDArray[np.int64],
    order: NDArray[np.int64],
    xyz: NDArray[np.float64],
    lo: int,
    hi: int,
    rc2: float,
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """``cutoff._rank_pairs``' first two arrays (the pairs' vehicle indices,
    in its order) in one compiled pass over the candidates, without the
    arrays of every candidate nor the pairs' differences: a cell list's
    sorted keys ``skey``, its table of cells ``start`` (None: binary
    searches), the half shell's key offsets ``shell``, the sort ``order``,
    the sorted positions ``xyz (3, N)``, the first vehicles' ranks ``lo``
    to ``hi - 1`` and the squared radius ``rc2``. The same test on the
    same floats (``dx*dx + dy*dy + dz*dz < rc2`` of the sorted positions'
    differences), so the same pairs."""
    table = np.zeros(0, dtype=np.int64) if start is None else start
    pairs: tuple[NDArray[np.int64], NDArray[np.int64]] = _rank_pairs(
        skey, table, shell, order, xyz, int(lo), int(hi), float(rc2)
    )
    return pairs


@compiled(
    "UniTuple(int64, 2)(int64[:], float64[:, :], float64[:, :], float64[:, :], int64[:],"
    " float64[:], float64[:, :], boolean[:], int64[:], int64[:])"
)
def _bias_common(
    kk: NDArray[np.int64],
    reports: NDArray[np.float64],
    last: NDArray[np.float64],
    sums: NDArray[np.float64],
    count: NDArray[np.int64],
    cp_t: NDArray[np.float64],
    lim: NDArray[np.float64],
    banked: NDArray[np.bool_],
    odd: NDArray[np.int64],
    due: NDArray[np.int64],
) -> tuple[int, int]:  # pragma: no cover - compiled; tested through BiasBank
    n_odd = 0
    n_due = 0
    for j in range(kk.shape[0]):
        k = kk[j]
        t = reports[j, 0]
        dt = t - last[k, 0]
        i0 = 0.5 * (reports[j, 4] + last[k, 4]) * dt
        i1 = 0.5 * (reports[j, 5] + last[k, 5]) * dt
        i2 = 0.5 * (reports[j, 6] + last[k, 6]) * dt
        s0 = reports[j, 1] - last[k, 1] - i0
        s1 = reports[j, 2] - last[k, 2] - i1
        s2 = reports[j, 3] - last[k, 3] - i2
        sq = s0 * s0 + s1 * s1 + s2 * s2
        if not (banked[k] and dt > 0.0 and dt <= lim[k, 1] and sq < lim[k, 2]):
            odd[n_odd] = j
            n_odd += 1
            continue
        sums[k, 0] += i0
        sums[k, 1] += i1
        sums[k, 2] += i2
        for c in range(7):
            last[k, c] = reports[j, c]
        count[k] += 1
        if t - cp_t[k] >= lim[k, 0]:
            due[n_due] = j
            n_due += 1
    return n_odd, n_due


def bias_common_reports(
    kk: NDArray[np.int64],
    reports: NDArray[np.float64],
    last: NDArray[np.float64],
    sums: NDArray[np.float64],
    count: NDArray[np.int64],
    cp_t: NDArray[np.float64],
    lim: NDArray[np.float64],
    banked: NDArray[np.bool_],
) -> tuple[list[int], list[int]]:
    """``velocity_bias.BiasBank.update``'s arithmetic for the common report
    of each of rows ``kk`` (distinct), in place on the bank's arrays: the
    trapezoid ``0.5 (v + v_last) dt``, the unexplained step ``p - p_last -
    inc``, its square summed x, y, z; a banked row with ``0 < dt <=
    max_gap`` and the square below ``lim[k, 2]`` adds the trapezoid to its
    integral, keeps the report as its last and counts it. Returns (the
    report indices ``j`` that are not common, for the observer; those whose
    checkpoint is due, ``t - cp_t >= lim[k, 0]``), each in order. The
    element-wise operations of the numpy version, in its order: the same
    floats."""
    n = kk.shape[0]
    odd = np.empty(n, dtype=np.int64)
    due = np.empty(n, dtype=np.int64)
    n_odd, n_due = _bias_common(np.asarray(kk, dtype=np.int64), reports, last, sums, count,
                                cp_t, lim, banked, odd, due)  # fmt: skip
    return odd[:n_odd].tolist(), due[:n_due].tolist()
