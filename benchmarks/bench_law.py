"""Cost of the formation law (gcs_swarm.control), single-threaded.

Run from the repository root:

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 \
        python benchmarks/bench_law.py

(the script also sets these itself before numpy is imported). Prints
markdown tables; the figures in benchmarks/README.md come from it.
``--cutoff`` prints only the cost of the law against N with and without the
repulsion's cut-off (Eq. 9c, docs/formation-law.md section 3a);
``--counts 100,500,1000,2000`` chooses the N of that table. Both print the
whole controller step against N as well (``ControlLoop.command`` and
``account``: the leader, the supervisor, the law, the shaper, the step's
figures with the minimum separation), exact and with the cut-off.
``--margin`` prints only the cut-off law's step of one network's rows at
1,500 vehicles with the Verlet list's margin fixed or adapting, the
swarm at rest, swinging slowly and churning (``bench_verlet_margin``).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from functools import partial  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gcs_swarm.control import (  # noqa: E402
    Avoidance,
    Box,
    ConstantForce,
    Gains,
    LawConfig,
    Leader,
    SwarmController,
    law_accelerations,
    repulsion_force,
)
from gcs_swarm.control.cutoff import neighbour_pairs  # noqa: E402
from gcs_swarm.control.supervisor import Mode  # noqa: E402
from gcs_swarm.integrator import integrate  # noqa: E402


def _median_ms(fn: Callable[[], object], repeats: int, inner: int = 1) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(inner):
            fn()
        times.append((time.perf_counter() - t0) / inner)
    return 1e3 * statistics.median(times)


def _naive_repulsion(p: np.ndarray, q: np.ndarray, k_r: float) -> np.ndarray:
    d = p[:, None, :] - p[None, :, :]
    r = np.linalg.norm(d, axis=-1)
    np.fill_diagonal(r, np.inf)
    out: np.ndarray = k_r * q[:, None] * np.sum((q[None, :] / r**3)[..., None] * d, axis=1)
    return out


def bench_law_eval() -> list[str]:
    rng = np.random.default_rng(1)
    cfg = LawConfig()
    centre = np.zeros(3)
    rows = ["| N | law evaluation (ms) | of which repulsion (ms) | naive N x N x 3 (ms) |",
            "|---|---|---|---|"]  # fmt: skip
    for n in (10, 100, 1000, 3000):
        # Vehicles spread over a ball whose size grows with N (~2 m spacing).
        p = rng.normal(size=(n, 3)) * (n ** (1 / 3))
        v = rng.normal(size=(n, 3))
        q = np.full(n, 10.0)
        mode = Mode.formation(tuple(range(n)))
        obs = SwarmController(cfg).obstacles
        reps = 200 if n <= 100 else (30 if n <= 1000 else 15)
        inner = 20 if n <= 100 else 1
        law = partial(law_accelerations, cfg, mode, p, v, q, centre, obs)
        t_law = _median_ms(law, reps, inner)
        t_rep = _median_ms(partial(repulsion_force, p, q, 0.2), reps, inner)
        naive = (
            f"{_median_ms(partial(_naive_repulsion, p, q, 0.2), 5):.3f}"
            if n <= 1000
            else "(not run)"
        )
        rows.append(f"| {n} | {t_law:.3f} | {t_rep:.3f} | {naive} |")
    return rows


def sphere_swarm(n: int, gains: Gains) -> tuple[np.ndarray, float]:
    """N vehicles spread evenly on the sphere they settle on (a Fibonacci
    lattice), positions ``(N, 3)`` [m] and their mean nearest-neighbour
    distance d_nn [m]. The radius solves ``k_s R (R^2 - alpha^2) = k_r q^2 N /
    (2 R^2)`` (a uniformly charged shell: the outward field at its surface),
    near the exact law's equilibria (N = 100: 4.19 m; simulated, the outer
    shell settles at 4.29 m with a few vehicles inside, formation-law.md
    section 3a)."""
    k = gains.k_r * gains.q_default**2 * n / (2.0 * gains.k_s)
    r = max(gains.alpha, 1.0) * 1.5
    for _ in range(100):  # Newton on R^5 - alpha^2 R^3 - k = 0
        f = r**5 - gains.alpha**2 * r**3 - k
        r -= f / (5 * r**4 - 3 * gains.alpha**2 * r**2)
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5**0.5) * i
    s = np.sqrt(1.0 - z * z)
    p = r * np.stack((s * np.cos(phi), s * np.sin(phi), z), axis=1)
    d2 = np.einsum("nik,nik->ni", p[:, None] - p[None], p[:, None] - p[None])
    np.fill_diagonal(d2, np.inf)
    return p, float(np.sqrt(d2.min(axis=1)).mean())


def bench_cutoff(counts: list[int]) -> list[str]:
    """One law evaluation (formation, ``law_accelerations``) against N: the
    exact all-pairs repulsion and the cut-off at 2 and 3 x d_nn, vehicles on
    their equilibrium sphere; and a clump (every vehicle within one cut-off:
    the cell list's worst case) at the largest N."""
    rng = np.random.default_rng(2)
    rows = ["| N | sphere R (m), d_nn (m) | exact (ms) | r_c = 2 d_nn (ms) | pairs kept "
            "| r_c = 3 d_nn (ms) | pairs kept |", "|---|---|---|---|---|---|---|"]  # fmt: skip
    base = LawConfig()
    obs = SwarmController(base).obstacles
    centre = np.zeros(3)
    for n in counts:
        p, d_nn = sphere_swarm(n, base.gains)
        v = rng.normal(size=(n, 3)) * 0.1
        q = np.full(n, base.gains.q_default)
        mode = Mode.formation(tuple(range(n)))
        reps = 30 if n <= 1000 else 10
        inner = 10 if n <= 500 else 1
        cells = [f"| {n} | {float(np.linalg.norm(p[0])):.2f}, {d_nn:.3f}"]
        for factor in (None, 2.0, 3.0):
            cfg = LawConfig(gains=Gains(repulsion_cutoff=None if factor is None else factor * d_nn))
            law = partial(law_accelerations, cfg, mode, p, v, q, centre, obs)
            cells.append(f"{_median_ms(law, reps, inner):.3f}")
            if factor is not None:
                i, _, _, _ = neighbour_pairs(p, factor * d_nn)
                cells.append(f"{len(i) / (n * (n - 1) / 2):.1%}")
        rows.append(" | ".join(cells) + " |")
    n = max(counts)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1).max() * 2.0  # all inside a ball of radius 0.5 m
    q = np.full(n, 10.0)
    mode = Mode.formation(tuple(range(n)))
    clump = []
    for cutoff in (None, 1.0):
        cfg = LawConfig(gains=Gains(repulsion_cutoff=cutoff))
        law = partial(law_accelerations, cfg, mode, p, np.zeros((n, 3)), q, centre, obs)
        clump.append(_median_ms(law, 5))
    rows.append(f"| {n}, clump (all within 1 m = r_c) | | {clump[0]:.3f} | {clump[1]:.3f} "
                "| 100 % | | |")  # fmt: skip
    return rows


