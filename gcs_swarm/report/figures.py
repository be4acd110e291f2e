"""The run summary: a ``FlightRecord`` in numbers, as a JSON-ready dict.

Overall figures come from ``gcs_swarm.analysis.formation_figures`` (final radii and
pairwise distances, minimum separation and box clearance, time to form:
every radius and distance within 1 % of its final value); this module adds
the per-vehicle figures, who and when, behaviour switches, commanded
accelerations, setpoint rate and gaps, telemetry loss, join/leave events and
the safety filter's interventions. ``series`` gives the time series the
report picture plots. Pure numpy; JSON has no infinity or NaN, so a figure
that does not apply (no obstacle, a single vehicle) is ``null``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from gcs_swarm.analysis import formation_figures, pairwise_distances, time_to_form
from gcs_swarm.control.obstacles import Ellipsoids, box_signed_distance
from gcs_swarm.report.record import FlightRecord

__all__ = ["SUMMARY_FORMAT", "Series", "series", "summarize_record"]

SUMMARY_FORMAT = "gcs-swarm-summary/1"
HOLD_WINDOW_S = 20.0
"""The trailing window of ``final_radius_window_m``: a real vehicle's position wanders
(PX4 SIH in OFFBOARD acceleration: 0.2-0.7 m std over 20 s), so its last sample alone
says little about where the formation holds; the window's mean and std do."""
F64 = npt.NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Series:
    """Time series of a record (T steps, N vehicles), NaN where not applicable:
    ``radius_m (T, N)`` to the leader, ``nearest_m (T, N)`` distance to the
    nearest other vehicle, ``clearance_m (T, N)`` signed distance to the
    nearest box (negative inside; None without boxes), ``accel_mps2 (T, N)``
    commanded |a| where a setpoint was sent, ``min_separation_m (T,)`` and
    ``min_clearance_m (T,)`` over the vehicles."""

    radius_m: F64
    nearest_m: F64
    nearest_id: npt.NDArray[np.int64]
    clearance_m: F64 | None
    accel_mps2: F64
    min_separation_m: F64
    min_clearance_m: F64 | None


def _nanmin_rows(a: F64) -> F64:
    """Row minima ignoring NaN; NaN for an all-NaN row (no warning)."""
    filled = np.where(np.isnan(a), np.inf, a)
    out = filled.min(axis=1) if a.shape[1] else np.full(a.shape[0], np.inf)
    return np.where(np.isinf(out), np.nan, out)


def series(rec: FlightRecord) -> Series:
    t_n, n = rec.pos_m.shape[0], rec.pos_m.shape[1]
    with np.errstate(invalid="ignore"):
        radius = np.linalg.norm(rec.pos_m - rec.leader_pos_m[:, None, :], axis=-1)
    nearest = np.full((t_n, n), np.nan)
    nearest_id = np.full((t_n, n), -1, dtype=np.int64)
    for j in range(n):
        d = np.linalg.norm(rec.pos_m - rec.pos_m[:, j : j + 1, :], axis=-1)
        d[:, j] = np.nan
        filled = np.where(np.isnan(d), np.inf, d)
        k = filled.argmin(axis=1) if n > 1 else np.zeros(t_n, dtype=np.int64)
        best = filled[np.arange(t_n), k] if n > 1 else np.full(t_n, np.inf)
        ok = np.isfinite(best)
        nearest[ok, j] = best[ok]
        nearest_id[ok, j] = rec.ids[k[ok]]
    clearance = None
    min_clear = None
    if rec.boxes:
        obs = Ellipsoids.from_boxes(rec.boxes)
        flat = rec.pos_m.reshape(-1, 3)
        act = ~np.isnan(flat[:, 0])
        cl = np.full(flat.shape[0], np.nan)
        if act.any():
            cl[act] = box_signed_distance(flat[act], obs).min(axis=1)
        clearance = cl.reshape(t_n, n)
        min_clear = _nanmin_rows(clearance)
    accel = np.linalg.norm(rec.accel_mps2, axis=-1)
    return Series(radius, nearest, nearest_id, clearance, accel, _nanmin_rows(nearest), min_clear)


