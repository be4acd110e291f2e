"""DelayCompensator without I/O: the clock estimate from TIMESYNC answers and
the prediction over the commands in flight, against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from gcs_swarm.runtime.delay import MIN_SAMPLES, DelayCompensator

OFFSET, ONE_WAY = 100.0, 0.05  # vehicle clock 100 s ahead of the station's; 50 ms each way


def _synced(dc: DelayCompensator, sysid: int = 1) -> None:
    for k in range(MIN_SAMPLES):
        sent = 10.0 + k * 0.2
        vehicle_at = sent + ONE_WAY + OFFSET  # the vehicle stamps on receipt
        dc.timesync(sysid, round(vehicle_at * 1e9), round(sent * 1e9), sent + 2 * ONE_WAY)


def test_estimate_needs_enough_round_trips_then_finds_offset_and_delay() -> None:
    dc = DelayCompensator(accel_max_mps2=5.0)
    dc.timesync(1, round(110e9), round(10e9), 10.1)
    assert dc.estimate(1) is None
    _synced(dc)
    off, delay = dc.estimate(1) or (0.0, 0.0)
    assert off == pytest.approx(OFFSET, abs=1e-9) and delay == pytest.approx(ONE_WAY, abs=1e-9)


def test_prediction_integrates_the_commands_in_flight_exactly() -> None:
    dc = DelayCompensator(accel_max_mps2=5.0)
    _synced(dc)
    now = 20.0
    a = np.array([1.0, 0.0, 0.0])
    dc.sent(1, now - 0.2, a)  # lands at vehicle time now - 0.2 + OFFSET + ONE_WAY
    dc.sent(1, now - 0.1, 2 * a)
    report_s = now + OFFSET - 0.2  # a report 0.2 s old
    p, v = dc.predict(1, report_s, now, np.zeros(3), np.array([0.5, 0.0, 0.0]))
    # Vehicle time from the report (T): nothing in force for 0.05 s, then a
    # (landed at T + 0.05) for 0.1 s, then 2a (T + 0.15) for 0.1 s, to the
    # landing of a setpoint sent now (T + 0.25).
    x, vx = 0.5 * 0.05, 0.5
    x, vx = x + vx * 0.1 + 0.5 * 1.0 * 0.1**2, vx + 1.0 * 0.1
    x, vx = x + vx * 0.1 + 0.5 * 2.0 * 0.1**2, vx + 2.0 * 0.1
    np.testing.assert_allclose(p, [x, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(v, [vx, 0.0, 0.0], atol=1e-12)
    # A command beyond what the vehicle follows is predicted at its ceiling.
    dc.sent(1, now, np.array([0.0, 50.0, 0.0]))
    _, v = dc.predict(1, now + OFFSET, now + 0.1, np.zeros(3), np.zeros(3))
    assert v[1] == pytest.approx(5.0 * 0.1, abs=1e-12)


def test_no_prediction_without_estimate_or_past_the_horizon() -> None:
    dc = DelayCompensator(accel_max_mps2=5.0)
    p, v = np.ones(3), np.ones(3)
    assert dc.predict(1, 0.0, 0.0, p, v) == (p, v)
    _synced(dc)
    stale = dc.predict(1, 0.0, 20.0, p, v)  # a report 120 s old: nothing sensible
    assert stale[0] is p and stale[1] is v
