"""The formation law's accelerations for a few vehicles, in plain floats.

``formation_accelerations`` is Eq. 1 of the formation force (Eqs. 7-12),
``eq1_acceleration(formation_force(...))`` of ``gcs_swarm.control.formation``,
the readable reference, computed vehicle by vehicle and pair by pair in
Python floats: below ``SMALL_N`` vehicles numpy's cost per call is more than
the arithmetic (N = 6: about 45 us for the reference, 15 us here; the
station's lockstep benchmark, benchmarks/README.md). ``law_accelerations``
takes it for a formation step below ``SMALL_N``; nothing else calls it.

The same equations in the same readings (``Readings``, ``Gains.time_scale``).
Eq. 7 and Eq. 1 are the reference's operations in its order (the squared
distance summed as numpy's ``einsum`` sums three products, ``(x^2 + z^2) +
y^2``), so they agree bit for bit; the repulsion (Eqs. 8-9) sums each pair's ``q_n q_i (p_n - p_i)
/ |p_n - p_i|^3`` directly, where the reference takes ``|p_n - p_i|^2`` from
a Gram product of the centred positions, so the two differ by rounding
(a few units in the last place of the pair terms; the direct form is the
more accurate one). ``tests/control/test_formation_rows.py`` compares them
on seeded random swarms.

With ``Gains.repulsion_cutoff`` set, a pair at ``|p_n - p_i| >= r_c`` is
skipped (Eq. 9c, docs/formation-law.md section 3a), decided on the same
``dx*dx + dy*dy + dz*dz`` as ``cutoff.neighbour_pairs``, so both paths keep
the same pairs.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from gcs_swarm.control.formation import R_MIN_M
from gcs_swarm.control.params import Gains, Readings

__all__ = ["SMALL_N", "formation_accelerations"]

F64 = NDArray[np.float64]

SMALL_N = 10
"""Below this many vehicles ``law_accelerations`` flies formation through
``formation_accelerations``; from it on, the vectorised reference is cheaper.
The control step's other float paths take the same threshold: the input
check of ``law.as_states`` and the minimum separation of ``loop``."""


def formation_accelerations(
    pos_m: F64,
    vel_mps: F64,
    charges: F64,
    centre_m: F64,
    gains: Gains,
    readings: Readings,
) -> F64:
    """Eq. 1 of Eqs. 11-12's formation force [m/s^2] ``(N, 3)``:
    ``eq1_acceleration(formation_force(pos_m, charges, centre_m, gains,
    readings), vel_mps, gains)``, in floats (module docstring).

    ``pos_m``/``vel_mps (N, 3)`` mission frame, ``charges (N,)``,
    ``centre_m (3,)`` the virtual leader."""
    pos = pos_m.tolist()
    vel = vel_mps.tolist()
    q = charges.tolist()
    cx, cy, cz = centre_m.tolist()
    n = len(pos)
    # Eqs. 8-9 (READING: one q_n; Eq. 10 as printed: q_n q_n), each pair once (Eq. 9c: those
    # closer than the cut-off),
    # |p_n - p_i| clamped from below at R_MIN_M as in formation.repulsion_force.
    twice = readings.eq10_printed
    qw = [1.0] * n if twice else q
    r2_min = R_MIN_M * R_MIN_M
    rc = gains.repulsion_cutoff
    r2_cut = math.inf if rc is None else rc * rc  # Eq. 9c: pairs at r >= r_c skipped
    acc = [[0.0, 0.0, 0.0] for _ in range(n)]
    for a in range(n):
        xa, ya, za = pos[a]
        sa = acc[a]
        wa = qw[a]
        for b in range(a + 1, n):
            xb, yb, zb = pos[b]
            dx, dy, dz = xa - xb, ya - yb, za - zb
            r2 = dx * dx + dy * dy + dz * dz
            if r2 >= r2_cut:
                continue
            if r2 < r2_min:
                r2 = r2_min
            w = 1.0 / (r2 * math.sqrt(r2))
            wb = w * qw[b]
            sa[0] += wb * dx
            sa[1] += wb * dy
            sa[2] += wb * dz
            sb = acc[b]
            wab = w * wa
            sb[0] -= wab * dx
            sb[1] -= wab * dy
            sb[2] -= wab * dz
    k_r = gains.k_r
    # Eq. 7 (READING: alpha^2 kept; Eq. 12 as printed drops it), Eqs. 11-12
    # (READING: F + f_s; Eq. 11 as printed: F - f_s), then Eq. 1 with the time
    # scale's M and D + k: the reference's operations in its order.
    neg_k_s = -gains.k_s
    alpha2 = gains.alpha**2
    keep_alpha = not readings.eq12_printed
    flip = readings.eq11_printed
    c, m = gains.damping_scaled, gains.mass_scaled
    out = []
    for j in range(n):
        x, y, z = pos[j]
        dx, dy, dz = x - cx, y - cy, z - cz
        r2 = (dx * dx + dz * dz) + dy * dy  # numpy's einsum adds three squares so
        if keep_alpha:
            r2 = r2 - alpha2
        fx, fy, fz = neg_k_s * dx * r2, neg_k_s * dy * r2, neg_k_s * dz * r2
        if flip:
            fx, fy, fz = -fx, -fy, -fz
        kq = k_r * (q[j] * q[j] if twice else q[j])
        sa = acc[j]
        fx, fy, fz = fx + kq * sa[0], fy + kq * sa[1], fz + kq * sa[2]
        vx, vy, vz = vel[j]
        out.append(((fx - c * vx) / m, (fy - c * vy) / m, (fz - c * vz) / m))
    return np.array(out, dtype=np.float64).reshape(n, 3)
