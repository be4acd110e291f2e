"""Start and stop real ArduCopter SITL instances for the ``sitl`` tests.

The binary comes from the environment: ``GCS_SWARM_ARDUCOPTER`` names an
``arducopter`` built for the ``sitl`` board (``docs/sitl.md`` says how to
build one). Without it every ``sitl`` test is skipped with that reason: CI
has no SITL, and a skipped test is never counted as passed.

Instance ``i`` (``-I i``) serves MAVLink on ``tcp:127.0.0.1:5760+10i``, has
system id ``i + 1`` and its home ``spacing_m`` east of the previous one
(CMAC, like ``sim_vehicle.py --auto-offset-line 90,5``). Every instance
starts from a fresh EEPROM in its own folder (default parameters), in its
own session with stdin from /dev/null, and only the processes started here
are stopped, by PID.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import socket
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ENV_BINARY = "GCS_SWARM_ARDUCOPTER"
HOME = (-35.363261, 149.165230, 584.0)
"""SITL's CMAC location: latitude, longitude [deg], altitude [m AMSL]."""
EARTH_RADIUS_M = 6378137.0


def binary_or_skip() -> Path:
    """The ArduCopter SITL binary named by the environment, or skip the test."""
    value = os.environ.get(ENV_BINARY)
    if not value:
        pytest.skip(f"{ENV_BINARY} is not set: no ArduCopter SITL binary to fly (docs/sitl.md)")
    path = Path(value)
    if not path.is_file() or not os.access(path, os.X_OK):
        pytest.fail(f"{ENV_BINARY}={value} is not an executable file")
    return path


def defaults_file(binary: Path) -> Path:
    """``Tools/autotest/default_params/copter.parm`` of the checkout that built ``binary``."""
    parm = binary.resolve().parents[3] / "Tools" / "autotest" / "default_params" / "copter.parm"
    if not parm.is_file():
        pytest.fail(f"no {parm} beside {binary} (expected build/sitl/bin/arducopter in a checkout)")
    return parm


def tcp_port(instance: int) -> int:
    return 5760 + 10 * instance


def _port_busy(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


@dataclass
class SitlSwarm:
    """``count`` ArduCopter SITL instances numbered from ``first`` (ports and
    system ids follow the instance number, as SITL's own tools number them)."""

    binary: Path
    count: int
    workdir: Path
    first: int = 0
    spacing_m: float = 5.0
    home: tuple[float, float, float] = HOME
    procs: dict[int, subprocess.Popen[bytes]] = field(default_factory=dict)

    def sysid(self, k: int) -> int:
        """System id of the k-th instance: k + 1 whatever ``first`` is, as the
        missions number their vehicles."""
        return k + 1

    def link(self, k: int) -> str:
        return f"tcp:127.0.0.1:{tcp_port(self.first + k)}"

    def links(self) -> dict[int, str]:
        return {self.sysid(k): self.link(k) for k in range(self.count)}

    def links_from_one(self) -> dict[int, str]:
        """The k-th vehicle of a mission (system id k + 1) on the k-th instance."""
        return {k + 1: self.link(k) for k in range(self.count)}

    def start(self) -> None:
        parm = defaults_file(self.binary)
        lat, lon, alt = self.home
        for k in range(self.count):
            inst = self.first + k
            if _port_busy(tcp_port(inst)):
                pytest.fail(f"port {tcp_port(inst)} is taken: another SITL instance {inst} runs")
            d = self.workdir / f"I{inst}"
            d.mkdir(parents=True, exist_ok=True)
            (d / "eeprom.bin").unlink(missing_ok=True)
            east = (inst * self.spacing_m) / (EARTH_RADIUS_M * math.cos(math.radians(lat)))
            home = f"{lat:.7f},{lon + math.degrees(east):.7f},{alt:g},0"
            with open(d / "sitl.log", "wb") as log:
                self.procs[k] = subprocess.Popen(
                    [str(self.binary), f"-I{inst}", "--model", "+", "--speedup", "1",
                     "--defaults", str(parm), "--sim-address=127.0.0.1", "--home", home,
                     "--sysid", str(k + 1)],
                    cwd=d, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                    start_new_session=True,
                )  # fmt: skip
        deadline = time.monotonic() + 30.0
        for k in range(self.count):
            while not _port_busy(tcp_port(self.first + k)):
                if self.procs[k].poll() is not None:
                    pytest.fail(f"SITL instance {self.first + k} exited: see {self.workdir}")
                if time.monotonic() > deadline:
                    pytest.fail(f"SITL instance {self.first + k} not listening after 30 s")
                time.sleep(0.1)

    def kill(self, k: int) -> None:
        """SIGKILL instance ``k`` (a vehicle that stops answering)."""
        proc = self.procs.get(k)
        if proc is not None and proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=10)

    def pause(self, k: int, on: bool) -> None:
        """SIGSTOP (``on``) or SIGCONT instance ``k``: a vehicle whose link goes
        quiet and comes back (its simulation is frozen meanwhile)."""
        proc = self.procs.get(k)
        if proc is not None and proc.poll() is None:
            proc.send_signal(signal.SIGSTOP if on else signal.SIGCONT)

    def stop(self) -> None:
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGCONT)  # a paused one hears its SIGTERM
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in self.procs.values():
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.send_signal(signal.SIGKILL)
                proc.wait(timeout=5)


@contextlib.contextmanager
def sitl_swarm(
    count: int, workdir: Path, *, first: int = 0, home: tuple[float, float, float] = HOME
) -> Iterator[SitlSwarm]:
    """Fresh instances (default parameters: the station sets what it needs) for
    one test, instance ``i``'s home ``5 i`` m east of ``home``; always stopped
    afterwards."""
    swarm = SitlSwarm(binary_or_skip(), count, workdir, first=first, home=home)
    try:
        swarm.start()
        yield swarm
    finally:
        swarm.stop()
