"""The mission keys of the vehicle's own safety (``mission.failsafe``,
``mission.startup.read_envelope``) and what each vehicle then gets."""

from __future__ import annotations

import pytest

from gcs_swarm.errors import MissionError
from gcs_swarm.mission import Failsafe, parse_mission
from gcs_swarm.runtime.run import param_settings

# The sim vehicle first: with a real first vehicle it would need a geodetic mission.origin.
VEHICLES = """vehicles:
  - {sysid: 2, start: [5, 0, 10]}
  - {sysid: 1, link: "udpin:127.0.0.1:14550", start: [0, 0, 10]}
"""
FENCE = """limits:
  geofence: {min: [-50, -40, 0], max: [50, 40, 30]}
"""


def test_defaults_on_for_ardupilot_off_for_sim() -> None:
    m = parse_mission(VEHICLES + FENCE, "m.yaml")
    assert m.settings.failsafe == Failsafe() and m.settings.startup.read_envelope is None
    sim, real = (param_settings(m, v) for v in m.vehicles)
    assert (real.read_envelope, real.gcs_failsafe, real.fences, real.restore) == (
        True, True, True, True
    )  # fmt: skip
    assert (real.gcs_timeout_s, real.fence_margin_m, real.end) == (5.0, 5.0, "hold")
    assert real.geofence_max == (50.0, 40.0, 30.0) and real.station_sysid == 255
    assert not sim.active


def test_keys_are_taken_and_a_fence_needs_a_geofence() -> None:
    text = (
        """mission:
  end: rtl
  startup: {read_envelope: false}
  failsafe: {gcs: true, timeout: 8, fence: false, fence_margin: 2, restore: false}
"""
        + VEHICLES
    )
    m = parse_mission(text, "m.yaml")
    sim, real = (param_settings(m, v) for v in m.vehicles)
    assert real == sim  # given explicitly: the same for sim vehicles
    assert (real.read_envelope, real.gcs_failsafe, real.gcs_timeout_s, real.fence) == (
        False, True, 8.0, False
    )  # fmt: skip
    assert (real.restore, real.end, real.fence_margin_m) == (False, "rtl", 2.0)
    # No geofence: the default (null) sets no fence; true is an error at its line.
    assert not param_settings(parse_mission(VEHICLES, "m.yaml"), m.vehicles[1]).fences
    bad = "mission:\n  failsafe:\n    fence: true\n" + VEHICLES
    with pytest.raises(MissionError, match=r"m\.yaml:3: mission\.failsafe\.fence: expected "
                       r"limits\.geofence"):  # fmt: skip
        parse_mission(bad, "m.yaml")


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("timeout: 1", r"m\.yaml:3: mission\.failsafe\.timeout: expected a number 2\.\.120"),
        ("gcs: yes", r"m\.yaml:3: mission\.failsafe\.gcs: expected true or false or null"),
        ("restor: true", r'm\.yaml:3: mission\.failsafe\.restor: unknown key.*"restore"'),
    ],
)
def test_bad_values_name_file_line_and_key(line: str, message: str) -> None:
    with pytest.raises(MissionError, match=message):
        parse_mission(f"mission:\n  failsafe:\n    {line}\n" + VEHICLES, "m.yaml")
