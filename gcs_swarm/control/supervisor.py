"""The behaviour supervisor (Eqs. 29-30): the law's discrete logic.

Evaluated once per control step (or integration step) and held within it; it
returns a frozen :class:`Mode` that the continuous law reads. Per vehicle it
keys everything by the vehicle's stable integer id, so latched senses, planes
and slot targets follow the right vehicle when vehicles join or leave.

- Episodes (formation-law.md s8): an avoidance episode starts when
  ``rho_min = min over vehicles and obstacles of rho <= r0`` and ends when
  ``rho_min > r0``. Being a latched state, it does not chatter like a purely
  state-based switch inside the field. The episode's end leaves the last
  vehicle on the field's boundary, and the re-forming formation can dip back
  in; so that one pass is one episode, every obstacle entered during the
  episode is then "passed": it re-arms once every vehicle is beyond
  ``rho > r0 + target_margin``, and until then it starts a new episode only if
  a vehicle reaches ``rho <= PASSED_TRIGGER_RHO`` (its minimum-volume
  ellipsoid, i.e. about to touch the box).
- READING (targets): at the switch the leader's obstacle-free path is
  predicted with Eq. 13 (fixed-step RK4, :data:`TARGET_DT_S`). The episode
  point is the first predicted point that is "beyond the obstacle" (the
  path's ellipsoidal radius to every obstacle in range is no longer
  decreasing) at which every slot target ``point + (p_n - centroid)`` has
  ``rho >= r0 + target_margin`` for every obstacle. If none is found within
  :data:`TARGET_HORIZON_S` (or the leader is at rest), the last predicted
  point's slots are pushed radially out to the ``rho = r0 + target_margin``
  level set of each obstacle. A vehicle that joins during an episode gets
  the slot ``point + (p - centroid now)``.
- Senses are latched at the first update that finds a vehicle inside an
  obstacle's field (rho <= r0) and released when it is found outside. A
  vehicle that crosses into the field within a step keeps its previous sense
  until the next update; the field's gain is zero at rho = r0, so this only
  concerns a sliver of the field for one step.
- Plane (``Avoidance.plane == "auto"``): when an obstacle's field is first
  entered in an episode, a :class:`~gcs_swarm.control.lookahead.LookaheadJob`
  picks the plane per vehicle; until it is resolved the horizontal plane is
  used. It runs at once, or is handed to the caller when deferred.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from gcs_swarm.control.fields import desired_force
from gcs_swarm.control.leader import LeaderLaw, LeaderState
from gcs_swarm.control.lookahead import LookaheadJob, LookaheadResult, entry_senses
from gcs_swarm.control.obstacles import Ellipsoids, rho
from gcs_swarm.control.params import LawConfig

__all__ = [
    "PASSED_TRIGGER_RHO",
    "TARGET_DT_S",
    "TARGET_HORIZON_S",
    "Behaviour",
    "Mode",
    "Supervisor",
    "ids_key",
]

F64 = NDArray[np.float64]
Behaviour = Literal["formation", "avoidance"]

#: A passed obstacle (see the module docstring) starts a new episode before it
#: is re-armed only if a vehicle reaches its minimum-volume ellipsoid.
PASSED_TRIGGER_RHO = 1.0
#: RK4 step [s] of the leader's predicted path used for slot targets.
TARGET_DT_S = 0.1
#: Longest predicted leader path [s] searched for slot targets.
TARGET_HORIZON_S = 300.0
_CHUNK_STEPS = 100


@dataclass(frozen=True)
class Mode:
    """The discrete state held for one step, arrays in ``ids`` order.

    ``targets_m (N, 3)`` slot targets [m] (avoidance only, else None);
    ``vertical (N, K)`` plane per vehicle and obstacle; ``sense_h``/``sense_v
    (N, K)`` +1 cw/up, -1 ccw/down; ``repulsion`` whether Eq. 9 is applied.
    """

    behaviour: Behaviour
    episode: int
    ids: tuple[int, ...]
    targets_m: F64 | None
    vertical: NDArray[np.bool_]
    sense_h: F64
    sense_v: F64
    repulsion: bool

    @classmethod
    def formation(cls, ids: tuple[int, ...]) -> Mode:
        """Formation behaviour for ``ids`` with no obstacle (K = 0): what the
        supervisor holds for a swarm that meets none, episode 0, Eq. 9 on."""
        n = len(ids)
        return cls(
            behaviour="formation",
            episode=0,
            ids=ids,
            targets_m=None,
            vertical=np.zeros((n, 0), dtype=bool),
            sense_h=np.ones((n, 0)),
            sense_v=np.ones((n, 0)),
            repulsion=True,
        )


@dataclass
class _Vehicle:
    latched: NDArray[np.bool_]
    sense_h: F64
    sense_v: F64
    vertical: NDArray[np.bool_]
    target_m: F64 | None = None


@dataclass
class _Episode:
    number: int
    point_m: F64
    entered: NDArray[np.bool_]
    planned: set[int] = field(default_factory=set)


def ids_key(ids: Sequence[int], known: tuple[int, ...] | None = None) -> tuple[int, ...]:
    """A step's vehicle ids as a tuple of ints: ``known`` itself when ``ids``
    is that very tuple, ``ids`` itself when it is a tuple of ints already,
    else ``tuple(map(int, ids))``. A step per network reads all N ids several
    times a period; handed on as one tuple they are neither copied nor
    compared item by item."""
    if ids is known and known is not None:
        return known
    if type(ids) is tuple and all(type(x) is int for x in ids):
        return ids
    return tuple(map(int, ids))


class Supervisor:
    """Behaviour switch, slot targets, latched senses and planes (Eqs. 29-30)."""

    def __init__(self, config: LawConfig, leader_law: LeaderLaw, *, defer_lookahead: bool) -> None:
        self._cfg = config
        self._law = leader_law
        self._obs = Ellipsoids.from_boxes(config.obstacles)
        self._defer = defer_lookahead
        self._vehicles: dict[int, _Vehicle] = {}
        self._ids: tuple[int, ...] | None = None
        """The last step's ids (``ids_key``), the vehicles ``_vehicles`` holds."""
        self._episode: _Episode | None = None
        self._count = 0
        self._pending: list[LookaheadJob] = []
        self._active = config.avoidance.method != "none" and self._obs.count > 0
        self._passed = np.zeros(self._obs.count, dtype=bool)
        self._idle: Mode | None = None
        """The mode of the last step while avoidance is off (``_active`` False):
        it depends only on the ids then, so a step with the same ids reuses it."""

    @property
    def obstacles(self) -> Ellipsoids:
        """The obstacles as ellipsoid arrays (Eqs. 14-17)."""
        return self._obs

    @property
    def behaviour(self) -> Behaviour:
        """``"formation"`` or ``"avoidance"``."""
        return "avoidance" if self._episode is not None else "formation"

    @property
    def episode_count(self) -> int:
        """Number of avoidance episodes started so far."""
        return self._count

    def pending_lookahead(self) -> LookaheadJob | None:
        """Hand over the oldest look-ahead job not yet handed over (each job once)."""
        return self._pending.pop(0) if self._pending else None

    def resolve_lookahead(self, job: LookaheadJob, result: LookaheadResult) -> None:
        """Apply a look-ahead's plane choice; ignored if its episode is over."""
        ep = self._episode
        if ep is None or ep.number != job.episode:
            return
        for vid, vert in zip(result.ids, result.vertical, strict=True):
            veh = self._vehicles.get(vid)
            if veh is not None:
                veh.vertical[job.obstacle] = bool(vert)

    def update(
        self,
        t: float,
        ids: Sequence[int],
        pos_m: F64,
        vel_mps: F64,
        leader: LeaderState,
    ) -> tuple[Mode, str | None]:
        """The discrete step at time ``t`` [s]: returns the held :class:`Mode` and
        the transition (``"start"``, ``"end"`` or None)."""
        av = self._cfg.avoidance
        key = ids_key(ids, self._ids)
        n, k = len(key), self._obs.count
        if key is not self._ids:  # the same tuple as the last step's: the same vehicles
            self._sync_vehicles(key)
            self._ids = key
        event: str | None = None
        if not self._active:
            idle = self._idle
            if idle is None or idle.ids != key:
                idle = self._idle = self._mode(key, None, np.zeros((n, k), dtype=bool))
            return idle, None
        r = rho(pos_m, self._obs) if n else np.zeros((0, k))
        inside = r <= av.r0
        rho_k = r.min(axis=0) if n else np.full(k, math.inf)  # (K,) closest vehicle
        rho_min = float(rho_k.min())
        self._passed &= ~(rho_k > av.r0 + av.target_margin)  # re-arm passed obstacles
        trigger = np.where(self._passed, rho_k <= PASSED_TRIGGER_RHO, rho_k <= av.r0)
        if self._episode is None and trigger.any():
            self._start_episode(t, key, pos_m, leader, inside | trigger[None, :])
            event = "start"
        elif self._episode is not None and rho_min > av.r0:
            self._passed |= self._episode.entered
            self._episode = None
            self._pending.clear()  # stale look-aheads of the finished episode
            for veh in self._vehicles.values():
                veh.target_m = None
                veh.vertical[:] = av.plane == "vertical"
            event = "end"
        targets = None
        if self._episode is not None:
            ep = self._episode
            ep.entered |= inside.any(axis=0)
            centroid = pos_m.mean(axis=0)
            targets = np.empty((n, 3))
            for j, vid in enumerate(key):
                veh = self._vehicles[vid]
                if veh.target_m is None:  # joined during the episode
                    veh.target_m = ep.point_m + (pos_m[j] - centroid)
                targets[j] = veh.target_m
            self._plan_planes(ep, key, pos_m, vel_mps, targets, inside)
        f_des = desired_force(pos_m, targets, av.F_D) if targets is not None else np.zeros((n, 3))
        self._latch(key, pos_m, vel_mps, f_des, inside)
        return self._mode(key, targets, inside), event

    # -- internals -------------------------------------------------------------

    def _sync_vehicles(self, key: tuple[int, ...]) -> None:
        k = self._obs.count
        vertical = self._cfg.avoidance.plane == "vertical"
        members = set(key)  # a set: this runs every step for every vehicle
        if self._vehicles.keys() == members:
            return
        for vid in self._vehicles.keys() - members:
            del self._vehicles[vid]
        for vid in key:
            if vid not in self._vehicles:
                self._vehicles[vid] = _Vehicle(
                    latched=np.zeros(k, dtype=bool),
                    sense_h=np.ones(k),
                    sense_v=np.ones(k),
                    vertical=np.full(k, vertical),
                )

    def _latch(
        self,
        key: tuple[int, ...],
        pos_m: F64,
        vel_mps: F64,
        f_des: F64,
        inside: NDArray[np.bool_],
    ) -> None:
        if not key:
            return
        latched = np.array([self._vehicles[vid].latched for vid in key]).reshape(inside.shape)
        entering = inside & ~latched
        rows = np.flatnonzero(entering.any(axis=1))
        if rows.size:
            sh, sv = entry_senses(
                pos_m[rows], vel_mps[rows], f_des[rows], self._obs, self._cfg.avoidance
            )
            for i, row in enumerate(rows.tolist()):
                veh = self._vehicles[key[row]]
                new = entering[row]
                veh.sense_h[new] = sh[i, new]
                veh.sense_v[new] = sv[i, new]
        for j, vid in enumerate(key):
            self._vehicles[vid].latched = inside[j].copy()

    def _mode(self, key: tuple[int, ...], targets: F64 | None, inside: NDArray[np.bool_]) -> Mode:
        n, k = len(key), self._obs.count
        if n and k:  # one stacking call per array, not one row copy per vehicle
            vehs = [self._vehicles[vid] for vid in key]
            vert = np.array([veh.vertical for veh in vehs], dtype=bool)
            sh = np.array([veh.sense_h for veh in vehs], dtype=np.float64)
            sv = np.array([veh.sense_v for veh in vehs], dtype=np.float64)
        else:
            vert = np.zeros((n, k), dtype=bool)
            sh = np.ones((n, k))
            sv = np.ones((n, k))
        avoiding = self._episode is not None
        return Mode(
            behaviour="avoidance" if avoiding else "formation",
            episode=self._count,
            ids=key,
            targets_m=targets,
            vertical=vert,
            sense_h=sh,
            sense_v=sv,
            repulsion=(not avoiding) or self._cfg.readings.repulsion_in_avoidance,
        )

    def _start_episode(
        self,
        t: float,
        key: tuple[int, ...],
        pos_m: F64,
        leader: LeaderState,
        inside: NDArray[np.bool_],
    ) -> None:
        self._count += 1
        trig = np.flatnonzero(inside.any(axis=0))
        centroid = pos_m.mean(axis=0)
        offsets = pos_m - centroid
        point, targets = self.slot_targets(t, leader, offsets, trig)
        for j, vid in enumerate(key):
            self._vehicles[vid].target_m = targets[j].copy()
        self._episode = _Episode(self._count, point, np.any(inside, axis=0, keepdims=False))

    def slot_targets(
        self, t: float, leader: LeaderState, offsets_m: F64, trigger: NDArray[np.intp]
    ) -> tuple[F64, F64]:
        """READING (targets): the episode point [m] on the leader's predicted path
        and the slot targets ``point + offsets_m`` ``(N, 3)`` (module docstring)."""
        av = self._cfg.avoidance
        clear = av.r0 + av.target_margin
        state, tt = leader, t
        prev = rho(np.asarray([state.pos_m], dtype=np.float64), self._obs)[0, trigger]
        n_chunks = max(1, math.ceil(TARGET_HORIZON_S / (TARGET_DT_S * _CHUNK_STEPS)))
        # READING (time scale): the leader's path is lambda times slower, so its
        # prediction's step and horizon are lambda times longer (same points).
        step = TARGET_DT_S * self._cfg.gains.time_scale
        for _ in range(n_chunks):
            times, pts, state = self._law.predict(tt, state, step, _CHUNK_STEPS)
            cand = pts[1:]
            rl = rho(cand, self._obs)
            rt = rl[:, trigger]
            before = np.vstack([prev[None, :], rt[:-1]])
            receding = np.all(rt >= before - 1e-12, axis=1)
            slots = (cand[:, None, :] + offsets_m[None, :, :]).reshape(-1, 3)
            ok_slots = rho(slots, self._obs) >= clear
            ok = receding & ok_slots.reshape(len(cand), -1).all(axis=1)
            if ok.any():
                i = int(np.argmax(ok))
                return cand[i].copy(), cand[i] + offsets_m
            prev, tt = rt[-1], float(times[-1])
            if float(np.linalg.norm(pts[-1] - pts[0])) < 1e-6:
                break  # the leader is at rest: waiting longer finds nothing new
        point = np.asarray(state.pos_m, dtype=np.float64)
        return point, self._push_out(point + offsets_m, clear)

    def _push_out(self, targets: F64, clear: float) -> F64:
        """Fallback: move each target radially out to ``rho = clear`` of every
        obstacle whose level set it lies inside."""
        out = targets.copy()
        for kk in range(self._obs.count):
            c = self._obs.centres_m[kk]
            coeff = self._obs.coeffs_per_m[kk]
            d = out - c
            r = np.sqrt(np.sum((d * coeff) ** 2, axis=1))
            low = r < clear
            at_centre = low & (r <= 1e-9)
            d[at_centre] = (0.0, 0.0, 1.0 / coeff[2])
            r = np.where(at_centre, 1.0, r)
            out[low] = c + d[low] * (clear / r[low])[:, None]
        return out

    def _plan_planes(
        self,
        ep: _Episode,
        key: tuple[int, ...],
        pos_m: F64,
        vel_mps: F64,
        targets: F64,
        inside: NDArray[np.bool_],
    ) -> None:
        av = self._cfg.avoidance
        if av.method != "rotational" or av.plane != "auto":
            return
        for kk in np.flatnonzero(inside.any(axis=0)):
            obstacle = int(kk)
            if obstacle in ep.planned:
                continue
            ep.planned.add(obstacle)
            job = LookaheadJob(
                episode=ep.number,
                obstacle=obstacle,
                ids=key,
                pos_m=pos_m.copy(),
                vel_mps=vel_mps.copy(),
                targets_m=targets.copy(),
                obstacle_set=self._obs.subset(obstacle),
                gains=self._cfg.gains,
                avoidance=av,
                readings=self._cfg.readings,
            )
            if self._defer:
                self._pending.append(job)
            else:
                self.resolve_lookahead(job, job())
