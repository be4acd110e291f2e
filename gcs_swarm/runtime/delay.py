"""Delay compensation (``mission.delay_compensation``), I/O free.

Real time only. Each vehicle's clock offset and round trip come from TIMESYNC
(the vehicle answers a request with its boot time); a report's state at its
own ``time_boot_ms`` is integrated forward, as a double integrator (Eq. 1's
state), over the commands sent since, to the vehicle time the new setpoint
will land: now + offset + half the round trip. One-way delay cannot be told
from clock offset, so the round trip is split in halves.

The station feeds ``timesync`` with every TIMESYNC answer, ``sent`` with
every acceleration setpoint, and asks ``predict`` at each control step.
"""

from __future__ import annotations

from collections import deque

import numpy as np
import numpy.typing as npt

__all__ = ["DelayCompensator"]

F64 = npt.NDArray[np.float64]

SAMPLES = 50
"""TIMESYNC round trips kept per vehicle (10 s at the station's 5 Hz)."""
MIN_SAMPLES = 5
"""Round trips needed before any prediction."""
MAX_HORIZON_S = 1.0
"""Longer predictions are not made: the estimate is off or the link is down."""


class DelayCompensator:
    """Clock estimates and commands in flight per vehicle; see the module
    docstring. ``accel_max_mps2``: the acceleration a vehicle is taken to
    follow (larger commands are scaled down to it in the prediction)."""

    def __init__(self, accel_max_mps2: float) -> None:
        self.accel_max_mps2 = accel_max_mps2
        self._samples: dict[int, deque[tuple[float, float]]] = {}
        """(round trip [s], vehicle - station clock [s]) per vehicle."""
        self._estimate: dict[int, tuple[float, float]] = {}
        self._sent: dict[int, deque[tuple[float, F64]]] = {}
        """(vehicle time it lands [s], accel [m/s^2]) per vehicle."""

    def timesync(self, sysid: int, tc1_ns: int, ts1_ns: int, now: float) -> None:
        """A TIMESYNC answer (``tc1`` the vehicle's boot time, ``ts1`` our
        request's stamp) received at station time ``now`` [s]."""
        rtt = now - ts1_ns * 1e-9
        if not 0.0 <= rtt < 2.0:
            return
        samples = self._samples.setdefault(sysid, deque(maxlen=SAMPLES))
        samples.append((rtt, tc1_ns * 1e-9 - (ts1_ns * 1e-9 + now) / 2))
        if len(samples) >= MIN_SAMPLES:
            rtts = sorted(r for r, _ in samples)
            median = rtts[len(rtts) // 2]
            offsets = sorted(o for r, o in samples if r <= median)
            self._estimate[sysid] = (offsets[len(offsets) // 2], median / 2)

    def estimate(self, sysid: int) -> tuple[float, float] | None:
        """(vehicle clock - station clock [s], one-way delay [s]), or None
        before ``MIN_SAMPLES`` round trips: the median round trip halved, and
        the median offset of the quicker half of the last ``SAMPLES``."""
        return self._estimate.get(sysid)

    def sent(self, sysid: int, now: float, accel_mps2: F64) -> None:
        """An acceleration setpoint [m/s^2] sent to ``sysid`` at station time ``now``."""
        est = self._estimate.get(sysid)
        if est is None:
            return
        a = np.array(accel_mps2, dtype=np.float64)
        norm = float(np.linalg.norm(a))
        if norm > self.accel_max_mps2:
            a *= self.accel_max_mps2 / norm
        self._sent.setdefault(sysid, deque(maxlen=200)).append((now + est[0] + est[1], a))

    def predict(self, sysid: int, report_s: float, now: float, p: F64, v: F64) -> tuple[F64, F64]:
        """Position and velocity of ``sysid`` when a setpoint sent at station
        time ``now`` lands, from its report (``p``, ``v``) at vehicle time
        ``report_s``; unchanged while there is no estimate."""
        est = self._estimate.get(sysid)
        if est is None:
            return p, v
        t = report_s
        t_land = now + est[0] + est[1]
        if not 0.0 <= t_land - t <= MAX_HORIZON_S:
            return p, v
        sent = self._sent.get(sysid, ())
        a = np.zeros(3)
        for lands, acc in sent:  # the command in force at the report's time
            if lands <= t:
                a = acc
        for lands, acc in sent:
            if t < lands < t_land:
                dt = lands - t
                p, v = p + v * dt + 0.5 * a * dt * dt, v + a * dt
                t, a = lands, acc
        dt = t_land - t
        return p + v * dt + 0.5 * a * dt * dt, v + a * dt
