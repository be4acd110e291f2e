"""A shard's state batch as the rows that changed (``shard_wire.changes``)
and the controller's whole batch back from it (``shard_wire.expand``), on
numbers alone; whole flights through them are
tests/swarm/test_shard_step_per_network.py and test_shard_split.py (bit for
bit against one station)."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from swarm_harness import mission_from

from gcs_swarm.swarm.controller import ControllerCore
from gcs_swarm.swarm.shard_wire import (
    HEADER_BYTES,
    STATE_BYTES_PER_VEHICLE,
    StateBatch,
    changes,
    decode_state,
    encode_state,
    expand,
)

_KEYS = np.array([1, 2, 3, 257, 258, 513], dtype=np.int32)


def _whole(seq: int, rng: np.random.Generator, fresh: list[int] = ()) -> StateBatch:
    n = len(_KEYS)
    ms = np.full(n, -1, dtype=np.int64)
    ms[list(fresh)] = 1000 + seq
    return StateBatch(0, seq, _KEYS, ms, rng.normal(size=(n, 3)) * 50, rng.normal(size=(n, 3)))


def _same(a: StateBatch, b: StateBatch) -> bool:
    return (
        a[:2] == b[:2] and a.base == b.base and a.keys.tolist() == b.keys.tolist()
        and a.boot_ms.tolist() == b.boot_ms.tolist()
        and a.pos_m.tobytes() == b.pos_m.tobytes() and a.vel_mps.tobytes() == b.vel_mps.tobytes()
    )  # fmt: skip


def test_changes_carry_the_rows_whose_bits_moved_and_expand_gives_the_whole_batch() -> None:
    rng = np.random.default_rng(7)
    held = _whole(4, rng)
    held.pos_m[1, 2] = np.nan
    held.vel_mps[2, 0] = 0.0
    now = StateBatch(0, 6, _KEYS, held.boot_ms.copy(), held.pos_m.copy(), held.vel_mps.copy())
    now.boot_ms[3] = 2220  # fresh, its numbers as they were: still sent (the step answers it)
    now.pos_m[0, 1] += 1e-12  # the last bit moved
    now.vel_mps[2, 0] = -0.0  # equal as a float, not as bits
    now.pos_m[4, 0] = np.nan  # a number to NaN; row 1's NaN kept as it was: not sent
    sent = changes(now, held)
    assert sent.keys.tolist() == [1, 3, 257, 258] and sent.base == 4 and sent.seq == 6
    assert sent.boot_ms.tolist() == [-1, -1, 2220, -1]
    back = decode_state(encode_state(sent))
    assert len(encode_state(sent)) == HEADER_BYTES + 4 * STATE_BYTES_PER_VEHICLE
    assert _same(back, sent)
    whole = expand(back, held)
    assert whole is not None and whole.base == -1
    assert _same(whole, now._replace(base=-1))
    assert np.signbit(whole.vel_mps[2, 0])


def test_a_whole_batch_crosses_with_base_minus_one_and_expands_to_itself() -> None:
    batch = _whole(3, np.random.default_rng(1), fresh=[0, 5])
    back = decode_state(encode_state(batch))
    assert back.base == -1 and _same(back, batch)
    assert expand(back, None) is back


@pytest.mark.parametrize(
    "held_seq, keys, why",
    [
        (None, [1, 3], "no batch held"),
        (3, [1, 3], "held older than the base"),
        (9, [1, 3], "held not older than the batch"),
        (5, [1, 4], "a vehicle not held"),
        (5, [1, 999], "past the last vehicle held"),
    ],
)
def test_changes_without_their_base_cannot_be_expanded(
    held_seq: int | None, keys: list[int], why: str
) -> None:
    rng = np.random.default_rng(3)
    held = None if held_seq is None else _whole(held_seq, rng)
    n = len(keys)
    batch = StateBatch(0, 9, np.array(keys, dtype=np.int32), np.full(n, 1009, dtype=np.int64),
                       np.zeros((n, 3)), np.zeros((n, 3)), base=4)  # fmt: skip
    assert expand(batch, held) is None, why


def test_the_controller_counts_and_drops_changes_it_cannot_place(
    caplog: pytest.LogCaptureFixture,
) -> None:
    rng = np.random.default_rng(5)
    law = mission_from("example1_tetrahedron.yaml", duration=10.0).law
    ctl = ControllerCore(law, {int(k): 1.0 for k in _KEYS}, 50.0, shards=1, duration_s=10.0,
                         stale_timeout_s=1.0, lockstep=True, step_per_network=True)  # fmt: skip
    ctl.start(0.0, {0: len(_KEYS)})
    first = _whole(1, rng, fresh=list(range(len(_KEYS))))
    ctl.receive_state(first, 0.0)
    assert ctl.step_wanted
    (reply,) = ctl.control_step(0.0)
    assert reply.seq == 1 and len(reply.keys) == len(_KEYS)
    later = _whole(3, rng, fresh=[1])
    with caplog.at_level(logging.WARNING, logger="gcs_swarm.controller"):
        ctl.receive_state(changes(later, _whole(2, rng)), 0.02)  # its base, 2, never came
        ctl.receive_state(changes(later, _whole(2, rng))._replace(seq=4), 0.04)
    assert ctl.unplaced == 2 and not ctl.step_wanted
    assert sum("not the one held" in r.message for r in caplog.records) == 1
    ctl.receive_state(changes(later, first), 0.06)  # on the batch it holds: stepped
    assert ctl.unplaced == 2 and ctl.step_wanted
    (reply,) = ctl.control_step(0.06)
    assert reply.seq == 3 and reply.keys.tolist() == [2]
