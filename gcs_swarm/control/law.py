"""The complete law: continuous accelerations for a held mode, and the
:class:`SwarmController` that the ground station steps in vehicle time.

``law_accelerations`` is the continuous part (habit 2, "the law is a
function"): for the discrete :class:`~gcs_swarm.control.supervisor.Mode`
held over a step it maps vehicle states to Eq. 1 accelerations:

- formation (Eqs. 11-12): ``f_n = F_n + f_s,n`` around the virtual leader;
- avoidance (Eqs. 27-29): ``f_n = f_n(oa)`` toward the vehicle's slot target
  (Eq. 28), plus Eq. 9's repulsion only if
  ``Readings.repulsion_in_avoidance`` (the paper mode drops it).

:class:`SwarmController` owns the virtual leader (Eq. 13, RK4 sub-steps of at
most ``MAX_LEADER_STEP_S`` over each time jump) and the supervisor; during an
episode the leader is the centroid of the vehicles (Eq. 30), and when the
episode ends Eq. 13 restarts from the centroid's position and velocity.
Accelerations are in the mission frame (x east, y north, z up), m/s^2, BEFORE
any limits or safety filter (the caller applies those).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gcs_swarm.control.fields import avoidance_force, desired_force
from gcs_swarm.control.formation import (
    RowForces,
    eq1_acceleration,
    formation_force,
    repulsion_force,
    repulsion_rows,
    sphere_attraction,
)
from gcs_swarm.control.formation_rows import SMALL_N, formation_accelerations
from gcs_swarm.control.leader import LeaderLaw, LeaderState
from gcs_swarm.control.lookahead import LookaheadJob, LookaheadResult
from gcs_swarm.control.neighbours import NeighbourList
from gcs_swarm.control.obstacles import Ellipsoids
from gcs_swarm.control.params import LawConfig
from gcs_swarm.control.supervisor import Behaviour, Mode, Supervisor, ids_key

__all__ = ["ControlOutput", "SwarmController", "law_accelerations"]

F64 = NDArray[np.float64]


def law_accelerations(
    config: LawConfig,
    mode: Mode,
    pos_m: F64,
    vel_mps: F64,
    charges: F64,
    leader_pos_m: F64,
    obstacles: Ellipsoids,
    rows: NDArray[np.int64] | None = None,
    forces_of: RowForces | None = None,
) -> F64:
    """Eq. 1 accelerations [m/s^2] ``(N, 3)`` of the law for the held ``mode``.

    ``pos_m``/``vel_mps (N, 3)`` mission frame, ``charges (N,)``,
    ``leader_pos_m (3,)`` the virtual leader (used in formation only).

    ``rows`` (indices): only those vehicles' accelerations, ``(R, 3)``, each
    against every vehicle's state (docs/formation-law.md section 3b). In
    formation from ``SMALL_N`` vehicles on, Eqs. 7, 9 (9c) and 1 are taken
    for the rows alone (``formation.repulsion_rows``: equal to the whole
    step's rows to rounding); otherwise the whole step, then its rows.
    ``forces_of``: the rows' Eq. 9c from a neighbour list (``repulsion_rows``).
    """
    g, rd = config.gains, config.readings
    if rows is not None:
        if mode.behaviour != "formation" or pos_m.shape[0] < SMALL_N:
            whole = law_accelerations(config, mode, pos_m, vel_mps, charges, leader_pos_m,
                                      obstacles)  # fmt: skip
            return whole[rows]
        fs = sphere_attraction(pos_m[rows], leader_pos_m, g, rd)
        if rd.eq11_printed:
            fs = -fs
        f = fs + repulsion_rows(pos_m, rows, charges, g.k_r, q_n_twice=rd.eq10_printed,
                                cutoff_m=g.repulsion_cutoff, forces_of=forces_of)  # fmt: skip
        return eq1_acceleration(f, vel_mps[rows], g)
    if mode.behaviour == "formation":
        if pos_m.shape[0] < SMALL_N:  # the same equations in floats (formation_rows.py)
            return formation_accelerations(pos_m, vel_mps, charges, leader_pos_m, g, rd)
        f = formation_force(pos_m, charges, leader_pos_m, g, rd)
    else:
        assert mode.targets_m is not None
        av = config.avoidance
        f_des = desired_force(pos_m, mode.targets_m, av.F_D)
        f = avoidance_force(
            pos_m,
            vel_mps,
            f_des,
            obstacles,
            method=av.method,
            r0=av.r0,
            vertical=mode.vertical,
            sense_h=mode.sense_h,
            sense_v=mode.sense_v,
            printed_eq27=rd.eq27_printed,
            heading_from_velocity=av.heading == "velocity",
        )
        if mode.repulsion:
            f = f + repulsion_force(
                pos_m, charges, g.k_r, q_n_twice=rd.eq10_printed, cutoff_m=g.repulsion_cutoff
            )
    return eq1_acceleration(f, vel_mps, g)


@dataclass(frozen=True)
class ControlOutput:
    """One control step's result.

    ``accel_mps2 (N, 3)`` in ``ids`` order, mission frame, before limits and
    safety; ``behaviour`` "formation" | "avoidance"; ``leader_pos_m``/
    ``leader_vel_mps (3,)``; ``episode`` the number of avoidance episodes
    started so far; ``event`` "start"/"end" when the behaviour switched at
    this step, else None; ``targets_m (N, 3)`` slot targets during avoidance.
    """

    t: float
    ids: tuple[int, ...]
    accel_mps2: F64
    behaviour: Behaviour
    leader_pos_m: F64
    leader_vel_mps: F64
    episode: int
    event: str | None = None
    targets_m: F64 | None = None
    rows: NDArray[np.int64] | None = None
    """Set when the step answered only these rows of ``ids``: ``accel_mps2``
    is then ``(R, 3)``, row k vehicle ``ids[rows[k]]``."""


def as_states(
    ids: Sequence[int],
    pos_m: ArrayLike,
    vel_mps: ArrayLike,
    charges: ArrayLike,
    known: tuple[int, ...] | None = None,
) -> tuple[tuple[int, ...], F64, F64, F64]:
    """Validate and convert one step's inputs; raise ``ValueError`` on a shape
    mismatch, a repeated id or a non-finite value (naming the vehicle id).
    ``known``: ids already found distinct (the last step's): equal ones are
    not searched for repeats again."""
    key = ids_key(ids, known)
    n = len(key)
    p = np.asarray(pos_m, dtype=np.float64).reshape(-1, 3) if n else np.zeros((0, 3))
    v = np.asarray(vel_mps, dtype=np.float64).reshape(-1, 3) if n else np.zeros((0, 3))
    q = np.asarray(charges, dtype=np.float64).reshape(-1) if n else np.zeros(0)
    if p.shape != (n, 3) or v.shape != (n, 3) or q.shape != (n,):
        raise ValueError(
            f"expected {n} ids, positions (N,3), velocities (N,3), charges (N,); "
            f"got {p.shape}, {v.shape}, {q.shape}"
        )
    if key is not known and key != known and len(set(key)) != n:
        raise ValueError(f"vehicle ids repeat: {key}")
    if n < SMALL_N:  # plain floats: cheaper than six numpy calls for a few rows
        # Every value is finite when their sum is (a NaN or an infinity makes it NaN
        # or infinite); a sum that overflows only sends finite values the long way.
        total = sum(p.ravel().tolist()) + sum(v.ravel().tolist()) + sum(q.tolist())
        if math.isfinite(total):
            return key, p, v, q
    elif np.isfinite(p).all() and np.isfinite(v).all() and np.isfinite(q).all():
        return key, p, v, q
    bad = ~(np.isfinite(p).all(axis=1) & np.isfinite(v).all(axis=1) & np.isfinite(q))
    if bad.any():
        raise ValueError(
            f"non-finite state for vehicle ids {[key[j] for j in np.flatnonzero(bad)]}"
        )
    return key, p, v, q


class SwarmController:
    """The formation law with obstacle avoidance, stepped in vehicle time.

    ``step`` may be called at any rate with any ``dt > 0`` (a call with a time
    not after the previous one does not move the leader) and with a different
    set of vehicles each time (join/leave, keyed by stable integer ids).
    With ``defer_lookahead=True`` the plane look-ahead is not run inside
    ``step``: take it from :meth:`pending_lookahead`, run it anywhere and give
    the result to :meth:`resolve_lookahead`.
    """

    def __init__(
        self, config: LawConfig, *, t0: float = 0.0, defer_lookahead: bool = False
    ) -> None:
        self._cfg = config
        self._law = LeaderLaw(config.leader.force, config.gains)
        self._leader = self._law.initial_state(config.leader.start, config.leader.velocity)
        self._t = float(t0)
        self._sup = Supervisor(config, self._law, defer_lookahead=defer_lookahead)
        self._key: tuple[int, ...] | None = None  # the last step's ids (as_states)
        cut = config.gains.repulsion_cutoff
        self._neighbours = None if cut is None else NeighbourList(cut)
        """The candidates of steps of some rows with a cut-off (``neighbours.NeighbourList``)."""

    @property
    def config(self) -> LawConfig:
        """The law's parameters."""
        return self._cfg

    @property
    def time_s(self) -> float:
        """Vehicle time [s] the leader has been advanced to."""
        return self._t

    @property
    def leader_state(self) -> LeaderState:
        """The virtual leader's full state."""
        return self._leader

    @property
    def leader_pos_m(self) -> F64:
        """Virtual leader position [m], mission frame, ``(3,)``."""
        return self._leader.pos_array

    @property
    def leader_vel_mps(self) -> F64:
        """Virtual leader velocity [m/s], mission frame, ``(3,)``."""
        return self._leader.vel_array

    @property
    def behaviour(self) -> Behaviour:
        """``"formation"`` or ``"avoidance"``."""
        return self._sup.behaviour

    @property
    def episode(self) -> int:
        """Number of avoidance episodes started so far."""
        return self._sup.episode_count

    @property
    def obstacles(self) -> Ellipsoids:
        """The mission's obstacles as ellipsoid arrays."""
        return self._sup.obstacles

    def step(
        self,
        t: float,
        ids: Sequence[int],
        pos_m: ArrayLike,
        vel_mps: ArrayLike,
        charges: ArrayLike,
        rows: NDArray[np.int64] | None = None,
    ) -> ControlOutput:
        """Advance the leader to vehicle time ``t`` [s], update the discrete
        logic once from the measured states, and return the law's
        accelerations (``(N, 3)`` in ``ids`` order, m/s^2, mission frame),
        or only those of ``rows`` (``law_accelerations``)."""
        key, p, v, q = as_states(ids, pos_m, vel_mps, charges, self._key)
        self._key = key
        t = float(t)
        if self._sup.behaviour == "formation":
            self._leader = self._law.advance(self._t, self._leader, t)
        self._t = max(self._t, t)
        mode, event = self._sup.update(t, key, p, v, self._leader)
        if (mode.behaviour == "avoidance" or event == "end") and key:
            # Eq. 30: the leader is the centroid; Eq. 13 restarts from it afterwards.
            self._leader = self._law.restart(self._leader, p.mean(axis=0), v.mean(axis=0))
        lead = self.leader_pos_m
        forces_of = None
        if rows is not None and self._neighbours is not None:
            nl = self._neighbours

            def forces_of(
                pos: F64, at: NDArray[np.int64], q: F64, k_r: float, twice: bool, r_min: float
            ) -> F64:
                return nl.row_repulsion(pos, at, key, q, k_r, q_n_twice=twice, r_min_m=r_min)

        accel = law_accelerations(self._cfg, mode, p, v, q, lead, self.obstacles, rows, forces_of)
        return ControlOutput(
            t=t,
            ids=key,
            accel_mps2=accel,
            behaviour=mode.behaviour,
            leader_pos_m=lead,
            leader_vel_mps=self.leader_vel_mps,
            episode=mode.episode,
            event=event,
            targets_m=mode.targets_m,
            rows=rows,
        )

    def closest_pair_m(self, ids: Sequence[int], pos_m: F64) -> float | None:
        """The smallest pairwise distance [m] of ``ids`` at ``pos_m`` from the
        cut-off's neighbour list when it holds it (``NeighbourList.closest``),
        else None."""
        nl = self._neighbours
        return None if nl is None else nl.closest(pos_m, ids_key(ids, self._key))

    def pending_lookahead(self) -> LookaheadJob | None:
        """The next look-ahead job to run (each job is handed over once), or None."""
        return self._sup.pending_lookahead()

    def resolve_lookahead(self, job: LookaheadJob, result: LookaheadResult) -> None:
        """Apply a finished look-ahead (ignored if its episode has ended)."""
        self._sup.resolve_lookahead(job, result)
