"""The missions shipped in config/missions/ validate, load into the law's
``LawConfig`` and carry the figures their comments claim.

(Simulating them is the simulator's test; this file only loads them.)
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from gcs_swarm.commands import check_command
from gcs_swarm.control.params import (
    ConstantForce,
    ExpressionForce,
    LawConfig,
    WaypointForce,
)
from gcs_swarm.mission import DEFAULT_SIM_HOME, enu_offset_m, load_mission

MISSIONS = Path(__file__).resolve().parents[2] / "config" / "missions"
SHIPPED = sorted(MISSIONS.glob("*.yaml"))
EXAMPLE1_STARTS = [(2, 1, 2), (-1, -1, -1), (3, 4, 2), (4, 2, 2), (3, 3, 3), (-2, -2, -2)]


def test_the_issue_s_missions_are_all_there() -> None:
    names = {p.name for p in SHIPPED}
    assert names >= {
        "example1_octahedron.yaml",
        "example1_tetrahedron.yaml",
        "scenario1_local_minimum.yaml",
        "scenario2_join.yaml",
        "scenario3_obstacle.yaml",
        "sitl_arducopter.yaml",
    }


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_shipped_mission_checks_ok_and_gives_a_law_config(
    path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert check_command(str(path)) == 0
    out, err = capsys.readouterr()
    assert out.startswith(f"OK: {path}: ") and err == ""
    mission = load_mission(path)
    assert isinstance(mission.law_config(), LawConfig)
    assert mission.initial, "someone flies from the start"


@pytest.mark.parametrize("n", [6, 4])
def test_example1_is_the_paper_s(n: int) -> None:
    name = "example1_octahedron.yaml" if n == 6 else "example1_tetrahedron.yaml"
    m = load_mission(MISSIONS / name)
    g = m.law.gains
    assert (g.M, g.D, g.k, g.k_s, g.k_r, g.alpha, g.q_default) == (1, 1, 9, 1, 0.2, 2, 10)
    assert [v.start for v in m.vehicles] == EXAMPLE1_STARTS[:n]
    assert all(v.q == 10 for v in m.vehicles)
    assert m.law.leader.start == (0, 0, 0)
    assert m.law.leader.force == ConstantForce((0.0, 0.0, 0.0))
    assert m.law.readings.eq12_printed is False  # the spec's reading, not the printed Eq. 12
    # sim homes sit 20 m below the mission origin: every start is airborne
    assert all(v.origin is not None and v.start[2] > v.origin[2] for v in m.vehicles)  # type: ignore[index]


def test_scenario1_leader_gives_the_paper_s_desired_force() -> None:
    for name in ("scenario1_local_minimum.yaml", "scenario1_rotational.yaml"):
        m = load_mission(MISSIONS / name)
        (v,) = m.vehicles
        assert v.start == (16, 6, 4)
        (box,) = m.law.obstacles
        assert box.centre == (16, 14, 4) and box.half_extents == (3, 2, 1)
        assert m.law.avoidance.r0 == 2 and m.law.avoidance.F_D == 2
        # Eq. 7 toward the far leader: 2 N at the start (to 1e-4 N, the
        # rounding of k_s to 5 digits), pointing +y exactly.
        d = [m.law.leader.start[i] - v.start[i] for i in range(3)]
        r = math.hypot(*d)
        pull = m.law.gains.k_s * r * (r * r - m.law.gains.alpha**2)
        assert pull == pytest.approx(2.0, abs=1e-4)
        assert d[0] == 0 and d[2] == 0 and d[1] > 0
    classic = load_mission(MISSIONS / "scenario1_local_minimum.yaml").law.avoidance
    rotational = load_mission(MISSIONS / "scenario1_rotational.yaml").law.avoidance
    assert classic.method == "classic"
    assert (rotational.method, rotational.plane, rotational.sense) == (
        "rotational",
        "horizontal",
        "ccw",
    )


def test_scenario2_is_the_moving_tetrahedron_with_a_join_at_25_s() -> None:
    m = load_mission(MISSIONS / "scenario2_join.yaml")
    g = m.law.gains
    assert (g.k_s, g.k_r, g.q_default, g.alpha) == (5, 5, 10, 2)
    assert m.law.leader.start == (1, 1, 1)
    assert m.law.leader.force == ExpressionForce(("10.0", "10*sin(x/8)", "2.0"))
    assert len(m.initial) == 4 and [v.sysid for v in m.reserves] == [5]
    (event,) = m.events
    assert (event.t, event.action, event.sysid) == (25, "join", 5)


def test_scenario3_box_is_on_the_leader_s_path() -> None:
    m = load_mission(MISSIONS / "scenario3_obstacle.yaml")
    (box,) = m.law.obstacles
    assert box.half_extents == (2, 3, 3)
    # Eq. 13 with f_v = (10, 10 sin(x/8), 2), M = 1, D + k = 10, explicit Euler
    # at 1 ms (ample for a 0.1 s time constant): the leader goes through the box.
    x, y, z = m.law.leader.start
    vx = vy = vz = 0.0
    dt, inside = 1e-3, False
    for _ in range(int(40 / dt)):
        fx, fy, fz = 10.0, 10.0 * math.sin(x / 8.0), 2.0
        vx, vy, vz = vx + (fx - 10 * vx) * dt, vy + (fy - 10 * vy) * dt, vz + (fz - 10 * vz) * dt
        x, y, z = x + vx * dt, y + vy * dt, z + vz * dt
        p = (x, y, z)
        inside = inside or all(abs(p[i] - box.centre[i]) <= box.half_extents[i] for i in range(3))
    assert inside


def test_sitl_mission_is_scaled_for_real_copters() -> None:
    m = load_mission(MISSIONS / "sitl_arducopter.yaml")
    assert [v.link for v in m.vehicles] == [f"tcp:127.0.0.1:{5760 + 10 * i}" for i in range(4)]
    assert all(v.autopilot == "ardupilot" for v in m.vehicles)
    assert m.settings.origin == "first-vehicle" and m.origin_geo() is None
    g = m.law.gains
    # Tetrahedron equilibrium of formation-law.md section 3:
    # k_s R (R^2 - alpha^2) = k_r q^2 S / R^2, S = 3 (4/3) / (8/3)^1.5; bisection.
    s = 3 * (4 / 3) / (8 / 3) ** 1.5
    lo, hi = g.alpha, 10 * g.alpha
    for _ in range(200):
        mid = (lo + hi) / 2
        if g.k_s * mid * (mid**2 - g.alpha**2) > g.k_r * g.q_default**2 * s / mid**2:
            hi = mid
        else:
            lo = mid
    assert 15 <= lo <= 20, f"sphere radius {lo:.2f} m"
    force = m.law.leader.force
    assert isinstance(force, WaypointForce)
    assert 1 <= force.cruise_speed <= 5  # terminal speed of Eq. 13 is the cruise speed
    assert 1 <= m.law.limits.a_max <= 5 and m.law.limits.v_max > force.cruise_speed
    assert m.law.safety.enabled
    # the starts are about one radius from the leader (fly-in is short)
    for v in m.vehicles:
        assert abs(math.dist(v.start, m.law.leader.start) - lo) < 1.0


def test_sim_missions_put_the_emulator_ground_20_m_below_the_origin() -> None:
    m = load_mission(MISSIONS / "example1_octahedron.yaml")
    origin = m.origin_geo()
    assert origin is not None
    homes = m.sim_origins(origin)
    # first home is the default SITL location, 20 m below the mission origin;
    # the others 5 m apart due east (emulator.origin_spread); 1 mm tolerance
    # covers the flat-earth round trip.
    for k, v in enumerate(m.vehicles):
        east, north, up = enu_offset_m(origin, homes[v.sysid])
        assert (east, north, up) == pytest.approx((5.0 * k, 0.0, -20.0), abs=1e-3)
    assert homes[1].lat == pytest.approx(DEFAULT_SIM_HOME.lat, abs=1e-9)
    assert homes[1].alt == pytest.approx(DEFAULT_SIM_HOME.alt, abs=1e-9)
