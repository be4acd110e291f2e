"""Keep-out columns of vehicles that left the formation unheard (Eq. K1).

The column itself (``control.keep_out.lost_column``), the filter's row (e)
keeping the vehicle separation from it on exact double-integrator
kinematics, ``ControlLoop``'s set of columns across a new envelope, the
sharded controller's columns (a dead shard's vehicles; a live shard's lost
ones, sent with its heartbeats) and their wire form. The flights on the
emulator are in tests/swarm/test_swarm_flights.py (a lost vehicle's
failsafe descent) and tests/station/test_shards.py (a killed shard).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from gcs_swarm.control.keep_out import BRAKE_CAP_MPS2, HOLD_DRIFT_M, REACH_M, lost_column
from gcs_swarm.control.loop import ControlLoop
from gcs_swarm.control.params import Box, Envelope, LawConfig, Limits, Safety
from gcs_swarm.control.safety import SafetyFilter, box_signed_distance
from gcs_swarm.errors import LinkError
from gcs_swarm.mission import parse_mission
from gcs_swarm.swarm.controller import ControllerCore
from gcs_swarm.swarm.shard_wire import StateBatch, keep_out_from_json, keep_out_json

DT = 0.02
POS_TOL = 1e-6  # as tests/safety/test_safety_closed_loop.py: rounding only


def _extent(box: Box) -> tuple[np.ndarray, np.ndarray]:
    c, h = np.array(box.centre), np.array(box.half_extents)
    return c - h, c + h


def test_the_column_of_a_vehicle_at_rest_is_its_hold_drift_wide_and_reaches_down() -> None:
    box = lost_column([3.0, -2.0, 10.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0],
                      coast_s=0.5, brake_mps2=2.5)  # fmt: skip
    lo, hi = _extent(box)
    assert lo[:2] == pytest.approx([3.0 - HOLD_DRIFT_M, -2.0 - HOLD_DRIFT_M], abs=1e-12)
    assert hi == pytest.approx([3.0 + HOLD_DRIFT_M, -2.0 + HOLD_DRIFT_M, 10.0 + HOLD_DRIFT_M])
    assert lo[2] == pytest.approx(10.0 - REACH_M)  # below any ground


def test_the_column_grows_with_the_speed_the_last_command_and_the_coast() -> None:
    """Eq. K1a by hand: |v| = 2 m/s, |a| = 1 m/s^2, T = 0.5 s, b = 2.5 m/s^2:
    r = 0.5 + 1 + 0.125 + 2.5^2 / 5 = 2.875 m."""
    box = lost_column([0.0, 0.0, 5.0], [0.0, 2.0, 0.0], [0.6, 0.0, 0.8],
                      coast_s=0.5, brake_mps2=2.5)  # fmt: skip
    assert box.half_extents[0] == box.half_extents[1] == pytest.approx(2.875, abs=1e-12)
    assert _extent(box)[1][2] == pytest.approx(5.0 + 2.875)
    # A harder brake than ArduCopter's default is not counted on; a softer one widens it.
    hard = lost_column([0, 0, 5], [0, 2, 0], [0.6, 0, 0.8], coast_s=0.5, brake_mps2=50.0)
    soft = lost_column([0, 0, 5], [0, 2, 0], [0.6, 0, 0.8], coast_s=0.5, brake_mps2=1.0)
    assert hard.half_extents[0] == pytest.approx(0.5 + 1 + 0.125 + 2.5**2 / (2 * BRAKE_CAP_MPS2))
    assert soft.half_extents[0] == pytest.approx(0.5 + 1 + 0.125 + 2.5**2 / 2.0)
    # An unbounded envelope (inf) brakes at the cap too.
    assert lost_column([0, 0, 5], [0, 2, 0], [0, 0, 0], coast_s=0.5,
                       brake_mps2=math.inf).half_extents[0] == pytest.approx(
        0.5 + 1 + 2.0**2 / (2 * BRAKE_CAP_MPS2))  # fmt: skip


def test_an_rtl_failsafe_s_column_reaches_up_too() -> None:
    box = lost_column([0.0, 0.0, 5.0], [0, 0, 0], [0, 0, 0], coast_s=0.5, brake_mps2=2.5,
                      climbs=True)  # fmt: skip
    lo, hi = _extent(box)
    assert hi[2] == pytest.approx(5.0 + REACH_M) and lo[2] == pytest.approx(5.0 - REACH_M)


@pytest.mark.parametrize(
    ("pos", "coast"), [([0.0, math.nan, 1.0], 0.5), ([0.0, 0.0, math.inf], 0.5), ([0, 0, 0], -1)]
)
def test_a_column_of_a_state_that_is_not_finite_is_refused(pos: list[float], coast: float) -> None:
    with pytest.raises(ValueError, match="lost_column"):
        lost_column(pos, [0, 0, 0], [0, 0, 0], coast_s=coast, brake_mps2=2.5)


def _fly(flt: SafetyFilter, p: np.ndarray, target: np.ndarray, steps: int) -> tuple[float, float]:
    """A reckless PD law toward ``target`` through the keep-out; the filter
    between. Returns the smallest signed distance to any keep-out box and
    the last distance, on exact double-integrator kinematics."""
    boxes = flt.keep_out
    centres = np.array([b.centre for b in boxes]).reshape(-1, 3)
    halves = np.array([b.half_extents for b in boxes]).reshape(-1, 3)
    v = np.zeros_like(p)
    worst = last = math.inf
    for _ in range(steps):
        a, rep = flt.filter(p, v, 4.0 * (target - p) - 0.5 * v)
        assert not rep.infeasible.any()
        assert math.isinf(float(rep.min_clearance_m.min()))  # not an obstacle: no clearance
        p = p + v * DT + a * DT * DT / 2.0
        v = v + a * DT
        last = float(box_signed_distance(p, centres, halves)[0].min())
        worst = min(worst, last)
    return worst, last


def test_the_filter_keeps_the_separation_from_a_keep_out_column() -> None:
    """A member flies at a lost vehicle's column (the law would take it
    straight through); with the column kept it stops at the separation."""
    flt = SafetyFilter(Limits(a_max=5.0, v_max=4.0), Safety(True, 0.5, 1.5), [], dt=DT)
    column = lost_column([10.0, 0.0, 8.0], [0, 0, 0], [0, 0, 0], coast_s=0.5, brake_mps2=2.5)
    flt.set_keep_out([column])
    start = np.array([[0.0, 0.2, 5.0], [0.0, 0.0, 12.0]])  # below it, and above it
    target = np.array([[20.0, 0.2, 5.0], [20.0, 0.0, 12.0]])
    worst, _ = _fly(flt, start.copy(), target, 400)
    assert worst >= 1.5 - POS_TOL
    # The one above its top passes over it: only the column is kept out of.
    flt.set_keep_out([column])
    p = start[1:].copy()
    worst_above, last = _fly(flt, p, target[1:], 400)
    assert worst_above >= 1.5 - POS_TOL and last > 9.0  # past it, 20 m on


def test_with_the_filter_off_a_keep_out_column_changes_nothing() -> None:
    """``Safety.enabled`` off (the paper's mode): the column is not a row,
    and the limits alone act, as without it."""
    lim = Limits(a_max=5.0, v_max=4.0)
    with_col, without = (SafetyFilter(lim, Safety(False), [], dt=DT) for _ in range(2))
    with_col.set_keep_out([lost_column([1, 0, 0], [0, 0, 0], [0, 0, 0], coast_s=0.5,
                                       brake_mps2=2.5)])  # fmt: skip
    p, v, a = np.array([[0.0, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]), np.array([[3.0, 0, 0]])
    assert np.array_equal(with_col.filter(p, v, a)[0], without.filter(p, v, a)[0])


def _loop(enabled: bool = True) -> ControlLoop:
    law = LawConfig(limits=Limits(a_max=5.0), safety=Safety(enabled, 0.5, 1.0))
    return ControlLoop(law, {1: 1.0, 2: 1.0}, 50.0)


def test_the_loop_s_columns_outlive_a_new_envelope_and_end_on_release() -> None:
    loop = _loop()
    box = lost_column([0, 0, 5], [0, 0, 0], [0, 0, 0], coast_s=0.5, brake_mps2=2.5)
    loop.keep_out_of(7, box)
    loop.set_envelope(Envelope(accel_xy=2.0, accel_z=1.0))  # a new filter
    assert loop.safety.keep_out == (box,)
    assert loop.release(7) and not loop.release(7)
    assert loop.safety.keep_out == () and loop.keep_out == {}


def test_a_member_inside_a_fresh_column_is_counted_and_pushed_out() -> None:
    """The column appears around a member (Example 1's vehicle 6 was 0.23 m
    aside, 3.5 m below the one lost): the step's figure says how deep, and
    the filtered command points out of it."""
    loop = _loop()
    loop.keep_out_of(9, lost_column([0, 0, 5], [0, 0, 0], [0, 0, 0], coast_s=0.5,
                                    brake_mps2=2.5))  # fmt: skip
    pos = np.array([[0.2, 0.0, 1.5], [6.0, 0.0, 1.5]])
    res = loop.step([1, 2], pos, np.zeros((2, 3)))
    assert loop.min_keep_out_m == pytest.approx(-0.3)
    assert res.accel_mps2[0, 0] > 0.0  # out through the nearest face, +x


def _controller(departures: dict[int, tuple[float, bool]] | None = None) -> ControllerCore:
    law = parse_mission("""\
mission: {name: split, duration: 10, rate: 50}
leader: {start: [0, 0, 0], force: [0, 0, 0]}
limits: {safety: {enabled: true, separation: 1.5}}
vehicles:
  - {sysid: 1, start: [2, 1, 2]}
  - {sysid: 2, start: [-1, -1, -1]}
""").law
    core = ControllerCore(law, {1: 1.0, 2: 1.0, 257: 1.0}, 50.0, shards=2, duration_s=10.0,
                          stale_timeout_s=1.0, lockstep=True, departures=departures)  # fmt: skip
    core.start(0.0, {0: 2, 1: 1})
    return core


def _batch(
    shard: int, keys: list[int], pos: list[list[float]], vel: list[list[float]]
) -> StateBatch:
    n = len(keys)
    return StateBatch(shard, 1, np.array(keys, dtype=np.int32), np.full(n, 1000, dtype=np.int64),
                      np.array(pos, dtype=np.float64), np.array(vel, dtype=np.float64))  # fmt: skip


def test_a_dead_shard_s_vehicles_become_columns_at_their_last_states() -> None:
    core = _controller({257: (1.0, False)})
    core.receive_state(_batch(0, [1, 2], [[2, 1, 2], [-1, -1, -1]], [[0, 0, 0], [0, 0, 0]]), 0.0)
    core.receive_state(_batch(1, [257], [[3, 4, 2]], [[0.0, 2.0, 0.0]]), 0.0)
    core.control_step(0.0)
    a = core.control.last.accel_mps2[2] if core.control.last is not None else None
    assert a is not None
    core.receive_state(_batch(0, [1, 2], [[2, 1, 2], [-1, -1, -1]], [[0, 0, 0], [0, 0, 0]]), 1.1)
    core.handle_timer(1.1)  # shard 1 silent for 1.1 s: dead
    assert core.dead_shards() == [1]
    box = core.control.keep_out[257]
    want = lost_column([3, 4, 2], [0, 2, 0], a, coast_s=1.0, brake_mps2=math.inf)
    assert box == want
    assert any("columns of shard 1's 1 vehicles" in line for line in core.log)


def test_a_live_shard_s_lost_vehicles_are_kept_out_of_until_it_hears_them() -> None:
    core = _controller()
    box = lost_column([3, 4, 2], [0, 0, 0], [0, 0, 0], coast_s=0.5, brake_mps2=2.5)
    wire = keep_out_from_json(keep_out_json({257: box}))
    assert wire == {257: box}  # exact: floats cross JSON as their shortest repr
    core.heard(1, 0.1, 0, wire)
    assert core.control.keep_out == {257: box}
    core.heard(1, 0.2, 0, wire)  # the same again: nothing new said
    assert sum("left unheard" in line for line in core.log) == 1
    core.heard(1, 0.3, 1, {})
    assert core.control.keep_out == {}
    assert any("vehicle 257 heard again" in line for line in core.log)


@pytest.mark.parametrize("bad", [{"1": [0, 0, 0]}, {"x": [0] * 6}, [1, 2], {"1": ["a"] * 6}])
def test_a_malformed_keep_out_in_a_heartbeat_is_a_link_error(bad: object) -> None:
    with pytest.raises(LinkError, match="keep_out"):
        keep_out_from_json(bad)


def test_with_the_filter_off_a_dead_shard_leaves_no_column() -> None:
    core = _controller()
    core.control.config = dataclasses.replace(core.control.config, safety=Safety(False))
    core.receive_state(_batch(1, [257], [[3, 4, 2]], [[0, 0, 0]]), 0.0)
    core.handle_timer(1.1)
    assert core.dead_shards() == [0, 1] and core.control.keep_out == {}


def test_offline_members_keep_out_of_the_column_of_a_vehicle_that_left() -> None:
    """``simulate_mission`` holds a vehicle that left where it left; with the
    filter on the others keep the separation from its column, as the station
    keeps them from one that left and flies on. Example 1's octahedron with
    its leader pushed along +x (1 m/s) and 3 m of separation: vehicle 2, in
    front, leaves at 40 s and the others come up to it. Measured: 2.897 m
    from it (1.466 m without its column). The integrator filters at every
    RK4 stage, not the zero-order hold the barrier is exact for (0.10 m
    inside the margin here): 0.2 m allowed."""
    from gcs_swarm.control import ConstantForce
    from gcs_swarm.mission import Event, load_mission
    from gcs_swarm.offline import simulate_mission

    path = Path(__file__).resolve().parents[2] / "config" / "missions" / "example1_octahedron.yaml"
    m = load_mission(path)
    law = dataclasses.replace(
        m.law,
        safety=dataclasses.replace(m.law.safety, enabled=True, separation=3.0),
        leader=dataclasses.replace(m.law.leader, force=ConstantForce((10.0, 0.0, 0.0))),
    )
    m = dataclasses.replace(m, law=law, events=(Event(40.0, "leave", 2),))
    res = simulate_mission(m, dt_s=0.02, duration_s=70.0).result
    k = int(np.flatnonzero(res.active[:, 1])[-1])  # its last sample
    held = res.pos_m[k, 1]  # held there (one step's travel on: |v| dt < 1e-3 m)
    others = np.delete(res.pos_m[k + 1 :], 1, axis=1)
    closest = float(np.linalg.norm(others - held, axis=-1).min())
    assert closest >= 3.0 - 0.2, closest


def test_a_live_shard_s_vehicles_out_of_the_formation_are_kept_out_of_where_they_fly() -> None:
    """A shard's heartbeats carry the columns of its vehicles that left while
    heard and fly on (``keep_live``): the controller keeps them out of each
    at its latest, says so once, drops it when the shard does; if the shard
    dies, the last one stays (the vehicle is unheard from then on)."""
    core = _controller()
    at = [lost_column([3, 4, 2 - 0.5 * i], [0, 0, -0.5], [0, 0, 0], coast_s=0.0, brake_mps2=2.5)
          for i in range(3)]  # fmt: skip
    core.heard(1, 0.1, 0, {}, {257: at[0]})
    core.heard(1, 0.2, 0, {}, {257: at[1]})  # landing: it moved down
    assert core.control.live_keep_out == {257: at[1]} and core.control.keep_out == {}
    assert core.control.safety.keep_out == (at[1],)
    assert sum("out of the formation and in the air" in line for line in core.log) == 1
    core.heard(1, 0.3, 0, {}, {})  # down
    assert core.control.live_keep_out == {} and core.control.safety.keep_out == ()
    core.heard(1, 0.4, 0, {}, {257: at[2]})
    core.handle_timer(2.0)  # both shards silent: dead
    assert core.control.keep_out == {257: at[2]} and core.control.live_keep_out == {}
    assert core.control.keep_outs_taken == 1
