"""``gains.repulsion_cutoff`` (Eq. 9c, docs/formation-law.md section 3a):
what the mission accepts and refuses (one line naming file, line and key),
its schema, and a closed-loop simulation with it against the measured
equilibrium error (the table of section 3a, ``benchmarks/cutoff_equilibrium.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from gcs_swarm.errors import MissionError
from gcs_swarm.mission import parse_mission, schema
from gcs_swarm.offline import simulate_mission

ONE = "vehicles:\n  - {sysid: 1, start: [0, 0, 5]}\n"
EXPECTED = "expected a number > 0.01 and <= 100000 or null"


def cutoff_of(text: str) -> float | None:
    return parse_mission(text + ONE, "m.yaml").law.gains.repulsion_cutoff


def test_absent_or_null_is_the_exact_law_and_a_number_is_metres() -> None:
    assert cutoff_of("") is None
    assert cutoff_of("gains: {k_r: 0.2}\n") is None
    assert cutoff_of("gains: {repulsion_cutoff: null}\n") is None
    assert cutoff_of("gains: {repulsion_cutoff: 6}\n") == 6.0
    assert cutoff_of("gains:\n  repulsion_cutoff: 4.5\n") == 4.5
    assert cutoff_of("gains: {repulsion_cutoff: 100000}\n") == 1e5


@pytest.mark.parametrize(
    ("value", "got"),
    [
        ("0", "0"),
        ("-3", "-3"),
        ("0.01", "0.01"),  # the clamp radius R_MIN_M: a cut-off must exceed it
        ("1e6", "1e6"),
        (".inf", ".inf (not finite)"),
        (".nan", ".nan (not finite)"),
        ("far", '"far"'),
        ('"5"', '"5"'),
        ("true", "true"),
        ("[5]", "a list of 1 item"),
        ("{r: 5}", "a mapping"),
    ],
)
def test_a_bad_cutoff_is_one_line_naming_file_line_and_key(value: str, got: str) -> None:
    text = "mission: {duration: 10}\ngains:\n  k_r: 0.2\n  repulsion_cutoff: " + value + "\n"
    with pytest.raises(MissionError) as info:
        parse_mission(text + ONE, "m.yaml")
    (line,) = str(info.value).splitlines()
    assert line.startswith(f"m.yaml:4: gains.repulsion_cutoff: {EXPECTED}, got {got}")


def test_a_misspelt_key_is_named_with_the_right_one() -> None:
    want = r"m\.yaml:1: gains\.repulsion_cutof: .*repulsion_cutoff"
    with pytest.raises(MissionError, match=want):
        parse_mission("gains: {repulsion_cutof: 5}\n" + ONE, "m.yaml")


def test_the_schema_states_the_field() -> None:
    prop = schema()["properties"]["gains"]["properties"]["repulsion_cutoff"]
    assert prop["type"] == ["number", "null"]
    assert prop["exclusiveMinimum"] == 0.01
    assert prop["maximum"] == 1e5
    assert "default" not in prop  # absent: the exact law
    assert "Eq. 9c" in prop["description"]


def _mission(cutoff: float, seconds: float) -> str:
    """N = 12 from the seeded starts of benchmarks/cutoff_equilibrium.py."""
    rng = np.random.default_rng(12)
    u = rng.normal(size=(12, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    starts = (u * rng.uniform(1.0, 6.0, size=(12, 1))).tolist()
    lines = [f"mission: {{duration: {seconds}}}", f"gains: {{repulsion_cutoff: {cutoff}}}"]
    lines.append("vehicles:")
    lines += [f"  - {{sysid: {k + 1}, start: {p!r}}}" for k, p in enumerate(starts)]
    return "\n".join(lines) + "\n"


def test_simulate_with_the_cutoff_forms_within_the_measured_error() -> None:
    """Section 3a's table, N = 12: the exact law settles at R = 2.78886 m (an
    icosahedron, d_nn = 2.9324 m); with r_c = 1.5 d_nn = 4.399 m only the 5
    nearest neighbours push and the radii settle 6.99 % lower, 2.5934-2.5945 m
    after 300 s. After 60 s (what this test can afford) they are within 0.5 %
    of that (2.5919-2.6017 m when measured), the whole formation below the
    exact radius by the measured error."""
    res = simulate_mission(parse_mission(_mission(4.399, 60), "m.yaml"), dt_s=0.02).result
    r = np.linalg.norm(res.pos_m[-1] - res.leader_pos_m[-1], axis=1)
    np.testing.assert_allclose(r, 2.59383, rtol=5e-3)
    err = r.mean() / 2.78886 - 1.0
    assert -0.075 < err < -0.065  # measured: -0.0699
    nn = np.linalg.norm(res.pos_m[-1][:, None] - res.pos_m[-1][None], axis=-1)
    np.fill_diagonal(nn, np.inf)
    assert nn.min() > 2.6  # measured after 300 s: 2.7120..2.7130