def _controller_step(loop: Any, ids: list[int], p: np.ndarray, v: np.ndarray) -> None:
    out, accel, report = loop.command(ids, p, v)
    loop.account(ids, p, out, accel, report)


def bench_controller_step(counts: list[int]) -> list[str]:
    """What the station's controller spends per control step against N:
    ``ControlLoop.command`` then ``account``, vehicles on their equilibrium
    sphere, exact and with the cut-off at 2 d_nn (issue 19 item 4)."""
    from gcs_swarm.control.loop import ControlLoop

    rng = np.random.default_rng(3)
    rows = ["| N | controller step, exact (ms) | with r_c = 2 d_nn (ms) |", "|---|---|---|"]
    base = LawConfig()
    for n in counts:
        p, d_nn = sphere_swarm(n, base.gains)
        v = rng.normal(size=(n, 3)) * 0.1
        ids = list(range(1, n + 1))
        cells = [f"| {n}"]
        for cutoff in (None, 2.0 * d_nn):
            loop = ControlLoop(LawConfig(gains=Gains(repulsion_cutoff=cutoff)),
                               dict.fromkeys(ids, base.gains.q_default), 50.0)  # fmt: skip
            step = partial(_controller_step, loop, ids, p, v)
            cells.append(f"{_median_ms(step, 30 if n <= 1000 else 10):.3f}")
        rows.append(" | ".join(cells) + " |")
    return rows


