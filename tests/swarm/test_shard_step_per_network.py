"""``mission.step: network`` through link shards (issue 19 item 4: a sharded
run's latency must not wait for the other networks' phases): the
controller steps each state batch as it comes, commanding its fresh
vehicles against the other shards' latest states and answering only the
shard that delivered (``swarm.controller``, docs/formation-law.md section
3b). Whole flights of the split on the hand clock
(tests/swarm/shard_harness.py) against one station stepping per network,
bit for bit; the controller's rule alone is in
tests/swarm/test_shard_split.py, the processes over Zenoh in
tests/station/test_step_per_network_udp.py."""

from __future__ import annotations

import pytest
from shard_harness import Split, recording
from swarm_harness import Sky

from gcs_swarm.mission import parse_mission

# Twelve vehicles on three networks (the rows' own law from SMALL_N = 10 on),
# Example 1's gains, the leader moving along x at 0.2 m/s ((D + k) v = 2 N).
_MISSION = """\
mission: {name: split per network, duration: 4, rate: 50, end: hold, step: network}
emulator: {dynamics: ideal}
gains: {M: 1, D: 1, k: 9, k_s: 1, k_r: 0.2, alpha: 2, q: 10}
leader: {start: [0, 0, 0], force: [2, 0, 0]}
networks:
  - name: blue
    vehicles:
      - {sysid: 1, start: [2, 1, 2]}
      - {sysid: 2, start: [-1, -1, -1]}
      - {sysid: 3, start: [3, 4, 2]}
      - {sysid: 4, start: [-3, 2, 1]}
  - name: red
    vehicles:
      - {sysid: 1, start: [1, -3, -2]}
      - {sysid: 2, start: [0, 3, -3]}
      - {sysid: 3, start: [4, 2, 2]}
      - {sysid: 4, start: [3, 3, 3]}
  - name: green
    vehicles:
      - {sysid: 1, start: [-2, -2, -2]}
      - {sysid: 2, start: [-4, 0, 2]}
      - {sysid: 3, start: [2, -4, 0]}
      - {sysid: 4, start: [-1, 4, 4]}
"""
BLUE, RED, GREEN = (1, 2, 3, 4), (257, 258, 259, 260), (513, 514, 515, 516)


@pytest.mark.parametrize(
    "shards",
    [[(*BLUE, *RED, *GREEN)], [(*BLUE, *RED), GREEN], [BLUE, RED, GREEN]],
    ids=["one shard of three networks", "two networks and one", "a shard each"],
)
def test_the_split_steps_per_network_with_the_station_s_numbers(
    shards: list[tuple[int, ...]],
) -> None:
    """Each network's emulator steps and its reports reach its shard before
    the next network's (their phases their own, ``stagger``): one station
    takes a step per network; the split takes the same steps, in the same
    order, with the same floats, whichever shard owns which network."""
    mission = parse_mission(_MISSION)
    one = Sky(mission, stagger=True)
    one_steps = recording(one)
    one.ready()
    one.start()
    one.run_until(lambda: one.core.finished, 30.0)
    split = Split(mission, [set(s) for s in shards], stagger=True)
    split.ready()
    split.start()
    split.together(lambda: split.ctl.finished)
    # A step per network and period (the first steps all three at once).
    assert 3 * 200 <= len(one_steps) <= 3 * 200 + 3
    assert [s[:2] for s in split.steps] == [s[:2] for s in one_steps]
    assert split.steps == one_steps  # every command's float64 bits too
    assert split.ctl.fallbacks == 0
    answered = sum((sky.answered for sky in split.skies), start=type(one.answered)())
    assert answered == one.answered
    a, b = one.core.control.last, split.ctl.control.last
    assert a is not None and b is not None and a.t_s == b.t_s == 4.0
    # Those floats crossed as changes (shard_wire.changes): once the
    # controller has answered a shard's batch, the next carries only the rows
    # it does not hold as they are, here (each reply in before the next
    # network reports) the reporting network's 4. Only the first step, the
    # three networks at once, carries all of a shard's rows. None was dropped.
    for side in split.sides:
        per_batch = side.rows_flying / side.states  # every row: all its networks'
        assert side.rows_sent == side.rows_flying - (side.states - 1) * (per_batch - 4)
    assert split.ctl.unplaced == 0
    assert a.pos_m.tobytes() == b.pos_m.tobytes()
    assert a.radii_m.tobytes() == b.radii_m.tobytes()
