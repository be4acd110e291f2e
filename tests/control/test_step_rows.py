"""A step of some rows (docs/formation-law.md section 3b): each piece against
the whole step's rows.

The rows' sums run in another order than the whole step's, so they agree to
rounding: the tolerance is 1e-12 of the largest force of the step (tens of
additions of terms of that size, each off by at most an ulp, about 2e-16
relative). The pairs found, the separation figure and the safety filter's
rows are compared exactly.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from gcs_swarm.control.cutoff import _cells, _rank_pairs, neighbour_pairs, row_pairs
from gcs_swarm.control.envelope import ARDUCOPTER
from gcs_swarm.control.formation import repulsion_force, repulsion_rows
from gcs_swarm.control.law import law_accelerations
from gcs_swarm.control.loop import ControlLoop
from gcs_swarm.control.neighbours import (
    AHEAD_SHARE,
    KEPT_LIST,
    LONG_LIST,
    MAX_SKIN_SHARE,
    SKIN_GROWTH,
    SKIN_SHARE,
    SLICES,
    NeighbourList,
)
from gcs_swarm.control.obstacles import Ellipsoids
from gcs_swarm.control.params import Gains, LawConfig, Limits, Safety
from gcs_swarm.control.supervisor import Mode

ROUNDING = 1e-12
"""Of the step's largest force (module docstring)."""


