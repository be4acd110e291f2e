"""The operator view's server over real sockets on 127.0.0.1 (port 0): the
frames of a lockstep run of the demo against the real emulator, the end
buttons, the token, and a stalled page that loses frames while the
setpoints keep flowing."""

from __future__ import annotations

import asyncio
import json
import socket
import time
from collections.abc import Awaitable, Callable
from typing import Any

import pytest
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import InvalidStatus

from gcs_swarm.errors import LinkError
from gcs_swarm.mission import Mission
from gcs_swarm.runtime import RunSummary, run_mission
from gcs_swarm.view import ViewServer, live_view
from sim_vehicle import Emulator, VehicleState
from tests.station.station_harness import lockstep_config, mission_from

DEMO = "example1_octahedron.yaml"
LONG_S = 3600.0
"""Mission time [s] of the runs a button ends: never reached (lockstep on an
idle machine flies the demo's own 150 s in a few seconds)."""

During = Callable[[ViewServer], Awaitable[None]]


def _ws_url(server: ViewServer, token: str | None = None) -> str:
    return f"ws://127.0.0.1:{server.port}/ws?token={server.token if token is None else token}"


async def _fly_with_view(
    mission: Mission, during: During, *, timeout_s: float = 25.0, **view: Any
) -> tuple[RunSummary, dict[int, VehicleState]]:
    """Fly ``mission`` in lockstep with the view on; ``during(server)`` runs
    once the view listens; the run's summary and the emulator's vehicles."""
    servers: list[ViewServer] = []
    listening = asyncio.Event()

    def on_server(server: ViewServer) -> None:
        servers.append(server)
        listening.set()

    async with asyncio.timeout(timeout_s), Emulator(lockstep_config(mission)) as emu:
        links = {s: f"udpout:{h}:{p}" for s, (h, p) in emu.endpoints.items()}
        lv = live_view(mission, on_server=on_server, **view)
        run = asyncio.create_task(
            run_mission(mission, links=links, lockstep=True, picture=False, view=lv)
        )
        try:
            await listening.wait()
            await during(servers[0])
            summary = await run
        finally:
            run.cancel()  # a failed test: end the run before the emulator closes
            await asyncio.wait([run])
        states = {s: emu.vehicle_state(s) for s in emu.endpoints}
    return summary, states


async def _frames_until(
    ws: ClientConnection, done: Callable[[dict[str, Any]], bool], limit: int = 2000
) -> list[dict[str, Any]]:
    out = []
    for _ in range(limit):
        msg = json.loads(await ws.recv())
        if msg["type"] == "frame":
            out.append(msg)
            if done(msg):
                return out
    raise AssertionError(f"not seen in {limit} messages")


def _flying(f: dict[str, Any]) -> bool:
    return f["t"] >= 1.0 and all(f["vehicles"]["in_formation"])


async def _press(ws: ClientConnection, action: str) -> dict[str, Any]:
    await ws.send(json.dumps({"type": "end", "action": action}))
    while True:
        msg = json.loads(await ws.recv())
        if msg["type"] == "answer":
            return msg  # type: ignore[no-any-return]


def test_frames_show_the_six_vehicles_moving_and_hold_ends_the_run() -> None:
    mission = mission_from(DEMO, duration=LONG_S)  # ended by the button
    seen: list[dict[str, Any]] = []
    answers: list[dict[str, Any]] = []

    async def during(server: ViewServer) -> None:
        assert server.host == "127.0.0.1"
        async with connect(_ws_url(server)) as ws:
            hello = json.loads(await ws.recv())
            assert hello["type"] == "hello" and hello["mode"] == "live"
            assert [a for a, _ in hello["actions"]] == ["hold", "land", "rtl"]
            seen.extend(await _frames_until(ws, _flying))
            seen.extend(await _frames_until(ws, lambda f: f["t"] >= seen[-1]["t"] + 0.5))
            async with connect(_ws_url(server)) as late:  # a page opened late gets the story
                story = json.loads(await late.recv())["events"]
                joins = sorted(e["sysid"] for e in story if e["kind"] == "join")
                assert joins == [1, 2, 3, 4, 5, 6]
            answers.append(await _press(ws, "takeoff"))  # not an end action: refused
            answers.append(await _press(ws, "hold"))
            answers.append(await _press(ws, "land"))  # one end action per run

    summary, states = asyncio.run(_fly_with_view(mission, during))
    first, last = seen[0], seen[-1]
    assert first["vehicles"]["sysid"] == last["vehicles"]["sysid"] == [1, 2, 3, 4, 5, 6]
    assert last["stage"] == "flying" and last["behaviour"] == "formation"
    flying = next(f for f in seen if _flying(f))  # and the last is 0.5 s of flight later
    moved = [
        max(abs(a - b) for a, b in zip(p0, p1, strict=True))
        for p0, p1 in zip(flying["vehicles"]["pos"], last["vehicles"]["pos"], strict=True)
    ]
    assert min(moved) > 1e-3  # every vehicle's position changed [m]
    assert [s["seq"] for s in seen] == sorted({s["seq"] for s in seen})
    assert [a["ok"] for a in answers] == [False, True, False]
    assert summary.outcome == "completed" and summary.mission_time_s < LONG_S
    assert {v.mode for v in summary.vehicles} == {"BRAKE"}
    assert {st.mode_name for st in states.values()} == {"BRAKE"}
    assert any("operator's request: hold" in line for line in summary.log)


