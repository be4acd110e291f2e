"""A link shard's half of a step, without I/O (docs/architecture.md, "Scaled
out: shards").

A shard runs a ``SwarmCore`` over its own networks' vehicles: links, codec,
the vehicles' protocols, membership, the telemetry table, its links' states.
When that core wants a step (every one of its flying vehicles fresh, or the
fallback delay: ``SwarmCore._maybe_step``) the shard does not run the law:
``ShardSide.take_state`` takes the fresh reports and the flying vehicles'
mission-frame states (``swarm.step.flying_states``) as a ``StateBatch`` for
the controller, and ``ShardSide.apply`` answers them with the controller's
``SetpointReply`` through the same ``swarm.step.answer`` the one-process
station uses (mission frame -> NED, Eq. V1, one ``SetpointBatch`` per link).

Membership is the shard's own, as in one station: its core holds only its
vehicles' join/leave events (``runtime.plans.shard_config``), readies its
reserves with the others, and runs the events due before each batch is
taken (``SwarmCore.advance_clock_and_events``), at the mission time of its
own clock: ``ControlLoop.advance_clock`` over its own fresh reports, which
in lockstep (every vehicle's report of the same instant) is the
controller's time over all of them. So a vehicle leaving or joining at time
t is out of or in the law at the step it would be in one process. The
controller's time (``SetpointReply.t_s``) only replaces ``control.t_s``, what
the shard's notes say, until the next step; the clock's own state stays
the shard's. The controller sees a leaving vehicle vanish from the batch
(it forgets its clock and shaper) and a joining one appear (mapped afresh,
shaped from hover), as ``ControlLoop`` does in one process.

The controller's silence is watched here too (``controller_silent``): once
nothing has come from it for ``stale_timeout_s`` (``STARTUP_SILENCE_S``
before the formation starts) the shell ends every
vehicle of the shard (``SwarmCore.finish_all``: zero acceleration, then the
end action), as a vehicle's own GCS failsafe would once the shard stopped.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from gcs_swarm.swarm.shard_wire import SetpointReply, StateBatch, changes
from gcs_swarm.swarm.step import Write, answer, flying_states, send_rejoiners

if TYPE_CHECKING:
    from gcs_swarm.swarm.core import SwarmCore

__all__ = ["STARTUP_SILENCE_S", "ShardSide"]

STARTUP_SILENCE_S = 5.0
"""How long a shard waits on a silent controller before the formation has
started [s] (the stale timeout once it flies). Nothing the vehicles do
then depends on the controller, and on a loaded machine a busy controller
process was measured silent for 1 s during start-up (1 run in about 15),
which the 1 s stale timeout turned into a failed start-up."""

FloatArray = npt.NDArray[np.float64]


class ShardSide:
    """Shard ``index``'s step over ``core`` (module docstring). Time is an
    argument [s] (the shell's loop clock)."""

    def __init__(self, core: SwarmCore, index: int, stale_timeout_s: float) -> None:
        self.core = core
        self.index = index
        self.stale_timeout_s = stale_timeout_s
        self.seq = 0
        """The last state batch's number (the reply names the one it used)."""
        self.heard_at: float | None = None
        """When the controller was last heard (None: not yet)."""
        self.replies = 0
        self.states = 0
        self._unanswered: deque[StateBatch] = deque()
        """The state batches sent after the last one answered, whole: a reply
        answers its batch's vehicles from the velocities that batch carried
        (Eq. V1 starts there)."""
        self._answered: StateBatch | None = None
        """The last batch the controller answered, whole: it holds it (or a
        later one), so the next batch need carry only what changed since
        (``shard_wire.changes``)."""
        self.rows_sent = 0
        self.rows_flying = 0
        """Rows the state batches carried, and the flying vehicles they stood for."""

    def take_state(self, now: float) -> StateBatch | None:
        """The step the core wants, as the controller's input: None while
        ending. Once the controller has answered a batch of the same
        vehicles as every batch sent since, only the rows that changed since
        that batch (``shard_wire.changes``; the controller lays them over it,
        ``shard_wire.expand``); the whole batch otherwise."""
        core = self.core
        fresh = core.take_step()
        if fresh is None:
            return None
        # The step's mission time on the shard's own clock, and its events: a
        # vehicle leaving or joining now is out of, or in, this batch.
        core.advance_clock_and_events(fresh, now)
        batch = self._batch(now, fresh)
        self.states += 1
        self._unanswered.append(batch)
        base = self._answered
        if base is not None and all(
            b.keys is base.keys or np.array_equal(b.keys, base.keys) for b in self._unanswered
        ):
            sent = changes(batch, base)
        else:  # nothing answered yet, or a vehicle joined or left since: every row
            sent = batch
        self.rows_sent += len(sent.keys)
        self.rows_flying += len(batch.keys)
        return sent

    def opening(self, now: float) -> StateBatch:
        """The flying vehicles' states as the formation starts, none of them a
        fresh report (nothing to answer): sent before the first step, so the
        controller knows every shard's vehicles from its first step on (with
        ``step: network`` it steps the first network's batch at once, with
        the others' states: ``swarm.controller``)."""
        return self._batch(now, {})

    def _batch(self, now: float, fresh: dict[int, int]) -> StateBatch:
        core = self.core
        # The flying vehicles' order, rows and keys change only on a join or a
        # leave (FlyingOrder, as a station's step reads them); a batch is taken
        # once per network and period, at 1,500 vehicles six times a period.
        order = core.order
        order.update(core.flying, core.table)
        ids = order.ids
        if ids:
            _, pos, vel = flying_states(core, ids, now, order.ks)
        else:
            pos, vel = np.zeros((0, 3)), np.zeros((0, 3))
        boot_ms = np.full(len(ids), -1, dtype=np.int64)
        index = order.index
        for key, ms in fresh.items():
            row = index.get(key)
            if row is not None:  # a fresh report of a vehicle that left since is not sent
                boot_ms[row] = ms
        self.seq += 1
        return StateBatch(self.index, self.seq, order.keys, boot_ms, pos, vel)

    def apply(self, reply: SetpointReply, now: float, write: Write) -> None:
        """The controller's setpoints for this shard, handed to ``write`` link
        by link; a vehicle that left the formation since is skipped."""
        self.heard(now)
        batch = None
        waiting = self._unanswered
        while waiting and waiting[0].seq <= reply.seq:  # answered, or its reply lost
            older = waiting.popleft()
            if older.seq == reply.seq:
                batch = self._answered = older
        core = self.core
        if core.ending or not len(reply.keys) or batch is None or not len(batch.keys):
            return
        self.replies += 1
        # The mission time the shard's notes give until its next step. Its own
        # clock (advance_clock's offsets and milliseconds) is not touched: the
        # events run on that, as in one process (module docstring).
        core.control.t_s = reply.t_s
        # Each key's row in its batch (sorted keys); one that left since is skipped.
        at = np.minimum(np.searchsorted(batch.keys, reply.keys), len(batch.keys) - 1)
        there = (batch.keys[at] == reply.keys).tolist()
        flying, keys = core.flying, reply.keys.tolist()
        rows = [i for i, s in enumerate(keys) if there[i] and s in flying]
        if not rows:
            return
        ids = [keys[i] for i in rows]
        whole = len(rows) == len(keys)
        accel = reply.accel_mps2 if whole else reply.accel_mps2[rows]
        vel = batch.vel_mps[at if whole else at[rows]]
        answer(core, ids, core.table.slots(ids), accel, now, reply.t_s, vel, write)

    def in_flight(self) -> int:
        """Fresh reports in the state batches sent after the last one the
        controller answered: their setpoints on their way (at the mission's
        end, never sent). A batch whose reply was lost is not counted once a
        later one is answered."""
        return sum(int(np.count_nonzero(b.boot_ms >= 0)) for b in self._unanswered)

    def leader_at(
        self,
        leader_m: FloatArray,
        leader_vel: FloatArray | None = None,
        radius_m: float | None = None,
    ) -> None:
        """The controller's leader is at ``leader_m`` [m], moving at
        ``leader_vel`` [m/s], its farthest member ``radius_m`` [m] from it (its
        beats, 10 a second, also while this shard has nobody flying): members
        being readied again fly to their rejoin point beside it, as in one
        station (``swarm.step.send_rejoiners``), not to their mission start."""
        if self.core.started and not self.core.ending:
            send_rejoiners(self.core, leader_m, leader_vel, radius_m)

    def heard(self, now: float) -> None:
        """Something came from the controller at ``now``."""
        self.heard_at = now

    def silence_s(self) -> float:
        """How long the controller may say nothing [s]: the stale timeout in
        flight, at least ``STARTUP_SILENCE_S`` before the formation starts."""
        if self.core.started:  # the formation flies: its setpoints come from the controller
            return self.stale_timeout_s
        return max(self.stale_timeout_s, STARTUP_SILENCE_S)

    def get_timer(self) -> float | None:
        """When the controller's silence would reach ``silence_s`` [s]."""
        return None if self.heard_at is None else self.heard_at + self.silence_s()

    def controller_silent(self, now: float) -> bool:
        """The controller has said nothing for ``silence_s`` at ``now``."""
        due = self.get_timer()
        return due is not None and now >= due
