"""Run folders and the files in them; ``gcs-swarm report``.

A run folder is ``<log dir>/<YYYYmmdd-HHMMSS>-<mission slug>/`` (log dir from
the mission's ``log.dir``, default ``runs``; local time of the start; the
slug is the mission name in lower case, runs of other characters as ``-``)
holding:

- ``flight.tlog``: every MAVLink frame in and out, plus the station's
  annotations (``gcs_swarm.report.notes``), standard ``.tlog`` format; a
  mission with networks has one ``flight-<network>.tlog`` each instead
  (the annotations in the first), and a sharded run (``gcs-swarm run
  --shards N``) keeps the annotations in ``controller.tlog``, each shard
  writing its own networks' logs;
- ``mission.yaml``: a byte-for-byte copy of the mission file flown;
- ``summary.json``: the figures of ``gcs_swarm.report.figures``;
- ``report.png``: the picture of ``gcs_swarm.report.plot``;
- ``vehicle_params.json`` (``gcs-swarm run``): per vehicle, its envelope and
  every parameter the station changed on it (old value, new, read-back,
  restored or not; ``gcs_swarm.mavlink.vehicle_params``).

``rebuild_report`` rebuilds the last two from a run folder or a ``.tlog``
alone (given the mission file); ``write_simulation_report`` writes them for
``gcs-swarm simulate``.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import shutil
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from gcs_swarm.errors import ReportError
from gcs_swarm.mission import Mission, load_mission
from gcs_swarm.mission.model import DEFAULT_NETWORK
from gcs_swarm.report.figures import summarize_record
from gcs_swarm.report.networks import label_summary
from gcs_swarm.report.record import FlightRecord
from gcs_swarm.report.replay import CONTROLLER_TLOG_NAME, ReplayStats, record_from_tlog

__all__ = [
    "CONTROLLER_TLOG_NAME",
    "MISSION_NAME",
    "PICTURE_NAME",
    "SUMMARY_NAME",
    "TLOG_NAME",
    "VEHICLE_PARAMS_NAME",
    "RunFolder",
    "create_run_folder",
    "flown_run",
    "from_sim_result",
    "network_tlogs",
    "rebuild_report",
    "report_from_tlog",
    "run_folder_name",
    "summary_text",
    "write_json",
    "write_report",
    "write_simulation_report",
]

TLOG_NAME = "flight.tlog"
#: A network's log in a run with networks (``network_tlogs``).
_NETWORK_TLOG = re.compile(r"flight-[A-Za-z][A-Za-z0-9_-]{0,31}\.tlog")
MISSION_NAME = "mission.yaml"
SUMMARY_NAME = "summary.json"
PICTURE_NAME = "report.png"
VEHICLE_PARAMS_NAME = "vehicle_params.json"


@dataclass(frozen=True)
class RunFolder:
    """The paths of one run's artefacts."""

    path: Path

    @property
    def tlog(self) -> Path:
        return self.path / TLOG_NAME

    @property
    def controller_tlog(self) -> Path:
        """A sharded run's annotations (``report.replay.CONTROLLER_TLOG_NAME``)."""
        return self.path / CONTROLLER_TLOG_NAME

    def tlogs(self, networks: tuple[str, ...]) -> list[Path]:
        """The run's telemetry logs, one per network in the mission's order:
        ``flight.tlog`` alone for a mission without networks (as ever),
        ``flight-<name>.tlog`` each otherwise (``network_tlogs``)."""
        return network_tlogs(self.path, networks)

    @property
    def mission(self) -> Path:
        return self.path / MISSION_NAME

    @property
    def summary(self) -> Path:
        return self.path / SUMMARY_NAME

    @property
    def picture(self) -> Path:
        return self.path / PICTURE_NAME

    @property
    def vehicle_params(self) -> Path:
        return self.path / VEHICLE_PARAMS_NAME


def network_tlogs(folder: Path, networks: tuple[str, ...]) -> list[Path]:
    """The telemetry logs of a run in ``folder`` with ``networks`` (a
    mission's ``networks``): one per network, since each network has its own
    system ids and a .tlog holds one id space (pymavlink's tools read each
    as it is); ``flight.tlog`` alone without networks."""
    if networks == (DEFAULT_NETWORK,):
        return [folder / TLOG_NAME]
    return [folder / f"flight-{name}.tlog" for name in networks]


