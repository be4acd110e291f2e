"""The reported velocity's bias and its reversal (docs/emulator.md, Eq. T1).

ArduCopter 4.5.6 SITL's EKF reports every velocity about 2 cm/s off its own
position's derivative, and at 304 s of boot time, on every instance, that
bias reverses exponentially with a time constant of about 14 s
(docs/velocity-bias.md, measured 2026-12-03). The emulator's ``ardupilot``
preset reports the same; these tests read it from the LOCAL_POSITION_NED
frames the emulator sends.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import EmulatorConfig, VehicleSpec
from sim_vehicle.fleet import Fleet
from sim_vehicle.schedule import bias_factor, report_frames
from sim_vehicle.vehicles import autopilot_for

BIAS = (-0.015, 0.013, 0.0)


def _reported_velocity(flip_s: float, tau_s: float, boot_s: float) -> tuple[float, float, float]:
    """The velocity a still vehicle reports ``boot_s`` after its boot."""
    f = Fleet()
    row = f.add(1, 1, (0.0, 0.0, -10.0), landed=False)
    f.vbias[row] = BIAS
    f.vbias_flip[row] = flip_s
    f.vbias_tau[row] = tau_s
    f.boot[row] = 100.0  # sim time of the boot: the frame's time is now - boot
    (frame,) = report_frames(f, np.array([row], dtype=np.intp), 100.0 + boot_s, [])
    (msg,) = mav.MAVLink(None).parse_buffer(frame) or []
    assert msg.time_boot_ms == round(boot_s * 1000.0)
    return (msg.vx, msg.vy, msg.vz)


def test_the_bias_is_constant_until_the_flip_then_reverses_with_tau() -> None:
    # float32 on the wire: 1e-8 m/s
    np.testing.assert_allclose(_reported_velocity(304.0, 14.0, 200.0), BIAS, atol=1e-8)
    np.testing.assert_allclose(_reported_velocity(304.0, 14.0, 304.0), BIAS, atol=1e-8)
    one_tau = np.array(BIAS) * (2.0 / math.e - 1.0)
    np.testing.assert_allclose(_reported_velocity(304.0, 14.0, 318.0), one_tau, atol=1e-8)
    # the sign changes at tau ln 2 after the flip (313.7 s)
    assert (
        _reported_velocity(304.0, 14.0, 313.0)[0] < 0.0 < _reported_velocity(304.0, 14.0, 314.5)[0]
    )
    np.testing.assert_allclose(_reported_velocity(304.0, 14.0, 600.0), -np.array(BIAS), atol=1e-8)


def test_a_flip_of_zero_never_reverses() -> None:
    np.testing.assert_allclose(_reported_velocity(0.0, 14.0, 1000.0), BIAS, atol=1e-8)


def test_bias_factor_is_the_exponential_of_eq_t1() -> None:
    t = np.array([0.0, 303.9, 304.0, 310.0, 350.0, 1e4])
    got = bias_factor(t, np.full(6, 304.0), np.full(6, 14.0))
    want = np.where(t > 304.0, 2.0 * np.exp(-(t - 304.0) / 14.0) - 1.0, 1.0)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)
    assert np.all(np.diff(got) <= 0.0)  # it only ever moves towards -1


@pytest.mark.parametrize(
    ("cfg", "autopilot", "flip"),
    [
        (EmulatorConfig(dynamics="ardupilot"), "ardupilot", EmulatorConfig.ARDUPILOT_VBIAS_FLIP_S),
        (EmulatorConfig(dynamics="ideal"), "ardupilot", 0.0),
        (EmulatorConfig(dynamics="ardupilot"), "px4", 0.0),
        (EmulatorConfig(dynamics="ardupilot", vel_bias_flip_s=42.0), "ardupilot", 42.0),
        (EmulatorConfig(dynamics="ardupilot", vel_bias_flip_s=0.0), "ardupilot", 0.0),
    ],
)
def test_the_preset_flips_at_sitls_boot_time(
    cfg: EmulatorConfig, autopilot: str, flip: float
) -> None:
    spec = VehicleSpec(sysid=1, autopilot=autopilot)  # type: ignore[arg-type]
    params = autopilot_for(cfg, spec, 0.0).params
    assert params["SIM_VBIAS_FLIP"] == pytest.approx(flip)
    assert params["SIM_VBIAS_TAU"] == pytest.approx(14.0)


def test_a_negative_flip_is_refused() -> None:
    with pytest.raises(ValueError, match="vel_bias_flip_s"):
        EmulatorConfig(vel_bias_flip_s=-1.0)
