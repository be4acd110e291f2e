"""Rotational and classic fields (Eqs. 19-28): properties checked with hypothesis."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gcs_swarm.control import Box, Ellipsoids
from gcs_swarm.control.fields import (
    avoidance_force,
    desired_force,
    field_gain,
    heading,
    horizontal_tangent_cw,
    sense_rule,
    unit_or_zero,
    vertical_tangent_up,
)
from gcs_swarm.control.obstacles import box_signed_distance, rho, rho_gradient

coord = st.floats(-50.0, 50.0, allow_nan=False)
half = st.floats(0.1, 20.0, allow_nan=False)
angle = st.floats(-np.pi, np.pi, allow_nan=False)
vec3 = st.tuples(coord, coord, coord)
halves = st.tuples(half, half, half)


def _setup(
    p: tuple[float, float, float], h: tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray, Ellipsoids]:
    obs = Ellipsoids.from_boxes([Box((1.0, -2.0, 3.0), h)])
    d, _, grad = rho_gradient(np.array([p]), obs)
    return d, grad, obs


def _cos(a: np.ndarray, b: np.ndarray) -> float:
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    return 0.0 if na == 0.0 or nb == 0.0 else float(np.dot(a, b) / (na * nb))


@settings(max_examples=300, deadline=None)
@given(p=vec3, h=halves)
def test_horizontal_field_is_tangent(p: tuple[float, float, float], h: tuple[float, ...]) -> None:
    d, grad, obs = _setup(p, h)  # type: ignore[arg-type]
    t = horizontal_tangent_cw(d, obs.coeffs_per_m[None])
    # Tangency: the cosine between t and grad rho is 0 to 1e-9 (pure rounding:
    # A B dx dy - A B dx dy cancels exactly up to a few ulp).
    assert abs(_cos(t[0, 0], grad[0, 0])) <= 1e-9
    assert t[0, 0, 2] == 0.0  # parallel to the x-y plane


@settings(max_examples=300, deadline=None)
@given(p=vec3, h=halves, phi=angle)
def test_vertical_field_is_tangent_and_in_the_heading_plane(
    p: tuple[float, float, float], h: tuple[float, ...], phi: float
) -> None:
    d, grad, obs = _setup(p, h)  # type: ignore[arg-type]
    t = vertical_tangent_up(d, obs.coeffs_per_m[None], np.array([phi]))[0, 0]
    assert abs(_cos(t, grad[0, 0])) <= 1e-9
    # In the vertical plane of heading phi: no component along (-sin, cos, 0).
    assert abs(_cos(t, np.array([-np.sin(phi), np.cos(phi), 0.0]))) <= 1e-9


def test_vertical_field_matches_the_sheet_in_the_plane_through_the_centre() -> None:
    # A = B: kappa = C / A and s = dx cos phi + dy sin phi (formation-law.md s6 form).
    obs = Ellipsoids.from_boxes([Box((0.0, 0.0, 0.0), (2.0, 2.0, 1.0))])
    a, _, c = obs.coeffs_per_m[0]
    phi = 0.7
    s, dz = -3.0, 0.4
    d = np.array([[[s * np.cos(phi), s * np.sin(phi), dz]]])
    t = vertical_tangent_up(d, obs.coeffs_per_m[None], np.array([phi]))[0, 0]
    kappa = c / a
    expected = (kappa * dz * np.cos(phi), kappa * dz * np.sin(phi), -s / kappa)
    np.testing.assert_allclose(t, expected, rtol=1e-12)
    assert t[2] > 0.0  # in front of the obstacle (s < 0) "up" climbs


@settings(max_examples=300, deadline=None)
@given(p=vec3, v=vec3, f=vec3, h=halves)
def test_sense_rule_gives_an_acute_angle(
    p: tuple[float, ...], v: tuple[float, ...], f: tuple[float, ...], h: tuple[float, ...]
) -> None:
    d, _, obs = _setup(p, h)  # type: ignore[arg-type]
    vel, fdes = np.array([v]), np.array([f])
    ref = vel[0] if np.linalg.norm(vel) >= 1e-3 else fdes[0]
    for t in (
        horizontal_tangent_cw(d, obs.coeffs_per_m[None]),
        vertical_tangent_up(d, obs.coeffs_per_m[None], heading(vel, fdes)),
    ):
        sense = sense_rule(t, vel, fdes)[0, 0]
        assert sense in (1.0, -1.0)
        assert float(np.dot(sense * t[0, 0], ref)) >= 0.0  # acute (or right) angle


def test_sense_rule_tie_gives_clockwise_or_up() -> None:
    t = np.array([[[1.0, 0.0, 0.0]]])
    assert sense_rule(t, np.array([[0.0, 1.0, 0.0]]), np.zeros((1, 3)))[0, 0] == 1.0
    assert sense_rule(t, np.zeros((1, 3)), np.zeros((1, 3)))[0, 0] == 1.0  # at rest, no force
    # At rest the desired force decides.
    assert sense_rule(t, np.zeros((1, 3)), np.array([[-1.0, 0.0, 0.0]]))[0, 0] == -1.0


def test_gain_law() -> None:
    g = field_gain(np.array([0.5, 1.0, 2.0, 2.5, 0.0]), 2.0)
    np.testing.assert_allclose(g[:4], [4.0 * 1.5, 0.5, 0.0, 0.0])
    assert np.isfinite(g[4]) and g[4] > 0.0  # rho clamped at the centre


def test_on_axis_and_degenerate_inputs_are_finite() -> None:
    obs = Ellipsoids.from_boxes([Box((0.0, 0.0, 0.0), (3.0, 2.0, 1.0))])
    pts = np.array(
        [
            [0.0, 0.0, 1.5],  # horizontal field's axis: |t| = 0
            [0.0, 0.0, 0.0],  # obstacle centre
            [1.0, 0.0, 0.0],  # vertical field's axis for phi = pi/2
        ]
    )
    vel = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    f_des = np.array([[0.0, 2.0, 0.0], [0.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    for method in ("rotational", "classic"):
        for vert in (False, True):
            f = avoidance_force(
                pts, vel, f_des, obs, method=method, r0=2.0, vertical=np.full((3, 1), vert)
            )
            assert np.all(np.isfinite(f))
    # On the horizontal axis the rotational term vanishes: f = f_des.
    f = avoidance_force(pts[:1], vel[:1], f_des[:1], obs, method="rotational", r0=2.0)
    np.testing.assert_array_equal(f, f_des[:1])
    # Eq. 28 at the target and unit_or_zero of zero are zero, not NaN.
    np.testing.assert_array_equal(desired_force(pts, pts, 10.0), np.zeros((3, 3)))
    np.testing.assert_array_equal(unit_or_zero(np.zeros((2, 3))), np.zeros((2, 3)))


def test_classic_field_pushes_along_the_outward_normal() -> None:
    obs = Ellipsoids.from_boxes([Box((0.0, 0.0, 0.0), (3.0, 2.0, 1.0))])
    p = np.array([[4.0, 3.0, 0.5]])
    f = avoidance_force(p, np.zeros((1, 3)), np.zeros((1, 3)) + 1.0, obs, method="classic", r0=2.0)
    _, r, grad = rho_gradient(p, obs)
    push = f[0] - 1.0
    assert _cos(push, grad[0, 0]) == pytest.approx(1.0, abs=1e-12)
    assert r[0, 0] < 2.0


def test_eq27_printed_variant_is_per_component() -> None:
    obs = Ellipsoids.from_boxes([Box((0.0, 0.0, 0.0), (3.0, 2.0, 1.0))])
    p = np.array([[1.0, -4.0, 0.2]])
    f_des = np.array([[0.0, 2.0, 0.0]])
    vec = avoidance_force(p, np.zeros((1, 3)), f_des, obs, method="rotational", r0=2.0)
    comp = avoidance_force(
        p, np.zeros((1, 3)), f_des, obs, method="rotational", r0=2.0, printed_eq27=True
    )
    # |f_des,x| = 0: the printed form loses the x push the vector form has.
    assert vec[0, 0] != 0.0 and comp[0, 0] == 0.0
    assert comp[0, 1] == pytest.approx(vec[0, 1], abs=1e-12)


def test_rho_and_signed_distance() -> None:
    obs = Ellipsoids.from_boxes([Box((1.0, 2.0, 3.0), (3.0, 2.0, 1.0))])
    corner = np.array([[4.0, 4.0, 4.0]])  # a box corner lies on the min-volume ellipsoid
    np.testing.assert_allclose(rho(corner, obs), 1.0, rtol=1e-12)
    pts = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 5.0], [6.0, 2.0, 3.0], [5.0, 5.0, 3.0]])
    np.testing.assert_allclose(
        box_signed_distance(pts, obs)[:, 0], [-1.0, 1.0, 2.0, np.hypot(1.0, 1.0)]
    )


def test_heading_source() -> None:
    vel = np.array([[0.0, 2.0, 0.0], [1e-4, 0.0, 0.0], [0.0, 0.0, 0.0]])
    f_des = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]])
    # Spec reading: the velocity's azimuth, the desired force's when nearly at rest.
    np.testing.assert_allclose(heading(vel, f_des), [np.pi / 2, -np.pi / 2, 0.0])
    # Avoidance.heading == "desired": always the desired force's azimuth.
    np.testing.assert_allclose(heading(vel, f_des, from_velocity=False), [0.0, -np.pi / 2, 0.0])
