"""Flying missions on SITL and on the emulator, and comparing the two.

Helpers of the ``sitl`` tests: the station runs either as the command a user
types (``gcs-swarm run``, a subprocess) or in process (``run_mission``) with
the mission's links pointed at the SITL instances; ``emulator_twin`` turns the
same mission into one flown by the bundled emulator with SITL's geometry
(homes 5 m apart due east, the first home the mission origin) and ArduCopter
dynamics, and ``emulator_replay_twin`` into one that starts hovering where a
flown SITL run's formation started, so the two flights can be set side by
side (``compare``, ``convergence_times``).

Figures go to ``SITL_REPORT`` (``GCS_SWARM_SITL_REPORT``, default the test's
temporary folder) as one JSON file per test, and are printed (``-s``).
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import math
import os
import subprocess
import sys
from collections.abc import Awaitable, Callable, Mapping
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs_swarm.mavlink.coordinates import vector_ned_to_mission
from gcs_swarm.mission import Mission, load_mission
from gcs_swarm.report.replay import record_from_tlog
from gcs_swarm.report.tlog import read_tlog
from gcs_swarm.runtime import run_mission
from sim_vehicle import EmulatorConfig

ROOT = Path(__file__).resolve().parents[2]
_MAV = mav.MAVLink(None)
_LPN_ID, _SPT_ID = 32, 84
_ACCEL_ONLY = 3135
"""SET_POSITION_TARGET_LOCAL_NED's type mask of an acceleration setpoint (mavlink-protocol.md)."""
MISSIONS = ROOT / "config" / "missions"


def report_dir(tmp_path: Path) -> Path:
    d = Path(os.environ.get("GCS_SWARM_SITL_REPORT", tmp_path))
    d.mkdir(parents=True, exist_ok=True)
    return d


def write_figures(tmp_path: Path, name: str, figures: Mapping[str, Any]) -> None:
    path = report_dir(tmp_path) / f"{name}.json"
    path.write_text(json.dumps(figures, indent=2, default=float))
    print(f"\n{name}: {json.dumps(figures, indent=2, default=float)}")


def gcs_swarm_run(
    mission: Path, log_dir: Path, *, timeout_s: float, extra: tuple[str, ...] = ()
) -> tuple[int, str, Path | None]:
    """``gcs-swarm run MISSION --log-dir DIR`` as a user types it; (exit code,
    output, run folder)."""
    exe = Path(sys.executable).with_name("gcs-swarm")
    proc = subprocess.run(
        [str(exe), "run", str(mission), "--log-dir", str(log_dir), "--no-status", *extra],
        capture_output=True, text=True, timeout=timeout_s, stdin=subprocess.DEVNULL, cwd=ROOT,
    )  # fmt: skip
    folders = sorted(p.parent for p in log_dir.glob("*/summary.json"))
    return proc.returncode, proc.stdout + proc.stderr, folders[-1] if folders else None


def summary_of(folder: Path) -> dict[str, Any]:
    out: dict[str, Any] = json.loads((folder / "summary.json").read_text())
    return out


def with_links(mission: Mission, links: Mapping[int, str]) -> Mission:
    """The mission with each vehicle's link replaced (autopilot ArduPilot)."""
    vehicles = tuple(
        dataclasses.replace(v, link=links[v.sysid], autopilot="ardupilot", origin=None)
        for v in mission.vehicles
    )
    return dataclasses.replace(mission, vehicles=vehicles)


def emulator_twin(mission: Mission, *, spacing_m: float = 5.0) -> Mission:
    """The same mission on the bundled emulator, laid out as the SITL swarm:
    vehicle k's home ``spacing_m * k`` east of the first, which is the mission
    origin; ArduCopter-like dynamics; lockstep (exact and fast)."""
    vehicles = tuple(
        dataclasses.replace(v, link="sim", autopilot="sim", origin=(spacing_m * k, 0.0, 0.0))
        for k, v in enumerate(mission.vehicles)
    )
    emu = dataclasses.replace(
        mission.emulator,
        mode="lockstep", dynamics="ardupilot-like", ground=0.0, origin_spread=spacing_m,
        spawn="ground",
    )  # fmt: skip
    return dataclasses.replace(mission, vehicles=vehicles, emulator=emu)