def _swarm(n: int, seed: int, spread: float = 6.0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(-spread, spread, (n, 3)), rng.uniform(5.0, 15.0, n)


def _rows(n: int, seed: int, size: int) -> np.ndarray:
    return np.sort(np.random.default_rng(seed + 1).choice(n, size, replace=False))


@pytest.mark.parametrize("n", [12, 63, 64, 300])
@pytest.mark.parametrize("cutoff", [None, 2.0])
@pytest.mark.parametrize("twice", [False, True])
def test_the_rows_repulsion_is_the_whole_repulsion_s_rows(
    n: int, cutoff: float | None, twice: bool
) -> None:
    pos, q = _swarm(n, n)
    rows = _rows(n, n, n // 3)
    whole = repulsion_force(pos, q, 0.2, q_n_twice=twice, cutoff_m=cutoff)
    got = repulsion_rows(pos, rows, q, 0.2, q_n_twice=twice, cutoff_m=cutoff)
    assert got.shape == (len(rows), 3)
    np.testing.assert_allclose(got, whole[rows], rtol=0, atol=ROUNDING * np.abs(whole).max())


@pytest.mark.parametrize("n", [20, 400])
def test_row_pairs_are_the_cells_pairs_of_those_rows_both_ways(n: int) -> None:
    pos, _ = _swarm(n, 7 * n)
    rows = _rows(n, n, n // 4)
    i, j, _, _ = neighbour_pairs(pos, 1.7) or ((), (), None, None)
    want = {(a, b) for a, b in zip(i.tolist(), j.tolist(), strict=True)}
    want |= {(b, a) for a, b in want}
    want = {(a, b) for a, b in want if a in set(rows.tolist())}
    r, other, d, r2 = row_pairs(pos, rows, 1.7)
    got = {(int(rows[a]), int(b)) for a, b in zip(r, other, strict=True)}
    assert got == want
    np.testing.assert_array_equal(d, pos[rows[r]] - pos[other])
    assert (r2 < 1.7**2).all()


def test_the_neighbour_list_finds_the_cells_pairs_and_rebuilds_only_when_a_vehicle_moved() -> None:
    n, rc = 300, 1.5
    pos, _ = _swarm(n, 3)
    rows = _rows(n, 3, 60)
    nl = NeighbourList(rc)
    rng = np.random.default_rng(9)

    def same() -> None:
        want = row_pairs(pos, rows, rc)
        got = nl.row_pairs(pos, rows, key="ids")
        assert sorted(
            zip(got[0].tolist(), got[1].tolist(), got[3].tolist(), strict=True)
        ) == sorted(zip(want[0].tolist(), want[1].tolist(), want[3].tolist(), strict=True))

    same()
    assert nl.builds == 1
    pos = pos + np.array([100.0, -40.0, 7.0])  # the whole formation flies on: same distances
    same()
    # each vehicle within skin / 2 of where it was, relative to the swarm's mean
    step = rng.normal(size=(n, 3))
    step *= 0.45 * nl.skin_m / np.linalg.norm(step, axis=1, keepdims=True)
    assert np.linalg.norm(step - step.mean(axis=0), axis=1).max() < 0.5 * nl.skin_m
    pos = pos + step
    same()
    assert nl.builds == 1
    pos[17] += [nl.skin_m, 0.0, 0.0]  # one vehicle farther
    same()
    assert nl.builds == 2
    nl.row_pairs(pos, rows, key="others")  # other vehicles: built again
    assert nl.builds == 3


def test_the_pairs_found_by_slices_of_ranks_are_the_whole_search_s() -> None:
    """``neighbour_pairs`` is ``_rank_pairs`` over every rank; any cut of the
    ranks into slices finds the same pairs, each once (the arrays joined in
    slice order are the whole search's, element for element)."""
    n, rc = 500, 1.4
    pos, _ = _swarm(n, 11)
    whole = neighbour_pairs(pos, rc)
    assert whole is not None
    c = _cells(pos, rc)
    xyz = np.ascontiguousarray(pos[c.order].T)
    for cuts in ([0, n], [0, 1, 2, 250, 499, n], [*list(range(0, n, 97)), n]):
        parts = [_rank_pairs(c, xyz, a, b, rc * rc) for a, b in itertools.pairwise(cuts)]
        i = np.concatenate([p[0] for p in parts if p is not None])
        j = np.concatenate([p[1] for p in parts if p is not None])
        assert {(a, b) for a, b in zip(i.tolist(), j.tolist(), strict=True)} == {
            (a, b) for a, b in zip(whole[0].tolist(), whole[1].tolist(), strict=True)
        }
        assert len(i) == len(whole[0])


def test_the_neighbour_list_built_ahead_in_slices_keeps_every_step_s_pairs() -> None:
    """A swarm churning in place (every vehicle on its own straight line):
    after the first list, every list is built ahead in slices (``ahead``),
    none at once (``builds`` stays 1), and every step's pairs are
    ``row_pairs``' on the positions of that step. A vehicle that then jumps
    past the margin while the next list is half found gets a list at once,
    still with every pair."""
    n, rc = 400, 1.5
    pos, _ = _swarm(n, 21)
    nl = NeighbourList(rc)
    rng = np.random.default_rng(5)
    # Each step moves every vehicle 1/40 of the margin's half: the next list
    # starts at AHEAD_SHARE of it and is done SLICES + 1 steps later, well
    # before the margin is used.
    per_step = 0.5 * nl.skin_m / 40
    assert (1 - AHEAD_SHARE) * 40 > SLICES + 1

    def same(rows: np.ndarray) -> None:
        want = row_pairs(pos, rows, rc)
        got = nl.row_pairs(pos, rows, key="ids")
        assert sorted(zip(got[0].tolist(), got[1].tolist(), strict=True)) == sorted(
            zip(want[0].tolist(), want[1].tolist(), strict=True)
        )

    sets = [np.arange(k, n, 4) for k in range(4)]
    way = rng.normal(size=(n, 3))
    way *= per_step / np.linalg.norm(way, axis=1, keepdims=True)
    for step in range(400):
        pos = pos + way
        same(sets[step % 4])
    assert nl.builds == 1
    assert nl.ahead >= 400 // 40
    while nl._next is None:  # until the next list is under way
        pos = pos + per_step * np.array([1.0, 0.0, 0.0]) * (np.arange(n) % 2)[:, None]
        same(sets[0])
    same(sets[1])  # one slice of it found
    pos = pos.copy()
    pos[7] += [nl.skin_m, 0.0, 0.0]  # past the margin of the list and of the next
    builds = nl.builds
    same(sets[2])
    assert nl.builds == builds + 1
    same(sets[3])
    # A vehicle back where the current list has it, but farther than the
    # margin from where the next one started: the next is built at once
    # when put together, not used.
    while nl._next is None:
        pos = pos + way
        same(sets[0])
    start = nl._next.pos.copy()
    ahead, builds = nl.ahead, nl.builds
    mean = pos.mean(axis=0)
    back = nl._ref[3] + mean  # vehicle 3 where the current list has it
    away = back - (start[3] - start.mean(axis=0) + mean)  # from where the next one has it
    pos = pos.copy()
    pos[3] = back + 0.2 * nl.skin_m * away / np.linalg.norm(away)
    now = pos - pos.mean(axis=0)
    assert np.linalg.norm(now[3] - nl._ref[3]) < 0.5 * nl.skin_m
    assert np.linalg.norm(now[3] - (start[3] - start.mean(axis=0))) > 0.5 * nl.skin_m
    for step in range(SLICES + 1):
        same(sets[step % 4])
    assert nl.ahead == ahead + 1 and nl.builds == builds + 1


def test_the_margin_widens_while_the_swarm_churns_and_narrows_once_it_is_calm() -> None:
    """Every vehicle swinging about its own point (0.5 m, faster than a list
    of the least margin lasts two steps): the lists' margin grows to
    ``MAX_SKIN_SHARE`` of the cut-off; held still, it comes back to
    ``SKIN_SHARE``'s in lists built ahead (none at once). Churning again,
    then swinging slowly (lists outliving ``KEPT_LIST`` steps, though never
    ``LONG_LIST``), it narrows until their life is within the band, and
    stays there. Every step's pairs are
    ``row_pairs``' on that step's positions throughout."""
    n, rc = 400, 1.5
    home, _ = _swarm(n, 31)
    rng = np.random.default_rng(8)
    way = rng.normal(size=(n, 3))
    way /= np.linalg.norm(way, axis=1, keepdims=True)
    phase = rng.uniform(0, 2 * np.pi, n)
    nl = NeighbourList(rc)
    sets = [np.arange(k, n, 4) for k in range(4)]

    def same(pos: np.ndarray, rows: np.ndarray) -> None:
        want = row_pairs(pos, rows, rc)
        got = nl.row_pairs(pos, rows, key="ids")
        assert sorted(zip(got[0].tolist(), got[1].tolist(), strict=True)) == sorted(
            zip(want[0].tolist(), want[1].tolist(), strict=True)
        )

    assert nl.skin_m == pytest.approx(SKIN_SHARE * rc)
    fixed = NeighbourList(rc, SKIN_SHARE, max_share=SKIN_SHARE)
    for step in range(120):
        pos = home + 0.5 * np.sin(0.6 * step + phase)[:, None] * way
        same(pos, sets[step % 4])
        fixed.row_pairs(pos, sets[step % 4], key="ids")
    assert nl.skin_m == pytest.approx(MAX_SKIN_SHARE * rc)
    assert fixed.skin_m == pytest.approx(SKIN_SHARE * rc)  # max_share: the margin held
    churned = nl.builds + nl.ahead
    builds = nl.builds
    for step in range(6 * (LONG_LIST + SLICES + 2)):  # calm: every list outlives LONG_LIST
        same(pos, sets[step % 4])
    assert nl.skin_m == pytest.approx(SKIN_SHARE * rc)
    assert nl.builds == builds  # the tighter lists came ahead, in slices
    assert nl.builds + nl.ahead - churned <= 6  # 1.0 -> 0.3 r_c by 1.3 each: five lists
    for step in range(120):
        pos = home + 0.5 * np.sin(0.6 * step + phase)[:, None] * way
        same(pos, sets[step % 4])
    assert nl.skin_m == pytest.approx(MAX_SKIN_SHARE * rc)
    installed, skins = [], []
    for step in range(600):  # slowly: 0.015 rad a step
        pos = home + 0.5 * np.sin(0.015 * step + 0.6 * 119 + phase)[:, None] * way
        before = nl.builds + nl.ahead
        same(pos, sets[step % 4])
        if nl.builds + nl.ahead > before:
            installed.append(step)
            skins.append(nl.skin_m)
    # Narrowed twice by lists that motion made stale after KEPT_LIST steps
    # (none kept LONG_LIST), then steady: 1.0 -> 0.59 r_c here.
    lives = np.diff(installed)
    assert (lives[:2] > KEPT_LIST).all() and (lives < LONG_LIST).all()
    assert skins[-1] == pytest.approx(MAX_SKIN_SHARE * rc / SKIN_GROWTH**2)
    assert len(set(skins[-5:])) == 1


@pytest.mark.parametrize("n", [6, 40])
@pytest.mark.parametrize("cutoff", [None, 2.5])
def test_the_law_s_rows_are_the_whole_law_s_rows(n: int, cutoff: float | None) -> None:
    pos, q = _swarm(n, 11, spread=3.0)
    vel = np.random.default_rng(5).normal(size=(n, 3))
    cfg = LawConfig(gains=Gains(repulsion_cutoff=cutoff))
    mode = Mode.formation(tuple(range(n)))
    lead, obs = np.array([0.5, -0.2, 1.0]), Ellipsoids.from_boxes(())
    whole = law_accelerations(cfg, mode, pos, vel, q, lead, obs)
    rows = _rows(n, n, max(1, n // 3))
    got = law_accelerations(cfg, mode, pos, vel, q, lead, obs, rows)
    np.testing.assert_allclose(got, whole[rows], rtol=0, atol=ROUNDING * np.abs(whole).max())


def test_the_filter_s_row_for_a_vehicle_does_not_read_the_others_commands() -> None:
    """What ``ControlLoop.command`` relies on for a step of some rows: the
    safety filter's answer for one vehicle depends on the states, its own
    desired command and every vehicle's last command sent, not on the
    others' desired commands (a pair's work is split in halves, safety.py).
    A packed swarm, ArduCopter's envelope, random last commands: the whole
    swarm filtered, then with the others' desired commands zeroed."""
    n = 30
    pos, _ = _swarm(n, 2, spread=2.5)
    rng = np.random.default_rng(4)
    vel, a_des, prev = (rng.normal(scale=s, size=(n, 3)) for s in (2.0, 3.0, 1.0))
    law = LawConfig(
        limits=Limits(a_max=8.0, envelope=ARDUCOPTER), safety=Safety(enabled=True, separation=1.0)
    )
    filt = ControlLoop(law, dict.fromkeys(range(n), 10.0), 50.0).safety
    whole, report = filt.filter(pos, vel, a_des, prev_accel_mps2=prev)
    assert report.intervened.sum() > n // 2 and report.infeasible.any()
    for rows in np.array_split(np.arange(n), 3):
        some = np.zeros_like(a_des)
        some[rows] = a_des[rows]
        got, rep = filt.filter(pos, vel, some, prev_accel_mps2=prev)
        np.testing.assert_allclose(got[rows], whole[rows], rtol=0, atol=ROUNDING * 8.0)
        np.testing.assert_array_equal(rep.infeasible[rows], report.infeasible[rows])


def test_a_filtered_step_in_three_steps_of_rows_sends_what_the_whole_step_sends() -> None:
    """The law, the filter and the shaper (ArduCopter's envelope) over a
    packed swarm where the filter acts, from the same last commands: one loop
    steps the whole swarm, another three steps of rows; each row's command
    and report as the whole step's, every command in ``last``, and the
    separation taken once, at the third step (as many rows as vehicles)."""
    n = 30
    pos, _ = _swarm(n, 2, spread=2.5)
    vel = np.random.default_rng(4).normal(scale=2.0, size=(n, 3))
    law = LawConfig(
        limits=Limits(a_max=8.0, envelope=ARDUCOPTER), safety=Safety(enabled=True, separation=1.0)
    )
    ids = list(range(1, n + 1))
    whole = ControlLoop(law, dict.fromkeys(ids, 10.0), 50.0)
    parts = ControlLoop(law, dict.fromkeys(ids, 10.0), 50.0)
    out, accel, report = whole.command(ids, pos, vel)
    assert report is not None and report.intervened.any()
    tol = ROUNDING * np.abs(out.accel_mps2).max()
    whole.account(ids, pos, out, accel, report)
    seps = []
    for rows in np.array_split(np.arange(n), 3):
        o, a, rep = parts.command(ids, pos, vel, rows)
        np.testing.assert_allclose(a, accel[rows], rtol=0, atol=tol)
        assert rep is not None
        np.testing.assert_array_equal(rep.infeasible, report.infeasible[rows])
        np.testing.assert_array_equal(rep.min_separation_m, report.min_separation_m[rows])
        seps.append(parts.account(ids, pos, o, a, rep).min_separation_m)
    assert whole.last is not None and parts.last is not None
    assert seps[:2] == [np.inf, np.inf] and seps[2] == whole.last.min_separation_m
    np.testing.assert_allclose(parts.last.accel_mps2, whole.last.accel_mps2, rtol=0, atol=tol)


def test_the_neighbour_list_s_closest_pair_is_the_separation_when_it_holds_it() -> None:
    """``NeighbourList.closest``: the same float as ``loop._min_separation``
    while the list is fresh and its closest pair is nearer than r_c; None
    when stale (a vehicle moved), for other vehicles, or when every pair is
    at r_c or beyond (then the list may not hold the nearest pair)."""
    from gcs_swarm.control.loop import _min_separation

    n = 300
    pos, _ = _swarm(n, 8)
    nl = NeighbourList(1.5)
    nl.row_pairs(pos, np.arange(10), key="ids")
    assert nl.closest(pos, key="ids") == _min_separation(pos)
    assert nl.closest(pos, key="others") is None
    moved = pos.copy()
    moved[3] += [nl.skin_m, 0.0, 0.0]
    assert nl.closest(moved, key="ids") is None
    far = NeighbourList(0.9 * _min_separation(pos))  # r_c below the nearest pair
    far.row_pairs(pos, np.arange(10), key="ids")
    assert far.closest(pos, key="ids") is None  # the nearest pair is beyond r_c
