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

from gcs_swarm.mavlink.vehicle import VehicleProtocol, clip_accel_ned

__all__ = ["accel_ned", "mission_states"]

FloatArray = npt.NDArray[np.float64]


def mission_states(vps: Sequence[VehicleProtocol]) -> tuple[FloatArray, FloatArray]:
    """Positions [m] and velocities [m/s] ``(N, 3)`` in the mission frame:
    row k is ``vps[k].state_mission()`` (p = (e, n, -d) + offset, v = (v_e,
    v_n, -v_d) less the velocity bias, formation-law.md s1 and
    docs/velocity-bias.md). ``RuntimeError`` if one has no position
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
    bias = np.array([vp.vel_correction_ned for vp in vps], dtype=np.float64)
    pos = np.empty((n, 3))
    pos[:, 0] = ned[:, 2] + offset[:, 0]
    pos[:, 1] = ned[:, 1] + offset[:, 1]
    pos[:, 2] = -ned[:, 3] + offset[:, 2]
    vel = np.empty((n, 3))
    vel[:, 0] = ned[:, 5] - bias[:, 1]
    vel[:, 1] = ned[:, 4] - bias[:, 0]
    vel[:, 2] = bias[:, 2] - ned[:, 6]
    return pos, vel


def accel_ned(vps: Sequence[VehicleProtocol], accel_mps2: FloatArray) -> FloatArray:
    """The NED accelerations [m/s^2] ``(N, 3)`` that ``vps[k].accel_setpoint(
    accel_mps2[k])`` would send (``clip_accel_ned``, the same function), with
    its side effects: ``last_accel_ned`` and ``clipped_setpoints``."""
    ned, clipped = clip_accel_ned(accel_mps2)
    for k in np.flatnonzero(clipped).tolist():
        vps[k].clipped_setpoints += 1
    for k, vp in enumerate(vps):
        vp.last_accel_ned = ned[k]
    return ned
