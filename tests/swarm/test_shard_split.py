"""The link-shard split without I/O (issue 19 item 2): the wire's bytes, the
controller's step rule and dead-shard rule, the shard's watch on its
controller, and whole flights of the split on the in-process harness
(bit-equal to the station's own step, also with a leave and a reserve's
join run by two shards; a silent controller ends every vehicle), all on a
hand-advanced clock (no Zenoh, no sockets, no sleeps).
The processes over Zenoh are tests/station/test_shards.py."""

from __future__ import annotations

import numpy as np
import pytest
from shard_harness import Split
from swarm_harness import Sky, mission_from

from gcs_swarm.control.params import LawConfig
from gcs_swarm.errors import LinkError
from gcs_swarm.mavlink.states import Phase
from gcs_swarm.mission import Mission, parse_mission
from gcs_swarm.swarm.controller import ControllerCore
from gcs_swarm.swarm.shard import STARTUP_SILENCE_S, ShardSide
from gcs_swarm.swarm.shard_wire import (
    HEADER_BYTES,
    REPLY_BYTES_PER_VEHICLE,
    STATE_BYTES_PER_VEHICLE,
    SetpointReply,
    StateBatch,
    decode_reply,
    decode_state,
    encode_reply,
    encode_state,
)
from gcs_swarm.swarm.step import Write

STALE_S = 1.0


def _law() -> LawConfig:
    text = """\
mission: {name: split, duration: 10, rate: 50}
leader: {start: [0, 0, 0], force: [0, 0, 0]}
vehicles:
  - {sysid: 1, start: [2, 1, 2]}
  - {sysid: 2, start: [-1, -1, -1]}
  - {sysid: 3, start: [3, 4, 2]}
  - {sysid: 4, start: [4, 2, 2]}
"""
    return parse_mission(text).law


def _controller(lockstep: bool = True, step_per_network: bool = False) -> ControllerCore:
    core = ControllerCore(_law(), {1: 1.0, 2: 1.0, 257: 1.0, 258: 1.0}, 50.0, shards=2,
                          duration_s=10.0, stale_timeout_s=STALE_S, lockstep=lockstep,
                          step_per_network=step_per_network)  # fmt: skip
    core.start(0.0, {0: 2, 1: 2})
    return core


_POS = {1: (2.0, 1.0, 2.0), 2: (-1.0, -1.0, -1.0), 257: (3.0, 4.0, 2.0), 258: (4.0, 2.0, 2.0)}


def _state(
    shard: int, seq: int, keys: list[int], ms: int, fresh: bool = True, shift: float = 0.0
) -> StateBatch:
    pos = np.array([_POS[k] for k in keys], dtype=np.float64).reshape(len(keys), 3) + shift
    return StateBatch(shard, seq, np.array(keys, dtype=np.int32),
                      np.full(len(keys), ms if fresh else -1, dtype=np.int64),
                      pos, np.zeros((len(keys), 3)))  # fmt: skip


def test_state_and_reply_cross_as_exact_float64_bits_in_stated_sizes() -> None:
    rng = np.random.default_rng(19)
    pos, vel = rng.normal(size=(3, 3)) * 1e3, rng.normal(size=(3, 3))
    batch = StateBatch(1, 7, np.array([3, 257, 510], dtype=np.int32),
                       np.array([1200, -1, 4294967295], dtype=np.int64), pos, vel)  # fmt: skip
    data = encode_state(batch)
    assert len(data) == HEADER_BYTES + 3 * STATE_BYTES_PER_VEHICLE == 24 + 180
    back = decode_state(data)
    assert (back.shard, back.seq) == (1, 7)
    assert back.keys.tolist() == [3, 257, 510] and back.boot_ms.tolist() == [1200, -1, 4294967295]
    assert back.pos_m.tobytes() == pos.tobytes() and back.vel_mps.tobytes() == vel.tobytes()
    assert back.fresh() == {3: 1200, 510: 4294967295}
    reply = SetpointReply(1, 7, 0.1 + 0.2, np.array([3, 510], dtype=np.int32), pos[:2] * np.pi)
    data = encode_reply(reply)
    assert len(data) == HEADER_BYTES + 2 * REPLY_BYTES_PER_VEHICLE == 24 + 56
    got = decode_reply(data)
    assert got.t_s == 0.1 + 0.2 and got.keys.tolist() == [3, 510]
    assert got.accel_mps2.tobytes() == reply.accel_mps2.tobytes()


