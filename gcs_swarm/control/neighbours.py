"""The Verlet list of the cut-off law's steps of some rows (Eq. 9c of
docs/formation-law.md, sections 3a-3b): ``NeighbourList`` keeps each row's
candidates between steps, so a step of one network's rows tests only those,
and finds the next list ahead of need, in slices, on ``cutoff``'s cells.
numpy, and the compiled loops of ``kernels`` (the same pairs and floats as
their numpy references); no I/O.
"""

from __future__ import annotations

import math

import numpy as np

from gcs_swarm.control.cutoff import (
    _HALF_SHELL,
    ALL_PAIRS_BELOW,
    F64,
    I64,
    Pairs,
    _cells,
    _expand,
    _near_rows,
    neighbour_pairs,
)

__all__ = [
    "AHEAD_SHARE",
    "KEPT_LIST",
    "LONG_LIST",
    "MAX_SKIN_SHARE",
    "SHORT_LIST",
    "SKIN_GROWTH",
    "SKIN_SHARE",
    "SLICES",
    "NeighbourList",
]

SKIN_SHARE = 0.3
"""``NeighbourList``'s least margin beyond the cut-off, as a share of it: a
formation holding its shape (its lists last, and a wider margin would only
add candidates to every step)."""

MAX_SKIN_SHARE = 1.0
"""The widest margin, as a share of the cut-off, that the lists of a
churning swarm grow to (``NeighbourList``: measured best at 1,500 vehicles)."""

SKIN_GROWTH = 1.3
"""The factor by which the margin grows after a short-lived list, and
shrinks after a long-lived one."""

SHORT_LIST = 12
"""A list that vehicles' motion makes stale within this many steps (two
periods of six networks' steps) has the next one's margin grown."""

KEPT_LIST = 3 * SHORT_LIST
"""A list that motion makes stale only after more than this many steps has
the next one's margin narrowed (three times ``SHORT_LIST``, a band wider
than ``SKIN_GROWTH``: a steady motion settles on one margin)."""

LONG_LIST = 120
"""A list kept this many steps with a margin wider than the least starts a
tighter next one (a churn that has calmed down)."""

AHEAD_SHARE = 0.7
"""``NeighbourList`` starts its next list in slices once a vehicle has used
this share of the margin (the rest covers the slices' steps)."""

SLICES = 6
"""The next list's pair search in this many slices of the vehicles, one per
step, and one more step puts it together. At 1,500 vehicles on their
sphere (r_c = 2 d_nn, margin 0.3-1.0 r_c) a slice's pairs take 0.03-0.05
ms compiled (``kernels.rank_pair_indices``; numpy's ``cutoff._rank_pairs``
0.20-0.38 ms), the whole list at once 0.40-0.65 ms with its cell list."""


def _centred(pos_m: F64) -> F64:
    """``pos_m`` less its mean, a new array: the bits of ``pos_m - pos_m.mean(axis=0)``
    (numpy's mean is this sum over the count) without ``mean``'s Python wrapper,
    twice per step at 1,500 vehicles."""
    n = pos_m.shape[0]
    return pos_m - pos_m.sum(axis=0) / n if n else pos_m.copy()


class _Ahead:
    """The next list being found in slices: the positions when it started
    (``pos``, less their mean ``ref``), their cell list and the pairs found
    so far."""

    def __init__(self, pos_m: F64, ref: F64, key: object, side_m: float, skin_m: float) -> None:
        self.pos = pos_m.copy()
        self.ref = ref
        self.key = key
        self.skin_m = skin_m
        """The margin it is found with (``side_m`` is the cut-off plus it)."""
        self.cells = _cells(self.pos, side_m)
        self.xyz = np.ascontiguousarray(self.pos[self.cells.order].T)
        self.shell = _HALF_SHELL @ self.cells.stride
        """The half shell's cells as key offsets (``cutoff._rank_pairs``)."""
        self.rc2 = side_m * side_m
        self.done = 0
        """Ranks searched so far."""
        self.i: list[I64] = []
        self.j: list[I64] = []


