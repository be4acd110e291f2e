"""Figures of a formation, pure numpy: radii, pairwise distances, separation,
obstacle clearance, time to form and shape checks.

Used by the simulator's summary, the station's summary and the reports.
Positions are mission-frame metres; ``(N, 3)`` for one instant, ``(T, N, 3)``
for a trajectory, NaN rows marking inactive vehicles.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gcs_swarm.control.envelope import Demand
from gcs_swarm.control.obstacles import Ellipsoids, box_signed_distance
from gcs_swarm.control.params import Box

__all__ = [
    "Bipyramid",
    "FormationFigures",
    "classify_bipyramid",
    "command_demand",
    "formation_figures",
    "group_values",
    "min_box_clearance",
    "min_separation",
    "pairwise_distances",
    "radii",
    "shape_name",
    "time_to_form",
]

F64 = NDArray[np.float64]


def radii(pos_m: F64, centre_m: F64) -> F64:
    """Distance [m] of each vehicle ``(N, 3)`` to ``centre_m (3,)``; ``(N,)``."""
    return np.asarray(np.linalg.norm(pos_m - centre_m, axis=-1), dtype=np.float64)


def pairwise_distances(pos_m: F64) -> F64:
    """All ``N (N - 1) / 2`` inter-vehicle distances [m], sorted ascending."""
    n = pos_m.shape[0]
    i, j = np.triu_indices(n, k=1)
    return np.sort(np.linalg.norm(pos_m[i] - pos_m[j], axis=-1))


def min_separation(pos_m: F64) -> float:
    """Smallest inter-vehicle distance [m] (``inf`` for fewer than two vehicles)."""
    d = pairwise_distances(pos_m)
    return float(d[0]) if d.size else math.inf


def min_box_clearance(pos_m: F64, boxes: Sequence[Box] | Ellipsoids) -> float:
    """Smallest signed distance [m] of any vehicle to any box (negative inside;
    ``inf`` without boxes or vehicles)."""
    obs = boxes if isinstance(boxes, Ellipsoids) else Ellipsoids.from_boxes(boxes)
    if obs.count == 0 or pos_m.shape[0] == 0:
        return math.inf
    return float(box_signed_distance(pos_m, obs).min())


def time_to_form(times_s: F64, series: F64, *, rel_tol: float = 0.01) -> float:
    """First time [s] after which every column of ``series (T, M)`` stays within
    ``rel_tol`` (relative) of its final value; NaN samples are ignored."""
    final = series[-1]
    bad = np.abs(series - final) > rel_tol * np.abs(final)
    bad_any = np.any(bad & ~np.isnan(series), axis=1)
    idx = np.flatnonzero(bad_any)
    if idx.size == 0:
        return float(times_s[0])
    last = int(idx[-1])
    return float(times_s[min(last + 1, len(times_s) - 1)])


def group_values(values: F64, *, tol: float = 1e-4) -> list[tuple[float, int]]:
    """Group sorted values that differ by at most ``tol`` from their group's
    first member: ``[(mean, count), ...]`` (e.g. 12 x 3.51316, 3 x 4.96836)."""
    groups: list[list[float]] = []
    for x in np.sort(np.asarray(values, dtype=np.float64)):
        if groups and x - groups[-1][0] <= tol:
            groups[-1].append(float(x))
        else:
            groups.append([float(x)])
    return [(sum(g) / len(g), len(g)) for g in groups]


def shape_name(n: int) -> str:
    """The shape N charges take on a sphere (formation-law.md s9)."""
    names = {
        1: "point",
        2: "pair (antipodal)",
        3: "equilateral triangle",
        4: "tetrahedron",
        5: "triangular bipyramid",
        6: "octahedron",
    }
    return names.get(n, f"{n}-vehicle sphere")


@dataclass(frozen=True)
class Bipyramid:
    """A triangular bipyramid: ``poles`` and ``equator`` vehicle indices, the
    pole axis (unit) and the largest |cos| between the axis and an equatorial
    direction (0 for a perfect shape)."""

    poles: tuple[int, int]
    equator: tuple[int, ...]
    axis: F64
    tilt: float


def classify_bipyramid(pos_m: F64, centre_m: F64) -> Bipyramid:
    """Classify 5 vehicles: the poles are the most nearly antipodal pair."""
    if pos_m.shape[0] != 5:
        raise ValueError(f"a triangular bipyramid has 5 vehicles, got {pos_m.shape[0]}")
    u = pos_m - centre_m
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    cos = u @ u.T
    np.fill_diagonal(cos, np.inf)
    a, b = np.unravel_index(int(np.argmin(cos)), cos.shape)
    poles = (int(min(a, b)), int(max(a, b)))
    axis = u[poles[0]] - u[poles[1]]
    axis /= np.linalg.norm(axis)
    eq = tuple(i for i in range(5) if i not in poles)
    tilt = float(np.max(np.abs(u[list(eq)] @ axis)))
    return Bipyramid(poles, eq, axis, tilt)


@dataclass(frozen=True)
class FormationFigures:
    """Figures of one run (``formation_figures``)."""

    n_vehicles: int
    final_radii_m: F64
    final_distances_m: F64
    distance_groups: tuple[tuple[float, int], ...]
    min_separation_m: float
    min_separation_t_s: float
    min_clearance_m: float | None
    min_clearance_t_s: float | None
    episodes: int
    time_to_form_s: float

    def text(self) -> str:
        """A short human-readable summary (a few lines)."""
        r = self.final_radii_m
        lines = [f"vehicles: {self.n_vehicles} ({shape_name(self.n_vehicles)})"]
        if r.size:
            lines.append(f"final radius to leader [m]: min {r.min():.5f}  max {r.max():.5f}")
        if self.distance_groups:
            groups = ", ".join(f"{c} x {v:.5f}" for v, c in self.distance_groups)
            lines.append(f"final pairwise distances [m]: {groups}")
        lines.append(
            f"minimum separation [m]: {self.min_separation_m:.4f} "
            f"at t = {self.min_separation_t_s:.2f} s"
        )
        if self.min_clearance_m is not None:
            lines.append(
                f"minimum obstacle clearance [m]: {self.min_clearance_m:.4f} at "
                f"t = {self.min_clearance_t_s:.2f} s (negative: inside a box)"
            )
        lines.append(f"avoidance episodes: {self.episodes}")
        lines.append(f"time to form (1 %) [s]: {self.time_to_form_s:.2f}")
        return "\n".join(lines)


def formation_figures(
    times_s: F64,
    pos_m: F64,
    leader_pos_m: F64,
    boxes: Sequence[Box],
    *,
    episodes: int = 0,
    form_tol: float = 0.01,
) -> FormationFigures:
    """Summarize a trajectory ``pos_m (T, N, 3)`` (NaN = inactive) around the
    leader path ``leader_pos_m (T, 3)``."""
    final_act = ~np.isnan(pos_m[-1, :, 0])
    fin = pos_m[-1, final_act]
    r_fin = radii(fin, leader_pos_m[-1])
    d_fin = pairwise_distances(fin)
    n_t, n = pos_m.shape[0], pos_m.shape[1]
    i, j = np.triu_indices(n, k=1)
    with np.errstate(invalid="ignore"):
        pair_d = np.linalg.norm(pos_m[:, i] - pos_m[:, j], axis=-1)  # (T, P), NaN if inactive
    seps = np.full(n_t, math.inf)
    if pair_d.shape[1]:
        seps = np.min(np.where(np.isnan(pair_d), math.inf, pair_d), axis=1)
    k_sep = int(np.argmin(seps))
    obs = Ellipsoids.from_boxes(boxes)
    clear_m: float | None = None
    clear_t: float | None = None
    if obs.count:
        flat = pos_m.reshape(-1, 3)
        cl = box_signed_distance(np.nan_to_num(flat, nan=math.inf), obs).min(axis=1)
        cl = np.where(np.isnan(flat[:, 0]), math.inf, cl).reshape(n_t, n).min(axis=1)
        k_cl = int(np.argmin(cl))
        clear_m, clear_t = float(cl[k_cl]), float(times_s[k_cl])
    # Time to form over the trailing stretch where the final set is active.
    sub = pos_m[:, final_act]
    gaps = np.flatnonzero(np.isnan(sub[:, :, 0]).any(axis=1))
    first = int(gaps[-1]) + 1 if gaps.size else 0
    if fin.shape[0]:
        rr = np.linalg.norm(sub[first:] - leader_pos_m[first:, None, :], axis=-1)
        fi, fj = np.triu_indices(fin.shape[0], k=1)
        dd = np.linalg.norm(sub[first:, fi] - sub[first:, fj], axis=-1)
        ttf = time_to_form(times_s[first:], np.hstack([rr, dd]), rel_tol=form_tol)
    else:
        ttf = math.nan
    return FormationFigures(
        n_vehicles=int(final_act.sum()),
        final_radii_m=r_fin,
        final_distances_m=d_fin,
        distance_groups=tuple(group_values(d_fin, tol=1e-3)),
        min_separation_m=float(seps[k_sep]),
        min_separation_t_s=float(times_s[k_sep]),
        min_clearance_m=clear_m,
        min_clearance_t_s=clear_t,
        episodes=episodes,
        time_to_form_s=ttf,
    )


def command_demand(
    times_s: F64, accel_mps2: F64, vel_mps: F64, *, t_form_s: float | None = None,
    steps: NDArray[np.bool_] | None = None,
) -> Demand:  # fmt: skip
    """Peaks of what a run asked of its vehicles (``control.envelope.Demand``):
    ``accel_mps2``/``vel_mps (T, N, 3)`` the commands and velocities (NaN =
    inactive), ``times_s (T,)``.

    Jerk is the difference of consecutive commands over their time step, so it
    is only as fine as the sampling; a vehicle's first command (from hover,
    which the jerk limit ramps) and the sample after a gap are not counted,
    nor the differences flagged in ``steps (T - 1,)``: the law's own steps
    (a behaviour switch, a vehicle joining or leaving), which no time scale
    smooths and the jerk limit ramps.
    """
    with np.errstate(invalid="ignore"):
        a_xy = np.linalg.norm(accel_mps2[..., :2], axis=-1)
        v_xy = np.linalg.norm(vel_mps[..., :2], axis=-1)
        step = np.diff(times_s)[:, None]
        da = np.diff(accel_mps2, axis=0)
        j_xy = np.linalg.norm(da[..., :2], axis=-1) / step
        j_z = np.abs(da[..., 2]) / step
    if steps is not None:
        j_xy[steps] = np.nan
        j_z[steps] = np.nan

    def peak(x: F64) -> float:
        x = x[~np.isnan(x)]
        return float(x.max()) if x.size else 0.0

    return Demand(
        accel_xy=peak(a_xy),
        accel_z=peak(np.abs(accel_mps2[..., 2])),
        jerk_xy=peak(j_xy),
        jerk_z=peak(j_z),
        speed_xy=peak(v_xy),
        speed_up=max(peak(vel_mps[..., 2]), 0.0),
        speed_down=max(peak(-vel_mps[..., 2]), 0.0),
        t_form_s=t_form_s,
    )