def run_folder_name(mission_name: str, when: datetime) -> str:
    """``YYYYmmdd-HHMMSS-<slug>``, e.g. ``20250301-142501-scenario-3-moving-tetrahedron``."""
    slug = re.sub(r"[^a-z0-9]+", "-", mission_name.lower()).strip("-")[:48].strip("-")
    return f"{when:%Y%m%d-%H%M%S}-{slug or 'mission'}"


def create_run_folder(
    mission: Mission,
    *,
    base_dir: str | os.PathLike[str] | None = None,
    when: datetime | None = None,
) -> RunFolder:
    """Create a new run folder under ``base_dir`` (default the mission's
    ``log.dir``) and write the mission into it (the text that was loaded); ``-2``, ``-3``... are
    appended when two runs start in the same second."""
    base = Path(base_dir if base_dir is not None else mission.log.dir)
    name = run_folder_name(mission.settings.name, when or datetime.now())
    try:
        base.mkdir(parents=True, exist_ok=True)
        path, k = base / name, 1
        while True:
            try:
                path.mkdir()
                break
            except FileExistsError:
                k += 1
                path = base / f"{name}-{k}"
        folder = RunFolder(path)
        source = Path(mission.source)
        if mission.text:  # the text that was validated, even if the file changed since
            folder.mission.write_text(mission.text, encoding="utf-8")
        elif source.is_file():
            shutil.copyfile(source, folder.mission)
    except OSError as err:
        raise ReportError(f"{base}: cannot create the run folder: {err.strerror or err}") from None
    return folder


