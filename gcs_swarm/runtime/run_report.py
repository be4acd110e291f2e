"""What a run writes into its folder once it has ended, whichever shell flew
it: ``vehicle_params.json``, ``summary.json`` and ``report.png``
(``runtime.run`` for one station process, ``runtime.sharded`` for a
controller with link shards; the folder's layout: ``report.artefacts``).

Nothing here may hide how the flight ended: a file that cannot be written
is logged as an error and the run's outcome stands.
"""

from __future__ import annotations

import asyncio
import logging
import shutil
from collections.abc import Callable, Iterable, Mapping, Sequence
from types import TracebackType
from typing import Any

from gcs_swarm.mavlink.vehicle import VehicleProtocol
from gcs_swarm.mission import Mission
from gcs_swarm.mission.model import KEY_STRIDE
from gcs_swarm.report.artefacts import RunFolder, write_json, write_report
from gcs_swarm.report.record import FlightRecorder, LinkCounts
from gcs_swarm.report.replay import safety_applied
from gcs_swarm.runtime.summary import RunSummary
from gcs_swarm.runtime.tlog import TlogWriter

__all__ = [
    "ControllerLog",
    "frame_sink",
    "note_sink",
    "run_recorder",
    "vehicle_param_records",
    "write_run_report",
    "write_vehicle_params",
]

_log = logging.getLogger("gcs_swarm.run")


def vehicle_param_records(vehicles: Mapping[int, VehicleProtocol]) -> list[dict[str, Any]]:
    """Each vehicle's envelope and every parameter the station changed on it
    (old, new, read-back, restored), by key; a vehicle of a named network is
    told by ``network:sysid`` (docs/mission-format.md) and its own system id."""
    records = []
    for key, vp in sorted(vehicles.items()):
        record = vp.vehicle_params.record()
        if str(key) != vp.label:
            record = {"vehicle": vp.label, **record, "sysid": key % KEY_STRIDE}
        records.append(record)
    return records


def write_vehicle_params(folder: RunFolder, records: Iterable[dict[str, Any]]) -> None:
    """``vehicle_params.json`` from ``vehicle_param_records`` (of every station
    or shard of the run)."""
    try:
        write_json({"vehicles": list(records)}, folder.vehicle_params)
    except OSError as err:  # never let the record hide how the flight ended
        _log.error("%s: not written: %s", folder.vehicle_params, err.strerror or err)


def run_recorder(mission: Mission, notes: TlogWriter) -> FlightRecorder:
    """The flight recorder of a run of ``mission``, its annotations into
    the ``notes`` log."""
    return FlightRecorder(
        name=mission.settings.name,
        source="run",
        boxes=mission.law.obstacles,
        r0=mission.law.avoidance.r0,
        rate_hz=mission.settings.rate,
        safety=safety_applied(mission),
        sink=note_sink(notes),
    )


def note_sink(tlog: TlogWriter) -> Callable[[bytes], None]:
    """The flight recorder's annotations into ``tlog``."""

    def sink(frame: bytes) -> None:
        tlog.write(frame)

    return sink


def frame_sink(tlog: TlogWriter) -> Callable[[bytes, str], None]:
    """A link's frames, in and out, into ``tlog``."""

    def sink(frame: bytes, direction: str) -> None:
        tlog.write(frame)

    return sink


