"""Run artefacts: the flight record, its summary (JSON), the report picture
and the run folder, from a live run, a ``.tlog`` or a simulation.

- ``record``: ``FlightRecord`` (arrays per control step) and the
  ``FlightRecorder`` the station feeds;
- ``notes``: the station's log-only annotation frames in the ``.tlog``;
- ``replay``: a ``.tlog`` plus the mission file -> ``FlightRecord``;
- ``figures``: ``FlightRecord`` -> the JSON summary;
- ``plot``: ``FlightRecord`` -> the report picture (matplotlib, imported lazily);
- ``artefacts``: run folders, ``gcs-swarm report``, the simulation report.
"""

from __future__ import annotations

from gcs_swarm.report.artefacts import (
    MISSION_NAME,
    PICTURE_NAME,
    SUMMARY_NAME,
    TLOG_NAME,
    RunFolder,
    create_run_folder,
    from_sim_result,
    rebuild_report,
    report_from_tlog,
    run_folder_name,
    summary_text,
    write_json,
    write_report,
    write_simulation_report,
)
from gcs_swarm.report.figures import SUMMARY_FORMAT, summarize_record
from gcs_swarm.report.notes import LOG_COMPID, NoteWriter, parse_note
from gcs_swarm.report.record import FlightRecord, FlightRecorder, LinkCounts, TelemetryCounter
from gcs_swarm.report.replay import ReplayStats, record_from_tlog

__all__ = [
    "LOG_COMPID",
    "MISSION_NAME",
    "PICTURE_NAME",
    "SUMMARY_FORMAT",
    "SUMMARY_NAME",
    "TLOG_NAME",
    "FlightRecord",
    "FlightRecorder",
    "LinkCounts",
    "NoteWriter",
    "ReplayStats",
    "RunFolder",
    "TelemetryCounter",
    "create_run_folder",
    "from_sim_result",
    "parse_note",
    "rebuild_report",
    "record_from_tlog",
    "report_from_tlog",
    "run_folder_name",
    "summarize_record",
    "summary_text",
    "write_json",
    "write_report",
    "write_simulation_report",
]