def _swinging(
    home: np.ndarray, amp_m: float, rad_per_period: float, seed: int
) -> Callable[[float], np.ndarray]:
    """Positions at period ``k``: each vehicle swinging about its ``home``
    along its own direction, ``amp_m`` at ``rad_per_period``, own phase."""
    rng = np.random.default_rng(seed)
    way = rng.normal(size=home.shape)
    way /= np.linalg.norm(way, axis=1, keepdims=True)
    phase = rng.uniform(0.0, 2.0 * np.pi, home.shape[0])
    return lambda k: home + amp_m * np.sin(rad_per_period * k + phase)[:, None] * way


def bench_verlet_margin(n: int = 1500, networks: int = 6, periods: int = 100) -> list[str]:
    """The cut-off law's step of one network's rows (``ControlLoop.command``
    with rows, as a station or controller with ``step: network`` steps)
    with the Verlet list's margin fixed at 0.3 or 1.0 r_c, or adapting
    (``neighbours.NeighbourList``), on N vehicles on their sphere: at rest,
    swinging slowly, and churning as the 1,500-vehicle benchmark ball did
    in the seventh session's overloaded runs (relative to its centre up to
    0.145 m a period: amplitude 0.3 m at 0.5 rad a period). Each network's
    vehicles move when it is stepped (its reports), the others keep their
    last positions."""
    from gcs_swarm.control.loop import ControlLoop
    from gcs_swarm.control.neighbours import MAX_SKIN_SHARE, SKIN_SHARE, NeighbourList

    base = LawConfig()
    home, d_nn = sphere_swarm(n, base.gains)
    cut = 2.0 * d_nn
    ids = tuple(range(1, n + 1))
    nets = np.arange(n) % networks
    sets = [np.flatnonzero(nets == j) for j in range(networks)]
    motions = (("at rest", 0.0, 0.0), ("swinging slowly (0.3 m, 0.05 rad a period)", 0.3, 0.05),
               ("churning (0.3 m, 0.5 rad a period)", 0.3, 0.5))  # fmt: skip
    margins = (("0.3 r_c", SKIN_SHARE, SKIN_SHARE), ("1.0 r_c", 1.0, 1.0),
               ("adapting", SKIN_SHARE, MAX_SKIN_SHARE))  # fmt: skip
    rows = [f"N = {n} on {networks} networks, r_c = 2 d_nn = {cut:.3f} m, {periods} periods; "
            "ms a network step (lists built at once / ahead)", "",
            "| motion | " + " | ".join(m[0] for m in margins) + " |",
            "|---|" + "---|" * len(margins)]  # fmt: skip
    for name, amp, rad in motions:
        at = _swinging(home, amp, rad, seed=4)
        cells = [f"| {name}"]
        for _, least, most in margins:
            loop = ControlLoop(LawConfig(gains=Gains(repulsion_cutoff=cut)),
                               dict.fromkeys(ids, base.gains.q_default), 50.0)  # fmt: skip
            nl = NeighbourList(cut, least, most)
            loop.controller._neighbours = nl  # the law's list, with these margins
            pos, vel = home.copy(), np.zeros((n, 3))
            took = 0.0
            for k in range(2 * periods):  # the first half warms up (the margin settles)
                now = at(k)
                for rows_j in sets:
                    pos[rows_j] = now[rows_j]
                    t0 = time.process_time()
                    loop.command(ids, pos, vel, rows_j)
                    if k >= periods:
                        took += time.process_time() - t0
            steps = periods * networks
            cells.append(f"{1e3 * took / steps:.3f} ({nl.builds} / {nl.ahead})")
        rows.append(" | ".join(cells) + " |")
    return rows


