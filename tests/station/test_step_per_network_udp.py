"""``mission.step: network`` over real UDP on 127.0.0.1, in real time: twelve
vehicles on two networks, each network on an emulator of its own (its own
clock, so its own phase), fly Example 1's gains to their sphere and
complete. The hand-clock twin (tests/swarm/test_step_per_network.py) checks
the steps themselves; this one the station's real-time path around them
(timers, the fallback, two links), in one process and on two link shards."""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
import pytest

from gcs_swarm.mission import Mission, parse_mission
from gcs_swarm.runtime import RunSummary, run_mission
from gcs_swarm.runtime.shard import WINDOW_S
from gcs_swarm.runtime.sharded import ShardedRun, run_sharded
from gcs_swarm.swarm.shard_wire import HEADER_BYTES, STATE_BYTES_PER_VEHICLE

_STARTS = [
    [2, 1, 2], [-1, -1, -1], [3, 4, 2], [-3, 2, 1], [1, -3, -2], [0, 3, -3],
    [4, 2, 2], [3, 3, 3], [-2, -2, -2], [-4, 0, 2], [2, -4, 0], [-1, 4, 4],
]  # fmt: skip
DURATION_S = 12.0
SPHERE_M = 2.79
"""The twelve's equilibrium radius [m] (the hand-clock twin's, 2.7900 m at 40 s)."""


def _mission() -> Mission:
    text = (
        f"mission: {{name: step-network, duration: {DURATION_S}, rate: 50, end: hold,"
        " step: network}\n"
        "emulator: {dynamics: ideal, spawn: air}\n"
        "gains: {M: 1, D: 1, k: 9, k_s: 1, k_r: 0.2, alpha: 2, q: 10}\n"
        "leader: {start: [0, 0, 0], force: [0, 0, 0]}\nnetworks:\n"
    )
    for name, starts in (("blue", _STARTS[:6]), ("red", _STARTS[6:])):
        text += f"  - name: {name}\n    vehicles:\n"
        text += "".join(f"      - {{sysid: {i + 1}, start: {s}}}\n" for i, s in enumerate(starts))
    return parse_mission(text)


def _formed(summary: RunSummary) -> None:
    assert summary.outcome == "completed", summary.log[-5:]
    assert len(summary.vehicles) == 12
    radii = np.array([v.radius_m for v in summary.vehicles], dtype=float)
    # 12 s from the starts (1.7-5.7 m out): within 5 % of the sphere (the
    # hand-clock flight is within 0.23 % by then, its closest pair 1.36 m;
    # real time adds the loop's jitter, not a different law).
    np.testing.assert_allclose(radii, SPHERE_M, rtol=0.05)
    assert summary.min_separation_m > 1.0


def _fly_sharded(tmp_path: Path, shards: int) -> tuple[RunSummary, ShardedRun]:
    """The mission on ``shards`` shard processes (the controller here, Zenoh
    on 127.0.0.1), checked to have formed; its summary and its run."""
    runs: list[ShardedRun] = []

    async def fly() -> RunSummary:
        async with asyncio.timeout(120):
            return await run_sharded(_mission(), shards, log_dir=tmp_path, picture=False,
                                     end_timeout_s=5.0, on_run=runs.append)  # fmt: skip

    summary = asyncio.run(fly())
    _formed(summary)
    return summary, runs[0]


def test_two_networks_stepped_each_on_its_own_reports_form_the_sphere(tmp_path: Path) -> None:
    async def fly() -> RunSummary:
        async with asyncio.timeout(90):
            return await run_mission(_mission(), log_dir=tmp_path, picture=False,
                                     end_timeout_s=5.0)  # fmt: skip

    summary = asyncio.run(fly())
    _formed(summary)
    # At least one step a period (steps of both networks at once when their
    # phases fall together): 50 Hz over the mission time.
    assert summary.steps >= 0.9 * 50 * DURATION_S


