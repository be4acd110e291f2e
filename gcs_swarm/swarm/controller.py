"""The controller of a sharded station, without I/O (docs/architecture.md,
"Scaled out: shards").

The link shards (``swarm.shard``) own the vehicles; the controller owns the
law: one ``ControlLoop`` (the leader in vehicle time, the law, the safety
filter, the shaper: ``control/loop.py``) over every shard's flying vehicles.
Driven like ``SwarmCore`` (STYLE.md habit 1): ``receive_state(batch, now)``
and ``heard(shard, now)`` as messages arrive, ``handle_timer(now)`` at
``get_timer()``, ``control_step(now)`` when ``step_wanted``; it returns one
``SetpointReply`` per shard that delivered.

- a step is wanted when every live shard with flying vehicles has delivered
  a state batch since the last step, or a fallback delay after the first one
  (0.5 s in lockstep, a period in real time: longer than a shard's own 0.2 s
  and half period): ``SwarmCore``'s rule, one level up. The law gets every
  live shard's latest states (a shard that has
  not delivered this step counts with its last ones, as a vehicle's stale
  table row does), the mission clock advances on the union of the fresh
  reports (``ControlLoop.advance_clock``), and each shard is answered for
  its fresh vehicles only;
- with ``step_per_network`` (the mission's ``step: network``) a state batch
  is stepped as it comes, once every live shard with flying vehicles has
  sent its states (until then a batch waits, at most the fallback delay;
  each shard's opening batch, ``ShardSide.opening``, gives them at the
  start, so the law has every shard's vehicles from its first step): each
  shard's core already delivers one per network whose reports are all in
  (``SwarmCore.take_step``); the law commands only that batch's fresh
  vehicles against every other shard's latest states
  (``ControlLoop.command``'s rows: formation-law.md section 3b, as one
  station's step of a network) and only that shard is answered, so no
  shard waits for another's phase (a shard's own fallback sends what it
  has when one of its vehicles is late);
- a shard silent (no state batch, no heartbeat) for ``stale_timeout_s`` is
  dead: its vehicles leave the formation (the law gets the rest, which
  re-form: formation-law.md s9) and are never waited for again; each is
  kept out of as a column (Eq. K1: its last state, then its failsafe
  brings it down) for the rest of the run. A vehicle a shard stops
  reporting (lost, failed, ended) leaves the same way; the columns of the
  vehicles a live shard calls lost come with its heartbeats (``heard``),
  until it hears them again;
- the mission ends at its duration, when the law fails (``failure``), or
  when every shard is dead.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from gcs_swarm.control.lookahead import LookaheadJob, LookaheadResult
from gcs_swarm.control.loop import ControlLoop
from gcs_swarm.control.params import Box, Envelope, LawConfig
from gcs_swarm.mavlink.states import ProtocolConfig
from gcs_swarm.swarm.departures import column, describe
from gcs_swarm.swarm.shard_wire import SetpointReply, StateBatch, expand
from gcs_swarm.swarm.step import command, resolve_lookahead

if TYPE_CHECKING:
    from gcs_swarm.report.record import FlightRecorder

__all__ = ["ControllerCore", "ShardView"]

_log = logging.getLogger("gcs_swarm.controller")


def _rows_of(
    ids: npt.NDArray[np.int64], keys: Mapping[int, int]
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.intp]]:
    """Those of ``keys`` that are in ``ids`` (sorted, unique), in key order,
    and their rows in ``ids``: one ``searchsorted`` for a network's 250
    fresh vehicles instead of a dict lookup each."""
    want = np.fromiter(keys, dtype=np.int64, count=len(keys))
    want.sort()
    at = np.searchsorted(ids, want)
    inside = at < len(ids)
    found = inside.copy()
    found[inside] = ids[at[inside]] == want[inside]
    return want[found], at[found]


@dataclass
class ShardView:
    """What the controller knows of one shard."""

    index: int
    alive: bool = True
    heard_at: float | None = None
    flying: int = 0
    """Its flying vehicles, as its last state batch or heartbeat said."""
    batch: StateBatch | None = None
    """Its latest state batch (the law's input for its vehicles)."""
    fresh: dict[int, int] = field(default_factory=dict)
    """Fresh reports delivered since the last step (key -> time_boot_ms)."""
    delivered: bool = False
    died_at: float | None = None
    kept: set[int] = field(default_factory=set)
    """Its vehicles whose keep-out columns it sent (lost, unheard)."""
    live: dict[int, Box] = field(default_factory=dict)
    """The columns of its vehicles out of the formation, heard and in the air."""


class ControllerCore:
    """The law over ``shards`` link shards (module docstring). Time is an
    argument [s]; ``charges`` by vehicle key."""

    def __init__(
        self,
        law: LawConfig,
        charges: Mapping[int, float],
        rate_hz: float,
        *,
        shards: int,
        duration_s: float,
        stale_timeout_s: float,
        lockstep: bool,
        recorder: FlightRecorder | None = None,
        departures: Mapping[int, tuple[float, bool]] | None = None,
        labels: Mapping[int, str] | None = None,
        step_per_network: bool = False,
    ) -> None:
        """``recorder`` (a run with a folder) gets every step of the law and
        every vehicle that comes into or goes out of it, as one station's
        (``SwarmCore``) does; its annotations go to the controller's log.
        ``departures``: Eq. K1's (coast [s], climbs) per vehicle key
        (``departures.departure_terms``), for the columns of a dead shard's
        vehicles; a key not named coasts ``ProtocolConfig.guid_timeout_s``.
        ``labels``: how the log names each key (``blue:7``; default the key).
        ``step_per_network``: a step per state batch (module docstring)."""
        self.departures = dict(departures or {})
        self.labels = dict(labels or {})
        # The plane look-ahead as one station runs it: in real time off the step
        # (``lookahead``, ``resolve_lookahead``); in lockstep inline at its step,
        # where the emulators wait for it and the run stays repeatable.
        self.control = ControlLoop(law, charges, rate_hz, defer=not lockstep)
        self.lookahead: list[LookaheadJob] = []
        """Plane look-aheads to run off the step; the shell empties it."""
        self.rate_hz = rate_hz
        self.duration_s = duration_s
        self.stale_timeout_s = stale_timeout_s
        self.lockstep = lockstep
        self.step_per_network = step_per_network
        self.recorder = recorder
        self.shards = {i: ShardView(i) for i in range(shards)}
        self.started = False
        self.finished = False
        self.failure: str | None = None
        self.step_wanted = False
        self.timer_moved = False
        self.log: deque[str] = deque(maxlen=2000)
        self._keys = np.zeros(0, dtype=np.int64)
        """The last step's batches' keys, as they came (``_order``)."""
        self._ids: tuple[int, ...] = ()
        self._sort = np.zeros(0, dtype=np.intp)
        self._sorted = np.zeros(0, dtype=np.int64)
        """``_ids`` as an array (each key's row: ``_rows_of``)."""
        self._flown: tuple[int, ...] = ()
        """The vehicles the law flew at the last step (``flying``)."""
        self.fallbacks = 0
        """Steps taken on the fallback delay, without every shard's states."""
        self.unplaced = 0
        """State batches of changes dropped for want of their base (``receive_state``)."""
        self._fallback_at: float | None = None

    @property
    def flying(self) -> list[int]:
        """The vehicles the law flew at the last step (keys, sorted)."""
        return list(self._flown)

    # ------------------------------------------------------------ inbound
    def heard(
        self,
        shard: int,
        now: float,
        flying: int | None = None,
        keep_out: Mapping[int, Box] | None = None,
        live: Mapping[int, Box] | None = None,
    ) -> None:
        """Shard ``shard`` said something at ``now`` (a heartbeat: with its
        flying count once it flies, the keep-out columns of its vehicles it
        calls lost, and those of its vehicles out of the formation, heard and
        in the air, by key)."""
        view = self.shards.get(shard)
        if view is None or not view.alive:
            return
        view.heard_at = now
        if keep_out is not None:
            self._keep(view, keep_out)
        if live is not None:
            self._live(view, live)
        if flying is not None:
            view.flying = flying
            self._maybe_step(now)

    def receive_state(self, batch: StateBatch, now: float) -> None:
        """A shard's state batch (a dead shard's is ignored: it stays out).
        One without a fresh report (``ShardSide.opening``) only gives its
        vehicles' states: nothing of it to answer (with a step per network,
        the last states a delivered batch waited for). A batch of changes
        is laid over the shard's last one (``shard_wire.expand``); one that
        cannot be (its base not held: out of order, or another run's) is
        counted in ``unplaced`` and dropped."""
        view = self.shards.get(batch.shard)
        if view is None or not view.alive:
            return
        view.heard_at = now
        whole = expand(batch, view.batch)
        if whole is None:
            self.unplaced += 1
            if self.unplaced == 1:
                self.note(f"shard {batch.shard}: state batch {batch.seq} updates batch "
                          f"{batch.base}, which is not the one held; dropped (counted in "
                          "unplaced)", level=logging.WARNING)  # fmt: skip
            return
        batch = whole
        view.batch = batch
        view.flying = len(batch.keys)
        fresh = batch.fresh()
        if fresh:
            view.fresh.update(fresh)
            view.delivered = True
        self._maybe_step(now)

    # ------------------------------------------------------------- timers
    def start(self, now: float, flying: Mapping[int, int]) -> None:
        """The formation starts at ``now``: each shard flies ``flying[i]``
        vehicles (its initial members) and counts as heard."""
        self.started = True
        for view in self.shards.values():
            view.heard_at = now
            view.flying = flying.get(view.index, 0)
        self.timer_moved = True

    def get_timer(self) -> float | None:
        """The earliest time [s] ``handle_timer`` has something to do."""
        times = [] if self._fallback_at is None else [self._fallback_at]
        if self.started and not self.finished:
            times += [v.heard_at + self.stale_timeout_s for v in self.shards.values()
                      if v.alive and v.heard_at is not None]  # fmt: skip
        return min(times) if times else None

    def handle_timer(self, now: float) -> None:
        """The step's fallback, and the shards silent for the stale timeout."""
        if self._fallback_at is not None and self._fallback_at <= now:
            self._fallback_at = None
            self.step_wanted = True
            self.fallbacks += 1
        if not self.started or self.finished:
            return
        for view in self.shards.values():
            if view.alive and view.heard_at is not None:
                if now - view.heard_at >= self.stale_timeout_s:
                    self._dead(view, now)
        if not any(v.alive for v in self.shards.values()):
            self.note("every shard is silent; ending", level=logging.WARNING)
            self.finished = True
        self._maybe_step(now)
        self.timer_moved = True

    def _keep(self, view: ShardView, boxes: Mapping[int, Box]) -> None:
        """A live shard's keep-out columns now: new ones kept, gone ones released."""
        control = self.control
        for key in sorted(view.kept - boxes.keys()):
            if control.release(key):
                self.note(f"vehicle {self.labels.get(key, key)} heard again: the others no "
                          "longer keep out of its column")  # fmt: skip
        sep = control.config.safety.separation
        for key in sorted(boxes.keys() - view.kept):  # a lost vehicle's column is fixed
            self.note(describe(str(self.labels.get(key, key)), boxes[key], sep),
                      level=logging.WARNING)  # fmt: skip
            control.keep_out_of(key, boxes[key])
        view.kept = set(boxes)

    def _live(self, view: ShardView, boxes: Mapping[int, Box]) -> None:
        """A live shard's columns of its heard vehicles out of the formation now."""
        sep = self.control.config.safety.separation
        for key in sorted(boxes.keys() - view.live.keys()):
            label = str(self.labels.get(key, key))
            self.note(describe(label, boxes[key], sep, heard=True), level=logging.WARNING)
        view.live = dict(boxes)
        self._merge_live()

    def _merge_live(self) -> None:
        """The law's live columns: every live shard's."""
        merged = {k: b for v in self.shards.values() if v.alive for k, b in v.live.items()}
        self.control.set_live_keep_out(merged)

    def _dead(self, view: ShardView, now: float) -> None:
        view.alive = False
        view.died_at = now
        gone = [] if view.batch is None else view.batch.keys.tolist()
        silent = 0.0 if view.heard_at is None else now - view.heard_at
        self.note(f"t={self.control.t_s:.2f} s: shard {view.index} silent for {silent:.2f} s: "
                  f"dead; its {len(gone)} vehicles leave the formation",
                  level=logging.WARNING)  # fmt: skip
        if gone and not self.control.config.safety.enabled:
            self.note(f"shard {view.index}'s vehicles left unheard with the safety filter "
                      "off: nothing keeps the others out from under them",
                      level=logging.WARNING)  # fmt: skip
        elif view.batch is not None:
            # Unheard from now on, in the air: each a column (Eq. K1) for the rest of the run.
            last = self.control.last
            sent = {} if last is None else dict(zip(last.ids, last.accel_mps2, strict=True))
            b = view.batch
            for k, key in enumerate(gone):
                terms = self.departures.get(key, (ProtocolConfig.guid_timeout_s, False))
                box = column(
                    self.control, b.pos_m[k], b.vel_mps[k], sent.get(key, np.zeros(3)), terms
                )
                self.control.keep_out_of(key, box)
            if gone:
                self.note(f"the others keep {self.control.config.safety.separation:g} m from "
                          f"the columns of shard {view.index}'s {len(gone)} vehicles (Eq. K1)",
                          level=logging.WARNING)  # fmt: skip
        view.batch, view.fresh, view.delivered, view.flying = None, {}, False, 0
        if view.live:  # its heard ones out of the formation: unheard now, columns where last seen
            for key, box in view.live.items():
                self.control.keep_out_of(key, box)
            view.live = {}
            self._merge_live()

    # --------------------------------------------------------- control step
    def _maybe_step(self, now: float) -> None:
        if not self.started or self.finished:
            return
        live = [v for v in self.shards.values() if v.alive]
        if not any(v.delivered for v in live):
            return
        if all(v.delivered or v.flying == 0 for v in live):
            self.step_wanted = True
        elif self.step_per_network and all(v.batch is not None or v.flying == 0 for v in live):
            self.step_wanted = True  # a step per batch, once every shard's states are in
        elif self._fallback_at is None:
            # Longer than a shard's own fallback (SwarmCore._maybe_step: 0.2 s in
            # lockstep, half a period in real time), so that a shard missing a
            # report still delivers its partial batch before the controller moves on.
            wait = 0.5 if self.lockstep else 1.0 / self.rate_hz
            self._fallback_at = now + wait
            self.timer_moved = True

    def set_envelope(self, envelope: Envelope) -> Envelope:
        """Plan and shape within the tightest of the shards' envelopes
        (``SwarmCore.apply_envelope`` of each); returns the one in force."""
        inforce = self.control.set_envelope(envelope)
        if inforce.bounded:
            self.note(f"envelope in force: {inforce.describe()}")
        return inforce

    def control_step(self, now: float) -> list[SetpointReply]:
        """One step of the law over every live shard's flying vehicles (with
        ``step_per_network``, commanding the fresh ones); the replies to the
        shards that delivered (empty while finished)."""
        self.step_wanted = False
        self._fallback_at = None
        if self.finished:
            return []
        live = [v for v in self.shards.values() if v.alive and v.batch is not None]
        fresh: dict[int, int] = {}
        for v in live:
            fresh.update(v.fresh)
        batches = [v.batch for v in live if v.batch is not None and len(v.batch.keys)]
        if batches:
            ids, order, keys = self._order(np.concatenate([b.keys for b in batches]))
            pos = np.concatenate([b.pos_m for b in batches])[order]
            vel = np.concatenate([b.vel_mps for b in batches])[order]
        else:
            ids, keys, pos, vel = (), self._sorted, np.zeros((0, 3)), np.zeros((0, 3))
        self._membership(ids)
        t = self.control.advance_clock(fresh)
        replies: list[SetpointReply] = []
        if ids:
            # Each delivering shard's fresh vehicles the law flies (key order)
            # and their rows; together they are ``fresh``'s (the others' are empty).
            theirs = {v.index: _rows_of(keys, v.fresh) for v in live if v.delivered}
            rows = None  # every vehicle commanded
            if self.step_per_network and theirs:  # the fresh ones only, when not every one
                some = np.sort(np.concatenate([at for _, at in theirs.values()]))
                if len(some) < len(ids):
                    rows = some
            commanded = command(self, ids, pos, vel, t, fresh.keys(), rows)
            if commanded is None:
                return []
            out, accel, report = commanded
            self.control.account(ids, pos, out, accel, report)
            job = self.control.pending_lookahead()
            if job is not None:
                self.lookahead.append(job)
            for v in live:
                if v.index not in theirs:
                    continue
                mine, at = theirs[v.index]
                idx = at if rows is None else np.searchsorted(rows, at)  # their accel rows
                replies.append(SetpointReply(v.index, v.batch.seq if v.batch else 0, t,
                                             mine.astype(np.int32), accel[idx]))  # fmt: skip
        for v in live:
            v.fresh, v.delivered = {}, False
        if t >= self.duration_s:
            self.note(f"mission time {t:.2f} s reached the duration")
            self.finished = True
        return replies

    def _order(
        self, keys: npt.NDArray[np.int32]
    ) -> tuple[tuple[int, ...], npt.NDArray[np.intp], npt.NDArray[np.int64]]:
        """The law's vehicles in key order from the batches' ``keys`` as they
        came: (keys sorted, the order that sorts them, the sorted keys as an
        array). The same keys as the last step's give the same objects back:
        a step per network reads all N several times a period, and the law
        knows its ids tuple at once (``supervisor.ids_key``)."""
        if not np.array_equal(keys, self._keys):
            self._keys = keys.astype(np.int64)
            self._sort = np.argsort(self._keys, kind="stable")
            self._sorted = self._keys[self._sort]
            self._ids = tuple(self._sorted.tolist())
        return self._ids, self._sort, self._sorted

    def _membership(self, ids: tuple[int, ...]) -> None:
        """The law's vehicles this step: those no shard reports any more
        (lost, ended, or of a dead shard) leave it, with their clock and
        shaper forgotten (they start afresh if they come back); new ones
        come in. Both told to the recorder at the mission time they were
        last flown at (``SwarmCore``'s ``_join`` and leaving do so)."""
        if ids is self._flown:
            return  # the same vehicles as the last step (the usual case)
        before, now_in = set(self._flown), set(ids)
        for gone in sorted(before - now_in):
            self.control.forget(gone)
            if self.recorder is not None:
                self.recorder.member(self.control.t_s, gone, False)
        if self.recorder is not None:
            for key in sorted(now_in - before):
                self.recorder.member(self.control.t_s, key, True)
        self._flown = ids

    def end(self) -> None:
        """The run ends: no more steps, and every vehicle still in the law
        leaves it (told to the recorder, as one station's ending does)."""
        self.finished = True
        self._membership(())

    def abort(self, why: str) -> None:
        """End the mission now, as failed (the shell brakes every vehicle)."""
        if self.failure is None:
            self.failure = why
            self.note(f"{why}; ending the mission (failed)", level=logging.ERROR)
        self.finished = True

    def dead_shards(self) -> list[int]:
        return [v.index for v in self.shards.values() if not v.alive]

    def resolve_lookahead(self, job: LookaheadJob, result: LookaheadResult, took_s: float) -> None:
        """A look-ahead's ``result``, computed off the step in ``took_s`` [s]."""
        self.note(resolve_lookahead(self.control, job, result, took_s))

    def note(self, text: str, *, level: int = logging.INFO) -> None:
        _log.log(level, "%s", text)
        self.log.append(text)