def trajectories(folder: Path, mission: Mission) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mission times [s], system ids, positions [m] (T, N, 3), NaN where not flying)."""
    rec = record_from_tlog(folder / "flight.tlog", mission)
    return rec.times_s, np.asarray(rec.ids), rec.pos_m


def rms_position_difference(
    a: tuple[np.ndarray, np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray, np.ndarray]
) -> dict[int, float]:
    """Per vehicle: RMS over A's times of |p_A(t) - p_B(t)| [m] (B interpolated
    linearly in mission time), where both flew."""
    ta, ida, pa = a
    tb, idb, pb = b
    out: dict[int, float] = {}
    for ja, sysid in enumerate(ida.tolist()):
        hits = np.flatnonzero(idb == sysid)
        if not len(hits):
            continue
        jb = int(hits[0])
        sq = np.zeros_like(ta)
        ok = np.isfinite(pa[:, ja, 0])
        for k in range(3):
            pbk = pb[:, jb, k]
            good = np.isfinite(pbk)
            interp = np.interp(ta, tb[good], pbk[good], left=np.nan, right=np.nan)
            sq += (pa[:, ja, k] - interp) ** 2
        ok &= np.isfinite(sq)
        out[int(sysid)] = math.sqrt(float(np.mean(sq[ok]))) if ok.any() else math.nan
    return out


def compare(sitl: dict[str, Any], emu: dict[str, Any]) -> dict[str, Any]:
    """Headline figures of two summaries side by side."""

    def fig(s: dict[str, Any]) -> dict[str, Any]:
        o = s["overall"]
        return {
            "time_to_form_s": o["time_to_form_s"],
            "radius_min_m": o["final_radius_m"]["min"] if o["final_radius_m"] else None,
            "radius_max_m": o["final_radius_m"]["max"] if o["final_radius_m"] else None,
            "min_separation_m": o["min_separation_m"],
            "min_clearance_m": o["min_clearance_m"],
            # The station's own rate matters: Example 1 from the paper's starts
            # forms at 283 s at 40 Hz and 327 s at 25 Hz (simulate).
            "setpoint_rate_hz_mean": o["setpoints"]["rate_hz_mean"],
        }

    return {"sitl": fig(sitl), "emulator": fig(emu)}


def formation_series(folder: Path, mission: Mission) -> tuple[np.ndarray, np.ndarray]:
    """(mission times [s], (T, M) every radius then every pairwise distance [m]),
    from the run's tlog: the columns ``time_to_form`` judges in the summary."""
    rec = record_from_tlog(folder / "flight.tlog", mission)
    pos = rec.pos_m
    radii = np.linalg.norm(pos - rec.leader_pos_m[:, None, :], axis=-1)
    i, j = np.triu_indices(pos.shape[1], k=1)
    dists = np.linalg.norm(pos[:, i] - pos[:, j], axis=-1)
    return rec.times_s, np.hstack([radii, dists])


def wander(times_s: np.ndarray, series: np.ndarray, *, window_s: float = 20.0) -> float:
    """How much a held formation wanders: the largest relative standard
    deviation of any column over the last ``window_s`` [s]."""
    win = series[times_s >= times_s[-1] - window_s]
    return float(np.nanmax(np.nanstd(win, axis=0) / np.abs(np.nanmean(win, axis=0))))


def time_to_enter(
    times_s: np.ndarray, series: np.ndarray, band: float, *, window_s: float = 20.0
) -> float | None:
    """The first time [s] every column is within a relative ``band`` of its
    mean over the last ``window_s`` [s] (None: never). On a vehicle that wanders
    by more than the summary's 1 % (PX4 SITL) the formation never stays inside
    it: this is the time to form that can be compared (docs/sitl.md)."""
    mean = _held(times_s, series, window_s)
    return _first(times_s, np.all(np.abs(series - mean) <= band * np.abs(mean), axis=1))


def time_to_rms_band(
    times_s: np.ndarray, series: np.ndarray, band: float, *, window_s: float = 20.0
) -> float | None:
    """The first time [s] the formation's RMS relative error (every radius and
    distance against its mean over the last ``window_s`` s) is within ``band``
    (None: never). Unlike ``time_to_enter`` one vehicle's wander does not decide
    it: on four PX4 SITL runs 2.62-2.88 s where ``time_to_enter`` gave 2.82-3.48 s
    (docs/sitl.md)."""
    held = _held(times_s, series, window_s)
    return _first(times_s, np.sqrt(np.nanmean(((series - held) / held) ** 2, axis=1)) <= band)


