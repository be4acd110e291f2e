"""Logging never ends a flight (issue 15 item 4).

Real OS errors, no mock: ``/dev/full`` answers every write with ENOSPC on
Linux, and a child process with ``RLIMIT_FSIZE`` gets EFBIG past its limit.
Before: the ``.tlog`` writer's ENOSPC cancelled the flight (traceback) and
``summary.json`` was left at 0 bytes.
"""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from gcs_swarm.report.artefacts import RunFolder, write_json
from gcs_swarm.runtime import RunSummary, run_mission
from gcs_swarm.runtime.tlog import TlogWriter
from sim_vehicle import Emulator
from tests.station.station_harness import lockstep_config, mission_from

FULL = Path("/dev/full")
needs_dev_full = pytest.mark.skipif(not FULL.exists(), reason="needs Linux /dev/full")


@needs_dev_full
def test_a_tlog_on_a_full_disk_stops_logging_once_and_never_raises() -> None:
    errors: list[str] = []

    async def main() -> TlogWriter:
        async with TlogWriter(FULL, flush_bytes=64, on_error=errors.append) as w:
            for k in range(200):
                w.write(b"\xfd" + bytes(20), t_us=k)
                if k == 10:
                    await w.flush()  # the first write fails here: ENOSPC
            await w.flush()
        return w

    w = asyncio.run(main())
    assert w.error is not None and "No space left on device" in w.error
    assert errors == [w.error]  # handed over once
    assert w.stats.write_errors == 1
    assert w.stats.frames == 11 and w.stats.dropped_frames == 189  # logging stopped


@needs_dev_full
def test_a_flight_whose_log_disk_is_full_flies_on_and_writes_its_summary(tmp_path: Path) -> None:
    """The run's ``.tlog`` is put on ``/dev/full`` (a symbolic link in the run
    folder, made as soon as the folder exists): the flight completes, the
    station says once that logging stopped, and ``summary.json`` is written."""
    mission = mission_from("example1_octahedron.yaml", n=4, duration=10.0)
    folders: list[RunFolder] = []

    def on_folder(folder: RunFolder) -> None:
        folder.tlog.symlink_to(FULL)
        folders.append(folder)

    async def main() -> RunSummary:
        async with Emulator(lockstep_config(mission)) as emu:
            links = {s: f"udpout:{h}:{p}" for s, (h, p) in emu.endpoints.items()}
            return await run_mission(
                mission, links=links, lockstep=True, log_dir=tmp_path, picture=False,
                on_folder=on_folder,
            )  # fmt: skip

    summary = asyncio.run(asyncio.wait_for(main(), 90))
    assert summary.outcome == "completed"
    log = "\n".join(summary.log)
    assert log.count("logging stopped, flying on") == 1
    written = json.loads(folders[0].summary.read_text())
    assert written["outcome"] == "completed"
    assert "No space left on device" in written["station"]["logging_error"]


_CHILD = textwrap.dedent(
    """
    import resource, signal, sys
    from gcs_swarm.report.artefacts import write_json
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG instead of a kill
    resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
    try:
        write_json({"big": "x" * 100_000}, sys.argv[1])
    except OSError as err:
        print(err.errno)
    """
)


def test_a_summary_that_does_not_fit_leaves_the_old_file_whole_and_no_temporary(
    tmp_path: Path,
) -> None:
    import errno

    target = tmp_path / "summary.json"
    write_json({"outcome": "completed"}, target)
    before = target.read_bytes()
    out = subprocess.run(
        [sys.executable, "-c", _CHILD, str(target)],
        capture_output=True, text=True, check=True, env={**os.environ, "PYTHONWARNINGS": ""},
    )  # fmt: skip
    assert out.stdout.strip() == str(errno.EFBIG), out.stderr
    assert target.read_bytes() == before  # never truncated, never 0 bytes
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]