async def write_run_report(
    folder: RunFolder,
    recorder: FlightRecorder,
    summary: RunSummary,
    *,
    picture: bool,
    networks: tuple[str, ...],
) -> None:
    """``summary.json`` and ``report.png`` of the run, off the event loop
    (matplotlib takes about a second); the links' counters go in too."""
    extra: dict[str, Any] = {
        "outcome": summary.outcome,
        "wall_time_s": summary.wall_time_s,
        "startup": {
            "start_tolerance_m": summary.start_tolerance_m,
            "start_speed_tolerance_mps": summary.start_speed_tolerance_mps,
        },
        "links": {
            "messages_sent": summary.messages_sent,
            "setpoints_dropped": summary.setpoints_dropped,
            "messages_dropped": summary.messages_dropped,
            "bad_packets": summary.bad_packets,
            "unknown_sysid_messages": summary.unknown_sysid_messages,
            "spoofed": summary.spoofed,
            "signature_rejected": summary.signature_rejected,
            "rebinds_refused": summary.rebinds_refused,
        },
        # What only the live station knows (a replay of the .tlog cannot).
        "station": {
            "failure": summary.failure,
            "clipped_setpoints": summary.clipped_setpoints,
            "logging_error": summary.logging_error,
            "telemetry_rate": {
                str(v.sysid): {"min_hz": v.telemetry_rate_min_hz, "requests": v.rate_requests}
                for v in summary.vehicles
            },
            "velocity_bias": {
                str(v.sysid): {
                    "estimate_ned_mps": list(v.velocity_bias_ned_mps),
                    "corrected": v.velocity_bias_corrected,
                    "at_cap": v.velocity_bias_saturated,
                }
                for v in summary.vehicles
            },
        },
    }
    rec = recorder.record()
    try:
        await asyncio.shield(
            asyncio.to_thread(
                write_report,
                rec,
                folder.summary,
                folder.picture if picture else None,
                extra=extra,
                networks=networks,
            )
        )
    except Exception as err:  # never let the report hide how the flight ended
        _log.error("%s: report not written: %s", folder.path, err)


class ControllerLog:
    """A sharded run's folder, on the controller's side (``runtime.sharded``):
    the flight recorder of its law, whose annotations go to
    ``controller.tlog`` (open in its ``async with``), the paths each shard
    logs its networks' frames to, and the closing files from the recorder
    and the shards' final reports. Does nothing without a folder."""

    def __init__(self, mission: Mission, folder: RunFolder | None) -> None:
        self.mission = mission
        self.folder = folder
        self._tlog: TlogWriter | None = None
        self._closed = False
        self.recorder: FlightRecorder | None = None
        if folder is not None:
            self._tlog = TlogWriter(folder.controller_tlog, on_error=_log.warning)
            self.recorder = run_recorder(mission, self._tlog)

    async def __aenter__(self) -> ControllerLog:
        if self._tlog is not None:
            await self._tlog.__aenter__()
        return self

    async def __aexit__(
        self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self._tlog is not None:
            await self._tlog.__aexit__(et, ev, tb)
        if not self._closed and self.folder is not None:
            # The run ended before its shards were started (an emulator or
            # the Zenoh session did not open): nothing was commanded.
            shutil.rmtree(self.folder.path, ignore_errors=True)

    def tlogs(self, networks: Sequence[int]) -> dict[str, str]:
        """Where a shard owning ``networks`` (indices) logs each one's frames
        (absolute paths; none without a folder)."""
        if self.folder is None:
            return {}
        paths = self.folder.tlogs(self.mission.networks)
        return {str(j): str(paths[j].resolve()) for j in networks}

    def error(self, reports: Iterable[Mapping[str, Any]]) -> str | None:
        """Why logging stopped, the controller's or a shard's, or None."""
        if self._tlog is not None and self._tlog.error:
            return self._tlog.error
        return next((str(d["logging_error"]) for d in reports if d.get("logging_error")), None)

    async def close(
        self,
        summary: RunSummary,
        reports: Iterable[Mapping[str, Any]],
        *,
        picture: bool,
        commanded: bool,
    ) -> None:
        """Write ``vehicle_params.json``, ``summary.json`` and ``report.png``
        with the shards' inbound counts and parameter records; or, when no
        shard ever joined (nothing was commanded), leave no folder behind."""
        self._closed = True
        if self.folder is None or self.recorder is None:
            return
        if not commanded:
            shutil.rmtree(self.folder.path, ignore_errors=True)
            return
        params: dict[int, dict[str, Any]] = {}
        for d in reports:
            for key, counts in d.get("telemetry", {}).items():
                self.recorder.telemetry.counts[int(key)] = LinkCounts(*counts)
            params.update({int(k): r for k, r in d.get("vehicle_params", {}).items()})
        write_vehicle_params(self.folder, [params[k] for k in sorted(params)])
        await write_run_report(self.folder, self.recorder, summary, picture=picture,
                               networks=self.mission.networks)  # fmt: skip