def error_curve(
    times_s: np.ndarray, series: np.ndarray, law: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(times [s], the formation's RMS relative error against the law's
    equilibrium ``law``) for ``formation_series`` columns (radii, then pairwise
    distances). The radii and the distances are each sorted at every sample,
    since which pairs end up opposite is the flight's choice. Unlike the time
    to form it is judged against fixed values, not the run's own last sample,
    so the noise of the final state does not move it."""
    m = series.shape[1]
    n = round((-1.0 + math.sqrt(1.0 + 8.0 * m)) / 2.0)  # n + n (n - 1) / 2 = m
    ok = np.all(np.isfinite(series), axis=1)
    t, s = times_s[ok], series[ok]
    got = np.hstack([np.sort(s[:, :n], axis=1), np.sort(s[:, n:], axis=1)])
    want = np.concatenate([np.sort(law[:n]), np.sort(law[n:])])
    return t, np.sqrt(np.mean(((got - want) / want) ** 2, axis=1))


def convergence_times(
    times_s: np.ndarray, series: np.ndarray, law: np.ndarray, bands: tuple[float, ...]
) -> dict[str, float | None]:
    """For each band: the first time [s] ``error_curve`` is within it (None: never)."""
    t, e = error_curve(times_s, series, law)
    return {str(b): _first(t, e <= b) for b in bands}


def curve_difference(
    a: tuple[np.ndarray, np.ndarray],
    b: tuple[np.ndarray, np.ndarray],
    *,
    floor: float = 0.005,
    until_s: float | None = None,
) -> dict[str, float]:
    """How far error curve ``b`` is from ``a`` (``error_curve``'s (t, e) pairs):
    both on a 1 s grid from 10 s, each a 5 s running mean, ``|e_b - e_a| / e_a``
    wherever ``e_a`` is at least ``floor`` (below it a flown formation's own
    wander, 0.1-0.2 % on SITL, is most of the error). Its median and its
    largest value, and when [s]; ``until_s``: the grid ends there."""
    (ta, ea), (tb, eb) = a, b
    end = min(float(ta[-1]), float(tb[-1]))
    grid = np.arange(10.0, end if until_s is None else min(end, until_s), 1.0)
    k = np.ones(5) / 5.0
    ya = np.convolve(np.interp(grid, ta, ea), k, "valid")
    yb = np.convolve(np.interp(grid, tb, eb), k, "valid")
    g = grid[2:-2]
    sel = ya >= floor
    rel = np.abs(yb[sel] - ya[sel]) / ya[sel]
    if not rel.size:
        return {"median": math.nan, "max": math.nan, "max_at_s": math.nan}
    k_max = int(np.argmax(rel))
    return {
        "median": float(np.median(rel)),
        "max": float(rel[k_max]),
        "max_at_s": float(g[sel][k_max]),
    }


def _held(times_s: np.ndarray, series: np.ndarray, window_s: float) -> np.ndarray:
    """Each column's mean over the last ``window_s`` [s]."""
    return np.asarray(np.nanmean(series[times_s >= times_s[-1] - window_s], axis=0))


def _first(times_s: np.ndarray, inside: np.ndarray) -> float | None:
    """The first time [s] ``inside`` holds (None: never)."""
    k = np.flatnonzero(inside)
    return float(times_s[k[0]]) if k.size else None


def held_radii(summary: dict[str, Any], r_eq: float) -> dict[str, Any]:
    """Each vehicle's radius over the summary's last 20 s (``final_radius_window_m``:
    mean, std) and the mean's error against ``r_eq`` [%]; None for a vehicle that
    left."""
    wins = [v["final_radius_window_m"] for v in summary["vehicles"].values()]
    means = [None if w is None else w["mean"] for w in wins]
    return {
        "radii_last_20s_mean_m": means,
        "radii_last_20s_std_m": [None if w is None else w["std"] for w in wins],
        "radius_last_20s_error_percent": [
            None if m is None else 100 * (m - r_eq) / r_eq for m in means
        ],
    }


async def fly_acting(
    mission: Mission, runs: Path, at_s: float, act: Callable[[], Awaitable[None]]
) -> dict[str, Any]:
    """Fly ``mission`` in this process (``run_mission``), ``act`` once the
    status line says ``at_s`` [s] of formation flight, and return the run's
    summary.json, with the station's own figures of the lost vehicles'
    columns (``RunSummary.keep_out_columns``, ``min_keep_out_m``) under
    ``"keep_out"``."""
    holder: list[Any] = []
    flying = asyncio.Event()

    def status(line: str) -> None:
        # "t=  61.20s | ... formation ...": that much formation flight
        if line.startswith("t=") and float(line[2:].split("s", 1)[0]) >= at_s:
            flying.set()

    task = asyncio.create_task(
        run_mission(mission, log_dir=runs, picture=False, on_folder=holder.append, on_status=status)
    )
    await flying.wait()
    await act()
    run = await task
    s = summary_of(holder[0].path)
    s["keep_out"] = {"columns": run.keep_out_columns, "closest_m": run.min_keep_out_m}
    return s


def load(name: str) -> Mission:
    return load_mission(MISSIONS / name)


class FormationStart(NamedTuple):
    """Each vehicle of a flown run when its formation started (``formation_start``)."""

    starts: dict[int, tuple[float, float, float]]
    """Where it was: mission frame [m], the first control step's positions."""
    boot: dict[int, float]
    """Its own boot time [s]: ``time_boot_ms`` of the last LOCAL_POSITION_NED it
    had sent before its first acceleration setpoint."""
    velocity: dict[int, tuple[float, float, float]]
    """That report's velocity, mission frame [m/s]: on ArduCopter what it flew the
    formation from (its Accel sub-mode's velocity reference, Eq. D9)."""


def formation_start(folder: Path, mission: Mission) -> FormationStart:
    """Where, at what boot time and from what velocity each vehicle of a flown
    run started its formation (``FormationStart``)."""
    rec = record_from_tlog(folder / "flight.tlog", mission)
    ids = [int(s) for s in np.asarray(rec.ids).tolist()]
    first = {}
    for j, sysid in enumerate(ids):
        k = np.flatnonzero(np.isfinite(rec.pos_m[:, j, 0]))
        first[sysid] = tuple(float(c) for c in rec.pos_m[k[0], j])
    boot: dict[int, float] = {}
    velocity: dict[int, tuple[float, float, float]] = {}
    last: dict[int, Any] = {}
    for r in read_tlog(folder / "flight.tlog"):
        h = r.header
        if h.direction == "in" and h.msgid == _LPN_ID:
            last[h.sysid] = _MAV.decode(bytearray(r.frame))
        elif h.direction == "out" and h.msgid == _SPT_ID:
            msg = _MAV.decode(bytearray(r.frame))
            k = msg.target_system
            if msg.type_mask == _ACCEL_ONLY and k in last and k not in boot:
                boot[k] = int(last[k].time_boot_ms) * 1e-3
                v = vector_ned_to_mission((last[k].vx, last[k].vy, last[k].vz))
                velocity[k] = (float(v[0]), float(v[1]), float(v[2]))
                if len(boot) == len(ids):
                    break
    return FormationStart(first, boot, velocity)


def emulator_replay_twin(
    mission: Mission,
    sitl_folder: Path,
    *,
    spacing_m: float = 5.0,
    jitter_m: float = 0.0,
    seed: int = 0,
    from_rest: bool = False,
) -> Mission:
    """The emulator twin of one SITL run from the moment its formation started:
    each emulated vehicle spawned hovering where the SITL vehicle was then
    (``formation_start``) and flying, from its first setpoint, from the
    velocity SITL's flew from (its reported velocity then, Eq. D9; at rest
    with ``from_rest``), so the two fly the same formation from the same
    state (a start-up on the ground would leave each vehicle up to the
    mission's start tolerance, 0.3 m, from where SITL's was, and this
    mission's time to form moves by +-6 % for 1 cm there; from rest the
    twins were 10-30 % slower than SITL from its start: docs/sitl.md); the
    velocity bias reverses at the same boot time as SITL's (304 s).
    ``jitter_m`` [m]: each start moved by N(0, jitter_m) per axis (generator
    seeded with ``seed``), for an ensemble of twins from starts as uncertain
    as SITL's (its vehicles were still moving: the octahedron's SITL test,
    ``test_sitl_arducopter._twin_figures``)."""
    starts, boot, velocity = formation_start(sitl_folder, mission)
    if jitter_m > 0.0:
        rng = np.random.default_rng(seed)
        starts = {
            k: tuple(float(c) for c in np.asarray(p) + rng.normal(0.0, jitter_m, 3))
            for k, p in sorted(starts.items())
        }
    since = float(np.median(list(boot.values())))  # the instances' boot time at the start
    flip = EmulatorConfig.ARDUPILOT_VBIAS_FLIP_S - since
    twin = emulator_twin(mission, spacing_m=spacing_m)
    vehicles = tuple(
        dataclasses.replace(
            v, start=starts[v.sysid], start_velocity=None if from_rest else velocity[v.sysid]
        )
        for v in twin.vehicles
    )
    emu = dataclasses.replace(
        twin.emulator, spawn="air", velocity_bias_flip=flip if flip > 0.0 else 0.0
    )
    return dataclasses.replace(twin, vehicles=vehicles, emulator=emu)