def _num(x: float | None) -> float | None:
    if x is None or not math.isfinite(x):
        return None
    return float(x)


def _argmin(a: F64) -> tuple[int, int] | None:
    """Index of the smallest non-NaN entry of ``a (T, N)``, or None."""
    if a.size == 0 or np.all(np.isnan(a)):
        return None
    k, j = np.unravel_index(int(np.nanargmin(a)), a.shape)
    return int(k), int(j)


def _runs(mask: npt.NDArray[np.bool_]) -> list[tuple[int, int]]:
    """Contiguous True runs of a 1-D mask as (first, last) indices."""
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) > 1)
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks], [idx[-1]]])
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True)]


def _setpoints(rec: FlightRecord, j: int) -> dict[str, Any]:
    """Sent count, achieved rate (1 / mean interval) and the largest interval
    between consecutive setpoints inside one stretch in the formation."""
    t = rec.times_s
    gaps: list[F64] = []
    starts: list[F64] = []
    for a, b in _runs(~np.isnan(rec.pos_m[:, j, 0])):
        ts = t[a : b + 1][rec.sent[a : b + 1, j]]
        if ts.size >= 2:
            gaps.append(np.diff(ts))
            starts.append(ts[:-1])
    sent = int(rec.sent[:, j].sum())
    if not gaps:
        return {"sent": sent, "rate_hz": None, "largest_gap_s": None, "largest_gap_at_s": None}
    g, s = np.concatenate(gaps), np.concatenate(starts)
    k = int(np.argmax(g))
    return {
        "sent": sent,
        "rate_hz": _num(1.0 / float(g.mean())) if g.mean() > 0 else None,
        "largest_gap_s": float(g[k]),
        "largest_gap_at_s": float(s[k]),
    }


