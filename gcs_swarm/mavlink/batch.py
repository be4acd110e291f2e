"""``VehicleProtocol`` reads and setpoints for the whole formation at once.

The control step reads every flying vehicle's state and answers each with a
setpoint, 50 times a second: done one vehicle at a time that was ~10 us of
numpy scalar work per vehicle per step (issue 8's station profile). These
functions do the same arithmetic on (N, 3) arrays and return the same values
as ``VehicleProtocol.state_mission`` and ``VehicleProtocol.accel_setpoint``
(``tests/mavlink/test_batch.py`` checks them against those, value for value).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from gcs_swarm.mavlink.vehicle import ACCEL_CEILING_MPS2, VehicleProtocol

__all__ = ["accel_ned", "boot_ms", "mission_states"]

FloatArray = npt.NDArray[np.float64]


def mission_states(vps: Sequence[VehicleProtocol]) -> tuple[FloatArray, FloatArray]:
    """Positions [m] and velocities [m/s] ``(N, 3)`` in the mission frame:
    row k is ``vps[k].state_mission()`` (p = (e, n, -d) + offset, v = (v_e,
    v_n, -v_d), formation-law.md s1). ``RuntimeError`` if one has no position
    or origin yet."""
    n = len(vps)
    if n == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    for vp in vps:
        if vp.position is None or vp.offset_m is None:
            vp.state_mission()  # raises with the vehicle named
    # (time_boot_ms, x, y, z, vx, vy, vz) per vehicle: LocalPositionNed[2:].
    ned = np.array([vp.position[2:] for vp in vps], dtype=np.float64)  # type: ignore[index]
    offset = np.array([vp.offset_m for vp in vps], dtype=np.float64)
    pos = np.empty((n, 3))
    pos[:, 0] = ned[:, 2] + offset[:, 0]
    pos[:, 1] = ned[:, 1] + offset[:, 1]
    pos[:, 2] = -ned[:, 3] + offset[:, 2]
    vel = np.empty((n, 3))
    vel[:, 0] = ned[:, 5]
    vel[:, 1] = ned[:, 4]
    vel[:, 2] = -ned[:, 6]
    return pos, vel


def accel_ned(vps: Sequence[VehicleProtocol], accel_mps2: FloatArray) -> FloatArray:
    """The NED accelerations [m/s^2] ``(N, 3)`` that ``vps[k].accel_setpoint(
    accel_mps2[k])`` would send, with its side effects: ``last_accel_ned``,
    and ``clipped_setpoints`` counted for a row whose norm is above
    ``ACCEL_CEILING_MPS2`` (scaled down to it, direction kept) or not finite
    (zeroed). ``accel_mps2`` (mission frame) is not changed.

    The norm here comes from one ``einsum`` over the rows, the one-vehicle
    path's from a dot product; they can differ in the last bit, so a norm
    within ~1e-13 of the ceiling may be clipped by one and not the other, a
    difference far below float32's resolution on the wire."""
    a = np.array(accel_mps2, dtype=np.float64)  # a copy: clipped in place
    norm = np.sqrt(np.einsum("ij,ij->i", a, a))
    clip = ~(norm <= ACCEL_CEILING_MPS2)  # True for NaN too
    if clip.any():
        finite = np.isfinite(norm)
        scale = clip & finite
        a[scale] *= (ACCEL_CEILING_MPS2 / norm[scale])[:, None]
        a[~finite] = 0.0  # NaN, infinite, or a norm that overflows
        for k in np.flatnonzero(clip).tolist():
            vps[k].clipped_setpoints += 1
    ned = np.empty_like(a)
    ned[:, 0] = a[:, 1]  # a_ned = (a_y, a_x, -a_z)
    ned[:, 1] = a[:, 0]
    ned[:, 2] = -a[:, 2]
    for k, vp in enumerate(vps):
        vp.last_accel_ned = ned[k]
    return ned


def boot_ms(vp: VehicleProtocol) -> int:
    """The ``time_boot_ms`` a setpoint to ``vp`` carries: its last report's."""
    return vp.position.time_boot_ms if vp.position is not None else 0
