"""Closed-loop tests of the safety filter on exact double-integrator kinematics.

The harness applies each filtered command for one zero-order-hold step,
p += v dt + a dt^2/2, v += a dt, at dt = 0.02 s, the station's control period.
"Bad" nominal controllers drive vehicles into boxes, into each other, into the
floor and the fence, and past v_max; the filter must keep every constraint for
the whole run.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from gcs_swarm.control.params import Box, Limits, Safety
from gcs_swarm.control.safety import SafetyFilter, box_signed_distance

DT = 0.02
# Position tolerance [m]. The barrier is exact for planes at the samples; for a
# box or a pair the supporting plane under-estimates the next distance (convex
# distance), so only rounding is left. 1e-6 m is far below anything physical
# and far above the 1e-13 m rounding seen.
POS_TOL = 1e-6

Nominal = Callable[[np.ndarray, np.ndarray, int], np.ndarray]


@dataclass
class Run:
    """Worst figures of one closed-loop run."""

    min_clearance: float = np.inf
    min_separation: float = np.inf
    min_floor_gap: float = np.inf
    max_speed: float = 0.0
    max_accel: float = 0.0
    infeasible_steps: int = 0
    final_pos: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


def run_loop(
    flt: SafetyFilter,
    boxes: list[Box],
    pos: np.ndarray,
    nominal: Nominal,
    steps: int,
    z_floor: float = 0.0,
) -> Run:
    centres = np.array([b.centre for b in boxes]).reshape(-1, 3)
    halves = np.array([b.half_extents for b in boxes]).reshape(-1, 3)
    p = pos.astype(float).copy()
    v = np.zeros_like(p)
    out = Run()
    n = p.shape[0]
    for k in range(steps):
        a, rep = flt.filter(p, v, nominal(p, v, k))
        assert np.all(np.isfinite(a))
        out.max_accel = max(out.max_accel, float(np.linalg.norm(a, axis=1).max()))
        out.infeasible_steps += int(rep.infeasible.any())
        p = p + v * DT + a * DT * DT / 2.0
        v = v + a * DT
        if len(boxes):
            out.min_clearance = min(
                out.min_clearance, box_signed_distance(p, centres, halves)[0].min()
            )
        if n > 1:
            d = np.linalg.norm(p[:, None] - p[None], axis=-1) + np.eye(n) * 1e9
            out.min_separation = min(out.min_separation, float(d.min()))
        out.min_floor_gap = min(out.min_floor_gap, float((p[:, 2] - z_floor).min()))
        out.max_speed = max(out.max_speed, float(np.linalg.norm(v, axis=1).max()))
    out.final_pos = p
    return out


def pd_to(target: np.ndarray, kp: float = 4.0, kd: float = 0.5) -> Nominal:
    """A reckless PD law: aims straight through whatever is in the way."""
    return lambda p, v, k: kp * (target - p) - kd * v


def test_straight_into_a_box_keeps_clearance() -> None:
    box = Box((10.0, 0.0, 3.0), (2.0, 2.0, 2.0))
    flt = SafetyFilter(
        Limits(a_max=5.0, v_max=4.0, z_floor=0.0), Safety(True, 0.5, 1.0), [box], dt=DT
    )
    start = np.array([[0.0, 0.3, 3.0], [0.0, 1.9, 4.9]])  # centre-on and at the edge
    res = run_loop(flt, [box], start, pd_to(np.array([[20.0, 0.3, 3.0], [20.0, 1.9, 4.9]])), 400)
    assert res.min_clearance >= 0.5 - POS_TOL
    assert res.max_accel <= 5.0 + 1e-9
    assert res.infeasible_steps == 0
    # It stopped at the margin rather than far short of it (within 5 cm).
    assert (
        box_signed_distance(
            res.final_pos[:1], np.array([box.centre]), np.array([box.half_extents])
        )[0][0, 0]
        < 0.55
    )


def test_grazing_a_box_corner_keeps_clearance() -> None:
    box = Box((5.0, 5.0, 3.0), (1.0, 1.0, 1.0))
    flt = SafetyFilter(Limits(a_max=6.0, v_max=5.0), Safety(True, 0.8, 1.0), [box], dt=DT)
    start = np.array([[0.0, 0.5, 3.7]])
    # Constant push diagonally past the corner at (4, 4, 4).
    push = np.array([[4.0, 4.0, 0.2]])
    res = run_loop(flt, [box], start, lambda p, v, k: push, 250)
    assert res.min_clearance >= 0.8 - POS_TOL
    assert res.max_speed <= 5.0 + (6.0 * DT) ** 2 / (2 * 5.0) + 1e-9
    assert res.infeasible_steps == 0


def test_head_on_and_converging_vehicles_keep_separation() -> None:
    flt = SafetyFilter(Limits(a_max=4.0, v_max=3.0), Safety(True, 0.5, 1.5), [], dt=DT)
    start = np.array([[-6.0, 0.0, 5.0], [6.0, 0.0, 5.0], [0.0, 6.0, 5.0], [0.0, -6.0, 5.2]])
    res = run_loop(flt, [], start, pd_to(np.array([[0.0, 0.0, 5.0]])), 400)
    assert res.min_separation >= 1.5 - POS_TOL
    assert res.max_accel <= 4.0 + 1e-9
    assert res.infeasible_steps == 0


def test_diving_into_the_floor_and_the_fence() -> None:
    lim = Limits(
        a_max=3.0, v_max=6.0, z_floor=0.5, geofence_min=(-10, -10, 0), geofence_max=(10, 10, 20)
    )
    flt = SafetyFilter(lim, Safety(), [], dt=DT)  # filter off: limits still apply
    start = np.array([[0.0, 0.0, 8.0], [8.0, 8.0, 3.0]])
    push = np.array([[0.0, 0.0, -30.0], [25.0, 25.0, -25.0]])
    res = run_loop(flt, [], start, lambda p, v, k: push, 300, z_floor=0.5)
    assert res.min_floor_gap >= -POS_TOL
    assert np.all(res.final_pos[:, :2] <= 10.0 + POS_TOL)
    assert res.max_accel <= 3.0 + 1e-9
    assert res.infeasible_steps == 0


def test_speed_never_grows_past_v_max() -> None:
    v_max, a_max = 2.0, 8.0
    flt = SafetyFilter(Limits(a_max=a_max, v_max=v_max), Safety(), [], dt=DT)
    rng = np.random.default_rng(2)
    pushes = rng.normal(size=(300, 3, 3)) * 20.0
    res = run_loop(
        flt,
        [],
        np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, 5.0, 0.0]]),
        lambda p, v, k: pushes[k],
        300,
    )
    # Tangent-plane limiter: overshoot at most (a_max dt)^2 / (2 v_max) (limits.speed_rows).
    assert res.max_speed <= v_max + (a_max * DT) ** 2 / (2 * v_max) + 1e-9
    assert res.max_speed >= v_max - 1e-3  # and it does reach the limit


# --- randomised property ----------------------------------------------------


def _random_case(seed: int) -> tuple[SafetyFilter, list[Box], np.ndarray, Nominal, Safety]:
    rng = np.random.default_rng(seed)
    n_boxes, n_veh = int(rng.integers(1, 4)), int(rng.integers(1, 5))
    a_max, v_max = float(rng.uniform(2.0, 8.0)), float(rng.uniform(1.0, 6.0))
    lim = Limits(
        a_max=a_max,
        v_max=v_max,
        z_floor=0.0,
        geofence_min=(-15.0, -15.0, -1.0),
        geofence_max=(15.0, 15.0, 12.0),
    )
    saf = Safety(True, float(rng.uniform(0.0, 1.0)), float(rng.uniform(0.3, 1.5)))
    boxes = [
        Box(tuple(rng.uniform([-8, -8, 1], [8, 8, 6])), tuple(rng.uniform(0.3, 3.0, 3)))
        for _ in range(n_boxes)
    ]
    centres = np.array([b.centre for b in boxes])
    halves = np.array([b.half_extents for b in boxes])
    starts: list[np.ndarray] = []
    while len(starts) < n_veh:  # rejection-sample safe starts at rest
        c = rng.uniform([-12, -12, 0.2], [12, 12, 10])
        if box_signed_distance(c[None], centres, halves)[0].min() < saf.clearance + 0.01:
            continue
        if any(np.linalg.norm(c - q) < saf.separation + 0.01 for q in starts):
            continue
        starts.append(c)
    mode = int(rng.integers(0, 3))
    target = rng.uniform([-14, -14, -3], [14, 14, 14], (n_veh, 3))
    const = rng.normal(size=(n_veh, 3)) * 2.0 * a_max
    meet = rng.uniform([-5, -5, 1], [5, 5, 6])
    nominals: list[Nominal] = [
        pd_to(target),
        lambda p, v, k: const,
        pd_to(np.broadcast_to(meet, (n_veh, 3))),
    ]
    flt = SafetyFilter(lim, saf, boxes, dt=DT)
    return flt, boxes, np.array(starts), nominals[mode], saf


@settings(max_examples=15, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1))
def test_random_layouts_keep_every_constraint_or_report(seed: int) -> None:
    flt, boxes, p, nominal, saf = _random_case(seed)
    lim = flt.limits
    centres = np.array([b.centre for b in boxes])
    halves = np.array([b.half_extents for b in boxes])
    n = p.shape[0]
    v = np.zeros_like(p)
    flagged = np.zeros(n, dtype=bool)  # reported infeasible at this step or before
    speed_tol = (lim.a_max * DT) ** 2 / (2 * lim.v_max) + 1e-9
    for k in range(150):
        a, rep = flt.filter(p, v, nominal(p, v, k))
        assert np.all(np.isfinite(a))
        assert np.all(np.linalg.norm(a, axis=1) <= lim.a_max + 1e-9)
        flagged |= rep.infeasible
        p = p + v * DT + a * DT * DT / 2.0
        v = v + a * DT
        env_bad = (
            (box_signed_distance(p, centres, halves)[0].min(axis=1) < saf.clearance - POS_TOL)
            | (p[:, 2] < lim.z_floor - POS_TOL)
            | np.any(p < np.array(lim.geofence_min) - POS_TOL, axis=1)
            | np.any(p > np.array(lim.geofence_max) + POS_TOL, axis=1)
            | (np.linalg.norm(v, axis=1) > lim.v_max + speed_tol)
        )
        assert not np.any(env_bad & ~flagged), f"step {k}: unreported violation"
        d = np.linalg.norm(p[:, None] - p[None], axis=-1) + np.eye(n) * 1e9
        pair_bad = d < saf.separation - POS_TOL
        assert not np.any(pair_bad & ~(flagged[:, None] | flagged[None, :])), f"step {k}"
