"""Every mission shipped in config/missions/ validates and flies in the
in-process simulator (issue 5), and the two Example 1 files reproduce the
paper's figures through the whole YAML -> simulator path (issue 3)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gcs_swarm.analysis import group_values, pairwise_distances, radii
from gcs_swarm.mission import load_mission
from gcs_swarm.offline import simulate_mission

MISSIONS = sorted((Path(__file__).parent.parent / "config" / "missions").glob("*.yaml"))
#: Smoke-run cap [s]: long enough for every scenario's first events (the
#: scenario-2 join is at 25 s, the scenario-3 episode starts near 12 s) while
#: keeping the suite short; the full durations are exercised below and by
#: the law tests.
SMOKE_S = 30.0


def test_the_expected_missions_are_shipped() -> None:
    names = {p.stem for p in MISSIONS}
    assert {
        "example1_octahedron",
        "example1_tetrahedron",
        "scenario1_local_minimum",
        "scenario2_join",
        "scenario3_obstacle",
        "sitl_arducopter",
    } <= names


@pytest.mark.parametrize("path", MISSIONS, ids=lambda p: p.stem)
def test_shipped_mission_validates_and_simulates(path: Path) -> None:
    mission = load_mission(path)
    duration = min(mission.settings.duration, SMOKE_S)
    out = simulate_mission(mission, duration_s=duration)
    res = out.result
    assert res.times_s[-1] == pytest.approx(duration)
    act = res.active
    assert np.isfinite(res.pos_m[act]).all()
    assert np.isfinite(res.accel_mps2[act]).all()
    # Every vehicle that is active at the end moved under the law (none is stuck
    # at an exactly unchanged start) - guards against a mission that loads but
    # never engages its vehicles.
    final = act[-1]
    assert final.any()
    starts = np.array([v.start for v in mission.vehicles])
    moved = np.linalg.norm(res.pos_m[-1, final] - starts[final], axis=-1)
    assert (moved > 1e-3).all()
    summary = out.text()
    assert "minimum separation" in summary


def test_example1_octahedron_file_gives_the_papers_figures() -> None:
    out = simulate_mission(load_mission(MISSIONS[0].parent / "example1_octahedron.yaml"))
    res = out.result
    p = res.pos_m[-1]
    # Tolerance 1e-4 m as issue 3 states; the file's 150 s settle the
    # distances to ~2e-5 (the slow tangential mode; see tests/control/test_example1.py).
    np.testing.assert_allclose(radii(p, res.leader_pos_m[-1]), 2.48418, atol=1e-4)
    d = pairwise_distances(p)  # sorted
    np.testing.assert_allclose(d[:12], 3.51316, atol=1e-4)
    np.testing.assert_allclose(d[12:], 4.96836, atol=1e-4)
    assert [c for _, c in group_values(d, tol=1e-4)] == [12, 3]


def test_example1_tetrahedron_file_gives_the_papers_radius() -> None:
    out = simulate_mission(load_mission(MISSIONS[0].parent / "example1_tetrahedron.yaml"))
    res = out.result
    np.testing.assert_allclose(radii(res.pos_m[-1], res.leader_pos_m[-1]), 2.33359, atol=1e-4)


def test_scenario2_fifth_vehicle_joins_at_its_event() -> None:
    mission = load_mission(MISSIONS[0].parent / "scenario2_join.yaml")
    (join,) = [e for e in mission.events if e.action == "join"]
    out = simulate_mission(mission, duration_s=join.t + 1.0)
    res = out.result
    before = res.times_s < join.t - 1e-9
    assert res.active[before].sum(axis=1).max() == 4
    assert res.active[-1].sum() == 5
    assert math.isfinite(float(np.nanmax(res.pos_m)))
