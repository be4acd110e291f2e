"""``BiasBank`` (control/velocity_bias.py) against the readable reference: a
``VelocityBiasObserver`` per vehicle fed every report by ``update``. Random
telemetry with every kind of report the observer branches on (gaps, reboots,
duplicates, jumps, steps a few units in 1e-16 from ``jump_m``, checkpoints,
estimates at their cap), fed to the bank as arrays, one report at a time, or
mixed, and rows detached and attached again: the same floats, the same
window, the same counters."""

from __future__ import annotations

import gc
import math
import random

import numpy as np
import pytest

from gcs_swarm.control.velocity_bias import BiasBank, BiasSettings, VelocityBiasObserver


def _f32(x: float) -> float:
    return float(np.float32(x))


class _Vehicle:
    """Reports of one vehicle: a wandering velocity, reported ``bias`` off,
    and now and then a gap, a reboot, a duplicate or a position jump."""

    def __init__(self, rng: random.Random, jump_m: float) -> None:
        self.rng = rng
        self.jump_m = jump_m
        self.t_ms = rng.randrange(10**6)
        self.p = [rng.uniform(-50, 50) for _ in range(3)]
        self.v = [0.0, 0.0, 0.0]
        self.bias = [rng.uniform(-0.2, 0.2) for _ in range(3)]
        self.last: tuple[float, ...] | None = None

    def report(self) -> tuple[float, ...]:
        rng = self.rng
        kind = rng.randrange(100)
        if kind == 0 and self.last is not None:
            return self.last  # a duplicate (dt = 0)
        dt_ms = rng.choice([20, 20, 20, 10, 40])
        if kind == 1:
            dt_ms = 700  # a gap
        elif kind == 2:
            self.t_ms = max(0, self.t_ms - 30_000)  # a reboot
        self.t_ms += dt_ms
        dt = dt_ms * 1e-3
        self.v = [c + rng.uniform(-0.3, 0.3) for c in self.v]
        self.p = [p + v * dt for p, v in zip(self.p, self.v, strict=True)]
        if kind == 3:
            self.p[rng.randrange(3)] += rng.choice([-2.0, 2.0]) * self.jump_m
        vel = [_f32(v + b) for v, b in zip(self.v, self.bias, strict=True)]
        pos = [_f32(p) for p in self.p]
        if kind == 4 and self.last is not None:
            # An unexplained step of jump_m as near as float32 positions allow.
            lt, lx, ly, lz, lvx, lvy, lvz = self.last
            t = self.t_ms * 1e-3
            ix = 0.5 * (vel[0] + lvx) * (t - lt)
            pos[0] = _f32(lx + ix + self.jump_m)
            pos[1] = _f32(ly + 0.5 * (vel[1] + lvy) * (t - lt))
            pos[2] = _f32(lz + 0.5 * (vel[2] + lvz) * (t - lt))
        self.last = (self.t_ms * 1e-3, *pos, *vel)
        return self.last


