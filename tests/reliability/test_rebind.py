"""No takeover window (issue 15 item 3): a system id stays bound to the
address it was first heard from for the whole run.

The issue's scenario, over real UDP on 127.0.0.1: four emulated vehicles on
a listening link (the station ``udpin``, the emulator sends to it with
``out``), real time. Vehicle 2's radio goes silent for longer than the old
rebinding window (``REBIND_S`` = 5 s of wall time) while another socket
sends HEARTBEAT and LOCAL_POSITION_NED as system 2; then vehicle 2 is back.
Vehicle 3's radio goes silent for good. The station must never write to
the impostor (no COMMAND_LONG, no HEARTBEAT, nothing), must keep vehicle 2
(it rejoins and gets the end action), must count and report the refused
frames once, and must not call the run ``completed`` while vehicle 3 is
lost. Before the fix the impostor took system 2 over after 5 s of silence.

The rule itself (``Link``, in process over real sockets): without signing a
vehicle is never rebound, whatever ``allow_rebind`` says; with signing and
``allow_rebind`` a well-signed new address takes a vehicle silent for
``REBIND_S`` over, and the old address loses its state.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import socket
import time
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as dialect

from gcs_swarm.mavlink.codec import Codec, MessageSpec
from gcs_swarm.runtime import emulator_config, run_mission
from gcs_swarm.runtime.links import REBIND_S, Link
from gcs_swarm.runtime.run import EXIT_CODES
from gcs_swarm.runtime.summary import RunSummary, VehicleAtEnd
from sim_vehicle import Emulator
from tests.station.station_harness import mission_from

KEY = bytes(range(7, 39))


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _impostor_frames(sysid: int, boot_ms: int) -> bytes:
    mav = dialect.MAVLink(None, sysid, 1)
    hb = mav.heartbeat_encode(2, 3, 1 | 128, 4, 4).pack(mav)  # GUIDED, armed
    lpn = mav.local_position_ned_encode(boot_ms, 0.0, 0.0, -5.0, 0, 0, 0).pack(mav)
    return bytes(hb) + bytes(lpn)


def test_a_silent_vehicle_is_never_handed_to_an_impostor() -> None:
    mission = mission_from("example1_octahedron.yaml", n=4, duration=30.0)
    port = _free_port()
    cfg = dataclasses.replace(
        emulator_config(mission, airborne=True),
        clock="realtime",
        speedup=1.0,
        dynamics="ideal",
        accel_tau_s=None,
        out=("127.0.0.1", port),
    )
    links = {v.sysid: f"udpin:127.0.0.1:{port}" for v in mission.vehicles}
    marks: dict[str, Any] = {}
    impostor = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    async def main() -> Any:
        async with asyncio.timeout(120), Emulator(cfg) as emu:
            impostor.bind(("127.0.0.1", 0))
            impostor.setblocking(False)
            stop = asyncio.Event()

            async def attack() -> None:
                await emu.wait_until(lambda: emu.sim_time_s >= 8.0)  # flying a while
                emu.set_silent(2)
                emu.set_silent(3)
                t0 = time.monotonic()
                boot = 10**6
                while not stop.is_set():
                    boot += 100
                    impostor.sendto(_impostor_frames(2, boot), ("127.0.0.1", port))
                    if "back" not in marks and time.monotonic() - t0 > REBIND_S + 1.5:
                        emu.set_silent(2, False)  # the real vehicle 2 is back; 3 never
                        marks["back"] = emu.sim_time_s
                    await asyncio.sleep(0.05)

            task = asyncio.create_task(attack())
            try:
                summary = await run_mission(mission, links=links, lockstep=False)
            finally:
                stop.set()
                await task
            received = []
            while True:
                try:
                    received.append(impostor.recv(65536))
                except BlockingIOError:
                    break
            return summary, received, emu.vehicle_state(2)

    with impostor:  # closed however the test ends
        summary, received, state2 = asyncio.run(main())
    assert "back" in marks
    # Nothing at all went to the impostor: no command, no heartbeat.
    assert received == []
    log = "\n".join(summary.log)
    # Refused, counted, reported once.
    assert summary.rebinds_refused is not None and summary.rebinds_refused.get(2, 0) > 50
    assert log.count("frames of vehicle 2 from") == 1
    assert "vehicle 2 rebound" not in log
    # Vehicle 2 was kept: it rejoined and got the end action (hold = BRAKE).
    assert log.count("vehicle 2 joins the formation") == 2
    v2 = {v.sysid: v for v in summary.vehicles}[2]
    assert v2.phase == "ended" and state2.mode_name == "BRAKE"
    # Vehicle 3 was lost for good: the run is not "completed", and exits non-zero.
    assert {v.sysid: v.phase for v in summary.vehicles}[3] == "lost"
    assert summary.outcome == "degraded" and EXIT_CODES[summary.outcome] != 0


class _Peer(asyncio.DatagramProtocol):
    def __init__(self) -> None:
        self.got: asyncio.Queue[bytes] = asyncio.Queue()

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.got.put_nowait(data)


def _telemetry(boot_ms: int) -> MessageSpec:
    return MessageSpec(
        "LOCAL_POSITION_NED",
        {"time_boot_ms": boot_ms, "x": 0.0, "y": 0.0, "z": -5.0, "vx": 0.0, "vy": 0.0, "vz": 0.0},
    )


def _rebind_case(*, key: bytes | None, allow: bool) -> tuple[int, int, list[str], int]:
    """Vehicle 7 heard from peer A, then from peer B after A has been silent
    for REBIND_S (the link's arrival clock is wall time: B waits it out).
    Returns (frames from B accepted, refused, notices, peers kept)."""

    async def main() -> tuple[int, int, list[str], int]:
        got: list[int] = []
        notices: list[str] = []
        changed = asyncio.Event()

        def on_message(m: Any, lk: Link) -> None:
            got.append(int(m.time_boot_ms))
            changed.set()

        async def until(done: Callable[[], bool]) -> None:
            while not done():
                changed.clear()
                await changed.wait()

        loop = asyncio.get_running_loop()
        async with asyncio.timeout(20):
            link = Link(
                "udpin:127.0.0.1:0",
                on_message,
                signing_key=key,
                sysids=[7],
                allow_rebind=allow,
                on_notice=notices.append,
            )
            async with link:
                addr = link.local_address
                assert addr is not None
                a, _ = await loop.create_datagram_endpoint(_Peer, local_addr=("127.0.0.1", 0))
                b, _ = await loop.create_datagram_endpoint(_Peer, local_addr=("127.0.0.1", 0))
                codec_a = Codec(7, 1, signing_key=key, unix_s=time.time() if key else None)
                codec_b = Codec(7, 1, signing_key=key, unix_s=time.time() if key else None)
                a.sendto(codec_a.encode(_telemetry(1)), addr)
                await until(lambda: got == [1])
                await asyncio.sleep(REBIND_S + 0.3)  # A silent for longer than REBIND_S
                for k in range(5):
                    b.sendto(codec_b.encode(_telemetry(100 + k)), addr)
                # A again, after B's five (loopback keeps the order); a fresh
                # signer so that its timestamp is newer than B's on the stream.
                codec_a = Codec(7, 1, signing_key=key, unix_s=time.time() + 1.0 if key else None)
                a.sendto(codec_a.encode(_telemetry(2)), addr)
                await until(lambda: 2 in got or len(got) >= 6)
                peers = link.peer_count
                a.close()
                b.close()
        from_b = sum(1 for x in got if x >= 100)
        return from_b, link.rebinds_refused[7], notices, peers

    return asyncio.run(main())


def test_unsigned_links_never_rebind_even_when_allowed() -> None:
    from_b, refused, notices, peers = _rebind_case(key=None, allow=True)
    assert from_b == 0 and refused == 5 and peers == 1
    assert len(notices) == 1 and "refused" in notices[0] and "bound to" in notices[0]


def test_signed_links_rebind_only_when_the_mission_allows_it() -> None:
    from_b, refused, notices, _ = _rebind_case(key=KEY, allow=False)
    assert from_b == 0 and refused == 5 and len(notices) == 1
    from_b, refused, notices, peers = _rebind_case(key=KEY, allow=True)
    # B takes vehicle 7 over and is reported; A (now speaking for nobody) loses
    # its state, and its late frame is refused.
    assert from_b == 5 and refused == 1 and peers == 1
    assert "vehicle 7 rebound from" in notices[0]


def test_the_summary_names_refused_frames_by_network_and_system_id() -> None:
    """``rebinds_refused`` is keyed like the vehicles (key = network index * 256
    + sysid); the summary line names each as the vehicles are named."""
    at_end = [
        VehicleAtEnd(sysid=k, phase="ended", mode="BRAKE", position_m=None, radius_m=None,
                     last_accel_ned_mps2=(0.0, 0.0, 0.0), failure=None, label=label)
        for k, label in ((2, "blue:2"), (258, "red:2"))
    ]  # fmt: skip
    summary = RunSummary(
        outcome="completed", mission_time_s=1.0, wall_time_s=1.0, steps=1, behaviour="formation",
        leader_pos_m=(0.0, 0.0, 0.0), vehicles=tuple(at_end), min_separation_m=1.0,
        min_clearance_m=math.inf, episodes=0, messages_sent=0, setpoints_dropped=0,
        messages_dropped=0, bad_packets=0, unknown_sysid_messages=0, spoofed=0,
        signature_rejected=0, safety="", log=(), rebinds_refused={258: 7, 2: 1},
    )  # fmt: skip
    line = next(s for s in summary.format().splitlines() if s.startswith("frames refused"))
    assert line.endswith("vehicle red:2: 7, vehicle blue:2: 1")
