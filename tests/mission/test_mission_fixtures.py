"""Every malformed mission in fixtures/bad/ gives exactly its expected lines.

Each fixture starts with a comment saying what is wrong, then one
``# expect: FILE:LINE: key.path: message`` line per problem, in the order
``gcs-swarm check`` prints them. The checker is run with the fixtures folder
as the current directory so the file name in each message is the bare name.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from gcs_swarm.commands import check_command
from gcs_swarm.errors import MissionError
from gcs_swarm.mission import load_mission

BAD = Path(__file__).parent / "fixtures" / "bad"
FIXTURES = sorted(BAD.glob("*.yaml"))
LINE_RE = re.compile(r"^(?P<file>[\w.]+\.yaml):(?P<line>\d+): (?P<path>\S+|\(top level\)): \S")


def expected_lines(path: Path) -> list[str]:
    """The ``# expect:`` lines at the top of a fixture (bytes: one is not UTF-8)."""
    text = path.read_bytes().decode("utf-8", errors="replace")
    return [
        line[len("# expect: ") :] for line in text.splitlines() if line.startswith("# expect: ")
    ]


def test_there_are_at_least_30_fixtures() -> None:
    assert len(FIXTURES) >= 30
    assert all(expected_lines(f) for f in FIXTURES), "every fixture states its expected lines"


@pytest.mark.parametrize("fixture", FIXTURES, ids=lambda p: p.stem)
def test_check_prints_exactly_the_expected_lines(
    fixture: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(BAD)
    want = expected_lines(fixture)
    code = check_command(fixture.name)
    out, err = capsys.readouterr()
    assert code == 2
    assert out == ""
    assert "Traceback" not in err
    assert err.splitlines() == want
    for line in want:
        m = LINE_RE.match(line)
        assert m is not None, f"not file:line: path: message: {line!r}"
        assert m["file"] == fixture.name


@pytest.mark.parametrize("fixture", FIXTURES, ids=lambda p: p.stem)
def test_load_raises_one_mission_error_listing_every_problem(
    fixture: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(BAD)
    with pytest.raises(MissionError) as info:
        load_mission(fixture.name)
    assert str(info.value).splitlines() == expected_lines(fixture)
    assert list(info.value.problems) == expected_lines(fixture)


def test_several_problems_are_all_reported_in_file_order() -> None:
    want = expected_lines(BAD / "many_problems.yaml")
    assert len(want) >= 5
    lines = [int(LINE_RE.match(w)["line"]) for w in want]  # type: ignore[index]
    assert lines == sorted(lines)
    sections = {LINE_RE.match(w)["path"].split(".")[0].split("[")[0] for w in want}  # type: ignore[index]
    assert sections >= {"mission", "gains", "vehicles", "leader", "events"}
