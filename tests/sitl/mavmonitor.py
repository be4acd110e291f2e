"""A listen-only MAVLink observer of SITL instances, on their SERIAL1 port.

ArduPilot SITL serves SERIAL0 on ``tcp:5760+10i`` (the station's link) and
SERIAL1 on ``tcp:5762+10i``; this watcher connects to the second, asks for
HEARTBEAT at 10 Hz so a mode change is timed to 0.1 s, and records every
HEARTBEAT and STATUSTEXT with its arrival time. It sends no HEARTBEAT of its
own and uses system id 254, so it never feeds a vehicle's GCS failsafe
(SYSID_MYGCS is the station's 255).
"""

from __future__ import annotations

import socket
import threading
import time
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mav


@dataclass
class Seen:
    heartbeats: list[tuple[float, int, bool]] = field(default_factory=list)
    """(monotonic arrival time [s], custom_mode, armed)."""
    texts: list[tuple[float, str]] = field(default_factory=list)


CONNECT_WAIT_S = 60.0
"""How long [s] a SITL instance may take to listen on SERIAL1. It opens its
serial ports as it starts; a run on a loaded machine (load 3, 2026-12-03)
found instance 2's still refusing when the station had just been started,
so the watcher tries again until then."""


def _connect(port: int, wait_s: float) -> socket.socket:
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return socket.create_connection(("127.0.0.1", port), timeout=10)
        except ConnectionRefusedError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


class Monitor:
    """Watch SITL instance ``instance`` from a thread until ``close()``."""

    def __init__(self, instance: int) -> None:
        self.seen = Seen()
        self._port = 5762 + 10 * instance
        self._stop = threading.Event()
        self._sock = _connect(self._port, CONNECT_WAIT_S)
        self._sock.settimeout(0.2)
        self._mav = mav.MAVLink(None, srcSystem=254, srcComponent=191)
        self._mav.robust_parsing = True
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        self._asked = 0.0

    def _ask_fast_heartbeat(self, target: int) -> None:
        msg = self._mav.command_long_encode(target, 1, 511, 0, 0, 100_000, 0, 0, 0, 0, 0)
        self._sock.sendall(msg.pack(self._mav))

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self._sock.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                return
            if not data:
                return
            now = time.monotonic()
            for msg in self._mav.parse_buffer(data) or []:
                kind = msg.get_type()
                if kind == "HEARTBEAT" and msg.autopilot != mav.MAV_AUTOPILOT_INVALID:
                    armed = bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
                    self.seen.heartbeats.append((now, int(msg.custom_mode), armed))
                    if now - self._asked > 5.0:
                        self._asked = now
                        self._ask_fast_heartbeat(msg.get_srcSystem())
                elif kind == "STATUSTEXT":
                    self.seen.texts.append((now, str(msg.text)))

    def first_mode_after(self, t0: float, modes: set[int]) -> float | None:
        """Arrival time of the first HEARTBEAT at or after ``t0`` in one of ``modes``."""
        for at, mode, _ in self.seen.heartbeats:
            if at >= t0 and mode in modes:
                return at
        return None

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self._sock.close()