@pytest.mark.parametrize(
    "bad",
    [
        b"",
        b"GSSH",
        b"XXXX" + bytes(20),
        bytes(
            encode_reply(SetpointReply(0, 1, 0.0, np.array([1], dtype=np.int32), np.zeros((1, 3))))
        )[:-1],
    ],
)
def test_a_malformed_shard_message_is_a_link_error(bad: bytes) -> None:
    with pytest.raises(LinkError):
        decode_reply(bad)
    with pytest.raises(LinkError):
        decode_state(bad)


def test_the_controller_steps_once_every_flying_shard_has_delivered() -> None:
    core = _controller()
    core.receive_state(_state(0, 1, [1, 2], 1000), 0.01)
    assert not core.step_wanted
    assert core.get_timer() == pytest.approx(0.51)  # lockstep fallback 0.5 s
    core.receive_state(_state(1, 1, [257, 258], 5000), 0.02)
    assert core.step_wanted
    replies = core.control_step(0.02)
    assert core.flying == [1, 2, 257, 258]
    assert [(r.shard, r.seq, r.keys.tolist()) for r in replies] == [(0, 1, [1, 2]),
                                                                    (1, 1, [257, 258])]  # fmt: skip
    assert replies[0].accel_mps2.shape == (2, 3) and np.isfinite(replies[0].accel_mps2).all()
    # Each vehicle's boot clock has its own offset (ControlLoop.advance_clock):
    # 20 ms later on both shards is 20 ms of mission time.
    core.receive_state(_state(0, 2, [1, 2], 1020), 0.03)
    core.receive_state(_state(1, 2, [257, 258], 5020), 0.04)
    (r0, r1) = core.control_step(0.04)
    assert r0.t_s == r1.t_s == pytest.approx(0.02)


def test_the_fallback_steps_without_a_late_shard_and_answers_only_the_fresh() -> None:
    core = _controller()
    core.receive_state(_state(1, 1, [257, 258], 5000), 0.0)
    core.receive_state(_state(0, 1, [1, 2], 1000), 0.0)
    core.control_step(0.0)
    core.receive_state(_state(0, 2, [1, 2], 1020), 0.02)
    core.handle_timer(0.51)
    assert not core.step_wanted  # not yet: 0.5 s after the first report
    core.handle_timer(0.52)
    assert core.step_wanted and core.fallbacks == 1
    replies = core.control_step(0.52)
    # The law flew all four (shard 1 with its last states); shard 0 is answered.
    assert core.flying == [1, 2, 257, 258]
    assert [(r.shard, r.keys.tolist()) for r in replies] == [(0, [1, 2])]


