"""An acceleration setpoint as it is sent: in NED, and never more than the
ceiling (``clip_accel_ned``), for one row or many (the telemetry table's
``answer``, ``VehicleProtocol.accel_setpoint``). No I/O."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["ACCEL_CEILING_MPS2", "SMALL_ROWS", "clip_accel_ned", "unclipped_ned_small"]

FloatArray = npt.NDArray[np.float64]

ACCEL_CEILING_MPS2 = 1000.0
"""Largest acceleration setpoint sent [m/s^2] (about 100 g): beyond any
multicopter, far inside float32, and above every figure of the paper."""
_NED_COLS = np.array([1, 0, 2], dtype=np.intp)
_NED_SIGN = np.array([1.0, 1.0, -1.0])
"""An acceleration's columns, mission frame (east, north, up) -> NED, and
up -> down (a sign flip: exact)."""

SMALL_ROWS = 16
"""Below this many rows ``answer`` tries ``unclipped_ned_small`` first."""
_SURELY_UNCLIPPED = 999.0**2
"""A squared norm [m^2/s^4] at most this is below the ceiling in any summation order."""


def unclipped_ned_small(accel_mps2: FloatArray) -> FloatArray | None:
    """``clip_accel_ned(accel_mps2)[0]`` for a few rows in Python floats when no
    row needs clipping (every squared norm finite and at most 999^2, so
    clearly below the ceiling whatever the order numpy sums it in), else
    None (the caller takes ``clip_accel_ned``). The rows are (a_y, a_x,
    -a_z): the reference's ``a * 1.0`` and ``a * -1.0``, exact, signed zeros
    included."""
    rows = accel_mps2.tolist()
    lim = _SURELY_UNCLIPPED
    for x, y, z in rows:
        if not x * x + y * y + z * z <= lim:  # NaN and inf fail too
            return None
    return np.array([(y, x, -z) for x, y, z in rows], dtype=np.float64).reshape(len(rows), 3)


def clip_accel_ned(accel_mps2: FloatArray) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Mission-frame accelerations ``(N, 3)`` [m/s^2] as the NED accelerations
    setpoints carry (a_ned = (a_y, a_x, -a_z)), each sendable: a row whose
    norm is above ``ACCEL_CEILING_MPS2`` is scaled down to it (direction kept),
    a non-finite row, or one whose norm overflows, becomes zero. Also returns
    which rows were changed. The input is not modified."""
    a = np.asarray(accel_mps2, dtype=np.float64)
    norm = np.sqrt(np.einsum("ij,ij->i", a, a))
    clip = ~(norm <= ACCEL_CEILING_MPS2)  # True for NaN too
    if clip.any():
        a = a.copy()  # clipped in place
        finite = np.isfinite(norm)
        scale = clip & finite
        a[scale] *= (ACCEL_CEILING_MPS2 / norm[scale])[:, None]
        a[~finite] = 0.0
    # (a_y, a_x, -a_z): a new array; the sign flip is exact (-a is a * -1).
    ned: FloatArray = np.multiply(a.take(_NED_COLS, axis=1), _NED_SIGN)
    return ned, clip
