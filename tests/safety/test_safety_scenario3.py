"""Scenario 3 (``config/missions/scenario3_obstacle.yaml``: the moving
tetrahedron meets a box) through the in-process simulator with the safety
filter as its acceleration hook, filter on and off.

Limits for both runs: a_max = 10 m/s^2, v_max = 5 m/s; the filter keeps 0.5 m
from the box and 1 m between vehicles. dt = 0.05 s (RK4; the hook runs in
every stage, so the filter acts as a state feedback) and 40 s, enough for
every vehicle to reach the far side of the box in the filter-off run (last at
22.6 s; the episode ends at 27.3 s), keep the run to a few seconds.
"""

from __future__ import annotations

import dataclasses
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from gcs_swarm.control.limits import box_signed_distance
from gcs_swarm.control.params import Limits, Safety
from gcs_swarm.control.safety import SafetyFilter, SafetyHook, SafetyTotals
from gcs_swarm.integrator import SimResult, integrate
from gcs_swarm.mission import load_mission

MISSION = Path(__file__).resolve().parents[2] / "config" / "missions" / "scenario3_obstacle.yaml"
DT = 0.05
A_MAX, V_MAX, CLEARANCE, SEPARATION = 10.0, 5.0, 0.5, 1.0
POS_TOL = 1e-6  # the barrier is exact up to rounding (measured >= 0.5 - 1e-12 m)


@cache
def _run(enabled: bool, heading: str = "desired") -> tuple[SimResult, SafetyTotals]:
    """Filter on or off; ``heading`` of the vertical field: ``desired`` is what
    a mission's ``heading: auto`` picks with the filter on."""
    law = load_mission(MISSION).law
    law = dataclasses.replace(law, avoidance=dataclasses.replace(law.avoidance, heading=heading))
    starts = [v.start for v in load_mission(MISSION).initial]
    lim = Limits(a_max=A_MAX, v_max=V_MAX)
    saf = Safety(enabled=enabled, clearance=CLEARANCE, separation=SEPARATION)
    cfg = dataclasses.replace(law, limits=lim, safety=saf)
    hook = SafetyHook(SafetyFilter(lim, saf, law.obstacles, dt=DT))
    res = integrate(cfg, starts, duration=40.0, dt=DT, accel_filter=hook)
    return res, hook.stats.totals()


def _clearance(res: SimResult) -> np.ndarray:
    box = res.config.obstacles[0]
    p = res.pos_m.reshape(-1, 3)
    d, _ = box_signed_distance(p, np.array([box.centre]), np.array([box.half_extents]))
    return d.reshape(res.pos_m.shape[:2])


def _time_past(res: SimResult) -> list[float | None]:
    """Per vehicle, the first time it is beyond the box's far face (x)."""
    box = res.config.obstacles[0]
    far = box.centre[0] + box.half_extents[0]
    out: list[float | None] = []
    for j in range(res.pos_m.shape[1]):
        k = np.flatnonzero(res.pos_m[:, j, 0] > far)
        out.append(float(res.times_s[k[0]]) if k.size else None)
    return out


def test_scenario3_filter_on_keeps_clearance_separation_and_limits() -> None:
    res, summary = _run(True)
    assert _clearance(res).min() >= CLEARANCE - POS_TOL
    p = res.pos_m
    d = np.linalg.norm(p[:, :, None] - p[:, None], axis=-1) + np.eye(p.shape[1]) * 1e9
    assert d.min() >= SEPARATION - POS_TOL
    assert np.nanmax(np.linalg.norm(res.accel_mps2, axis=-1)) <= A_MAX + 1e-9
    assert summary.infeasible == 0
    assert summary.interventions > 0


def test_scenario3_filter_off_cuts_into_the_box() -> None:
    res, summary = _run(False, "velocity")
    # Spec s11: the paper's paths cut into the box (measured -0.32 m);
    # every vehicle passes it.
    assert _clearance(res).min() < -0.2
    assert all(t is not None for t in _time_past(res))
    assert summary.max_correction_mps2 > 0  # a_max clamps the switch spikes


def test_scenario3_filter_on_every_vehicle_passes_and_reforms() -> None:
    on, _ = _run(True)
    off, _ = _run(False, "velocity")
    t_on, t_off = _time_past(on), _time_past(off)
    assert all(t is not None for t in t_on)
    # Time to pass, filter on next to off (measured 19.9/19.8/24.3/22.6 s on,
    # 18.4/19.8/21.4/22.6 s off): the filter costs at most a few seconds.
    for a, b in zip(t_on, t_off, strict=True):
        assert a is not None and b is not None and a - b < 5.0
    # Re-formed after the box: back in formation, with the same radii to the
    # leader as the filter-off run at the end (the moving formation is not the
    # static sphere: radii 2.74..2.99 m both ways; measured agreement 0.022 m
    # sorted, asserted to 0.1 m, 3.5 % of the radius).
    assert on.behaviour[-1] == "formation" and off.behaviour[-1] == "formation"
    r_on = np.sort(np.linalg.norm(on.pos_m[-1] - on.leader_pos_m[-1], axis=-1))
    r_off = np.sort(np.linalg.norm(off.pos_m[-1] - off.leader_pos_m[-1], axis=-1))
    np.testing.assert_allclose(r_on, r_off, atol=0.1)


@pytest.mark.xfail(
    strict=True,
    reason=(
        "law, not filter: with the spec's heading (phi = the velocity's azimuth, "
        "fields.heading) the filter stops the approach to the face, phi swings "
        "to +-90 deg each RK4 stage and vehicle 3 limit-cycles at x = 17.5 m; "
        "hence heading: auto picks the desired force's azimuth with the filter on"
    ),
)
def test_scenario3_filter_on_with_velocity_heading_passes() -> None:
    res, _ = _run(True, "velocity")
    assert all(t is not None for t in _time_past(res))
