"""A vehicle removed from the emulator's core takes its row's state with it.

``EmulatorCore`` keeps, per fleet row, the vehicle's key and its noise
generator (``_report_frames`` reads them for each LOCAL_POSITION_NED built);
a removal renumbers the rows behind it. Two cores of three noisy vehicles
on one port, one losing vehicle 2 after 10 steps: vehicle 3's reports (its
own noise stream, its own sequence numbers) stay byte for byte those of the
core that kept vehicle 2, and in lockstep the answer it awaits (rule 3)
stays its own.
"""

from __future__ import annotations

from typing import Any, Literal

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import EmulatorConfig, VehicleSpec
from sim_vehicle.core import EmulatorCore
from tests.sim_vehicle.test_sv_deferred_lane import STATION, _Port

_GCS = mav.MAVLink(None, srcSystem=255, srcComponent=190)


def _core(clock: Literal["realtime", "lockstep"]) -> tuple[EmulatorCore, _Port]:
    specs = tuple(
        VehicleSpec(sysid=s, start_ned_m=(5.0 * s, 0.0, -2.0), airborne=True) for s in (1, 2, 3)
    )
    cfg = EmulatorConfig(vehicles=specs, clock=clock, noise_pos_m=0.05, noise_vel_m_s=0.02)
    core, port = EmulatorCore(cfg), _Port()
    core.ports.append(port)
    for spec in cfg.vehicles:
        core.add(spec, port, initial=True, enc=mav.MAVLink(None, spec.sysid, spec.compid))
    parser = mav.MAVLink(None)
    for s in (1, 2, 3):  # LOCAL_POSITION_NED at 50 Hz
        cmd = mav.MAVLink_command_long_message(s, 1, 511, 0, 32, 20000, 0, 0, 0, 0, 0)
        core.receive(port, parser.parse_buffer(cmd.pack(_GCS)) or [], STATION, None)
    return core, port


def _reports_of(sysid: int, sent: list[bytes]) -> list[bytes]:
    parser = mav.MAVLink(None)
    out: list[Any] = []
    for data in sent:
        out.extend(parser.parse_buffer(data) or [])
    return [
        bytes(m.get_msgbuf())
        for m in out
        if m.get_srcSystem() == sysid and m.get_msgId() == mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED
    ]


@pytest.mark.parametrize("clock", ["realtime", "lockstep"])
def test_the_rows_behind_a_removed_vehicle_keep_their_own_noise_and_answers(
    clock: Literal["realtime", "lockstep"],
) -> None:
    (cut, cut_port), (kept, kept_port) = _core(clock), _core(clock)
    awaited = []
    for k in range(60):
        if k == 10:
            cut.remove(2)
        for core in (cut, kept):
            core.step()
        row = {c: next(v.row for v in c.rows if v.spec.sysid == 3) for c in (cut, kept)}
        awaited.append(bool(cut.fleet.awaiting[row[cut]]))
        assert awaited[-1] == bool(kept.fleet.awaiting[row[kept]])
    mine = _reports_of(3, cut_port.sent)
    assert len(mine) >= 50
    assert mine == _reports_of(3, kept_port.sent)
    # a lockstep clock keeps the flags (vehicle 3 awaited answers), a real-time one none
    assert any(awaited) == (clock == "lockstep")