def summarize_record(rec: FlightRecord, *, form_tol: float = 0.01) -> dict[str, Any]:
    """The summary of ``rec`` (see the module docstring); ``form_tol`` the
    relative band of "formed" (1 %)."""
    out: dict[str, Any] = {
        "format": SUMMARY_FORMAT,
        "mission": rec.name,
        "source": rec.source,
        "control_steps": rec.steps,
        "mission_time_s": float(rec.times_s[-1]) if rec.steps else 0.0,
        "rate_hz": rec.rate_hz,
    }
    ids = [int(s) for s in rec.ids]
    if rec.steps == 0:
        out["overall"] = {"vehicles_seen": ids, "note": "no control step was recorded"}
        out["vehicles"] = {}
        return out
    ser = series(rec)
    t = rec.times_s
    swarm = formation_figures(t, rec.pos_m, rec.leader_pos_m, rec.boxes,
                              episodes=int(rec.episode[-1]), form_tol=form_tol)  # fmt: skip
    final = ~np.isnan(rec.pos_m[-1, :, 0])
    final_ids = [ids[j] for j in np.flatnonzero(final)]
    switches = [{"t_s": ts, "event": ev, "episode": ep} for ts, ev, ep in rec.switches()]
    events = [{"t_s": ts, "action": a, "sysid": s} for ts, a, s in rec.events]

    # Trailing stretch where the final set is active (as analysis.formation_figures).
    gaps = np.flatnonzero(np.isnan(rec.pos_m[:, final, 0]).any(axis=1))
    first = int(gaps[-1]) + 1 if gaps.size else 0
    vehicles: dict[str, Any] = {}
    for j, sysid in enumerate(ids):
        v: dict[str, Any] = {}
        inside = ~np.isnan(rec.pos_m[:, j, 0])
        v["steps_in_formation"] = int(inside.sum())
        v["joined_at_s"] = [ts for ts, a, s in rec.events if s == sysid and a == "join"]
        v["left_at_s"] = [ts for ts, a, s in rec.events if s == sysid and a == "leave"]
        if final[j]:
            others = [k for k in np.flatnonzero(final) if k != j]
            v["final_radius_m"] = float(ser.radius_m[-1, j])
            dists = np.linalg.norm(rec.pos_m[:, others] - rec.pos_m[:, j : j + 1], axis=-1)
            v["final_distances_m"] = {str(ids[k]): float(dists[-1, i])
                                      for i, k in enumerate(others)}  # fmt: skip
            cols = np.hstack([ser.radius_m[first:, j : j + 1], dists[first:]])
            v["time_to_form_s"] = time_to_form(t[first:], cols, rel_tol=form_tol)
            v["final_radius_window_m"] = _window(t[first:], ser.radius_m[first:, j])
        else:
            v["final_radius_m"] = v["final_distances_m"] = v["time_to_form_s"] = None
            v["final_radius_window_m"] = None
        near = _argmin(ser.nearest_m[:, j : j + 1])
        v["min_separation_m"] = None if near is None else float(ser.nearest_m[near[0], j])
        v["min_separation_at_s"] = None if near is None else float(t[near[0]])
        v["min_separation_with"] = None if near is None else int(ser.nearest_id[near[0], j])
        if ser.clearance_m is not None:
            cl = _argmin(ser.clearance_m[:, j : j + 1])
            v["min_clearance_m"] = None if cl is None else float(ser.clearance_m[cl[0], j])
            v["min_clearance_at_s"] = None if cl is None else float(t[cl[0]])
        pk = _argmin(-ser.accel_mps2[:, j : j + 1])
        v["peak_accel_mps2"] = None if pk is None else float(ser.accel_mps2[pk[0], j])
        v["peak_accel_at_s"] = None if pk is None else float(t[pk[0]])
        v["setpoints"] = _setpoints(rec, j)
        v["telemetry"] = _telemetry(rec, sysid)
        if rec.correction_mps2 is not None:
            c = rec.correction_mps2[:, j]
            v["safety_interventions"] = int(np.count_nonzero(c > 0.0))
            v["safety_max_correction_mps2"] = float(np.nanmax(c, initial=0.0))
        vehicles[str(sysid)] = v

    sep = _argmin(ser.nearest_m)
    peak = _argmin(-ser.accel_mps2)
    windows = [v["final_radius_window_m"] for v in vehicles.values()]
    held = np.array([w["mean"] for w in windows if w is not None])
    overall: dict[str, Any] = {
        "vehicles_seen": ids,
        "vehicles_flown": [
            ids[j] for j in range(len(ids)) if vehicles[str(ids[j])]["steps_in_formation"]
        ],
        "vehicles_final": final_ids,
        "time_to_form_s": _num(swarm.time_to_form_s),
        "final_radius_m": _stats(swarm.final_radii_m),
        "final_radius_window_m": _stats(held),
        "final_pairwise_distances_m": [float(d) for d in pairwise_distances(rec.pos_m[-1, final])],
        "distance_groups": [{"distance_m": d, "count": c} for d, c in swarm.distance_groups],
        "min_separation_m": _num(swarm.min_separation_m),
        "min_separation_at_s": _num(swarm.min_separation_t_s) if sep is not None else None,
        "min_separation_pair": (
            None if sep is None else sorted([ids[sep[1]], int(ser.nearest_id[sep])])
        ),
        "min_clearance_m": _num(swarm.min_clearance_m),
        "min_clearance_at_s": _num(swarm.min_clearance_t_s),
        "min_clearance_vehicle": _clearance_vehicle(ser, ids),
        "avoidance_episodes": int(rec.episode[-1]),
        "behaviour_switches": switches,
        "peak_accel_mps2": None if peak is None else float(ser.accel_mps2[peak]),
        "peak_accel_at_s": None if peak is None else float(t[peak[0]]),
        "peak_accel_vehicle": None if peak is None else ids[peak[1]],
        "setpoints": _overall_setpoints(vehicles),
        "telemetry": _overall_telemetry(rec),
        "events": events,
        "safety": _overall_safety(rec),
    }
    out["overall"] = overall
    out["vehicles"] = vehicles
    return out