def test_a_land_click_lands_every_vehicle_as_the_end_action_does() -> None:
    mission = mission_from(DEMO, duration=LONG_S)  # end: hold in the file; the button: LAND

    async def during(server: ViewServer) -> None:
        async with connect(_ws_url(server)) as ws:
            await _frames_until(ws, _flying)
            answer = await _press(ws, "land")
            assert answer["ok"] and answer["action"] == "land"

    summary, states = asyncio.run(_fly_with_view(mission, during))
    # What tests/station/test_startup_end.py asks of the mission's own `end: land`.
    assert summary.outcome == "completed"
    assert {v.mode for v in summary.vehicles} == {"LAND"}
    assert {st.mode_name for st in states.values()} == {"LAND"}
    assert {v.last_accel_ned_mps2 for v in summary.vehicles} == {(0.0, 0.0, 0.0)}


async def _http_status(port: int, path: str) -> tuple[int, bytes]:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
    await writer.drain()
    data = await reader.read()
    writer.close()
    await writer.wait_closed()
    head, _, body = data.partition(b"\r\n\r\n")
    return int(head.split()[1]), body


def test_a_wrong_or_missing_token_is_refused() -> None:
    frame = {"type": "frame", "t": 0.0}

    async def main() -> None:
        async with ViewServer(lambda: dict(frame), token="right-token") as server:
            port = server.port
            assert server.url == f"http://127.0.0.1:{port}/?token=right-token"
            for path in ("/", "/?token=", "/?token=wrong", "/view.js", "/view.js?token=x",
                         "/ws", "/ws?token=wrong"):  # fmt: skip
                status, _ = await _http_status(port, path)
                assert status == 403, path
            status, body = await _http_status(port, "/?token=right-token")
            assert status == 200 and b'content="right-token"' in body
            status, body = await _http_status(port, "/view.js?token=right-token")
            assert status == 200 and b"WebSocket" in body
            assert (await _http_status(port, "/other?token=right-token"))[0] == 404
            for bad in ("", "wrong"):
                with pytest.raises(InvalidStatus) as err:
                    async with connect(_ws_url(server, bad)):
                        pass
                assert err.value.response.status_code == 403
            async with connect(_ws_url(server)) as ws:
                assert json.loads(await ws.recv())["type"] == "hello"
                assert json.loads(await ws.recv())["type"] == "frame"
            assert server.refused == 9

    asyncio.run(main())


def test_a_port_in_use_is_a_link_error() -> None:
    async def main() -> None:
        async with ViewServer(lambda: {}) as first:
            with pytest.raises(LinkError, match=f"operator view on 127.0.0.1:{first.port}: "):
                async with ViewServer(lambda: {}, port=first.port):
                    pass

    asyncio.run(main())


async def _stalled_client(port: int, token: str) -> socket.socket:
    """A page that opens the WebSocket, then never reads (a tiny receive buffer)."""
    loop = asyncio.get_running_loop()
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 2048)
    sock.setblocking(False)
    await loop.sock_connect(sock, ("127.0.0.1", port))
    await loop.sock_sendall(sock, (
        f"GET /ws?token={token} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
        "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
        "Sec-WebSocket-Version: 13\r\n\r\n").encode())  # fmt: skip
    head = await loop.sock_recv(sock, 12)
    assert head == b"HTTP/1.1 101", head
    return sock


def test_a_stalled_page_loses_frames_while_the_setpoints_keep_flowing() -> None:
    mission = mission_from(DEMO, duration=LONG_S)
    progress: list[float] = []
    view_drops: list[int] = []
    setpoint_drops: list[int] = []
    stalled: list[socket.socket] = []
    pressed: list[float] = []

    async def during(server: ViewServer) -> None:
        async with connect(_ws_url(server)) as ws:
            await _frames_until(ws, _flying)
            stalled.append(await _stalled_client(server.port, server.token))
            # Until the stalled page has lost frames, and the healthy one
            # goes on seeing the mission clock move (lockstep: vehicle time
            # advances only when the station answers every report).
            frames = await _frames_until(ws, lambda f: server.frames_dropped >= 5)
            t_drop = frames[-1]["t"]
            more = await _frames_until(ws, lambda f: f["t"] >= t_drop + 1.0)
            progress.extend([t_drop, more[-1]["t"]])
            # Setpoints the links replaced before writing (newest wins), while the page stalled.
            setpoint_drops.append(more[-1]["setpoints_dropped"] - frames[-1]["setpoints_dropped"])
            view_drops.append(more[-1]["view"]["dropped"])
            assert server.clients == 2
            assert (await _press(ws, "hold"))["ok"]
            pressed.append(time.monotonic())

    small = {"rate_hz": 20.0, "write_limit": 1024, "send_buffer": 4096}  # drops at once
    try:
        summary, _ = asyncio.run(_fly_with_view(mission, during, **small))
        ended_s = time.monotonic() - pressed[0]
    finally:
        for sock in stalled:
            sock.close()
    assert progress[1] >= progress[0] + 1.0
    assert view_drops[0] >= 5  # counted, and shown to the pages
    assert setpoint_drops == [0]  # every step's setpoints went out while the page stalled
    assert summary.outcome == "completed"
    # The stalled page, still open, does not hold up the end (it is cut after
    # 1 s; websockets alone waited ~20 s for it to take the closing frame).
    assert ended_s < 10.0
