"""The vehicle's own safety end to end (issue 14 item 3): ``run_mission`` on
the bundled emulator (lockstep, real UDP on 127.0.0.1) with the envelope
read, the GCS failsafe and the fence forced on for its ``sim`` vehicles; the
run folder's ``vehicle_params.json`` must show every value read, set, echoed
and restored.

Skipped while the emulator does not answer every parameter the station reads
and sets (``sim_vehicle/params.py``): a name it does not know gets no
PARAM_VALUE, so the station would wait on it and fail the start-up.
"""

from __future__ import annotations

import asyncio
import json
import math
from pathlib import Path

import numpy as np
import pytest

from gcs_swarm.mavlink.vehicle_params import ENVELOPE_PARAMS, FAILSAFE_PARAMS, FENCE_PARAMS
from gcs_swarm.mission import parse_mission
from gcs_swarm.report import RunFolder
from gcs_swarm.runtime import run_mission
from sim_vehicle.params import PARAM_TABLE

MISSING = [n for n in (*ENVELOPE_PARAMS, *FAILSAFE_PARAMS, *FENCE_PARAMS) if n not in PARAM_TABLE]
pytestmark = pytest.mark.skipif(
    bool(MISSING), reason=f"the emulator does not answer {', '.join(MISSING)} yet"
)

TEXT = """
mission:
  name: vehicle params
  duration: 2
  end: land
  startup: {read_envelope: true}
  failsafe: {gcs: true, fence: true, timeout: 7}
emulator: {mode: lockstep}
limits:
  geofence: {min: [-50, -40, -25], max: [50, 40, 30]}
vehicles:
  - {sysid: 1, start: [2, 1, 2]}
  - {sysid: 2, start: [-1, -1, -1]}
"""


def f32(x: float) -> float:
    return float(np.float32(x))


def test_envelope_failsafe_and_fence_are_set_checked_recorded_and_restored(
    tmp_path: Path,
) -> None:
    mission = parse_mission(TEXT, "params.yaml")
    folders: list[RunFolder] = []

    async def fly() -> None:
        async with asyncio.timeout(120):
            summary = await run_mission(mission, log_dir=tmp_path, picture=False,
                                        on_folder=folders.append)  # fmt: skip
            assert summary.outcome == "completed"
            log = "\n".join(summary.log)
            old = PARAM_TABLE["FS_GCS_ENABLE"][0]
            assert (
                f"vehicle 1: FS_GCS_ENABLE {old:g} -> 5 (Land after 7 s without the station)"
                in (log)
            )
            assert "vehicle 2: envelope accel" in log

    asyncio.run(fly())
    record = json.loads(folders[0].vehicle_params.read_text())
    for k, v in enumerate(record["vehicles"]):
        assert v["envelope_source"] == "vehicle" and v["unanswered"] == []
        assert v["read"] == {n: f32(PARAM_TABLE[n][0]) for n in ENVELOPE_PARAMS}
        params = {p["name"]: p for p in v["params"]}
        assert set(params) == {"GUID_TIMEOUT", "WP_YAW_BEHAVIOR", *FAILSAFE_PARAMS, *FENCE_PARAMS}
        for name, p in params.items():
            assert p["old"] == f32(PARAM_TABLE[name][0]), name
            assert p["readback"] == pytest.approx(p["new"], rel=1e-6), name
            assert p["restored"] is (True if p["changed"] else None), name
        # The k-th sim vehicle's home is [5 k, 0, -20] (emulator defaults).
        corners = [(x, y) for x in (-50, 50) for y in (-40, 40)]
        radius = math.ceil((max(math.hypot(x - 5 * k, y) for x, y in corners) + 5) * 10) / 10
        assert params["FENCE_RADIUS"]["new"] == pytest.approx(radius, abs=1e-9)
        assert params["FENCE_ALT_MAX"]["new"] == 30 + 5 + 20
        assert (params["FS_GCS_ENABLE"]["new"], params["FS_GCS_TIMEOUT"]["new"]) == (5, 7)