class NeighbourList:
    """``row_repulsion`` (Eq. 9c) and ``row_pairs`` for steps of some rows,
    from a kept list of candidates.

    A Verlet list (the molecular-dynamics device): every pair closer than
    ``r_c + skin`` when it was built (``neighbour_pairs``, both ways round,
    rows in order), with the positions then, less their mean. Any common
    translation leaves the distances unchanged, so while no vehicle has moved
    more than ``skin / 2`` from its built position relative to the swarm's
    mean, a pair closer than ``r_c`` now was closer than ``r_c + skin`` then:
    it is in the list. A step then tests only the rows' candidates
    (about 4.2 (1 + skin/r_c)^3 r_c^3 of volume each, against 27 r_c^3 for the
    cells) and rebuilds first when a vehicle moved farther, or when the
    vehicles are others (a join or a leave: ``key``). The same pairs as
    ``cutoff.row_pairs`` (the same test on the same floats), in another
    order. A formation holding its shape, however fast it flies, is built
    once.

    Built ahead, in slices: once a vehicle has used ``AHEAD_SHARE`` of its
    ``skin / 2``, the next list starts from the positions of that step and
    each following call searches ``1 / SLICES`` of the vehicles' pairs
    (``neighbour_pairs`` cut by sorted rank), the call after the last puts
    it together and it replaces the current one. A swarm churning in place
    (every vehicle moving) needs a list every few hundred milliseconds; at
    1,500 vehicles one build at once was 3.6 ms in numpy (0.4-0.65 ms
    compiled: ``SLICES``), added to one network's latency about nine times
    a second. Built ahead, each step carries at most a slice. If the
    current list goes stale first (a vehicle faster than the slices), the
    rest of the next list is found at once; a next list put together that
    is already stale (a vehicle moved more than ``skin / 2`` from where it
    started) gives way to a list built at once.

    The margin follows the swarm's motion: a list made stale by motion
    within ``SHORT_LIST`` steps has the next one's margin ``SKIN_GROWTH``
    times wider (up to ``MAX_SKIN_SHARE`` of the cut-off), one made stale
    after more than ``KEPT_LIST`` steps ``SKIN_GROWTH`` times tighter (down
    to ``skin_share``), and a list kept ``LONG_LIST`` steps with a wider
    margin than that starts a tighter next one. A wider margin lists more
    candidates (the volume grows as ``(r_c + skin)^3``) but lasts longer.
    Replayed over 1,654 network steps of the 1,500-vehicle benchmark
    formation, which churns (vehicles at about 2 m/s relative to its
    centre: a list of margin 0.3 r_c lasted 1.6 steps), fixed margins of
    0.3, 0.5, 1.0, 1.5 and 2.0 r_c took 0.975, 0.879, 0.823, 1.027 and
    1.232 ms a step; on that formation at rest 0.3 r_c took 0.77 ms and
    1.0 r_c 1.17 ms. Any margin gives the same pairs.
    """

    def __init__(
        self, cutoff_m: float, skin_share: float = SKIN_SHARE, max_share: float = MAX_SKIN_SHARE
    ) -> None:
        """Margins from ``skin_share`` to ``max_share`` of ``cutoff_m``
        (equal: a fixed margin, as ``benchmarks/bench_law.py --margin``
        compares)."""
        # The compiled loops (numba: about 0.4 s to load in a process) come
        # with the first list, made with its controller before any step, so
        # a mission without the cut-off never loads them.
        from gcs_swarm.control import kernels

        self._kernels = kernels
        self.cutoff_m = float(cutoff_m)
        self.least_share = float(skin_share)
        self.max_share = max(float(max_share), self.least_share)
        self.skin_m = skin_share * self.cutoff_m
        """The margin [m] of the list in use (of the first, before any)."""
        self._share = self.least_share
        """The margin of the next list, as a share of the cut-off."""
        self._age = 0
        """Steps (``row_repulsion`` or ``row_pairs`` calls) since the list in
        use was installed."""
        self.builds = 0
        """Lists built at once (the first, after a join or leave, or when
        the next was not ready in time)."""
        self.ahead = 0
        """Lists built ahead, in slices."""
        self._key: object = None
        self._ref = np.zeros((0, 3))
        self._start = np.zeros(1, dtype=np.int64)
        self._other = np.zeros(0, dtype=np.int64)
        self._half: tuple[I64, I64] = (self._other, self._other)
        """Each listed pair once, as ``neighbour_pairs`` gave them."""
        self._next: _Ahead | None = None

    def _moved2(self, pos_m: F64, key: object) -> float:
        """The largest squared displacement [m^2] since the list was built,
        relative to the mean; inf for other vehicles (``key``)."""
        if (key is not self._key and key != self._key) or pos_m.shape != self._ref.shape:
            return math.inf
        moved = _centred(pos_m)
        moved -= self._ref
        return float(np.einsum("ij,ij->i", moved, moved).max(initial=0.0))

    def _stale(self, pos_m: F64, key: object) -> bool:
        return self._moved2(pos_m, key) > 0.25 * self.skin_m * self.skin_m

    def _install(self, n: int, i: I64, j: I64, ref: F64, key: object, skin_m: float) -> None:
        src = np.concatenate((i, j))
        other = np.concatenate((j, i))
        # The same stable order; numpy radix-sorts 16-bit keys (8 times faster
        # than its int64 merge sort at 60 000 pairs).
        small = src.astype(np.int16) if n <= np.iinfo(np.int16).max else src
        order = np.argsort(small, kind="stable")
        self._other = other[order]
        self._start = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(src, minlength=n), out=self._start[1:])
        self._ref = ref
        self._key = key
        self._half = (i, j)
        self.skin_m = skin_m
        self._age = 0

    def _build(self, pos_m: F64, key: object) -> None:
        skin = self._share * self.cutoff_m
        n = pos_m.shape[0]
        if n < ALL_PAIRS_BELOW:  # every pair tested (``neighbour_pairs``)
            pairs = neighbour_pairs(pos_m, self.cutoff_m + skin)
            assert pairs is not None  # no max_candidates
            self._install(n, pairs[0], pairs[1], _centred(pos_m), key, skin)
        else:  # ``neighbour_pairs``' cells and pairs, in one compiled pass
            whole = _Ahead(pos_m, _centred(pos_m), key, self.cutoff_m + skin, skin)
            i, j = self._rank_pairs(whole, 0, n)
            self._install(n, i, j, whole.ref, key, skin)
        self._next = None
        self.builds += 1

    def _rank_pairs(self, nxt: _Ahead, lo: int, hi: int) -> tuple[I64, I64]:
        """``cutoff._rank_pairs``' vehicle indices of ``nxt``'s pairs whose first
        vehicle has sorted rank ``lo`` to ``hi - 1``: the same pairs, in its
        order, from ``kernels.rank_pair_indices``."""
        c = nxt.cells
        pairs: tuple[I64, I64] = self._kernels.rank_pair_indices(
            c.skey, c.start, nxt.shell, c.order, nxt.xyz, lo, hi, nxt.rc2
        )
        return pairs

    def _moving(self) -> None:
        """The list in use is being replaced because vehicles moved: a short
        life widens the next list's margin, a long one narrows it (class
        docstring)."""
        if self._age < SHORT_LIST:
            self._share = min(self.max_share, self._share * SKIN_GROWTH)
        elif self._age > KEPT_LIST:
            self._narrow()

    def _narrow(self) -> None:
        """The next list's margin ``SKIN_GROWTH`` times tighter, down to the least."""
        self._share = max(self.least_share, self._share / SKIN_GROWTH)

    def _slice(self, nxt: _Ahead, all_of_it: bool = False) -> bool:
        """Search the next slice of ``nxt`` (or all that is left); True when
        it was put together instead (and now is the list)."""
        n = nxt.pos.shape[0]
        if nxt.done < n:
            hi = n if all_of_it else min(n, nxt.done + -(-n // SLICES))
            i, j = self._rank_pairs(nxt, nxt.done, hi)
            nxt.i.append(i)
            nxt.j.append(j)
            nxt.done = hi
            if not all_of_it:
                return False
        self._install(n, np.concatenate(nxt.i), np.concatenate(nxt.j), nxt.ref, nxt.key,
                      nxt.skin_m)  # fmt: skip
        self._next = None
        self.ahead += 1
        return True

    def _prepare(self, pos_m: F64, key: object) -> None:
        """The list for ``pos_m``: fresh at once if it must be, the next
        one's slice otherwise (class docstring)."""
        n = pos_m.shape[0]
        self._age += 1
        nxt = self._next
        if nxt is not None and ((nxt.key is not key and nxt.key != key)
                                or nxt.pos.shape != pos_m.shape):  # fmt: skip
            self._next = nxt = None
        moved2 = self._moved2(pos_m, key)
        half2 = 0.25 * self.skin_m * self.skin_m
        if nxt is not None:
            # A stale list takes the rest of the next one at once. Put together,
            # the next list is checked as the current one was: a vehicle may
            # have moved from where it started more than from the current one's.
            if self._slice(nxt, all_of_it=moved2 > half2) and self._stale(pos_m, key):
                self._build(pos_m, key)
        elif moved2 > half2:
            if moved2 != math.inf:  # motion, not other vehicles
                self._moving()
            self._build(pos_m, key)
        elif n >= ALL_PAIRS_BELOW and moved2 > AHEAD_SHARE * AHEAD_SHARE * half2:
            self._moving()
            self._ahead(pos_m, key)
        elif n >= ALL_PAIRS_BELOW and self._age > LONG_LIST and self._share > self.least_share:
            # A wide margin kept long: the swarm has calmed down, a tighter list ahead.
            self._narrow()
            self._ahead(pos_m, key)

    def _ahead(self, pos_m: F64, key: object) -> None:
        """The next list starts from ``pos_m``, with the next list's margin."""
        skin = self._share * self.cutoff_m
        self._next = _Ahead(pos_m, _centred(pos_m), key, self.cutoff_m + skin, skin)

    def closest(self, pos_m: F64, key: object = None) -> float | None:
        """The swarm's smallest pairwise distance [m] at ``pos_m`` when the
        list holds it: fresh for these vehicles and positions, and its
        closest pair nearer than ``r_c`` (every such pair is listed); else
        None. The distance as ``loop._min_separation`` computes it (the
        difference's squares summed by ``einsum``): the same float."""
        if self._stale(pos_m, key) or self._half[0].size == 0:
            return None
        i, j = self._half
        # Every listed pair's square in one compiled pass, then the einsum's
        # float of the few within rounding of the smallest: the same bits as
        # every pair through einsum.
        near = self._kernels.listed_near_min(pos_m, i, j, 1e-9)
        if near.size == 0:  # a NaN position: no figure from the list
            return None
        diff = pos_m[i[near]] - pos_m[j[near]]
        d = float(np.sqrt(np.einsum("ij,ij->i", diff, diff)).min())
        return d if d < self.cutoff_m else None

    def row_pairs(self, pos_m: F64, rows: I64, key: object = None) -> Pairs:
        """``cutoff.row_pairs(pos_m, rows, cutoff_m)``'s pairs (same arrays,
        in another order); ``key`` names the vehicles (e.g. their ids): a
        different key rebuilds the list. The steps take ``row_repulsion``;
        this is its numpy reference (``cutoff.row_repulsion`` of these pairs
        is its floats bit for bit: tests/control/test_kernels.py)."""
        rows = np.asarray(rows, dtype=np.int64)
        self._prepare(pos_m, key)
        first = self._start[rows]
        count = self._start[rows + 1] - first
        owner = np.arange(rows.shape[0], dtype=np.int64)
        r_s, at = _expand(owner, first, count, int(count.sum()))
        rc = self.cutoff_m
        return _near_rows(pos_m, rows, r_s, self._other[at], rc * rc)

    def row_repulsion(
        self,
        pos_m: F64,
        rows: I64,
        key: object,
        charges: F64,
        k_r: float,
        *,
        q_n_twice: bool,
        r_min_m: float,
    ) -> F64:
        """``cutoff.row_repulsion(self.row_pairs(pos_m, rows, key), rows,
        charges, k_r, ...)``, the same floats, without the pairs: Eq. 9c
        for ``rows`` over their listed candidates in one compiled pass
        (``kernels.listed_repulsion_sums``)."""
        rows = np.asarray(rows, dtype=np.int64)
        self._prepare(pos_m, key)
        q = np.asarray(charges, dtype=np.float64)
        out = self._kernels.listed_repulsion_sums(
            pos_m, rows, self._start, self._other, q, self.cutoff_m,
            q_n_twice=q_n_twice, r_min_m=r_min_m,
        )  # fmt: skip
        qn = q[rows] * q[rows] if q_n_twice else q[rows]
        out *= (k_r * qn)[:, None]
        return out
