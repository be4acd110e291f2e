"""Per-call cost of SafetyFilter.filter (median of 5 x 200 calls).

Run from the repository root: ``python benchmarks/bench_safety.py``. Prints
the rows of the safety-filter table in ``benchmarks/README.md``.
"""

import statistics
import time

import numpy as np

from gcs_swarm.control.params import Box, Limits, Safety
from gcs_swarm.control.safety import SafetyFilter

rng = np.random.default_rng(0)
boxes = [
    Box((0.0, 0.0, 5.0), (3.0, 2.0, 1.0)),
    Box((10.0, 5.0, 4.0), (1.0, 1.0, 3.0)),
    Box((-8.0, 6.0, 2.0), (2.0, 2.0, 2.0)),
]
lim = Limits(
    a_max=5.0, v_max=5.0, z_floor=0.0, geofence_min=(-30, -30, 0), geofence_max=(30, 30, 20)
)
offset = np.array([0.0, 12.0, 0.0])
for enabled in (False, True):
    for n in (1, 6, 20, 50):
        for label, spacing in (("spread", 6.0), ("packed", 1.2)):
            f = SafetyFilter(lim, Safety(enabled, 0.5, 1.0), boxes, dt=0.02)
            side = spacing * n ** (1 / 3)
            p = rng.uniform([-side, -side, 6], [side, side, 6 + side], (n, 3)) + offset
            v = rng.normal(size=(n, 3)) * 2.0
            a = rng.normal(size=(n, 3)) * 8.0
            _, rep = f.filter(p, v, a)
            runs = []
            for _ in range(5):
                t = time.perf_counter()
                for _ in range(200):
                    f.filter(p, v, a)
                runs.append((time.perf_counter() - t) / 200 * 1e3)
            state = "on" if enabled else "off"
            print(
                f"| {state} | {n} | {label} | {statistics.median(runs):.2f} | "
                f"{int(rep.intervened.sum())} | {int(rep.infeasible.sum())} |"
            )
