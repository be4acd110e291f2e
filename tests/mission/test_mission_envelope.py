"""limits.envelope and gains.time_scale in mission files, and the demand
warning of ``gcs-swarm check`` (issue 14)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from gcs_swarm.cli import main
from gcs_swarm.control.envelope import ARDUCOPTER
from gcs_swarm.errors import MissionError
from gcs_swarm.mission import parse_mission
from gcs_swarm.mission.checks import key_line

BASE = """\
mission: {duration: 5, rate: 50}
gains:
  k_s: 1
  time_scale: TS
leader: {start: [0, 0, 0], force: [0, 0, 0]}
limits:
  envelope: ENV
vehicles:
  - {sysid: 1, start: [2, 1, 2]}
  - {sysid: 2, start: [-1, -1, -1]}
"""


def _text(ts: str = "1", env: str = "arducopter") -> str:
    return BASE.replace("TS", ts).replace("ENV", env)


def test_arducopter_is_the_45_defaults() -> None:
    m = parse_mission(_text(), "m.yaml")
    assert m.law.limits.envelope == ARDUCOPTER
    assert (ARDUCOPTER.accel_xy, ARDUCOPTER.accel_z, ARDUCOPTER.jerk_xy) == (2.5, 1.0, 5.0)
    assert (ARDUCOPTER.speed_xy, ARDUCOPTER.speed_up, ARDUCOPTER.speed_down) == (10, 2.5, 1.5)
    assert ARDUCOPTER.lag_s == 0.2


def test_envelope_mapping_nulls_are_unbounded() -> None:
    m = parse_mission(_text(env="{accel_xy: 2, jerk_z: null, lag: 0.1}"), "m.yaml")
    env = m.law.limits.envelope
    assert env.accel_xy == 2.0 and env.lag_s == 0.1
    assert math.isinf(env.accel_z) and math.isinf(env.jerk_z)


def test_without_the_key_the_envelope_is_the_point_mass() -> None:
    m = parse_mission(BASE.replace("  envelope: ENV\n", "  a_max: 3\n").replace("TS", "1"))
    assert not m.law.limits.envelope.bounded
    assert m.law.gains.time_scale == 1.0


@pytest.mark.parametrize(
    ("ts", "env", "want"),
    [
        ("0.5", "arducopter", "m.yaml:4: gains.time_scale: expected a number 1..100, got 0.5"),
        ("1", "ardupilot", 'm.yaml:7: limits.envelope: expected "arducopter", got "ardupilot"'),
        ("1", "{accel_xy: 0}", "m.yaml:7: limits.envelope.accel_xy: expected a number > 0"),
        ("1", "{jerk: 5}", "m.yaml:7: limits.envelope.jerk: unknown key"),
        ("1", "{lag: 9}", "m.yaml:7: limits.envelope.lag: expected a number 0..5, got 9"),
    ],
)
def test_bad_values_name_file_line_and_key(ts: str, env: str, want: str) -> None:
    with pytest.raises(MissionError) as err:
        parse_mission(_text(ts, env), "m.yaml")
    assert any(line.startswith(want) for line in err.value.problems), err.value.problems


def test_key_line_finds_the_key_or_its_parent() -> None:
    text = _text()
    assert key_line(text, "gains.time_scale") == 4
    assert key_line(text, "gains.nothing") == 2
    assert key_line(text, "nowhere") == 1


def test_check_warns_at_the_gains_with_the_time_scale_that_fits(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(_text("1.5"))
    assert main(["check", str(path)]) == 0  # a warning, not an error
    out, err = capsys.readouterr()
    assert out.startswith("OK: ")
    (line,) = err.splitlines()
    assert line.startswith(f"{path}:4: gains.time_scale: warning: the gains demand more")
    assert "accel_xy" in line
    lam = float(line.rsplit("gains.time_scale: ", 1)[1])
    assert lam > 1.5
    # Flown at the suggested scale, the same mission fits: no warning.
    path.write_text(_text(f"{lam:g}"))
    assert main(["check", str(path)]) == 0
    assert capsys.readouterr().err == ""


def test_check_without_envelope_says_nothing_more(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(BASE.replace("  envelope: ENV\n", "  a_max: 3\n").replace("TS", "1"))
    assert main(["check", str(path)]) == 0
    assert capsys.readouterr().err == ""