def _same(bank: BiasBank, k: int, ref: VelocityBiasObserver) -> None:
    obs = bank.sync(k)
    assert obs is not None
    assert obs.bias == ref.bias and obs.saturated == ref.saturated
    assert obs.resets == ref.resets and obs.samples == ref.samples
    assert obs._last == ref._last and obs._sum == ref._sum
    assert list(obs._checkpoints) == list(ref._checkpoints)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_bank_gives_each_observers_floats(seed: int) -> None:
    rng = random.Random(seed)
    n = 40
    settings = [
        BiasSettings(window_s=rng.choice([1.0, 2.0, 10.0]), min_span_s=0.3,
                     max_mps=rng.choice([0.05, 0.3]), jump_m=rng.choice([0.2, 1.0]))
        for _ in range(n)
    ]  # fmt: skip
    vehicles = [_Vehicle(random.Random(seed * 1000 + k), settings[k].jump_m) for k in range(n)]
    refs = [VelocityBiasObserver(s) for s in settings]
    bank = BiasBank(n)
    for k in range(n):
        bank.attach(k, VelocityBiasObserver(settings[k]))
    estimates = saturated = resets = 0
    for _ in range(1500):
        rows = sorted(rng.sample(range(n), rng.randrange(1, n + 1)))
        reports = [vehicles[k].report() for k in rows]
        for k, r in zip(rows, reports, strict=True):
            refs[k].update(*r)
        if rng.random() < 0.1:  # one at a time (a second report before a step)
            for k, r in zip(rows, reports, strict=True):
                bank.update([k], np.array([r]))
        else:
            before = [bank.observers[k].bias for k in rows]  # type: ignore[union-attr]
            changed = set(bank.update(rows, np.array(reports)))
            for k, b in zip(rows, before, strict=True):
                if k not in changed:  # the table looks for a new estimate only there
                    assert bank.observers[k].bias is b  # type: ignore[union-attr]
        if rng.random() < 0.02:  # a vehicle leaves flying and comes back
            k = rng.randrange(n)
            obs = bank.detach(k)
            assert obs is not None and bank.observers[k] is None
            _same_obs(obs, refs[k])
            bank.attach(k, obs)
        for k in rows:
            if rng.random() < 0.05:  # compared now and then: a sync mid-run changes nothing
                _same(bank, k, refs[k])
    for k in range(n):
        _same(bank, k, refs[k])
        estimates += refs[k].bias != (0.0, 0.0, 0.0)
        saturated += refs[k].saturated
        resets += refs[k].resets
    # The branches were taken: estimates, some at their cap, windows restarted.
    assert estimates == n and saturated > 0 and resets > 3 * n


def _same_obs(obs: VelocityBiasObserver, ref: VelocityBiasObserver) -> None:
    assert (obs.bias, obs.saturated, obs.resets, obs.samples) == (
        ref.bias, ref.saturated, ref.resets, ref.samples)  # fmt: skip
    assert obs._last == ref._last and obs._sum == ref._sum
    assert list(obs._checkpoints) == list(ref._checkpoints)


def test_a_step_at_jump_m_is_judged_by_the_observers_hypot() -> None:
    """Unexplained steps within a few units in 1e-16 of ``jump_m`` either
    side: the bank restarts the window exactly when the observer does."""
    jump = 0.7
    for sign in (-1, 1):
        for ulps in range(0, 6):
            step = jump + sign * ulps * math.ulp(jump)
            ref = VelocityBiasObserver(BiasSettings(jump_m=jump))
            bank = BiasBank(1)
            bank.attach(0, VelocityBiasObserver(BiasSettings(jump_m=jump)))
            first = (1.0, 0.0, 0.0, -5.0, 0.0, 0.0, 0.0)
            second = (1.02, step, 0.0, -5.0, 0.0, 0.0, 0.0)
            for r in (first, second):
                ref.update(*r)
                bank.update([0], np.array([r]))
            obs = bank.sync(0)
            assert obs is not None and obs.resets == ref.resets, (sign, ulps)
            assert obs._sum == ref._sum and list(obs._checkpoints) == list(ref._checkpoints)


def test_the_kept_window_is_nothing_the_garbage_collector_scans() -> None:
    """A 10 s window keeps about 20 checkpoints per vehicle (30,000 at 1,500
    vehicles): made of floats alone, each is untracked by the cyclic garbage
    collector at its first pass, so the station's collections do not grow
    with the fleet (a list in each took full collections to 12-14 ms)."""
    n = 20
    alone = [VelocityBiasObserver() for _ in range(n)]
    bank = BiasBank(n)
    for k in range(n):
        bank.attach(k, VelocityBiasObserver())
    for step in range(600):  # 12 s at 50 Hz: the window full
        t = step / 50
        reports = [(t, k + 0.5 * t, 2.0, -10.0, 0.6, 0.0, 0.0) for k in range(n)]
        for k in range(n):
            alone[k].update(*reports[k])
        bank.update(list(range(n)), np.array(reports))
    gc.collect()
    for obs in (*alone, *(bank.sync(k) for k in range(n))):
        assert obs is not None and len(obs._checkpoints) >= 15
        assert not any(gc.is_tracked(cp) for cp in obs._checkpoints)