def _episode_config() -> LawConfig:
    return LawConfig(
        leader=Leader(force=ConstantForce((10.0, 0.0, 0.0))),
        obstacles=(Box((40.0, 0.5, 0.3), (3.0, 2.0, 1.0)),),
        avoidance=Avoidance(),
    )


def bench_station_path() -> list[str]:
    """SwarmController.step costs for the Example 1 swarm at 50 Hz, and the
    look-ahead of one episode (6 vehicles, Scenario-3-like box pass)."""
    starts = [(2, 1, 2), (-1, -1, -1), (3, 4, 2), (4, 2, 2), (3, 3, 3), (-2, -2, -2)]
    cfg = _episode_config()
    res = integrate(cfg, starts, duration=40.0, dt=0.02)
    k0 = int(np.flatnonzero(res.behaviour == "avoidance")[0])
    ids = list(range(1, 7))
    q = np.full(6, 10.0)
    rows = ["| step (N = 6) | ms |", "|---|---|"]

    def formation_step() -> None:
        ctl = SwarmController(cfg)
        for k in range(0, 200):
            ctl.step(res.times_s[k], ids, res.pos_m[k], res.vel_mps[k], q)

    per_step = _median_ms(formation_step, 7) / 200
    rows.append(f"| `SwarmController.step`, formation | {per_step:.3f} |")

    prepared = [SwarmController(cfg, defer_lookahead=True) for _ in range(9)]
    for ctl in prepared:
        ctl.step(res.times_s[k0 - 1], ids, res.pos_m[k0 - 1], res.vel_mps[k0 - 1], q)
    starts_ms = []
    for ctl in prepared:
        t0 = time.perf_counter()
        ctl.step(res.times_s[k0], ids, res.pos_m[k0], res.vel_mps[k0], q)
        starts_ms.append(1e3 * (time.perf_counter() - t0))
    rows.append(
        f"| `step` at episode start (slot targets; look-ahead deferred) | "
        f"{statistics.median(starts_ms):.3f} |"
    )
    ctl = prepared[0]
    job = ctl.pending_lookahead()
    assert job is not None

    def avoid_step() -> None:
        for k in range(k0 + 1, k0 + 201):
            ctl.step(res.times_s[k], ids, res.pos_m[k], res.vel_mps[k], q)

    rows.append(f"| `step`, avoidance | {_median_ms(avoid_step, 3) / 200:.3f} |")
    rows.append(f"| look-ahead job, one episode (6 vehicles x 2 planes) | "
                f"{_median_ms(job, 5):.1f} |")  # fmt: skip
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description="Cost of the formation law, one core.")
    ap.add_argument("--cutoff", action="store_true", help="only the cut-off table")
    ap.add_argument("--counts", default="100,500,1000,2000", help="N of the cut-off table")
    ap.add_argument("--margin", action="store_true", help="only the Verlet margin's table")
    args = ap.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cpus, "
          f"Python {platform.python_version()}, numpy {np.__version__}, "
          f"OMP/OPENBLAS/MKL threads = {os.environ['OPENBLAS_NUM_THREADS']}")  # fmt: skip
    print(f"load average (1, 5, 15 min): {os.getloadavg()}")
    print()
    if args.margin:
        print("\n".join(bench_verlet_margin()))
        return
    counts = [int(x) for x in args.counts.split(",")]
    print("\n".join(bench_cutoff(counts)))
    print()
    print("\n".join(bench_controller_step(counts)))
    if args.cutoff:
        return
    print()
    print("\n".join(bench_law_eval()))
    print()
    print("\n".join(bench_station_path()))


if __name__ == "__main__":
    main()
