"""Eq. V1, the velocity reference (control/tracking.py), stepped in process
with a hand-advanced mission clock."""

from __future__ import annotations

import numpy as np
import pytest

from gcs_swarm.control.tracking import MAX_ERROR_MPS, MAX_GAP_S, VelocityReference

DT = 0.02


def _row(*v: float) -> np.ndarray:
    return np.array([v], dtype=np.float64)


def test_starts_from_the_measured_velocity_then_integrates_what_was_sent() -> None:
    ref = VelocityReference()
    v0 = (0.3, -0.2, 0.1)
    out = ref.setpoints([7], 10.0, _row(*v0), _row(1.0, 0.0, -0.5))
    assert out.tolist() == [list(v0)]
    # The vehicle is measured standing still (it did not follow): the reference
    # still integrates what was sent, a 1.0 and -0.5 m/s^2 held for 0.02 s.
    out = ref.setpoints([7], 10.0 + DT, _row(*v0), _row(0.0, 0.0, 0.0))
    assert out[0] == pytest.approx((0.3 + 1.0 * DT, -0.2, 0.1 - 0.5 * DT), abs=1e-15)
    # Zero sent: it stays.
    out2 = ref.setpoints([7], 10.0 + 2 * DT, _row(*v0), _row(0.0, 0.0, 0.0))
    assert out2.tolist() == out.tolist()


def test_a_constant_acceleration_over_many_steps_is_the_closed_form() -> None:
    ref = VelocityReference()
    a = np.array([[0.5, -0.25, 0.125]])
    t, v = 0.0, np.zeros((1, 3))
    for k in range(100):  # the vehicle follows exactly: measured = reference
        t = k * DT
        v = ref.setpoints([1], t, v, a)
    assert v[0] == pytest.approx(a[0] * 99 * DT, rel=1e-12)
    assert ref.held == 0 and ref.restarts == 0


def test_the_reference_is_held_within_max_error_of_the_measured_velocity() -> None:
    ref = VelocityReference()
    still = np.zeros((1, 3))
    push = np.array([[3.0, -3.0, 0.0]])  # a vehicle that cannot follow at all
    for k in range(200):
        out = ref.setpoints([1], k * DT, still, push)
    assert out[0].tolist() == [MAX_ERROR_MPS, -MAX_ERROR_MPS, 0.0]
    assert ref.held > 0
    # No wind-up to unwind: pushed past it, the vehicle drags the reference
    # along, held on the other side (2.5 - 1 rather than 1 + 3 * 0.02).
    out = ref.setpoints([1], 200 * DT, np.array([[2.5, 0.0, 0.0]]), np.zeros((1, 3)))
    assert out[0].tolist() == [2.5 - MAX_ERROR_MPS, -MAX_ERROR_MPS, 0.0]


def test_a_gap_or_time_going_back_restarts_from_the_measured_velocity() -> None:
    ref = VelocityReference()
    a = np.array([[1.0, 0.0, 0.0]])
    ref.setpoints([4], 0.0, np.zeros((1, 3)), a)
    gap = ref.setpoints([4], MAX_GAP_S + 0.01, _row(0.1, 0.2, 0.3), a)
    assert gap.tolist() == [[0.1, 0.2, 0.3]] and ref.restarts == 1
    back = ref.setpoints([4], 0.1, _row(-0.1, 0.0, 0.0), a)
    assert back.tolist() == [[-0.1, 0.0, 0.0]] and ref.restarts == 2
    # Within the gap: integrated (0.02 s of 1 m/s^2 on top of -0.1).
    on = ref.setpoints([4], 0.12, _row(-0.1, 0.0, 0.0), a)
    assert on[0] == pytest.approx((-0.1 + 0.02, 0.0, 0.0), abs=1e-15)


def test_vehicles_are_independent_and_forget_starts_one_again() -> None:
    ref = VelocityReference()
    a = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    z = np.zeros((2, 3))
    ref.setpoints([1, 2], 0.0, z, a)
    out = ref.setpoints([2, 1], DT, z, np.zeros((2, 3)))  # order of rows follows sysids
    assert out[0] == pytest.approx((0.0, 2.0 * DT, 0.0))
    assert out[1] == pytest.approx((1.0 * DT, 0.0, 0.0))
    ref.forget(1)
    again = ref.setpoints([1], 2 * DT, _row(0.5, 0.5, 0.5), np.zeros((1, 3)))
    assert again.tolist() == [[0.5, 0.5, 0.5]] and ref.restarts == 0


def test_a_non_finite_measurement_neither_starts_nor_holds_a_reference() -> None:
    ref = VelocityReference()
    first = ref.setpoints([1], 0.0, _row(np.nan, 0.0, 0.0), _row(1.0, 0.0, 0.0))
    assert np.isnan(first).all()  # no reference: the acceleration goes out alone
    start = ref.setpoints([1], DT, _row(0.2, 0.0, 0.0), _row(1.0, 0.0, 0.0))
    assert start.tolist() == [[0.2, 0.0, 0.0]] and ref.restarts == 0
    on = ref.setpoints([1], 2 * DT, _row(np.nan, np.nan, np.nan), np.zeros((1, 3)))
    assert on[0] == pytest.approx((0.2 + 1.0 * DT, 0.0, 0.0), abs=1e-15)  # integrated on


def test_bad_settings_are_refused() -> None:
    with pytest.raises(ValueError):
        VelocityReference(max_error_mps=0.0)
    with pytest.raises(ValueError):
        VelocityReference(max_gap_s=-1.0)
