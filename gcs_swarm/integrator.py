"""The in-process integrator (``integrate``): the law on ideal point masses (or
the envelope's vehicle model), deterministic, no MAVLink; the reference the
MAVLink closed loop is compared against. A mission file reaches it through
``gcs_swarm.offline`` (``gcs-swarm simulate``, ``gcs_swarm.simulate``).

Fixed-step classical RK4 of Eq. 1 for every active vehicle AND of the virtual
leader (Eq. 13) jointly: the leader's position inside each RK4 stage is the
stage's own. The discrete logic (behaviour supervisor, latched senses,
waypoint switch) is evaluated once at the start of each step and held within
it. During an avoidance episode the leader is the centroid (Eq. 30) and is
not integrated.

Join/leave events ``(time_s, "join" | "leave", vehicle_id)`` apply at the
first step whose time is >= ``time_s``. A vehicle that leaves is held where it
is, at rest; one that joins starts from its held state (its start position if
it never flew). Inactive vehicles are recorded as NaN. ``on_out`` is told,
at the first step and every step where the set changes, where the inactive
vehicles are held and which of them have flown (the station keeps its
members out of where such vehicles may be, Eq. K1).

An optional ``accel_filter(t, ids, pos, vel, accel) -> accel`` (limits, safety
filter) is applied to the law's output in every RK4 stage; the default is the
identity, i.e. the paper's law exactly.

Vehicle envelope (``vehicle=``, docs/vehicle-envelope.md): instead of the
ideal point mass, each vehicle is the model of an ArduCopter position
controller taking acceleration targets: the command is held over the step
(the station's zero-order hold, one ``accel_filter`` call per step, so ``dt``
is the control period), the vehicle moves its own acceleration target towards
it at most by its jerk (``control.envelope.jerk_limit``, ArduCopter's
shape_accel), and its acceleration follows that target with a first-order
lag ``lag_s`` (``vehicle_step``, exact for a held input). The leader keeps
its RK4. Without ``vehicle`` nothing changes.

Pure computation apart from :meth:`SimResult.save` (CSV or NPZ).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gcs_swarm.analysis import FormationFigures, formation_figures
from gcs_swarm.control.envelope import jerk_limit
from gcs_swarm.control.fields import avoidance_force, desired_force
from gcs_swarm.control.formation import eq1_acceleration
from gcs_swarm.control.law import law_accelerations
from gcs_swarm.control.leader import LeaderLaw, LeaderState
from gcs_swarm.control.lookahead import entry_senses
from gcs_swarm.control.obstacles import Ellipsoids, rho
from gcs_swarm.control.params import Avoidance, Box, Envelope, Gains, LawConfig, Readings
from gcs_swarm.control.supervisor import Mode, Supervisor

__all__ = [
    "AccelFilter",
    "SimResult",
    "VehicleRun",
    "integrate",
    "integrate_vehicle",
    "vehicle_step",
]

F64 = NDArray[np.float64]
#: ``(t_s, ids, pos_m (N,3), vel_mps (N,3), accel_mps2 (N,3)) -> accel_mps2 (N,3)``
AccelFilter = Callable[[float, tuple[int, ...], F64, F64, F64], F64]


@dataclass(frozen=True)
class SimResult:
    """Trajectories sampled at every step, mission frame.

    ``times_s (T,)``; ``ids (N,)``; ``charges (N,)``; ``pos_m``/``vel_mps``/
    ``accel_mps2 (T, N, 3)`` (NaN where inactive; the acceleration is the
    (filtered) command at the sample time); ``active (T, N)``;
    ``leader_pos_m``/``leader_vel_mps (T, 3)``; ``behaviour (T,)`` strings;
    ``episode (T,)`` episodes started so far; ``switches`` the behaviour
    transitions ``(t_s, "start" | "end")``; ``config`` the law's parameters.
    """

    config: LawConfig
    times_s: F64
    ids: NDArray[np.int64]
    charges: F64
    pos_m: F64
    vel_mps: F64
    accel_mps2: F64
    active: NDArray[np.bool_]
    leader_pos_m: F64
    leader_vel_mps: F64
    behaviour: NDArray[np.str_]
    episode: NDArray[np.int64]
    switches: tuple[tuple[float, str], ...]

    def figures(self, *, form_tol: float = 0.01) -> FormationFigures:
        """Figures of the run (``gcs_swarm.analysis.formation_figures``)."""
        return formation_figures(
            self.times_s,
            self.pos_m,
            self.leader_pos_m,
            self.config.obstacles,
            episodes=int(self.episode[-1]) if len(self.episode) else 0,
            form_tol=form_tol,
        )

    def save(self, path: str | Path, *, every: int = 1) -> Path:
        """Write the trajectories to ``path``: ``.npz`` (all arrays) or ``.csv``
        (one row per sample and active vehicle: ``t_s, id, x_m, y_m, z_m,
        vx_mps, vy_mps, vz_mps, ax_mps2, ay_mps2, az_mps2, leader_x_m,
        leader_y_m, leader_z_m, behaviour, episode``), every ``every``-th sample."""
        out = Path(path)
        sel = slice(None, None, max(1, int(every)))
        suffix = out.suffix.lower()
        if suffix == ".npz":
            np.savez_compressed(
                out,
                times_s=self.times_s[sel],
                ids=self.ids,
                charges=self.charges,
                pos_m=self.pos_m[sel],
                vel_mps=self.vel_mps[sel],
                accel_mps2=self.accel_mps2[sel],
                active=self.active[sel],
                leader_pos_m=self.leader_pos_m[sel],
                leader_vel_mps=self.leader_vel_mps[sel],
                behaviour=self.behaviour[sel],
                episode=self.episode[sel],
            )
            return out
        if suffix != ".csv":
            raise ValueError(f"{out}: trajectory files are .csv or .npz, got {suffix!r}")
        header = (
            "t_s,id,x_m,y_m,z_m,vx_mps,vy_mps,vz_mps,ax_mps2,ay_mps2,az_mps2,"
            "leader_x_m,leader_y_m,leader_z_m,behaviour,episode"
        )
        lines = [header]
        times, act = self.times_s[sel], self.active[sel]
        pos, vel, acc = self.pos_m[sel], self.vel_mps[sel], self.accel_mps2[sel]
        lead, beh, epi = self.leader_pos_m[sel], self.behaviour[sel], self.episode[sel]
        for i in range(len(times)):
            lx, ly, lz = (f"{c:.9g}" for c in lead[i])
            for j in np.flatnonzero(act[i]):
                nums = ",".join(f"{c:.9g}" for c in (*pos[i, j], *vel[i, j], *acc[i, j]))
                lines.append(
                    f"{times[i]:.9g},{self.ids[j]},{nums},{lx},{ly},{lz},{beh[i]},{epi[i]}"
                )
        out.write_text("\n".join(lines) + "\n", encoding="utf-8")
        return out


def integrate(
    config: LawConfig,
    starts: Sequence[Sequence[float]] | ArrayLike,
    charges: Sequence[float] | ArrayLike | None = None,
    *,
    duration: float,
    dt: float = 0.01,
    active: Sequence[bool] | None = None,
    events: Sequence[tuple[float, str, int]] = (),
    ids: Sequence[int] | None = None,
    accel_filter: AccelFilter | None = None,
    t0: float = 0.0,
    start_vel_mps: ArrayLike | None = None,
    vehicle: Envelope | None = None,
    on_out: Callable[[dict[int, F64], set[int]], None] | None = None,
) -> SimResult:
    """Integrate the swarm under the law for ``duration`` [s] with step ``dt`` [s].

    ``starts (N, 3)`` [m] initial positions (at rest unless ``start_vel_mps``),
    ``charges (N,)`` (default ``config.gains.q_default``), ``active`` initial
    flags (default all), ``ids`` stable vehicle ids (default 1..N), ``events``
    join/leave as described in the module docstring. ``vehicle``: integrate
    that envelope's jerk-limited, lagged vehicle with the command held over
    each step ``dt`` (module docstring) instead of the point mass.
    ``on_out(held, flown)``: where each inactive vehicle is held [m], by id,
    and the ids of those that have flown, whenever that set changes (module
    docstring).
    """
    p_all = np.array(starts, dtype=np.float64).reshape(-1, 3)
    m = p_all.shape[0]
    v_all = (
        np.zeros((m, 3))
        if start_vel_mps is None
        else np.array(start_vel_mps, dtype=np.float64).reshape(m, 3)
    )
    q_all = (
        np.full(m, config.gains.q_default)
        if charges is None
        else np.array(charges, dtype=np.float64).reshape(m)
    )
    vid = np.arange(1, m + 1, dtype=np.int64) if ids is None else np.array(ids, dtype=np.int64)
    if vid.shape != (m,) or len(set(vid.tolist())) != m:
        raise ValueError(f"ids must be {m} distinct integers, got {ids}")
    act = np.ones(m, dtype=bool) if active is None else np.array(active, dtype=bool).reshape(m)
    if not (dt > 0.0 and duration >= 0.0):
        raise ValueError(f"need dt > 0 and duration >= 0, got dt={dt}, duration={duration}")
    index = {int(v): j for j, v in enumerate(vid)}
    pending = sorted(events, key=lambda e: float(e[0]))
    for _, kind, who in pending:
        if kind not in ("join", "leave") or int(who) not in index:
            raise ValueError(f"bad event ({kind!r}, {who!r}): kinds are join/leave of known ids")
    filt: AccelFilter = accel_filter if accel_filter is not None else _identity

    law = LeaderLaw(config.leader.force, config.gains)
    leader = law.initial_state(config.leader.start, config.leader.velocity)
    sup = Supervisor(config, law, defer_lookahead=False)
    obs = sup.obstacles
    steps = round(duration / dt)
    n_t = steps + 1
    times: F64 = t0 + dt * np.arange(n_t, dtype=np.float64)
    rec_p = np.full((n_t, m, 3), np.nan)
    rec_v = np.full((n_t, m, 3), np.nan)
    rec_a = np.full((n_t, m, 3), np.nan)
    rec_act = np.zeros((n_t, m), dtype=bool)
    rec_lp = np.empty((n_t, 3))
    rec_lv = np.empty((n_t, 3))
    rec_beh = np.empty(n_t, dtype="<U9")
    rec_ep = np.zeros(n_t, dtype=np.int64)
    switches: list[tuple[float, str]] = []
    ev = 0
    model = vehicle
    tgt_all = np.zeros((m, 3))  # the vehicle's own (jerk-limited) acceleration target
    act_all = np.zeros((m, 3))  # its achieved (lagged) acceleration

    flown = act.copy()  # vehicles that have flown: one out of these is held in the air
    for k in range(n_t):
        t = float(times[k])
        changed = k == 0
        while ev < len(pending) and float(pending[ev][0]) <= t + 1e-9 * dt:
            _, kind, who = pending[ev]
            j = index[int(who)]
            act[j] = kind == "join"
            flown[j] |= act[j]
            v_all[j] = 0.0  # held at rest while out; rejoins from rest
            tgt_all[j] = act_all[j] = 0.0
            ev += 1
            changed = True
        if changed and on_out is not None:
            out = np.flatnonzero(~act)
            on_out({int(vid[j]): p_all[j].copy() for j in out},
                   {int(vid[j]) for j in out if flown[j]})  # fmt: skip
        idx = np.flatnonzero(act)
        key = tuple(int(vid[j]) for j in idx)
        p, v, q = p_all[idx], v_all[idx], q_all[idx]
        mode, event = sup.update(t, key, p, v, leader)
        if event is not None:
            switches.append((t, event))
        if (mode.behaviour == "avoidance" or event == "end") and key:
            leader = law.restart(leader, p.mean(axis=0), v.mean(axis=0))
        rhs = _Rhs(config, mode, key, q, obs, filt, law, leader.wp_index)
        lp0, lv0 = leader.pos_array, leader.vel_array
        a1, la1 = rhs(t, p, v, lp0, lv0)
        rec_p[k, idx], rec_v[k, idx], rec_a[k, idx] = p, v, a1
        rec_act[k, idx] = True
        rec_lp[k], rec_lv[k] = lp0, lv0
        rec_beh[k], rec_ep[k] = mode.behaviour, mode.episode
        if k == steps:
            break
        if model is not None:
            p_all[idx], v_all[idx], tgt_all[idx], act_all[idx] = vehicle_step(
                p, v, tgt_all[idx], act_all[idx], a1, model, dt
            )
            if mode.behaviour == "formation":
                leader = _leader_rk4(rhs, t, dt, lp0, lv0, la1, law, leader)
            continue
        h, hh = dt, 0.5 * dt
        p2, v2, lp2, lv2 = p + hh * v, v + hh * a1, lp0 + hh * lv0, lv0 + hh * la1
        a2, la2 = rhs(t + hh, p2, v2, lp2, lv2)
        p3, v3, lp3, lv3 = p + hh * v2, v + hh * a2, lp0 + hh * lv2, lv0 + hh * la2
        a3, la3 = rhs(t + hh, p3, v3, lp3, lv3)
        p4, v4, lp4, lv4 = p + h * v3, v + h * a3, lp0 + h * lv3, lv0 + h * la3
        a4, la4 = rhs(t + h, p4, v4, lp4, lv4)
        h6 = h / 6.0
        p_all[idx] = p + h6 * (v + 2.0 * v2 + 2.0 * v3 + v4)
        v_all[idx] = v + h6 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        if mode.behaviour == "formation":
            lp_new = lp0 + h6 * (lv0 + 2.0 * lv2 + 2.0 * lv3 + lv4)
            lv_new = lv0 + h6 * (la1 + 2.0 * la2 + 2.0 * la3 + la4)
            leader = law.restart(leader, lp_new, lv_new)  # keeps and switches the waypoint

    return SimResult(
        config=config,
        times_s=times,
        ids=vid,
        charges=q_all,
        pos_m=rec_p,
        vel_mps=rec_v,
        accel_mps2=rec_a,
        active=rec_act,
        leader_pos_m=rec_lp,
        leader_vel_mps=rec_lv,
        behaviour=rec_beh,
        episode=rec_ep,
        switches=tuple(switches),
    )


@dataclass(frozen=True)
class _Rhs:
    """Right-hand side of one step: the law with the mode held, plus Eq. 13."""

    config: LawConfig
    mode: Mode
    key: tuple[int, ...]
    charges: F64
    obs: Ellipsoids
    filt: AccelFilter
    law: LeaderLaw
    wp_index: int

    def __call__(self, t: float, p: F64, v: F64, lp: F64, lv: F64) -> tuple[F64, F64]:
        a = law_accelerations(self.config, self.mode, p, v, self.charges, lp, self.obs)
        a = self.filt(t, self.key, p, v, a)
        return a, self.leader(t, lp, lv)

    def leader(self, t: float, lp: F64, lv: F64) -> F64:
        """Eq. 13's acceleration [m/s^2] (zero in avoidance: the leader is the
        centroid, Eq. 30)."""
        if self.mode.behaviour == "avoidance":
            return np.zeros(3)
        lpt = (float(lp[0]), float(lp[1]), float(lp[2]))
        lvt = (float(lv[0]), float(lv[1]), float(lv[2]))
        return np.array(self.law.accel(t, lpt, lvt, self.wp_index))


def _leader_rk4(
    rhs: _Rhs, t: float, dt: float, lp0: F64, lv0: F64, la1: F64, law: LeaderLaw,
    leader: LeaderState,
) -> LeaderState:  # fmt: skip
    """One RK4 step of Eq. 13 alone (the vehicle-model path), as in ``integrate``."""
    hh = 0.5 * dt
    lp2, lv2 = lp0 + hh * lv0, lv0 + hh * la1
    la2 = rhs.leader(t + hh, lp2, lv2)
    lp3, lv3 = lp0 + hh * lv2, lv0 + hh * la2
    la3 = rhs.leader(t + hh, lp3, lv3)
    lp4, lv4 = lp0 + dt * lv3, lv0 + dt * la3
    la4 = rhs.leader(t + dt, lp4, lv4)
    h6 = dt / 6.0
    lp_new = lp0 + h6 * (lv0 + 2.0 * lv2 + 2.0 * lv3 + lv4)
    lv_new = lv0 + h6 * (la1 + 2.0 * la2 + 2.0 * la3 + la4)
    return law.restart(leader, lp_new, lv_new)


def vehicle_step(
    pos_m: F64,
    vel_mps: F64,
    target_mps2: F64,
    accel_mps2: F64,
    command_mps2: F64,
    envelope: Envelope,
    dt: float,
) -> tuple[F64, F64, F64, F64]:
    """One step ``dt`` [s] of the envelope's vehicle, all arrays (N, 3), mission frame.

    The vehicle's acceleration target moves towards the held ``command`` by at
    most its jerk (``jerk_limit``); the achieved acceleration ``a`` follows the
    target ``u`` with the first-order lag tau = ``lag_s``, exactly for a held
    input: a(t) = u + (a0 - u) e^(-t/tau), integrated twice in closed form
    (tau = 0: a = u at once). Returns (pos, vel, target, accel) after the step.
    """
    u = jerk_limit(target_mps2, command_mps2, envelope, dt)
    tau = envelope.lag_s
    if tau > 0.0:
        e = np.exp(-dt / tau)
        da = accel_mps2 - u
        vel = vel_mps + u * dt + da * tau * (1.0 - e)
        pos = pos_m + vel_mps * dt + 0.5 * u * dt * dt + da * tau * (dt - tau * (1.0 - e))
        acc = u + da * e
    else:
        vel = vel_mps + u * dt
        pos = pos_m + vel_mps * dt + 0.5 * u * dt * dt
        acc = u.copy()
    return pos, vel, u, acc


@dataclass(frozen=True)
class VehicleRun:
    """One vehicle's trajectory: ``times_s (T,)``, ``pos_m``/``vel_mps (T, 3)``."""

    times_s: F64
    pos_m: F64
    vel_mps: F64


