"""The safety filter on a jerk-limited, lagged vehicle (issue 14 item 2).

Closed loop, in process: the vehicle is ``integrator.vehicle_step`` with
ArduCopter's default envelope (jerk 5 m/s^3 horizontally and vertically,
first-order lag 0.2 s), the model of what SITL did. The filter that assumes a
point mass (the envelope unknown to the station) loses clearance and
separation on it; the filter planning within the envelope (B1'-B2', then the
shaper) keeps them every cycle. State tolerance: the barrier models the lag
as a pure delay and the vehicle has a first-order lag, so the guarantee is
met up to a few millimetres (2 cm allowed below).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gcs_swarm.control.envelope import ARDUCOPTER, CommandShaper
from gcs_swarm.control.params import Envelope, LawConfig, Limits, Safety
from gcs_swarm.control.safety import SafetyFilter, SafetyHook
from gcs_swarm.integrator import SimResult, integrate, vehicle_step
from gcs_swarm.mission import load_mission
from gcs_swarm.offline import EnvelopeHook, simulate_mission

MISSIONS_DIR = Path(__file__).resolve().parents[2] / "config" / "missions"
TOL_M = 0.02
SCENARIO_S = 30.0  # the tetrahedron is past the box by about 25 s


def _scenario3(station: Envelope) -> tuple[SimResult, LawConfig]:
    mission = load_mission(MISSIONS_DIR / "scenario3_safety.yaml")
    law = replace(mission.law, limits=replace(mission.law.limits, envelope=station))
    dt = 1.0 / mission.settings.rate
    filt = SafetyFilter(law.limits, law.safety, law.obstacles, dt=dt)
    hook = (
        EnvelopeHook(CommandShaper(station, dt), filt)
        if station.bounded
        else SafetyHook(filt)  # one call per step on the vehicle path: no RK4 stages
    )
    res = integrate(
        law,
        [v.start for v in mission.vehicles],
        duration=SCENARIO_S,
        dt=dt,
        accel_filter=hook,
        vehicle=ARDUCOPTER,
    )
    return res, law


def test_point_mass_filter_fails_on_the_jerk_limited_vehicle() -> None:
    """The motivating case: the issue-10 filter, right on a point mass, lets the
    SITL-like vehicle into the box and closer than the separation."""
    res, law = _scenario3(Envelope())
    s = res.figures()
    assert s.min_clearance_m is not None
    assert s.min_clearance_m < law.safety.clearance - 0.5  # inside the margin by far
    assert s.min_clearance_m < 0.0  # measured -1.9 m: inside the box


def test_envelope_filter_keeps_clearance_and_separation_every_cycle() -> None:
    res, law = _scenario3(ARDUCOPTER)
    s = res.figures()  # over every sample (every control cycle) of the run
    assert s.min_clearance_m is not None
    assert s.min_clearance_m >= law.safety.clearance - TOL_M
    assert s.min_separation_m >= law.safety.separation - TOL_M
    assert s.episodes >= 1  # the box was met, not avoided by luck
    # What was sent stays inside the envelope's accelerations and jerk.
    a = res.accel_mps2
    assert np.nanmax(np.linalg.norm(a[..., :2], axis=-1)) <= 2.5 + 1e-9
    assert np.nanmax(np.abs(a[..., 2])) <= 1.0 + 1e-9
    step = np.diff(a, axis=0)
    assert np.nanmax(np.linalg.norm(step[..., :2], axis=-1)) <= 5.0 * 0.02 + 1e-9
    assert np.nanmax(np.abs(step[..., 2])) <= 5.0 * 0.02 + 1e-9


def _head_on(planning: bool, steps: int = 600) -> float:
    """Two vehicles 20 m apart whose law pushes them at each other at 2.5 m/s^2
    (a stand-in for any law), 50 Hz, flown by the ArduCopter model. Returns the
    smallest distance [m] over every cycle."""
    dt = 0.02
    station = ARDUCOPTER if planning else Envelope()
    limits = Limits(a_max=2.5, v_max=5.0, envelope=station)
    filt = SafetyFilter(limits, Safety(enabled=True, separation=1.0), (), dt=dt)
    shaper = CommandShaper(station, dt)
    pos = np.array([[-10.0, 0.0, 10.0], [10.0, 0.1, 10.0]])
    vel = np.zeros((2, 3))
    tgt = np.zeros((2, 3))
    act = np.zeros((2, 3))
    want = np.array([[2.5, 0.0, 0.0], [-2.5, 0.0, 0.0]])
    closest = np.inf
    for _ in range(steps):
        prev = shaper.previous([1, 2])
        cmd, _ = filt.filter(pos, vel, want, prev_accel_mps2=prev)
        cmd = shaper.shape([1, 2], cmd)
        pos, vel, tgt, act = vehicle_step(pos, vel, tgt, act, cmd, ARDUCOPTER, dt)
        closest = min(closest, float(np.linalg.norm(pos[0] - pos[1])))
    return closest


def test_head_on_pair() -> None:
    """Point-mass planning lets the pair come within the separation (measured:
    well inside 1 m); planning within the envelope stops them outside it."""
    assert _head_on(planning=False) < 1.0 - 0.2
    assert _head_on(planning=True) >= 1.0 - TOL_M


def test_unbounded_envelope_leaves_the_filter_as_it_was() -> None:
    """The default envelope takes the point-mass code path: the same commands
    with and without a ``prev_accel_mps2`` (which only the envelope reads)."""
    rng = np.random.default_rng(3)
    limits = Limits(a_max=10.0, v_max=5.0, z_floor=0.0)
    filt = SafetyFilter(limits, Safety(enabled=True), (), dt=0.02)
    pos = rng.uniform(0.0, 3.0, size=(5, 3))
    vel = rng.normal(size=(5, 3))
    a = rng.normal(size=(5, 3)) * 20.0
    one, _ = filt.filter(pos, vel, a)
    two, _ = filt.filter(pos, vel, a, prev_accel_mps2=rng.normal(size=(5, 3)))
    assert np.array_equal(one, two)


@pytest.mark.parametrize("name", ["example1_octahedron", "scenario3_safety"])
def test_missions_without_envelope_simulate_the_point_mass(name: str) -> None:
    """No ``limits.envelope``: integrate stays the ideal point mass."""
    out = simulate_mission(load_mission(MISSIONS_DIR / f"{name}.yaml"), duration_s=1.0)
    assert out.envelope is None


@pytest.mark.parametrize(
    "env",
    [
        Envelope(jerk_xy=5.0, jerk_z=5.0),  # jerk only: unbounded accelerations
        Envelope(accel_z=1.0),  # one cap, no jerk, no lag
        Envelope(lag_s=0.2, accel_xy=2.0),  # lag without jerk
        Envelope(lag_s=0.2),  # lag alone
    ],
)
@pytest.mark.parametrize("limits", [Limits(), Limits(a_max=3.0, v_max=2.0, z_floor=0.0)])
def test_partial_envelopes_give_finite_commands(env: Envelope, limits: Limits) -> None:
    """Any mix of finite and infinite bounds: finite commands, no numpy warning
    (warnings are errors here), the caps that are finite respected."""
    from gcs_swarm.control.params import Box

    rng = np.random.default_rng(5)
    filt = SafetyFilter(
        replace(limits, envelope=env), Safety(enabled=True), [Box((5, 5, 5), (1, 1, 1))], dt=0.02
    )
    for _ in range(5):
        pos = rng.uniform(0.0, 8.0, (5, 3))
        vel = rng.normal(size=(5, 3))
        prev = rng.normal(size=(5, 3)) * 0.3
        out, _ = filt.filter(pos, vel, rng.normal(size=(5, 3)) * 3.0, prev_accel_mps2=prev)
        assert np.isfinite(out).all()
        assert np.all(np.abs(out[:, 2]) <= min(env.accel_z, limits.a_max) + 1e-6)
