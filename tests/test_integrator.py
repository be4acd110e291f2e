"""The in-process integrator (``gcs_swarm.integrator.integrate``): join/leave,
recording, files, the filter hook, determinism, and the summary figures
(gcs_swarm.analysis)."""

from __future__ import annotations

import math
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from gcs_swarm.analysis import (
    classify_bipyramid,
    group_values,
    min_box_clearance,
    min_separation,
    pairwise_distances,
    radii,
    time_to_form,
)
from gcs_swarm.control import Box, LawConfig
from gcs_swarm.integrator import SimResult, integrate

STARTS = [(2, 1, 2), (-1, -1, -1), (3, 4, 2), (4, 2, 2), (3, 3, 3), (-2, -2, -2)]
DT = 0.05


@cache
def _leave_rejoin() -> SimResult:
    # Vehicle 6 leaves at 10 s and rejoins at 200 s; the run ends at 400 s.
    # (Leaving a SETTLED octahedron leaves a square pyramid: an equilibrium of
    # the five, a saddle, which the bipyramid only re-forms from as fast as the
    # numerical asymmetry grows: still not done 140 s after a leave at 60 s,
    # measured. Leaving at 10 s, before the shape is exact, avoids that.)
    events = [(10.0, "leave", 6), (200.0, "join", 6)]
    return integrate(LawConfig(), STARTS, duration=400.0, dt=DT, events=events)


def test_leave_reforms_a_bipyramid_and_rejoin_an_octahedron() -> None:
    res = _leave_rejoin()
    k_out = round(199.0 / DT)
    assert not res.active[k_out, 5] and np.isnan(res.pos_m[k_out, 5]).all()
    assert res.active[k_out, :5].all() and res.active[-1].all()
    five = res.pos_m[k_out, :5]
    shape = classify_bipyramid(five, res.leader_pos_m[k_out])
    # 189 s after the leave the five have settled to ~1e-5 (measured: pole
    # distance within 6e-8 of its final value), so 1e-4 checks the shape.
    assert shape.tilt < 1e-4  # equator perpendicular to the pole axis
    r5 = radii(five, res.leader_pos_m[k_out])
    poles, eq = list(shape.poles), list(shape.equator)
    d_poles = float(np.linalg.norm(five[poles[0]] - five[poles[1]]))
    assert d_poles == pytest.approx(r5[poles].sum(), abs=1e-4)  # antipodal poles
    # The poles sit slightly farther out than the equator (measured 2.419915 vs 2.413238).
    assert r5[poles].min() > r5[eq].max()
    # Equilateral equator, side sqrt(3) R: the in-plane spacing is the slowest
    # mode (5e-4 off at this time, measured), hence 2e-3.
    side = math.sqrt(3.0) * r5[eq].mean()
    np.testing.assert_allclose(pairwise_distances(five[eq]), side, atol=2e-3)
    # Back to six: the octahedron of Example 1 (radius 2.48418, +-1e-4).
    np.testing.assert_allclose(radii(res.pos_m[-1], res.leader_pos_m[-1]), 2.48418, atol=1e-4)
    assert [c for _, c in group_values(pairwise_distances(res.pos_m[-1]), tol=1e-4)] == [12, 3]


def test_inactive_from_the_start_and_join() -> None:
    res = integrate(
        LawConfig(),
        STARTS[:2],
        duration=1.0,
        dt=0.1,
        active=[True, False],
        events=[(0.5, "join", 2)],
    )
    assert np.isnan(res.pos_m[:5, 1]).all() and not np.isnan(res.pos_m[5:, 1]).any()
    np.testing.assert_array_equal(res.pos_m[5, 1], STARTS[1])  # joins from its start, at rest


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="ids"):
        integrate(LawConfig(), STARTS[:2], duration=1.0, ids=[1, 1])
    with pytest.raises(ValueError, match="bad event"):
        integrate(LawConfig(), STARTS[:2], duration=1.0, events=[(0.1, "land", 1)])
    with pytest.raises(ValueError, match="dt > 0"):
        integrate(LawConfig(), STARTS[:2], duration=1.0, dt=0.0)


def test_deterministic() -> None:
    a = integrate(LawConfig(), STARTS, duration=5.0, dt=0.01)
    b = integrate(LawConfig(), STARTS, duration=5.0, dt=0.01)
    np.testing.assert_array_equal(a.pos_m, b.pos_m)
    np.testing.assert_array_equal(a.accel_mps2, b.accel_mps2)


