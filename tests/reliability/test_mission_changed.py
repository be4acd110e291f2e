"""A mission file that changes while its run goes on is not re-read half-way
(issue 9): ``gcs-swarm run`` (a subprocess, bundled emulator at 4 x real time)
loads it once. Mid-flight the file is overwritten with a mission of another
duration and then with YAML garbage; the run still flies the mission it
loaded, to its end, and its run folder holds the file as it was flown."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

MISSION = """
mission:
  name: changed under its feet
  duration: 6
  rate: 50
emulator: {mode: realtime, speedup: 4, dynamics: ideal, spawn: air}
leader: {start: [0, 0, 0], force: [0, 0, 0]}
vehicles:
  - {sysid: 1, start: [2, 0, 0]}
  - {sysid: 2, start: [-2, 0, 0]}
"""


def test_a_mission_file_changed_mid_run_is_not_re_read(tmp_path: Path) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(MISSION)
    logs = tmp_path / "runs"
    proc = subprocess.Popen(
        [sys.executable, "-m", "gcs_swarm", "run", "--no-status", "--log-dir", str(logs),
         str(path)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 30
        while not list(logs.glob("*/flight.tlog")) and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.3)  # well into the run
        path.write_text(MISSION.replace("duration: 6", "duration: 1000"))
        time.sleep(0.3)
        path.write_text("mission: [this is : not {a mission")
        assert proc.poll() is None  # changed while it runs (1.5 s of wall time)
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, out
    assert re.search(r"outcome: completed; mission time 6\.0\d s", out), out
    (folder,) = logs.iterdir()
    assert (folder / "mission.yaml").read_text() == MISSION


def test_the_run_folder_holds_the_text_that_was_loaded(tmp_path: Path) -> None:
    from gcs_swarm.mission import load_mission
    from gcs_swarm.report import create_run_folder

    path = tmp_path / "m.yaml"
    path.write_text(MISSION)
    mission = load_mission(path)
    path.write_text("mission: [changed after loading")  # before the folder exists
    folder = create_run_folder(mission, base_dir=tmp_path / "runs")
    assert folder.mission.read_text() == MISSION
