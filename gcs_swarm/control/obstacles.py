"""Box obstacles, their minimum-volume ellipsoids and the ellipsoidal radius (Eqs. 14-18).

All positions are in the mission frame (x east, y north, z up), metres.
Arrays of K obstacles are kept as ``centres_m (K, 3)`` and ``coeffs_per_m
(K, 3)`` (the A, B, C of Eq. 17 per obstacle) so every function is vectorised
over vehicles and obstacles.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gcs_swarm.control.params import Box

__all__ = [
    "RHO_MIN",
    "Ellipsoids",
    "box_signed_distance",
    "ellipsoid_coeffs",
    "rho",
    "rho_gradient",
]

F64 = NDArray[np.float64]

#: Lower clamp of the ellipsoidal radius where it is divided by (Eq. 27's g and
#: the normal of the classic field). Only reached within 1e-9 of a box centre,
#: which lies inside the box itself.
RHO_MIN = 1e-9


def ellipsoid_coeffs(half_extents_m: Sequence[float]) -> tuple[float, float, float]:
    """Eq. 17: ``A, B, C = 1 / (sqrt(3) v_i)`` [1/m] of the minimum-volume
    ellipsoid enclosing a box with half-extents ``(v1, v2, v3)`` [m]."""
    v1, v2, v3 = (float(v) for v in half_extents_m)
    if min(v1, v2, v3) <= 0.0 or not all(math.isfinite(v) for v in (v1, v2, v3)):
        raise ValueError(f"box half-extents must be positive and finite, got {half_extents_m}")
    s3 = math.sqrt(3.0)
    return 1.0 / (s3 * v1), 1.0 / (s3 * v2), 1.0 / (s3 * v3)


@dataclass(frozen=True)
class Ellipsoids:
    """K box obstacles as arrays: ``centres_m (K, 3)``, ``half_m (K, 3)``,
    ``coeffs_per_m (K, 3)`` = (A, B, C) of Eq. 17 for each box."""

    centres_m: F64
    half_m: F64
    coeffs_per_m: F64

    @classmethod
    def from_boxes(cls, boxes: Sequence[Box]) -> Ellipsoids:
        """Eqs. 14-17 for every box (an empty sequence gives K = 0)."""
        k = len(boxes)
        centres = np.zeros((k, 3))
        half = np.ones((k, 3))
        coeffs = np.ones((k, 3))
        for i, box in enumerate(boxes):
            centres[i] = box.centre
            half[i] = box.half_extents
            coeffs[i] = ellipsoid_coeffs(box.half_extents)
        for arr in (centres, half, coeffs):
            arr.setflags(write=False)
        return cls(centres, half, coeffs)

    @property
    def count(self) -> int:
        """Number of obstacles K."""
        return int(self.centres_m.shape[0])

    def subset(self, index: int) -> Ellipsoids:
        """The single obstacle ``index`` as a K = 1 set."""
        sl = slice(index, index + 1)
        return Ellipsoids(self.centres_m[sl], self.half_m[sl], self.coeffs_per_m[sl])


def rho(pos_m: F64, obs: Ellipsoids) -> F64:
    """Eq. 18, READING (r_n): ``rho = sqrt(A^2 dx^2 + B^2 dy^2 + C^2 dz^2)``,
    ``d = p - p_0``; dimensionless, 1 on the minimum-volume ellipsoid.

    ``pos_m (N, 3)`` -> ``(N, K)``.
    """
    d = pos_m[:, None, :] - obs.centres_m[None, :, :]
    s = d * obs.coeffs_per_m[None, :, :]
    out: F64 = np.sqrt(np.einsum("nki,nki->nk", s, s))
    return out


def rho_gradient(pos_m: F64, obs: Ellipsoids) -> tuple[F64, F64, F64]:
    """``(d, rho, grad rho)``: offsets ``d (N, K, 3)`` [m], ``rho (N, K)`` and
    the gradient ``(A^2 dx, B^2 dy, C^2 dz) / rho (N, K, 3)`` [1/m], the
    outward normal of the level set. At the centre (rho < RHO_MIN) the
    gradient is set to zero (it is undefined there)."""
    d = pos_m[:, None, :] - obs.centres_m[None, :, :]
    c2 = obs.coeffs_per_m[None, :, :] ** 2
    w = d * c2
    r = np.sqrt(np.einsum("nki,nki->nk", w, d))
    inv = np.where(r > RHO_MIN, 1.0 / np.maximum(r, RHO_MIN), 0.0)
    return d, r, w * inv[:, :, None]


def box_signed_distance(pos_m: F64, obs: Ellipsoids) -> F64:
    """Signed Euclidean distance [m] from each point to each box: positive
    outside, negative inside (minus the depth to the nearest face).

    ``pos_m (N, 3)`` -> ``(N, K)``.
    """
    q = np.abs(pos_m[:, None, :] - obs.centres_m[None, :, :]) - obs.half_m[None, :, :]
    outside = np.sqrt(np.sum(np.maximum(q, 0.0) ** 2, axis=-1))
    inside = np.minimum(np.max(q, axis=-1), 0.0)
    out: F64 = outside + inside
    return out