def test_accel_filter_hook_is_applied_in_every_stage() -> None:
    calls: list[float] = []

    def brake(t: float, ids: tuple[int, ...], p: np.ndarray, v: np.ndarray, a: np.ndarray):  # type: ignore[no-untyped-def]
        calls.append(t)
        return np.zeros_like(a)

    res = integrate(LawConfig(), STARTS, duration=1.0, dt=0.1, accel_filter=brake)
    np.testing.assert_array_equal(res.pos_m[-1], np.array(STARTS, dtype=float))
    assert len(calls) == 4 * 10 + 1  # 4 RK4 stages per step, plus the last sample
    np.testing.assert_array_equal(res.accel_mps2, 0.0)


def test_save_npz_and_csv(tmp_path: Path) -> None:
    res = integrate(
        LawConfig(), STARTS[:3], duration=1.0, dt=0.1, events=[(0.5, "leave", 9)], ids=[7, 8, 9]
    )
    npz = res.save(tmp_path / "run.npz")
    with np.load(npz) as data:
        np.testing.assert_array_equal(data["pos_m"], res.pos_m)
        assert list(data["ids"]) == [7, 8, 9]
    csv = res.save(tmp_path / "run.csv", every=5)
    lines = csv.read_text().splitlines()
    assert lines[0].startswith("t_s,id,x_m,y_m,z_m")
    # Samples 0, 5, 10 -> t = 0, 0.5, 1.0; vehicle 9 is gone from t = 0.5.
    assert len(lines) == 1 + 3 + 2 + 2
    first = lines[1].split(",")
    assert float(first[0]) == 0.0 and first[1] == "7" and float(first[2]) == 2.0
    assert first[-2] == "formation"
    with pytest.raises(ValueError, match=r"\.csv or \.npz"):
        res.save(tmp_path / "run.txt")


def test_summary_figures() -> None:
    res = integrate(LawConfig(), STARTS[:4], duration=200.0, dt=DT)
    s = res.figures()
    assert s.n_vehicles == 4 and s.episodes == 0 and s.min_clearance_m is None
    np.testing.assert_allclose(s.final_radii_m, 2.33359, atol=1e-4)
    assert [c for _, c in s.distance_groups] == [6]
    assert s.distance_groups[0][0] == pytest.approx(3.81074, abs=1e-4)
    assert 0.0 < s.min_separation_m < 3.81074 and s.time_to_form_s > 0.0
    text = s.text()
    assert "tetrahedron" in text and "6 x 3.81074" in text


def test_analysis_helpers() -> None:
    p = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(pairwise_distances(p), [1.0, 5.0, math.sqrt(26.0)])
    assert min_separation(p) == 1.0 and min_separation(p[:1]) == math.inf
    box = Box((10.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    assert min_box_clearance(p, [box]) == pytest.approx(math.hypot(6.0, 3.0))
    assert min_box_clearance(p, []) == math.inf
    t = np.linspace(0.0, 10.0, 11)
    series = np.where(t < 4.0, 0.0, 1.0)[:, None]
    assert time_to_form(t, series) == 4.0
    with pytest.raises(ValueError, match="5 vehicles"):
        classify_bipyramid(p, np.zeros(3))


def test_on_out_is_told_where_the_vehicles_that_left_are_held() -> None:
    """``on_out``: at the start the reserve 3, held at its start; at the
    leave, vehicle 2 too, where it stopped (held at rest), and it has flown;
    at the joins, nobody."""
    told: list[tuple[dict[int, np.ndarray], set[int]]] = []
    res = integrate(LawConfig(), STARTS[:3], duration=1.0, dt=0.1, active=[True, True, False],
                    events=[(0.5, "leave", 2), (0.8, "join", 2), (0.8, "join", 3)],
                    on_out=lambda held, flown: told.append((held, flown)))  # fmt: skip
    assert [(sorted(h), sorted(f)) for h, f in told] == [([3], []), ([2, 3], [2]), ([], [])]
    np.testing.assert_array_equal(told[0][0][3], STARTS[2])
    held = told[1][0][2]
    assert np.isnan(res.pos_m[5:8, 1]).all()
    np.testing.assert_array_equal(res.pos_m[8, 1], held)  # rejoins from where it was held