def _window(t: F64, radius: F64) -> dict[str, float] | None:
    """Mean, std, min and max of ``radius`` over the last ``HOLD_WINDOW_S`` of ``t``
    (less when the stretch is shorter; ``window_s`` says how much)."""
    if t.size == 0:
        return None
    inside = t >= t[-1] - HOLD_WINDOW_S
    r = radius[inside]
    return {
        "window_s": float(t[-1] - t[inside][0]), "mean": float(r.mean()),
        "std": float(r.std()), "min": float(r.min()), "max": float(r.max()),
    }  # fmt: skip


def _stats(x: F64) -> dict[str, float] | None:
    if x.size == 0:
        return None
    return {"min": float(x.min()), "max": float(x.max()), "mean": float(x.mean())}


def _clearance_vehicle(ser: Series, ids: list[int]) -> int | None:
    if ser.clearance_m is None:
        return None
    at = _argmin(ser.clearance_m)
    return None if at is None else ids[at[1]]


def _telemetry(rec: FlightRecord, sysid: int) -> dict[str, Any] | None:
    if rec.telemetry is None:
        return None
    c = rec.telemetry.get(sysid)
    if c is None:
        return {"received": 0, "lost": 0, "loss_percent": None}
    return {
        "received": c.received,
        "lost": c.lost,
        "loss_percent": 100.0 * c.loss_fraction,
        "duplicates": c.duplicates,
        "late": c.late,
        "local_position_received": c.local_position,
    }


def _overall_telemetry(rec: FlightRecord) -> dict[str, Any] | None:
    if rec.telemetry is None:
        return None
    received = sum(c.received for c in rec.telemetry.values())
    lost = sum(c.lost for c in rec.telemetry.values())
    total = received + lost
    known = set(int(s) for s in rec.ids)
    return {
        "received": received,
        "lost": lost,
        "loss_percent": 100.0 * lost / total if total else None,
        "local_position_received": sum(c.local_position for c in rec.telemetry.values()),
        "other_systems": sorted(s for s in rec.telemetry if s not in known),
    }


def _overall_setpoints(vehicles: dict[str, Any]) -> dict[str, Any]:
    sp = {s: v["setpoints"] for s, v in vehicles.items()}
    rates = [x["rate_hz"] for x in sp.values() if x["rate_hz"] is not None]
    worst = max(
        (s for s in sp if sp[s]["largest_gap_s"] is not None),
        key=lambda s: sp[s]["largest_gap_s"],
        default=None,
    )
    return {
        "sent": sum(x["sent"] for x in sp.values()),
        "rate_hz_min": min(rates) if rates else None,
        "rate_hz_mean": sum(rates) / len(rates) if rates else None,
        "largest_gap_s": None if worst is None else sp[worst]["largest_gap_s"],
        "largest_gap_at_s": None if worst is None else sp[worst]["largest_gap_at_s"],
        "largest_gap_vehicle": None if worst is None else int(worst),
    }


def _overall_safety(rec: FlightRecord) -> dict[str, Any]:
    safety: dict[str, Any] = {"applied": rec.correction_mps2 is not None}
    if rec.correction_mps2 is not None:
        c = rec.correction_mps2
        safety["interventions"] = int(np.count_nonzero(c > 0.0))
        safety["vehicle_steps"] = int(np.count_nonzero(~np.isnan(c)))
        safety["max_correction_mps2"] = float(np.nanmax(c, initial=0.0))
    for key, value in rec.extra.items():
        if key.startswith("safety_"):
            safety[key[len("safety_") :]] = value
    return safety
