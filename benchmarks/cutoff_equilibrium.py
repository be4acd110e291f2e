"""The error the repulsion cut-off (Eq. 9c, docs/formation-law.md section 3a)
makes on the formation's equilibrium: the exact law against cut-offs of a
few times the exact equilibrium's neighbour distance.

Run from the repository root:

    python benchmarks/cutoff_equilibrium.py            # N = 12 and N = 100 (~4 min)
    python benchmarks/cutoff_equilibrium.py --counts 12,100,200 --factors 1.5,2,3

For each N: Example 1's gains (k_s = 1, k_r = 0.2, q = 10, alpha = 2, M = D
= 1, k = 9), the leader at rest at the origin, N vehicles from rest at seeded
random points (``numpy.random.default_rng(N)``: uniform directions, radii
uniform in 1..6 m), flown by the in-process integrator
(``gcs_swarm.integrator.integrate``, RK4, ``--dt`` 0.02 s) for ``--seconds``
(300 s). The
exact law runs first; its mean nearest-neighbour distance d_nn sets the
cut-offs (``--factors`` x d_nn); every run starts from the same points. Prints
a markdown table of the final radii and nearest-neighbour distances, their
errors against the exact law, and the largest speed left (how settled).
Deterministic: the figures are the same on every machine up to rounding.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gcs_swarm.control.params import Gains, LawConfig
from gcs_swarm.integrator import integrate


def starts(n: int) -> np.ndarray:
    """N seeded random start points [m] around the origin (module docstring)."""
    rng = np.random.default_rng(n)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u * rng.uniform(1.0, 6.0, size=(n, 1))


def settle(n: int, cutoff_m: float | None, seconds: float, dt: float) -> tuple[np.ndarray, float]:
    """Final positions ``(N, 3)`` [m] and the largest final speed [m/s]."""
    cfg = LawConfig(gains=Gains(repulsion_cutoff=cutoff_m))
    res = integrate(cfg, starts(n), duration=seconds, dt=dt)
    speed = float(np.linalg.norm(res.vel_mps[-1], axis=1).max())
    return res.pos_m[-1], speed


def nearest(pos_m: np.ndarray) -> np.ndarray:
    """Each vehicle's nearest-neighbour distance [m], ``(N,)``."""
    d = np.linalg.norm(pos_m[:, None, :] - pos_m[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    return np.asarray(d.min(axis=1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--counts", default="12,100")
    ap.add_argument("--factors", default="1.5,2,3")
    ap.add_argument("--seconds", type=float, default=300.0)
    ap.add_argument("--dt", type=float, default=0.02)
    args = ap.parse_args()
    print(
        "| N | cut-off r_c | radius mean [min, max] (m) | radius error (mean; largest) "
        "| nearest neighbour mean [min, max] (m) | its error (mean) | pairs kept "
        "| largest speed left (m/s) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for n in (int(x) for x in args.counts.split(",")):
        exact, v_exact = settle(n, None, args.seconds, args.dt)
        r_ex = np.linalg.norm(exact, axis=1)
        nn_ex = nearest(exact)
        d_nn = float(nn_ex.mean())
        rows = [("exact (all pairs)", None, exact, v_exact)]
        for f in (float(x) for x in args.factors.split(",")):
            pos, v = settle(n, f * d_nn, args.seconds, args.dt)
            rows.append((f"{f:g} d_nn = {f * d_nn:.3f} m", f * d_nn, pos, v))
        for label, rc, pos, v in rows:
            r = np.linalg.norm(pos, axis=1)
            nn = nearest(pos)
            err = 100.0 * (r.mean() / r_ex.mean() - 1.0)
            outer = 100.0 * (r.max() / r_ex.max() - 1.0)
            nn_err = 100.0 * (nn.mean() / d_nn - 1.0)
            dist = np.linalg.norm(pos[:, None, :] - pos[None, :, :], axis=-1)
            total = n * (n - 1) // 2
            kept = total if rc is None else int(np.triu(dist < rc, k=1).sum())
            print(
                f"| {n} | {label} | {r.mean():.5f} [{r.min():.5f}, {r.max():.5f}] "
                f"| {err:+.3f} %; {outer:+.3f} % | {nn.mean():.4f} [{nn.min():.4f}, "
                f"{nn.max():.4f}] | {nn_err:+.2f} % | {kept} of {total} | {v:.1e} |"
            )


if __name__ == "__main__":
    main()
