"""A biased velocity report through the real station and the real emulator
(lockstep, UDP on 127.0.0.1): the law's prediction of what the bias does, and
the station taking it out (docs/velocity-bias.md)."""

from __future__ import annotations

import asyncio
import dataclasses

import numpy as np
import pytest
from station_harness import fly, lockstep_config, mission_from, radii

from gcs_swarm.integrator import integrate
from gcs_swarm.mission import Mission

# ArduCopter 4.5.6 SITL's EKF, hovering still (docs/velocity-bias.md), NED m/s.
BIAS_NED = (-0.015, 0.013, 0.0)
DURATION_S = 60.0


def _mission(correct: bool) -> Mission:
    m = mission_from("example1_octahedron.yaml", duration=DURATION_S)
    vb = dataclasses.replace(m.settings.velocity_bias, correct=correct)
    return dataclasses.replace(m, settings=dataclasses.replace(m.settings, velocity_bias=vb))


def _flown_radii(correct: bool) -> dict[int, float]:
    mission = _mission(correct)
    cfg = lockstep_config(mission, vel_bias_ned_m_s=BIAS_NED)
    flown = asyncio.run(fly(mission, cfg))
    assert flown.emu.stats.lockstep_timeouts == 0
    s = flown.ok
    assert s.outcome == "completed"
    for v in s.vehicles:  # the estimate the summary reports
        assert v.velocity_bias_corrected is correct
        np.testing.assert_allclose(v.velocity_bias_ned_mps, BIAS_NED, atol=1e-4)
    return radii(s)


def _predicted_radii() -> dict[int, float]:
    """Eq. 1 with the reported velocity v + b: a = (f - (D + k)(v + b)) / M, the
    bias a constant acceleration -(D + k) b / M (mission frame: b = (b_e, b_n, -b_d))."""
    m = _mission(False)
    g = m.law.gains
    b = np.array([BIAS_NED[1], BIAS_NED[0], -BIAS_NED[2]])
    push = -g.damping_scaled / g.mass_scaled * b

    def biased(t: float, ids: tuple[int, ...], pos: object, vel: object, acc: np.ndarray) -> object:
        return acc + push

    r = integrate(m.law, [v.start for v in m.vehicles], [v.q for v in m.vehicles],
                 duration=DURATION_S, dt=0.02, accel_filter=biased)  # fmt: skip
    return dict(zip([v.sysid for v in m.vehicles], r.figures().final_radii_m.tolist(), strict=True))


@pytest.mark.slow
def test_uncorrected_bias_moves_the_formation_as_the_law_predicts() -> None:
    flown = _flown_radii(correct=False)
    want = _predicted_radii()
    # At the paper's time scale the bias displaces the octahedron by a few
    # centimetres: radii up to 0.013 m off 2.48418 (measured), well outside
    # the 1e-3 the corrected loop holds.
    assert max(abs(r - 2.48418) for r in flown.values()) > 5e-3
    # The 50 Hz sampled loop against the 0.02 s RK4: 1.4e-3 at 100 s without a
    # bias (test_closed_loop); 2e-3 allowed here at 60 s.
    for sysid, r in flown.items():
        assert r == pytest.approx(want[sysid], abs=2e-3), (sysid, flown, want)


@pytest.mark.slow
def test_the_station_takes_the_bias_out() -> None:
    flown = _flown_radii(correct=True)
    np.testing.assert_allclose(list(flown.values()), 2.48418, atol=1e-3)
