"""Valid frames with impossible numbers (issue 9): NaN velocities and
positions of 1e30 m never reach the law; the vehicle is treated as stale and
leaves the formation after the stale timeout, exactly as if it were silent.
Duplicated and reordered telemetry is not answered twice. Hand-advanced
clock, no sockets (the fuzz tests cover the sockets)."""

from __future__ import annotations

import math

import pytest

from gcs_swarm.mavlink import Phase
from gcs_swarm.mavlink.inbound import GpsGlobalOrigin, LocalPositionNed, ParamValue, plausible
from tests.mavlink.test_vehicle_protocol import SYS, _flying, hb, make, pos

GUIDED = 4


@pytest.mark.parametrize(
    "bad",
    [
        pos(2000, (math.nan, 0.0, -20.0)),
        pos(2000, (1e30, 0.0, -20.0)),
        pos(2000, (0.0, 0.0, -20.0), (math.nan, 0.0, 0.0)),
        pos(2000, (0.0, 0.0, -20.0), (0.0, math.inf, 0.0)),
        pos(2000, (0.0, -1e6, -20.0)),
    ],
    ids=["nan-pos", "1e30-pos", "nan-vel", "inf-vel", "1000km"],
)
def test_implausible_telemetry_is_refused_and_the_vehicle_goes_stale(
    bad: LocalPositionNed,
) -> None:
    vp = make(stale_timeout_s=1.0, heartbeat_timeout_s=3.0)
    _flying(vp, 0.0)
    good = vp.position
    assert good is not None
    for k in range(10):  # 1 s of garbage at 10 Hz, heartbeats keep coming
        t = 0.1 * (k + 1)
        vp.handle_message(hb(GUIDED, armed=True), t)
        vp.handle_message(bad, t)
        assert vp.position is good  # the law still sees only the last good state
        vp.handle_timer(t)
    assert vp.rejected_values == 10
    assert vp.phase is Phase.LOST
    assert vp.failure == "no LOCAL_POSITION_NED for 1 s"


def test_plausible_rejects_an_origin_off_the_globe_and_nan_parameters() -> None:
    assert not plausible(GpsGlobalOrigin(SYS, 1, 2_000_000_000, 0, 0))
    assert plausible(GpsGlobalOrigin(SYS, 1, -353_632_610, 1_491_652_300, 584_000))
    assert not plausible(ParamValue(SYS, 1, "GUID_TIMEOUT", math.nan))


def test_duplicated_and_reordered_telemetry_is_not_used_twice() -> None:
    vp = make(stale_timeout_s=1.0, heartbeat_timeout_s=3.0)
    _flying(vp, 0.0)
    vp.handle_message(pos(2000, (-100.0, 5.0, -22.0)), 0.1)
    newest = vp.position
    vp.handle_message(pos(2000, (-100.0, 5.0, -22.0)), 0.12)  # duplicate
    vp.handle_message(pos(1980, (-99.0, 5.0, -22.0)), 0.13)  # late, older
    assert vp.position is newest and vp.stale_telemetry == 2
    vp.handle_message(pos(60_000, (-100.1, 5.0, -22.0)), 0.14)
    assert vp.position is not newest
    # A reboot (time back by more than 10 s) is news, not a reorder.
    vp.handle_message(pos(5, (-100.1, 5.0, -22.0)), 0.15)
    assert vp.position is not None and vp.position.time_boot_ms == 5