def test_each_shard_s_batch_is_stepped_as_it_comes_and_only_that_shard_answered() -> None:
    """``step: network`` (tests/swarm/test_shard_step_per_network.py flies it
    whole): a batch makes a step at once, commanding its vehicles only."""
    per, whole = _controller(False, True), _controller(False)
    # The start: shard 0's first batch waits until every shard's states are
    # in, here shard 1's opening (its states, none fresh: ShardSide.opening),
    # which then steps shard 0's batch at once, with all four vehicles.
    for core in (per, whole):
        core.receive_state(_state(0, 1, [1, 2], 1000), 0.0)
        assert not core.step_wanted
        assert core.get_timer() == pytest.approx(0.02)  # the fallback: a period
        core.receive_state(_state(1, 1, [257, 258], 5000, fresh=False), 0.001)
    assert not whole.step_wanted  # the whole swarm's step waits for shard 1's reports
    assert per.step_wanted
    (first,) = per.control_step(0.001)
    assert first.keys.tolist() == [1, 2] and per.flying == [1, 2, 257, 258]
    # The first period: both shards' batches, then each controller steps.
    for core in (per, whole):
        core.receive_state(_state(0, 2, [1, 2], 1000), 0.0)
        core.receive_state(_state(1, 2, [257, 258], 5000), 0.0)
        core.control_step(0.0)
    # The next: shard 0's vehicles moved, shard 1's did not (so the step of
    # shard 0 alone sees shard 1's states as the whole step does).
    s0, s1 = _state(0, 3, [1, 2], 1020, shift=0.01), _state(1, 3, [257, 258], 5020)
    whole.receive_state(s0, 0.02)
    assert not whole.step_wanted  # it waits for shard 1 (or a period)
    assert whole.get_timer() == pytest.approx(0.04)
    per.receive_state(s0, 0.02)
    assert per.step_wanted  # at once, without a fallback to wait for
    assert per.get_timer() == pytest.approx(1.0)  # only shard 1's stale timeout (heard at 0)
    (r0,) = per.control_step(0.02)
    assert (r0.shard, r0.seq, r0.keys.tolist()) == (0, 3, [1, 2])
    assert per.flying == [1, 2, 257, 258]  # the law flew all four, shard 1 at its last
    per.receive_state(s1, 0.03)
    assert per.step_wanted
    (r1,) = per.control_step(0.03)
    assert (r1.shard, r1.seq, r1.keys.tolist()) == (1, 3, [257, 258])
    assert r0.t_s == r1.t_s == pytest.approx(0.02)  # each on its own reports' time
    whole.receive_state(s1, 0.03)
    w0, w1 = whole.control_step(0.03)
    # The same law: each vehicle's command as the whole step gives it. Four
    # vehicles are below the rows' own law (formation_rows.SMALL_N), so the
    # rows are taken from the whole computation: equal to rounding (1e-12).
    np.testing.assert_allclose(r0.accel_mps2, w0.accel_mps2, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(r1.accel_mps2, w1.accel_mps2, rtol=1e-12, atol=1e-12)
    assert per.control.steps == 4 and whole.control.steps == 2
    assert per.fallbacks == whole.fallbacks == 0


@pytest.mark.parametrize("per_network", [False, True], ids=["whole swarm", "per network"])
def test_a_silent_shard_is_dead_after_the_stale_timeout_and_its_vehicles_leave(
    per_network: bool,
) -> None:
    core = _controller(step_per_network=per_network)
    core.receive_state(_state(0, 1, [1, 2], 1000), 0.0)
    core.receive_state(_state(1, 1, [257, 258], 5000), 0.0)
    core.control_step(0.0)
    t = 0.0
    for ms in range(1020, 2200, 20):  # shard 0 flies on; shard 1 went silent at 0.0
        t = (ms - 1000) * 1e-3
        core.receive_state(_state(0, ms, [1, 2], ms), t)
        due = core.get_timer()
        assert due is not None
        if due <= t:
            core.handle_timer(t)
        if core.step_wanted:
            core.control_step(t)
        if not core.shards[1].alive:
            break
    assert core.shards[1].died_at == pytest.approx(STALE_S)
    assert core.shards[0].alive and not core.finished
    assert any("shard 1 silent for 1.00 s: dead" in line for line in core.log)
    # Shard 0 alone is now waited for: its next report steps at once, with only
    # its own vehicles in the law.
    core.receive_state(_state(0, 9999, [1, 2], 2100), t + 0.02)
    assert core.step_wanted
    (reply,) = core.control_step(t + 0.02)
    assert core.flying == [1, 2] and reply.keys.tolist() == [1, 2]
    # A dead shard's late word is not taken back.
    core.receive_state(_state(1, 2, [257, 258], 6000), t + 0.04)
    assert core.shards[1].batch is None
    # Both dead: the mission ends.
    core.handle_timer(t + 0.02 + STALE_S)
    assert core.finished and core.dead_shards() == [0, 1]


def test_a_vehicle_its_shard_stops_reporting_leaves_the_law() -> None:
    core = _controller()
    core.receive_state(_state(0, 1, [1, 2], 1000), 0.0)
    core.receive_state(_state(1, 1, [257, 258], 5000), 0.0)
    core.control_step(0.0)
    core.receive_state(_state(0, 2, [1], 1020), 0.02)  # vehicle 2 lost on its shard
    core.receive_state(_state(1, 2, [257, 258], 5020), 0.02)
    replies = core.control_step(0.02)
    assert core.flying == [1, 257, 258]
    assert [r.keys.tolist() for r in replies] == [[1], [257, 258]]


def test_the_shard_side_watches_its_controller_on_the_hand_clock() -> None:
    sky = Sky(mission_from("example1_octahedron.yaml", duration=6.0))
    side = ShardSide(sky.core, index=0, stale_timeout_s=STALE_S)
    assert side.get_timer() is None and not side.controller_silent(100.0)
    side.heard(5.0)  # before the formation starts: STARTUP_SILENCE_S
    assert side.get_timer() == 5.0 + STARTUP_SILENCE_S
    assert not side.controller_silent(5.0 + STARTUP_SILENCE_S - 0.01)
    assert side.controller_silent(5.0 + STARTUP_SILENCE_S)
    sky.ready()
    sky.start()  # in flight: the stale timeout
    assert side.get_timer() == 6.0
    assert not side.controller_silent(5.99)
    assert side.controller_silent(6.0)


# ---------------------------------------------------------------- in process
# The split flown whole on the in-process harness (tests/swarm/swarm_harness.py:
# the station's core against the emulator's core, one hand-advanced clock): the
# core's step goes through ShardSide, the wire's bytes and a ControllerCore
# instead of run_step, as in a shard process, without Zenoh or sockets.


def _sharded_in_flight(
    mission: Mission, *, beats: bool = False, lockstep: bool = False
) -> tuple[Sky, ShardSide, ControllerCore]:
    """``mission`` on the harness with its step through the split, readied and
    started as a shard and its controller start it (``runtime/shard.py``);
    with ``beats`` the controller's leader (position and velocity) and its
    farthest member's distance reach the shard after each step
    (``ShardSide.leader_at``, as the controller's beats carry them)."""
    sky = Sky(mission)
    s = mission.settings
    side = ShardSide(sky.core, 0, s.stale_timeout)
    ctl = ControllerCore(mission.law, {v.key: v.q for v in mission.vehicles}, s.rate, shards=1,
                         duration_s=s.duration, stale_timeout_s=s.stale_timeout,
                         lockstep=lockstep)  # fmt: skip

    def step(now: float, write: Write) -> None:
        batch = side.take_state(now)
        if batch is None:
            return
        ctl.receive_state(decode_state(encode_state(batch)), now)
        if ctl.step_wanted:
            for reply in ctl.control_step(now):
                side.apply(decode_reply(encode_reply(reply)), now, write)
            if beats:
                law = ctl.control.controller
                side.leader_at(law.leader_pos_m.copy(), law.leader_vel_mps.copy(),
                               ctl.control.formation_radius_m())  # fmt: skip
        if ctl.finished:
            sky.core.finished = True

    sky.control_step = step
    sky.ready()
    ctl.set_envelope(sky.core.apply_envelope())
    sky.start()
    ctl.start(sky.now, {0: len(sky.core.flying)})
    return sky, side, ctl


def test_the_split_flies_the_station_s_numbers_on_the_hand_clock() -> None:
    mission = mission_from("example1_octahedron.yaml", duration=6.0)
    one = Sky(mission)
    one.ready()
    one.start()
    one.run_until(lambda: one.core.finished, 30.0)
    split, side, ctl = _sharded_in_flight(mission)
    split.run_until(lambda: split.core.finished, 30.0)
    a, b = one.core.control.last, ctl.control.last
    assert a is not None and b is not None
    assert (a.t_s, a.ids) == (b.t_s, b.ids) == (6.0, (1, 2, 3, 4, 5, 6))
    # The same floats: bit for bit.
    assert a.pos_m.tobytes() == b.pos_m.tobytes()
    assert a.accel_mps2.tobytes() == b.accel_mps2.tobytes()
    assert one.core.control.steps == ctl.control.steps
    assert one.answered == split.answered and side.replies == ctl.control.steps


def test_the_controller_runs_the_plane_look_ahead_off_its_step_in_real_time() -> None:
    """Scenario 3 (``plane: auto``) through the split. In real time the
    controller hands the look-ahead out (``ControllerCore.lookahead``, run by
    its shell in a worker thread: ``runtime.sharded``) and answers the step
    the episode starts at, as one station does; before, it ran the 0.15-0.25 s
    job inline, and no shard had a reply meanwhile. In lockstep it stays
    inline (the emulators wait for it; the run stays repeatable)."""
    mission = mission_from("scenario3_obstacle.yaml", duration=30.0)
    sky, side, ctl = _sharded_in_flight(mission)
    before = [side.replies]

    def handed_out() -> bool:
        if ctl.lookahead:
            return True
        before[0] = side.replies  # the replies before the next physics step
        return False

    sky.run_until(handed_out, 25.0)
    assert side.replies == before[0] + 1  # the step that handed the job out was answered
    job = ctl.lookahead.pop()
    t_job = ctl.control.t_s
    sky.advance(0.5)  # 25 steps flown on the horizontal plane meanwhile
    assert not ctl.lookahead  # one job per episode and obstacle
    ctl.resolve_lookahead(job, job(), 0.5)
    assert any(line.startswith(f"look-ahead for episode {job.episode}:") for line in ctl.log)
    sky.run_until(lambda: sky.core.finished, 30.0)
    assert ctl.finished and ctl.failure is None
    # In lockstep the same episode starts with no job handed out.
    sky2, _, ctl2 = _sharded_in_flight(mission, lockstep=True)
    sky2.run_until(lambda: ctl2.control.t_s >= t_job + 1.0, 30.0)
    assert not ctl2.lookahead
    assert not any(line.startswith("look-ahead for episode") for line in ctl2.log)


def test_a_shard_whose_controller_falls_silent_ends_its_vehicles_on_the_hand_clock() -> None:
    mission = mission_from("example1_octahedron.yaml", duration=60.0)
    sky, side, _ = _sharded_in_flight(mission)
    side.heard(sky.now)
    sky.advance(2.0)
    assert not side.controller_silent(sky.now)
    heard = side.heard_at
    assert heard is not None and sky.now - heard < 0.05

    def dead(now: float, write: Write) -> None:  # the controller is gone: nothing comes back
        side.take_state(now)

    sky.control_step = dead
    while not side.controller_silent(sky.now):  # the shard shell's watch (runtime/shard.py)
        sky.advance(sky.dt)
    assert sky.now - heard == pytest.approx(mission.settings.stale_timeout, abs=sky.dt + 1e-9)
    sky.end()  # Station.end: zero acceleration, then the mission's end action (hold)
    assert {vp.phase.value for vp in sky.core.vehicles.values()} == {"ended"}
    assert {v.ap.mode_name for v in sky.vehicles.values()} == {"BRAKE"}


# Example 1's six on two networks, a shard each (as run_sharded assigns them),
# with blue:2 leaving and red's reserve, red:4, joining: each event on its own
# shard's side of the split.
_EVENTS_MISSION = """\
mission: {name: split events, duration: 4, rate: 50, end: hold}
emulator: {dynamics: ideal}
leader: {start: [0, 0, 0], force: [0, 0, 0]}
networks:
  - name: blue
    vehicles:
      - {sysid: 1, start: [2, 1, 2]}
      - {sysid: 2, start: [-1, -1, -1]}
      - {sysid: 3, start: [3, 4, 2]}
  - name: red
    vehicles:
      - {sysid: 1, start: [4, 2, 2]}
      - {sysid: 2, start: [3, 3, 3]}
      - {sysid: 3, start: [-2, -2, -2]}
      - {sysid: 4, start: [1, -4, 3], reserve: true}
events:
  - {t: 1.5, leave: 2, network: blue}
  - {t: 2.5, join: 4, network: red}
"""
LEAVE_T_S, JOIN_T_S = 1.5, 2.5
BLUE, RED = (1, 2, 3), (257, 258, 259, 260)
"""The vehicles' keys: network j's system id s is j * 256 + s."""


def _flying_at(steps: list[tuple[float, tuple[int, ...]]], at: float) -> tuple[int, ...]:
    """The vehicles the law flew at the first step at or after mission time ``at``."""
    return next(ids for t, ids in steps if t >= at - 1e-9)


def test_the_split_runs_each_shard_s_events_at_the_station_s_steps() -> None:
    """Two shards on one hand clock (each a ``Sky`` of its own network's
    vehicles and events, one ``ControllerCore``) against one station of both
    networks: the leave and the join happen at the same step, and the law
    computes the same floats throughout (bit for bit, as the split without
    events)."""
    mission = parse_mission(_EVENTS_MISSION)
    one = Sky(mission)
    one_steps: list[tuple[float, tuple[int, ...]]] = []

    def station_step(now: float, write: Write) -> None:
        one.core.control_step(now, write)
        last = one.core.control.last
        if last is not None and one.core.control.steps > len(one_steps):
            one_steps.append((last.t_s, last.ids))

    one.control_step = station_step
    one.ready()
    ready_at = one.now
    one.start()
    one.run_until(lambda: one.core.finished, 30.0)

    split = Split(mission, [BLUE, RED])
    skies, ctl = split.skies, split.ctl
    split.ready()
    assert split.now == ready_at  # readied (the reserve took off) in the same time
    split.start()
    split.together(lambda: ctl.finished)
    split_steps = [(t, ids) for t, ids, _ in split.steps]

    # Each shard's core held only its own vehicles' events.
    assert [sky.core.config.events for sky in skies] == [((LEAVE_T_S, "leave", 2),),
                                                         ((JOIN_T_S, "join", 260),)]  # fmt: skip
    # The leave and the join at the station's steps: blue:2 out, then red:4 in.
    assert split_steps == one_steps
    assert _flying_at(one_steps, LEAVE_T_S - 0.02) == (1, 2, 3, 257, 258, 259)
    assert _flying_at(one_steps, LEAVE_T_S) == (1, 3, 257, 258, 259)
    assert _flying_at(one_steps, JOIN_T_S - 0.02) == (1, 3, 257, 258, 259)
    assert _flying_at(one_steps, JOIN_T_S) == (1, 3, 257, 258, 259, 260)
    a, b = one.core.control.last, ctl.control.last
    assert a is not None and b is not None
    assert (a.t_s, a.ids) == (b.t_s, b.ids) == (4.0, (1, 3, 257, 258, 259, 260))
    # The same floats: bit for bit (the split without events is too).
    assert a.pos_m.tobytes() == b.pos_m.tobytes()
    assert a.accel_mps2.tobytes() == b.accel_mps2.tobytes()
    assert a.radii_m.tobytes() == b.radii_m.tobytes()
    assert one.core.control.steps == ctl.control.steps
    assert one.answered == skies[0].answered + skies[1].answered
    # The leaver ended (the mission's end: hold) on its shard, as in one station.
    assert skies[0].core.vehicles[2].phase is one.core.vehicles[2].phase is Phase.ENDED


# A leader that moves at 0.25 m/s along x ((D + k) v = 2.5 N), so that a
# slot beside it is away from the mission's start points by the time a
# vehicle comes back (slower than the start's 0.3 m/s speed tolerance: a
# vehicle readied again must come to READY at its moving slot).
_MOVING = """\
mission: {name: rejoin, duration: 10, rate: 50, end: hold}
emulator: {dynamics: ideal}
leader: {start: [0, 0, 0], force: [2.5, 0, 0]}
vehicles:
  - {sysid: 1, start: [2, 1, 2]}
  - {sysid: 2, start: [-1, -1, -1]}
  - {sysid: 3, start: [3, 4, 2]}
  - {sysid: 4, start: [4, 2, 2]}
"""


def _lose_and_hear_again(sky: Sky) -> float:
    """Vehicle 3 silent from t = 1 s until the core calls it lost, then heard
    again; the mission time [s] at which its core flies it again."""
    sky.advance(1.0)
    sky.set_silent(3)
    sky.run_until(lambda: 3 not in sky.core.flying, 3.0)
    sky.set_silent(3, False)
    sky.run_until(lambda: 3 in sky.core.flying or sky.core.finished, 10.0)
    assert 3 in sky.core.flying, sky.phases()
    return sky.core.control.t_s


def test_a_vehicle_heard_again_on_its_shard_rejoins_at_its_slot_beside_the_leader() -> None:
    """One station sends a vehicle readied again mid-flight to its rejoin
    point: its start carried along with the leader, pushed out on that ray
    by the safety separation (``ControlLoop.rejoin_m``); a shard runs no law,
    so the controller's leader reaches it in the beats
    (``ShardSide.leader_at``): the split flies the station's numbers. Without
    them the vehicle would rejoin at its mission start, behind."""
    mission = parse_mission(_MOVING)
    one = Sky(mission)
    one.ready()
    one.start()
    t_one = _lose_and_hear_again(one)
    split, _, ctl = _sharded_in_flight(mission, beats=True)
    t_split = _lose_and_hear_again(split)
    assert t_split == t_one
    one.advance(0.1)
    split.advance(0.1)
    a, b = one.core.control.last, ctl.control.last
    assert a is not None and b is not None and a.ids == b.ids == (1, 2, 3, 4)
    assert a.pos_m.tobytes() == b.pos_m.tobytes()  # the same floats: bit for bit
    # Its start (3, 4, 2) is 5.39 m from the leader's, farther than the three
    # members (the point would be farther out otherwise, and this one missed):
    # the point is 1 m (the default separation) beyond it on the same ray.
    off = np.array([3.0, 4.0, 2.0])
    point = b.law.leader_pos_m + off * (1.0 + 1.0 / np.linalg.norm(off))
    start_gap = float(np.linalg.norm(b.pos_m[2] - (3.0, 4.0, 2.0)))
    # READY within the start tolerance (0.3 m) of the point, the leader ~1.2 m on.
    assert float(np.linalg.norm(b.pos_m[2] - point)) < 0.35 < 0.9 < start_gap, start_gap
    # Without the leader the shard sends it to its mission start.
    blind, _, ctl2 = _sharded_in_flight(mission)
    _lose_and_hear_again(blind)
    blind.advance(0.1)
    c = ctl2.control.last
    assert c is not None and c.ids == (1, 2, 3, 4)
    assert float(np.linalg.norm(c.pos_m[2] - (3.0, 4.0, 2.0))) < 0.35


def test_batches_queued_before_a_step_are_answered_by_one_step() -> None:
    """Real time, a step per network: a controller that fell behind takes the
    batches queued behind each other before it steps (``runtime.sharded``: the
    step waits for the loop's next turn). Their fresh vehicles add up, and one
    step answers each of them with the newest states; none is left out."""
    core = _controller(lockstep=False, step_per_network=True)
    core.receive_state(_state(1, 1, [257, 258], 5000), 0.0)
    core.receive_state(_state(0, 1, [1, 2], 1000), 0.0)
    core.control_step(0.0)
    # Shard 0's two networks report 10 ms apart (vehicle 1, then vehicle 2),
    # and both batches are in before the step: one step, both answered.
    first = _state(0, 2, [1, 2], 1020)._replace(boot_ms=np.array([1020, -1], dtype=np.int64))
    second = _state(0, 3, [1, 2], 1030, shift=0.5)._replace(
        boot_ms=np.array([-1, 1030], dtype=np.int64)
    )
    core.receive_state(first, 0.02)
    core.receive_state(second, 0.03)
    assert core.step_wanted
    (reply,) = core.control_step(0.03)
    assert (reply.shard, reply.seq, reply.keys.tolist()) == (0, 3, [1, 2])
    assert core.flying == [1, 2, 257, 258]
    assert not core.step_wanted and core.control_step(0.03) == []  # nothing fresh is left
