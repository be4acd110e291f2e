"""Join and leave over MAVLink (issue 6, formation-law.md s9): the formation
re-forms by itself when the set of vehicles changes. Gains k_s = k_r = 5 (the
paper's Scenario 2) around a resting leader: the shapes settle within ~10 s
(in-process: tetrahedron radii equal to 1e-5 by 10 s, the bipyramid by 10 s
after a join), so short runs check them tightly."""

from __future__ import annotations

import asyncio
import dataclasses

import numpy as np
import pytest
from station_harness import fly, lockstep_config, mission_from

from gcs_swarm.analysis import classify_bipyramid, pairwise_distances
from gcs_swarm.control import ConstantForce
from gcs_swarm.mission import Event, Mission
from gcs_swarm.runtime import RunSummary
from sim_vehicle import Emulator


def _resting(mission: Mission) -> Mission:
    law = mission.law
    leader = dataclasses.replace(law.leader, force=ConstantForce((0.0, 0.0, 0.0)))
    return dataclasses.replace(mission, law=dataclasses.replace(law, leader=leader))


def _assert_bipyramid(s: RunSummary, ids: list[int]) -> None:
    """Two poles at equal radius, three equator vehicles at equal radius on a
    plane through the leader square to the poles' axis, 120 degrees apart.
    Tolerances 1e-3 m / 1e-2: the in-process law settles to 1e-5 by then."""
    pos = np.array([s.positions()[i] for i in ids])
    centre = np.array(s.leader_pos_m)
    shape = classify_bipyramid(pos, centre)
    r = np.linalg.norm(pos - centre, axis=1)
    poles, equator = r[list(shape.poles)], r[list(shape.equator)]
    assert abs(poles[0] - poles[1]) < 1e-3, r
    assert np.ptp(equator) < 1e-3, r
    assert shape.tilt < 1e-2  # equator vehicles square to the axis
    eq = pos[list(shape.equator)]
    np.testing.assert_allclose(pairwise_distances(eq), np.sqrt(3) * equator.mean(), atol=2e-3)
    # Not a regular shape by accident: poles sit further out (in-process 2.989 vs 2.976).
    assert poles.mean() - equator.mean() > 5e-3


@pytest.mark.slow
def test_fifth_vehicle_joins_and_five_re_form_a_triangular_bipyramid() -> None:
    base = _resting(mission_from("scenario2_join.yaml", duration=40.0))
    reserve = dataclasses.replace(
        base.vehicles[4],
        start=(1.0, 1.0, 5.0),  # 4 m above the resting leader at (1, 1, 1)
        origin=(1.0, 1.0, 2.0),  # its home, so the take-off is short
    )
    mission = dataclasses.replace(
        base,
        vehicles=(*base.vehicles[:4], reserve),
        events=(Event(t=15.0, action="join", sysid=5),),
    )
    cfg = lockstep_config(mission)
    assert not cfg.vehicles[4].airborne  # a reserve waits on the ground
    flown = asyncio.run(fly(mission, cfg))
    s = flown.ok
    assert s.outcome == "completed"
    log = "\n".join(s.log)
    # The reserve went through the whole start-up with the others (armed,
    # took off, held at its start) and joined on its event.
    assert "vehicle 5: arming" in log and "vehicle 5: takeoff" in log
    assert log.index("vehicle 5: ready") < log.index("formation started with vehicles [1, 2, 3, 4]")
    assert "t=15.00 s: vehicle 5 joins the formation (5 flying)" in log
    assert flown.emu.stats.lockstep_timeouts == 0
    _assert_bipyramid(s, [1, 2, 3, 4, 5])


@pytest.mark.slow
def test_vehicle_removed_from_the_emulator_leaves_and_five_re_form() -> None:
    # Removed at 8 s, when the octahedron has formed: the five then sit near
    # a square pyramid, a saddle they leave slowly; in-process the bipyramid
    # is within 3e-3 m at 40 s and 3e-5 m at 50 s, so 55 s leaves a margin.
    mission = mission_from("example1_octahedron.yaml", duration=55.0)
    gains = dataclasses.replace(mission.law.gains, k_s=5.0, k_r=5.0)
    mission = dataclasses.replace(mission, law=dataclasses.replace(mission.law, gains=gains))

    async def remove_six(emu: Emulator, run: asyncio.Task[RunSummary]) -> None:
        await emu.wait_until(lambda: emu.sim_time_s >= 8.0)
        emu.remove_vehicle(6)

    flown = asyncio.run(fly(mission, lockstep_config(mission), during=remove_six))
    s = flown.ok
    # Vehicle 6 was lost for good: the run is not "completed" (issue 15 item 5).
    assert s.outcome == "degraded"
    v6 = next(v for v in s.vehicles if v.sysid == 6)
    assert v6.phase == "lost" and v6.position_m is None
    assert "no LOCAL_POSITION_NED" in str(v6.failure)
    assert any("vehicle 6 out of the formation (lost); 5 re-form" in line for line in s.log)
    _assert_bipyramid(s, [1, 2, 3, 4, 5])