def _clean(x: Any) -> Any:
    """JSON-ready: numpy scalars to Python, non-finite floats to None."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_clean(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def write_json(summary: dict[str, Any], path: str | os.PathLike[str]) -> None:
    """Write ``summary`` as indented JSON (no NaN or infinity), atomically:
    into a temporary file beside ``path``, then renamed over it, so a full
    disk leaves the old file (or none), never a truncated or empty one.
    ``OSError`` if it cannot be written (the temporary file is removed)."""
    text = json.dumps(_clean(summary), indent=2, allow_nan=False) + "\n"
    target = Path(path)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_report(
    rec: FlightRecord,
    summary_path: str | os.PathLike[str],
    picture_path: str | os.PathLike[str] | None,
    *,
    extra: dict[str, Any] | None = None,
    networks: tuple[str, ...] = (DEFAULT_NETWORK,),
) -> dict[str, Any]:
    """Summarize ``rec``, write the JSON and (unless None) the PNG; returns
    the summary. ``extra`` is merged at the top level of the JSON (e.g. the
    station's link counters). ``networks``: the mission's; with named
    networks every vehicle is told by ``network:sysid`` (``label_summary``)."""
    summary = summarize_record(rec)
    if extra:
        summary.update(extra)
    label_summary(summary, networks)
    try:
        write_json(summary, summary_path)
        if picture_path is not None:
            from gcs_swarm.report.plot import build_figure, save_picture

            save_picture(build_figure(rec, summary), picture_path)
    except OSError as err:
        raise ReportError(f"cannot write the report: {err.strerror or err}") from None
    return summary


def report_from_tlog(
    tlog_path: str | os.PathLike[str], mission: Mission
) -> tuple[dict[str, Any], FlightRecord]:
    """Summary and flight record of a logged run, from the ``.tlog`` and
    the mission file alone (``gcs_swarm.report.replay``)."""
    stats = ReplayStats()
    try:
        rec = record_from_tlog(tlog_path, mission, stats=stats)
    except OSError as err:
        raise ReportError(f"{tlog_path}: cannot read the log: {err.strerror or err}") from None
    summary = label_summary(summarize_record(rec), mission.networks)
    summary["log"] = {
        "records": stats.records,
        "undecodable": stats.undecodable,
        "damaged_bytes": stats.tlog.skipped_bytes,
        "truncated": stats.tlog.truncated,
        "station_annotations": stats.annotated,
    }
    return summary, rec


def _paths(path: Path, mission_path: str | None) -> tuple[Path, Path, Path, Path]:
    """(tlog, mission, summary, picture) for ``gcs-swarm report PATH``."""
    if path.is_dir():
        folder = RunFolder(path)
        mission = Path(mission_path) if mission_path else folder.mission
        tlog = folder.tlog
        if not tlog.is_file():  # a run with networks: one log per network, read together
            tlog = next(iter(sorted(path.glob("flight-*.tlog"))), tlog)
        return tlog, mission, folder.summary, folder.picture
    if mission_path:
        mission = Path(mission_path)
    else:
        mission = path.parent / MISSION_NAME
    if path.name == TLOG_NAME or _NETWORK_TLOG.fullmatch(path.name):
        return path, mission, path.parent / SUMMARY_NAME, path.parent / PICTURE_NAME
    return path, mission, path.with_name(path.stem + "-summary.json"), path.with_suffix(".png")


def flown_run(
    path: str | os.PathLike[str], mission_path: str | None = None
) -> tuple[Path, Mission]:
    """The ``.tlog`` and the mission of the run logged at ``path`` (a run
    folder or a ``.tlog``; the mission beside it unless ``mission_path``), as
    ``rebuild_report`` and ``gcs-swarm view`` read them. ``ReportError`` when
    a file is missing (``MissionError`` for a bad mission file)."""
    tlog, mission_file, _, _ = _paths(Path(path), mission_path)
    return tlog, _flown_mission(tlog, mission_file)


def _flown_mission(tlog: Path, mission_file: Path) -> Mission:
    if not tlog.is_file():
        raise ReportError(f"{tlog}: no such telemetry log")
    if not mission_file.is_file():
        raise ReportError(
            f"{mission_file}: no mission file; give the one that was flown with --mission FILE"
        )
    return load_mission(mission_file)


def _free_pair(summary: Path, picture: Path) -> tuple[Path, Path]:
    """``summary``, ``picture`` if neither exists, else both with the first
    suffix ``-1``, ``-2``, ... that names two free files."""
    n, s, p = 0, summary, picture
    while s.exists() or p.exists():
        n += 1
        s = summary.with_name(f"{summary.stem}-{n}{summary.suffix}")
        p = picture.with_name(f"{picture.stem}-{n}{picture.suffix}")
    return s, p


def rebuild_report(
    path: str | os.PathLike[str], mission_path: str | None = None, *, force: bool = False
) -> tuple[dict[str, Any], Path, Path]:
    """Rebuild the summary and picture of the run logged at ``path`` (a run
    folder or a ``.tlog``) beside it: in a run folder, or
    ``<name>-summary.json`` and ``<name>.png`` for another ``.tlog``. Returns
    (the summary, its path, the picture's path). Nothing is overwritten
    unless ``force``: when a summary or picture is there already (a run's own
    ``summary.json`` and ``report.png``), they go to ``summary-<n>.json`` and
    ``report-<n>.png``, n the first free number. ``ReportError`` when a file
    is missing or unreadable (``MissionError`` for the mission file)."""
    tlog, mission_file, summary_path, picture_path = _paths(Path(path), mission_path)
    if not force:
        summary_path, picture_path = _free_pair(summary_path, picture_path)
    mission = _flown_mission(tlog, mission_file)
    summary, rec = report_from_tlog(tlog, mission)
    write_report(rec, summary_path, picture_path, extra={"log": summary["log"]},
                 networks=mission.networks)  # fmt: skip
    return summary, summary_path, picture_path


def _f(x: Any, unit: str, digits: int = 3) -> str:
    return "-" if x is None or not math.isfinite(float(x)) else f"{float(x):.{digits}f} {unit}"


def summary_text(summary: dict[str, Any]) -> str:
    """A few human-readable lines of a summary."""
    o = summary.get("overall", {})
    lines = [
        f"{summary.get('mission') or 'run'} ({summary.get('source')}): "
        f"{summary.get('control_steps', 0)} control steps, "
        f"{_f(summary.get('mission_time_s'), 's', 2)} of mission time"
    ]
    if "time_to_form_s" not in o:
        return "\n".join([*lines, o.get("note", "")])
    r = o.get("final_radius_m") or {}
    lines.append(
        f"vehicles {o['vehicles_final']} at the end; formed (1 %) after "
        f"{_f(o['time_to_form_s'], 's', 2)}; final radius {_f(r.get('min'), 'm', 4)} .. "
        f"{_f(r.get('max'), 'm', 4)}"
    )
    groups = ", ".join(f"{g['count']} x {g['distance_m']:.4f}" for g in o["distance_groups"])
    if groups:
        lines.append(f"final pairwise distances [m]: {groups}")
    lines.append(
        f"min separation {_f(o['min_separation_m'], 'm')} at {_f(o['min_separation_at_s'], 's', 2)}"
        f" (vehicles {o['min_separation_pair']}); min clearance {_f(o['min_clearance_m'], 'm')}"
        f" at {_f(o['min_clearance_at_s'], 's', 2)}; avoidance episodes {o['avoidance_episodes']}"
    )
    sp, tm = o["setpoints"], o["telemetry"]
    lines.append(
        f"peak commanded |a| {_f(o['peak_accel_mps2'], 'm/s^2', 2)}; setpoints {sp['sent']}, "
        f"rate >= {_f(sp['rate_hz_min'], 'Hz', 1)}, largest gap {_f(sp['largest_gap_s'], 's')}"
    )
    if tm is not None:
        lines.append(
            f"telemetry received {tm['received']}, lost {tm['lost']} "
            f"({_f(tm['loss_percent'], '%', 2)})"
        )
    if o["events"]:
        ev = ", ".join(
            f"{e.get('vehicle', e['sysid'])} {e['action']}s at {e['t_s']:.2f} s"
            for e in o["events"]
        )
        lines.append(f"membership: {ev}")
    return "\n".join(lines)


def from_sim_result(
    result: Any, *, name: str = "", safety: Any | None = None, rate_hz: float | None = None
) -> FlightRecord:
    """The flight record of a ``gcs_swarm.integrator.SimResult`` (or a
    ``MissionSimResult``, whose safety totals then go to the summary).
    Every step's acceleration is the (filtered) law's command; there are no
    setpoints or telemetry in a simulation."""
    from gcs_swarm.integrator import SimResult

    if not isinstance(result, SimResult):
        safety = getattr(result, "safety", safety)
        result = result.result
    assert isinstance(result, SimResult)
    act = result.active
    events: list[tuple[float, str, int]] = []
    for j, sysid in enumerate(result.ids):
        prev = False
        for k in np.flatnonzero(np.diff(np.concatenate([[False], act[:, j]]).astype(np.int8))):
            prev = not prev
            events.append((float(result.times_s[k]), "join" if prev else "leave", int(sysid)))
    events.sort()
    extra: dict[str, object] = {}
    if safety is not None:
        for key in ("interventions", "vehicle_cycles", "infeasible", "max_correction_mps2"):
            extra[f"safety_{key}"] = getattr(safety, key)
    cfg = result.config
    return FlightRecord(
        name=name,
        source="simulation",
        times_s=result.times_s,
        ids=result.ids,
        pos_m=result.pos_m,
        leader_pos_m=result.leader_pos_m,
        accel_mps2=result.accel_mps2,
        sent=np.zeros(act.shape, dtype=bool),
        behaviour=result.behaviour,
        episode=result.episode,
        events=tuple(events),
        telemetry=None,
        boxes=tuple(cfg.obstacles),
        r0=cfg.avoidance.r0,
        rate_hz=rate_hz,
        extra=extra,
    )


def write_simulation_report(
    result: Any,
    out_dir: str | os.PathLike[str],
    *,
    name: str = "",
    picture: bool = True,
    networks: tuple[str, ...] = (DEFAULT_NETWORK,),
) -> dict[str, Any]:
    """``gcs-swarm simulate``: ``summary.json`` and ``report.png`` of a
    simulation in ``out_dir`` (created); returns the summary. ``networks``:
    the mission's (``write_report``)."""
    rec = from_sim_result(result, name=name)
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ReportError(f"{out}: cannot create the folder: {err.strerror or err}") from None
    return write_report(rec, out / SUMMARY_NAME, out / PICTURE_NAME if picture else None,
                        networks=networks)  # fmt: skip
