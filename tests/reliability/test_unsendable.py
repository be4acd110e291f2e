"""What the law asks can always be sent, and what cannot be framed never
stops a link. Found by flying far from the leader with a delay-compensation
experiment: the cubic spring of Eq. 7 asked more than float32 holds, the
setpoint could not be packed, and the exception ended the whole station."""

from __future__ import annotations

import asyncio
import math
import socket
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs_swarm.mavlink import ProtocolConfig, VehicleProtocol
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.codec import Codec
from gcs_swarm.mavlink.vehicle import ACCEL_CEILING_MPS2
from gcs_swarm.runtime.links import Link


def _accel_of(frame: bytes) -> np.ndarray:
    (msg,) = mav.MAVLink(None, 0, 0).parse_buffer(frame)
    return np.array((msg.afx, msg.afy, msg.afz))


def test_huge_and_nan_accelerations_become_sendable_setpoints() -> None:
    vp = VehicleProtocol(1, ProtocolConfig(), goto_m=(0.0, 0.0, 5.0))
    codec = Codec()
    huge = vp.accel_setpoint((3e4, -4e4, 1e39))  # cubic spring far out; past float32
    a = _accel_of(codec.encode(huge))
    assert math.isclose(float(np.linalg.norm(a)), ACCEL_CEILING_MPS2, rel_tol=1e-6)
    assert a[2] < -0.99 * ACCEL_CEILING_MPS2  # direction kept: mostly up (NED down < 0)
    moderate = vp.accel_setpoint((3e4, -4e4, 0.0))
    a = _accel_of(codec.encode(moderate))
    np.testing.assert_allclose(a, [-0.8e3, 0.6e3, 0.0], rtol=1e-6)  # NED: (y, x, -z)
    zero = vp.accel_setpoint((math.nan, 1.0, 0.0))
    np.testing.assert_array_equal(_accel_of(codec.encode(zero)), [0.0, 0.0, 0.0])
    ok = vp.accel_setpoint((1.0, 2.0, -3.0))  # the paper's figures pass untouched
    np.testing.assert_allclose(_accel_of(codec.encode(ok)), [2.0, 1.0, 3.0], rtol=1e-7)
    assert vp.clipped_setpoints == 3


def test_an_unframeable_message_is_counted_and_the_link_goes_on() -> None:
    async def run() -> None:
        heard = asyncio.Event()

        def on_message(msg: Any, lk: Link) -> None:
            heard.set()

        link = Link("udpin:127.0.0.1:0", on_message)
        async with asyncio.timeout(10), link:
            host, port = link.local_address or ("", 0)
            peer = Codec(sysid=7, compid=1)
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
                sock.setblocking(False)
                sock.sendto(peer.encode(b.heartbeat()), (host, port))
                await heard.wait()  # the link has learnt its peer
                link.send(b.accel_setpoint(7, 1, 0, (1e39, 0.0, 0.0)), 7)  # cannot be packed
                await asyncio.sleep(0.05)
                link.send(b.heartbeat(), 7)
                loop = asyncio.get_running_loop()
                data = await asyncio.wait_for(loop.sock_recv(sock, 2048), 5)
        assert link.stats.unencodable == 1
        (msg,) = mav.MAVLink(None, 0, 0).parse_buffer(data)
        assert msg.get_type() == "HEARTBEAT"

    asyncio.run(run())
