"""The operator view's frames without I/O: ``SnapshotBuilder`` over the
station's core flying against the emulator's autopilots on a hand-advanced
clock (tests/swarm/swarm_harness.py): no sockets, no event loop."""

from __future__ import annotations

import json

import numpy as np

from gcs_swarm.mavlink.states import Phase
from gcs_swarm.view import EVENT_KINDS, SnapshotBuilder, scene_of
from tests.swarm.swarm_harness import Sky, mission_from


def _frame(b: SnapshotBuilder, sky: Sky) -> dict:  # type: ignore[type-arg]
    frame = b.frame(sky.core, sky.now)
    json.dumps(frame, allow_nan=False)  # what the server sends: no NaN anywhere
    return frame


def test_frames_show_the_flight_as_the_core_sees_it() -> None:
    mission = mission_from("example1_octahedron.yaml", duration=30.0)
    sky = Sky(mission)
    b = SnapshotBuilder(scene_of(mission.law, name=mission.settings.name))
    first = _frame(b, sky)
    assert first["stage"] == "starting" and first["behaviour"] is None
    assert first["vehicles"]["sysid"] == [1, 2, 3, 4, 5, 6]
    sky.ready()
    # Readied, not yet flying: the positions come from each protocol, not the
    # telemetry table (no row is attached yet).
    ready = _frame(b, sky)["vehicles"]
    assert not any(sky.core.table.ned_positions(sky.core.table.slots(ready["sysid"]))[1])
    want = np.array([sky.core.vehicles[s].state_mission()[0] for s in ready["sysid"]])
    np.testing.assert_allclose(np.array(ready["pos"]), want, atol=5e-4)
    sky.start()
    sky.advance(3.0)  # past the first telemetry-rate window (2 s)
    f = _frame(b, sky)
    assert f["stage"] == "flying" and f["behaviour"] == "formation"
    v = f["vehicles"]
    assert v["in_formation"] == [True] * 6 and v["phase"] == ["flying"] * 6
    assert v["mode"] == ["GUIDED"] * 6 and v["armed"] == [True] * 6
    # Positions: the core's own (state_mission), to the frame's 1 mm rounding;
    # every row is now read from the telemetry table's columns.
    assert all(sky.core.table.ned_positions(sky.core.table.slots(v["sysid"]))[1])
    want = np.array([sky.core.vehicles[s].state_mission()[0] for s in v["sysid"]])
    np.testing.assert_allclose(np.array(v["pos"]), want, atol=5e-4)
    last = sky.core.control.last
    assert last is not None
    np.testing.assert_allclose(f["leader"], last.law.leader_pos_m, atol=5e-4)
    radius = np.linalg.norm(want - last.law.leader_pos_m, axis=1)
    np.testing.assert_allclose(v["radius"], radius, atol=1e-3)
    d = np.linalg.norm(want[:, None] - want[None, :], axis=2)
    np.fill_diagonal(d, np.inf)
    np.testing.assert_allclose(v["nearest"], d.min(axis=1), atol=1e-3)
    np.testing.assert_allclose(v["accel"], np.linalg.norm(last.accel_mps2, axis=1), atol=1e-3)
    assert v["clearance"] == [None] * 6  # no obstacles in Example 1
    assert v["correction"] == [None] * 6  # the safety filter is off (the paper's law)
    assert all(r is not None and 40.0 < r <= 60.0 for r in v["rate_hz"])
    assert all(h is not None and 0.0 <= h < 0.1 for h in v["heard_s"])
    kinds = [e["kind"] for e in f["events"]]
    assert kinds.count("join") == 6 and set(kinds) <= set(EVENT_KINDS)
    assert any("formation started" in e["text"] for e in f["events"])
    assert f["scene"]["sphere_radius"] == mission.law.gains.alpha
    # The next frame carries only what happened since.
    sky.advance(0.1)
    assert [e["kind"] for e in _frame(b, sky)["events"]] == []


def test_a_vehicle_leaving_and_the_switch_are_events() -> None:
    mission = mission_from("scenario3_obstacle.yaml", duration=60.0)
    sky = Sky(mission)
    b = SnapshotBuilder(scene_of(mission.law), sky.core.control.controller.obstacles)
    sky.ready()
    sky.start()
    seen: list[dict] = []  # type: ignore[type-arg]
    while sky.core.control.t_s < 25.0 and not any(e["kind"] == "switch" for e in seen):
        sky.advance(0.1)
        seen += _frame(b, sky)["events"]
    assert any(e["kind"] == "switch" and e["text"] == "avoidance" for e in seen)
    f = _frame(b, sky)
    assert len(f["scene"]["obstacles"]) == len(mission.law.obstacles) > 0
    box, drawn = mission.law.obstacles[0], f["scene"]["obstacles"][0]
    # The field's edge rho = r0 (Eqs. 15-18): semi-axes sqrt(3) r0 v_i.
    want = np.sqrt(3.0) * mission.law.avoidance.r0 * np.array(box.half_extents)
    np.testing.assert_allclose(drawn["field"], want)
    assert all(c is not None for c in f["vehicles"]["clearance"])
    # A vehicle whose link goes silent is lost and leaves the formation.
    victim = f["vehicles"]["sysid"][0]
    sky.set_silent(victim)
    events: list[dict] = []  # type: ignore[type-arg]
    for _ in range(40):
        sky.advance(0.1)
        events += _frame(b, sky)["events"]
        if sky.core.vehicles[victim].phase is Phase.LOST:
            break
    assert any(e["kind"] == "lost" and e["sysid"] == victim for e in events)


def test_the_scene_carries_the_geofence_and_the_floor() -> None:
    from gcs_swarm.mission import load_mission
    from tests.swarm.swarm_harness import MISSIONS

    scene = scene_of(load_mission(MISSIONS / "sitl_octahedron.yaml").law)
    assert scene["fence"] == {"min": [-40.0, -40.0, 0.0], "max": [60.0, 40.0, 40.0]}
    assert scene["floor"] == 5.0 and scene["obstacles"] == []
    bare = scene_of(mission_from("example1_octahedron.yaml", duration=1.0).law)
    assert bare["fence"] is None and bare["floor"] is None
    json.dumps(scene, allow_nan=False)