def test_two_networks_on_two_shards_are_stepped_each_on_its_shard_s_batch(tmp_path: Path) -> None:
    """The same mission with ``--shards 2`` (a shard process per network,
    the controller here, Zenoh on 127.0.0.1): the controller steps each
    shard's batch as it comes (tests/swarm/test_shard_step_per_network.py,
    the rule on the hand clock), never waiting for the other network."""
    summary, run = _fly_sharded(tmp_path, 2)
    # Each shard sends a batch a period: 1,200 over the mission (a batch a
    # real-time shard drops on a congested link is replaced by its next: 1.6
    # per period leaves 20 % for that). The controller steps each as it
    # comes: about a step per batch (measured 1,095 and 1,185 steps of 1,204
    # batches idle, 1,096 and 1,188 beside two busy loops), and
    # on a loaded one a late loop takes the batches already queued behind
    # the first in one step (docs/architecture.md, "A step"), which the
    # machine's load decides. A step of the whole swarm, waiting for the
    # other shard, would answer two batches every time: at most half as many
    # steps as batches (601 with the rule removed); 0.6 of the batches is
    # above that and leaves a loaded machine 80 % of the periods merged.
    b = run.bytes_per_step
    assert b["batches"] >= 1.6 * 50 * DURATION_S, b
    assert summary.steps >= 0.6 * b["batches"], (summary.steps, b)
    # The fallback steps only while a shard's states have not come yet, at the
    # start (measured 0; 5 allows a shard starting 0.1 s late on a loaded
    # machine).
    assert run.core.fallbacks <= 5
    # Each shard's report measures the formation's last WINDOW_S (from the
    # first reply at or past 2 s of mission time: a step later, 0.02 s, on an
    # idle machine; 0.5 s leaves room for a loaded one): every report its
    # six vehicles sent in it (50 Hz) is either answered or counted missed
    # (2 %: a period at either edge), and the latencies are that window's.
    for end in (d["flight_end"] for d in run.done.values()):
        assert DURATION_S - WINDOW_S <= end["from_t_s"] < DURATION_S - WINDOW_S + 0.5
        assert end["missed"] >= 0
        window_s = DURATION_S - end["from_t_s"]
        assert end["setpoints"] + end["missed"] == pytest.approx(6 * 50 * window_s, rel=0.02)
        assert 0.0 < end["p50_ms"] <= end["p99_ms"] <= end["max_ms"]


def test_one_shard_of_both_networks_sends_the_rows_that_changed(tmp_path: Path) -> None:
    """The same mission with ``--shards 1``: one shard process owns both
    networks and sends a state batch at each network's step; once the
    controller has answered it, each batch carries only the rows the
    controller does not hold as they are (``shard_wire.changes``): the
    network that reported, and the other network's vehicles only when their
    reports came since the batch answered. The sphere forms as without it,
    and no batch was dropped for want of its base."""
    summary, run = _fly_sharded(tmp_path, 1)
    assert run.core.unplaced == 0
    b = run.bytes_per_step
    # At least a step a period, as one station (the test above). Two when the
    # networks' reports reach the shard apart, which their emulators' phases
    # (their start times) and the machine's load decide: a shard that reads
    # both networks' reports in one go steps them together (measured 1,195
    # and 1,201 steps idle, 1,188 and 1,201 beside two busy loops, 751 in one
    # fresh-clone CI run beside a busy loop). That it did step them apart is
    # what the bytes below show: batches of one network's rows.
    assert summary.steps >= 0.9 * 50 * DURATION_S, summary.steps
    # A whole batch is 744 bytes, one network's rows 384: measured 385-518 on
    # average (the other network's rows go too when its reports came before
    # the answer). How many go depends on the timing; that some batches went
    # without the other network's rows does not (strictly fewer bytes than
    # whole batches), and the in-process tests hold the rows to the bit.
    whole = HEADER_BYTES + 12 * STATE_BYTES_PER_VEHICLE
    assert HEADER_BYTES * b["batches"] < b["state"] < whole * b["batches"]
