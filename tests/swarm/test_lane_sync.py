"""The emulator's setpoint lane copies into its fleet row all that the full ``sync`` would.

After the lane takes a setpoint for a vehicle whose row was in sync, the core
copies only what the lane moves (``EmulatorCore._sync_target``: deadline,
holding flag, target). Flown here against the station's core
(``swarm_harness.Sky``, hand clock) through a start, a vehicle's leave, a
radio silence longer than GUID_TIMEOUT (brake, stale, heard again) and lossy
links, with setpoints handed over as the UDP endpoint hands them (raw) and as
pymavlink messages: after every datagram a vehicle hears, a full ``sync`` of
every row must change nothing, bit for bit (row arrays, the feed-forward
waiting for the next step, each vehicle's record of what its row holds).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav
from swarm_harness import Radio, Sky, mission_from

from gcs_swarm.mission import Event
from sim_vehicle import Impairment
from sim_vehicle.core import EmulatorCore


def _rows(emu: EmulatorCore) -> Any:
    f = emu.fleet
    arrays = {k: a.tobytes() for k, a in vars(f).items() if isinstance(a, np.ndarray)}
    due = {r: tuple(x.hex() for x in a) for r, a in f._a_ff_due.items()}
    kept = [
        (v.seen_version, v.row_deadline, v.row_holding, v.row_target, v.row_dyn, v.row_dyn_key)
        for v in emu.rows
    ]
    return arrays, due, kept


class _CheckedSky(Sky):
    """A sky whose every delivery to a vehicle is followed by the check."""

    checks = 0
    streamed = 0  # checks after which some row flew the station's stream (control "accel")

    def _to_vehicle(self, radio: Radio, data: bytes) -> None:
        super()._to_vehicle(radio, data)
        for emu in self.emus:
            before = _rows(emu)
            for v in emu.rows:
                emu.sync(v, emu.sim_time_s)
            assert _rows(emu) == before, f"t={self.now:.2f} s"
            self.checks += 1
            self.streamed += any(v.ap.control == "accel" for v in emu.rows)


_OPERATOR = mav.MAVLink(None, srcSystem=255, srcComponent=190)


def _operator(sky: Sky, sysid: int, msg: Any) -> None:
    """``msg`` reaches vehicle ``sysid`` from the station's address (another GCS tool)."""
    sky._to_vehicle(sky.vehicles[sysid].radio, msg.pack(_OPERATOR))


@pytest.mark.parametrize("raw", [True, False])
def test_a_full_sync_after_the_lane_changes_nothing(raw: bool) -> None:
    m = mission_from("example1_tetrahedron.yaml", duration=6.0)
    startup = dataclasses.replace(m.settings.startup, guid_timeout=0.1)
    mission = dataclasses.replace(
        m,
        events=(Event(t=1.0, action="leave", sysid=2),),
        settings=dataclasses.replace(m.settings, startup=startup),
    )
    sky = _CheckedSky(mission, uplink=Impairment(loss=0.1), seed=3, raw_setpoints=raw)
    sky.ready()
    sky.start()
    sky.run_until(lambda: sky.core.control.t_s >= 1.5, 4.0)
    # A position target (no GUID_TIMEOUT deadline of its own) and a GUIDED that
    # restarts the stream (not holding): the lane's next setpoint lowers the
    # deadline and sets the holding flag.
    hold = mav.MAVLink_set_position_target_local_ned_message(
        0, 4, 1, mav.MAV_FRAME_LOCAL_NED, 3576, 1.0, 2.0, -10.0, 0, 0, 0, 0, 0, 0, 0, 0
    )
    for k in range(5):
        _operator(sky, 4, hold)
        sky.advance(0.3)
        _operator(sky, 1 + k % 2 * 2, mav.MAVLink_set_mode_message(1, 1, 4))
        sky.advance(0.1)
    sky.set_silent(3)  # past GUID_TIMEOUT: it brakes; past the stale timeout: it leaves
    sky.advance(1.5)
    assert sky.vehicles[3].ap.control != "accel"
    sky.set_silent(3, False)
    sky.run_until(lambda: sky.core.finished, 6.0)
    sky.end()
    assert sky.checks > 1000 and sky.streamed > 500, (sky.checks, sky.streamed)
