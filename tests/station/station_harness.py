"""Shared set-up of the closed-loop station tests: the real station against
the real emulator over real UDP on 127.0.0.1 (ephemeral ports), emulator in
lockstep with ideal dynamics at 50 Hz unless a test says otherwise."""

from __future__ import annotations

import asyncio
import dataclasses
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import numpy as np

from gcs_swarm.mission import Mission, load_mission
from gcs_swarm.runtime import RunSummary, emulator_config, run_mission
from sim_vehicle import Emulator, EmulatorConfig, VehicleState

MISSIONS = Path(__file__).resolve().parents[2] / "config" / "missions"


def mission_from(name: str, *, n: int | None = None, duration: float | None = None) -> Mission:
    """A shipped mission, optionally cut to its first ``n`` vehicles and given a
    ``duration`` [s] of formation flight."""
    m = load_mission(MISSIONS / name)
    if n is not None:
        m = dataclasses.replace(m, vehicles=m.vehicles[:n])
    if duration is not None:
        m = dataclasses.replace(m, settings=dataclasses.replace(m.settings, duration=duration))
    return m


def lockstep_config(mission: Mission, *, airborne: bool = True, **changes: Any) -> EmulatorConfig:
    """The mission's emulator, in lockstep with ideal dynamics (unless changed).

    ``speedup`` 20 paces the steps taken while no vehicle holds the clock
    (ground start-up, after the ending) at 20 x wall clock (lockstep rule 4).
    """
    cfg = emulator_config(mission, airborne=airborne)
    changes.setdefault("clock", "lockstep")
    changes.setdefault("dynamics", "ideal")
    changes.setdefault("accel_tau_s", None)
    changes.setdefault("speedup", 20.0)
    return dataclasses.replace(cfg, **changes)


@dataclasses.dataclass(frozen=True)
class Flown:
    """A finished run: its summary (also when it raised), the exception it
    raised if any, the (closed) emulator, its endpoints and every vehicle's
    state at the end."""

    summary: RunSummary | None
    error: BaseException | None
    emu: Emulator
    endpoints: dict[int, tuple[str, int]]
    states: dict[int, VehicleState]

    @property
    def ok(self) -> RunSummary:
        if self.error is not None:
            raise self.error
        assert self.summary is not None
        return self.summary


Hook = Callable[[Emulator, "asyncio.Task[RunSummary]"], Awaitable[None]]


async def fly(
    mission: Mission,
    emu_cfg: EmulatorConfig,
    *,
    timeout_s: float = 120.0,
    before: Callable[[Emulator], None] | None = None,
    during: Hook | None = None,
    after: Hook | None = None,
    lockstep: bool = True,
) -> Flown:
    """Run the station against its own emulator. ``before`` adjusts the
    emulator before the station starts; ``during`` acts while the run goes
    on; ``after`` runs once the run has ended (the emulator still runs)."""
    summaries: list[RunSummary] = []
    error: BaseException | None = None
    async with asyncio.timeout(timeout_s), Emulator(emu_cfg) as emu:
        if before is not None:
            before(emu)
        endpoints = emu.endpoints
        links = {s: f"udpout:{h}:{p}" for s, (h, p) in endpoints.items()}
        run = asyncio.create_task(
            run_mission(mission, links=links, lockstep=lockstep, on_summary=summaries.append)
        )
        try:
            if during is not None:
                await during(emu, run)
            await run
        except (Exception, asyncio.CancelledError) as err:  # the test inspects it
            error = err
        finally:
            run.cancel()
        if after is not None:
            await after(emu, run)
        present = set(emu.endpoints)  # without the vehicles a test removed
        states = {s: emu.vehicle_state(s) for s in endpoints if s in present}
    return Flown(summaries[0] if summaries else None, error, emu, endpoints, states)


def radii(summary: RunSummary) -> dict[int, float]:
    leader = np.array(summary.leader_pos_m)
    return {s: float(np.linalg.norm(p - leader)) for s, p in summary.positions().items()}
