"""``run_command``: a mission file in, the bundled emulator started on
127.0.0.1, the full start-up from the ground, a summary out, exit code 0."""

from __future__ import annotations

from pathlib import Path

import pytest

from gcs_swarm.commands import run_command
from gcs_swarm.errors import LinkError

MISSION = """
mission:
  name: two vehicles from the ground
  duration: 3
  rate: 50
  end: land
emulator:
  mode: lockstep
  dynamics: ideal
  ekf_ready_delay: 0.5
leader: {start: [0, 0, 0], force: [0, 0, 0]}
vehicles:
  - {sysid: 1, start: [2, 0, 0]}
  - {sysid: 2, start: [-2, 0, 0]}
"""


def test_run_command_flies_a_sim_mission_from_the_ground(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "two.yaml"
    path.write_text(MISSION)
    assert run_command(str(path), status=False) == 0
    out = capsys.readouterr().out
    assert "outcome: completed; mission time 3.00 s" in out
    assert "vehicle   1: ended    LAND" in out and "vehicle   2: ended    LAND" in out


def test_run_command_reports_an_unusable_link_as_a_link_error(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    # 203.0.113.0/24 is TEST-NET-3: binding a listening socket there fails locally.
    bad = "{sysid: 2, start: [-2, 0, 5], link: 'udpin:203.0.113.7:14550'}"
    path.write_text(MISSION.replace("{sysid: 2, start: [-2, 0, 0]}", bad))
    with pytest.raises(LinkError, match=r"udpin:203\.0\.113\.7:14550"):
        run_command(str(path), status=False)