def integrate_vehicle(
    start_m: Sequence[float],
    boxes: Sequence[Box],
    *,
    duration: float,
    dt: float = 0.01,
    desired_force_n: Sequence[float] | None = None,
    target_m: Sequence[float] | None = None,
    avoidance: Avoidance | None = None,
    gains: Gains | None = None,
    readings: Readings | None = None,
    vertical: bool = False,
) -> VehicleRun:
    """A lone vehicle avoiding ``boxes`` (the paper's Example 2 / Scenario 1):
    Eq. 1 driven by Eq. 27 with either a constant desired force
    ``desired_force_n`` [N] or Eq. 28 toward ``target_m`` (size
    ``avoidance.F_D``). Fixed-step RK4; the sense is latched at field entry
    (or forced by ``avoidance.sense``) once per step; the plane is horizontal
    unless ``vertical``. Starts at rest."""
    av = avoidance if avoidance is not None else Avoidance()
    g = gains if gains is not None else Gains()
    rd = readings if readings is not None else Readings()
    if (desired_force_n is None) == (target_m is None):
        raise ValueError("give exactly one of desired_force_n and target_m")
    obs = Ellipsoids.from_boxes(boxes)
    steps = round(duration / dt)
    times: F64 = dt * np.arange(steps + 1, dtype=np.float64)
    pos = np.empty((steps + 1, 3))
    vel = np.empty((steps + 1, 3))
    p = np.array([start_m], dtype=np.float64).reshape(1, 3)
    v = np.zeros((1, 3))
    tgt = None if target_m is None else np.array([target_m], dtype=np.float64).reshape(1, 3)
    const = None if desired_force_n is None else np.array([desired_force_n], dtype=np.float64)
    vert = np.full((1, obs.count), vertical)
    latched = np.zeros((1, obs.count), dtype=bool)
    sh, sv = np.ones((1, obs.count)), np.ones((1, obs.count))

    def f_des(pp: F64) -> F64:
        if const is not None:
            return const
        assert tgt is not None
        return desired_force(pp, tgt, av.F_D)

    def accel(pp: F64, vv: F64) -> F64:
        f = avoidance_force(
            pp,
            vv,
            f_des(pp),
            obs,
            method=av.method,
            r0=av.r0,
            vertical=vert,
            sense_h=sh,
            sense_v=sv,
            printed_eq27=rd.eq27_printed,
            heading_from_velocity=av.heading == "velocity",
        )
        return eq1_acceleration(f, vv, g)

    for k in range(steps + 1):
        pos[k], vel[k] = p[0], v[0]
        if k == steps:
            break
        new_sh, new_sv = entry_senses(p, v, f_des(p), obs, av)
        sh = np.where(latched, sh, new_sh)
        sv = np.where(latched, sv, new_sv)
        latched = rho(p, obs) <= av.r0
        hh = 0.5 * dt
        a1 = accel(p, v)
        v2 = v + hh * a1
        a2 = accel(p + hh * v, v2)
        v3 = v + hh * a2
        a3 = accel(p + hh * v2, v3)
        v4 = v + dt * a3
        a4 = accel(p + dt * v3, v4)
        p = p + (dt / 6.0) * (v + 2.0 * v2 + 2.0 * v3 + v4)
        v = v + (dt / 6.0) * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    return VehicleRun(times, pos, vel)


def _identity(t: float, ids: tuple[int, ...], pos: F64, vel: F64, accel: F64) -> F64:
    return accel
