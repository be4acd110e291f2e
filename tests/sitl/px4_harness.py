"""Start and stop real PX4 v1.14 SITL instances (SIH quadrotor) for the
``px4_sitl`` tests.

The binary comes from the environment: ``GCS_SWARM_PX4`` names the ``px4``
of a ``px4_sitl_default`` build (``docs/sitl.md``, PX4 section). Without it
every ``px4_sitl`` test is skipped with that reason.

PX4 binds its UDP ports on every address and has no option to bind one, so
the tests run PX4 and the station inside a private network namespace that
has only loopback: ``in_private_namespace_or_rerun`` re-executes the
calling test inside ``unshare -n`` (with ``ip link set lo up``) and reports
its outcome; inside, the test runs. Instance ``i`` has system id ``i + 1``,
its ground-station link on UDP ``18570 + i`` (``udpout``: speak first) and
its home ``spacing_m`` east of the previous one (``PX4_HOME_LAT/LON``, SIH's
default location). Every instance starts from default parameters in its own
folder, in its own session with stdin from /dev/null; only the processes
started here are stopped, by PID.
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ENV_BINARY = "GCS_SWARM_PX4"
ENV_INSIDE = "GCS_SWARM_PX4_NETNS"
HOME = (45.467116, -73.757837, 32.34)
"""SIH's default location (SIH_LOC_LAT0, SIH_LOC_LON0 in degE7, SIH_LOC_H0):
latitude, longitude [deg], altitude [m AMSL]."""
EARTH_RADIUS_M = 6378137.0


def binary_or_skip() -> Path:
    """The PX4 SITL binary named by the environment, or skip the test."""
    value = os.environ.get(ENV_BINARY)
    if not value:
        pytest.skip(f"{ENV_BINARY} is not set: no PX4 SITL binary to fly (docs/sitl.md)")
    path = Path(value)
    if not path.is_file() or not os.access(path, os.X_OK):
        pytest.fail(f"{ENV_BINARY}={value} is not an executable file")
    return path


def only_loopback() -> bool:
    """True inside a network namespace whose only device is ``lo``."""
    import socket

    # The current namespace's devices (/sys/class/net shows the mounter's).
    return [name for _, name in socket.if_nameindex()] == ["lo"]


def in_private_namespace_or_rerun(nodeid: str, keep: Path) -> bool:
    """True when the caller may start PX4 here (a namespace with only
    loopback). Otherwise the test ``nodeid`` is run again inside ``unshare
    -n`` (loopback up), this call fails if it failed there, and returns
    False: the caller then returns at once. Skipped when ``unshare -n`` is
    not allowed here.

    ``keep`` (the calling test's ``tmp_path``) holds what the re-run leaves:
    its temporary folders (``inside/``: the PX4 instances' folders and
    consoles, the station's run folders) and the station's whole log at
    INFO (``inside.log``), kept as pytest keeps the outer run's folder
    (its last three runs), not cleaned by the next re-run."""
    if only_loopback():
        return True
    if os.environ.get(ENV_INSIDE):
        pytest.fail("inside the private namespace but it has devices other than lo")
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        pytest.skip("no unshare or ip: PX4 needs a private network namespace (docs/sitl.md)")
    probe = subprocess.run(["unshare", "-n", "true"], capture_output=True)
    if probe.returncode != 0:
        pytest.skip(f"unshare -n not permitted here: {probe.stderr.decode().strip()}")
    root = Path(__file__).resolve().parents[2]
    cmd = (f"ip link set lo up && exec {sys.executable} -m pytest -x -q -p no:cacheprovider "
           f"--show-capture=no -m px4_sitl --basetemp='{keep / 'inside'}' "
           f"--log-file='{keep / 'inside.log'}' --log-file-level=INFO '{nodeid}'")  # fmt: skip
    env = dict(os.environ, **{ENV_INSIDE: "1"})
    run = subprocess.run(["unshare", "-n", "sh", "-c", cmd], cwd=root, env=env,
                         capture_output=True, text=True)  # fmt: skip
    sys.stdout.write(run.stdout[-20000:])
    if run.returncode != 0:
        pytest.fail(f"{nodeid} failed inside unshare -n (exit {run.returncode}; its folders"
                    f" and log: {keep}):\n"
                    f"{run.stdout[-6000:]}\n{run.stderr[-3000:]}")  # fmt: skip
    return False


def gcs_port(instance: int) -> int:
    return 18570 + instance


def link(instance: int) -> str:
    """The station's connection string to instance ``instance``."""
    return f"udpout:127.0.0.1:{gcs_port(instance)}"


def home_of(instance: int, spacing_m: float) -> tuple[float, float]:
    lat0, lon0, _ = HOME
    dlon = math.degrees(instance * spacing_m / (EARTH_RADIUS_M * math.cos(math.radians(lat0))))
    return lat0, lon0 + dlon


@dataclass
class Px4Instance:
    index: int
    folder: Path
    proc: subprocess.Popen[bytes]

    @property
    def sysid(self) -> int:
        return self.index + 1


@dataclass
class Px4Swarm:
    binary: Path
    instances: list[Px4Instance] = field(default_factory=list)
    started_at: float = 0.0

    def log(self, i: int) -> str:
        out = self.instances[i].folder / "out.log"
        return out.read_text(errors="replace") if out.is_file() else ""

    def pause(self, i: int, on: bool) -> None:
        """SIGSTOP (``on``) or SIGCONT instance ``i``'s process group: a vehicle
        whose link goes quiet and comes back (its simulation, SIH in the same
        process, is frozen meanwhile)."""
        p = self.instances[i].proc
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGSTOP if on else signal.SIGCONT)

    def kill(self, i: int) -> None:
        """Stop instance ``i`` (SIGKILL to the process started here)."""
        p = self.instances[i].proc
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(5)


@contextlib.contextmanager
def px4_swarm(
    binary: Path, n: int, workdir: Path, *, first: int = 0, spacing_m: float = 5.0
) -> Iterator[Px4Swarm]:
    """Start instances ``first .. first + n - 1`` from default parameters in
    ``workdir``, instance ``i``'s home ``i spacing_m`` east of SIH's default; stop
    them on exit."""
    etc = binary.resolve().parent.parent / "etc"
    if not etc.is_dir():
        pytest.fail(f"no etc/ (ROMFS) beside {binary}")
    swarm = Px4Swarm(binary, started_at=time.monotonic())
    try:
        for k in range(n):
            i = first + k
            folder = workdir / f"I{i}"
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir(parents=True)
            lock = Path(f"/tmp/px4_lock-{i}")
            fuser = ["fuser", str(lock)]
            held = lock.exists() and subprocess.run(fuser, capture_output=True).returncode == 0
            if held:
                pytest.fail(f"PX4 instance {i} is already running on this machine ({lock})")
            for stale in (lock, Path(f"/tmp/px4-sock-{i}")):
                with contextlib.suppress(OSError):
                    stale.unlink()  # left by a killed instance (start-px4-swarm.sh does this)
            lat, lon = home_of(i, spacing_m)  # by instance: a mixed swarm's homes stay apart
            # PX4_HOME_LAT/LON go to SIH_LOC_LAT0/LON0, INT32 parameters in degE7.
            env = dict(os.environ, PX4_SIM_MODEL="sihsim_quadx", PX4_HOME_LAT=str(round(lat * 1e7)),
                       PX4_HOME_LON=str(round(lon * 1e7)))  # fmt: skip
            with (folder / "out.log").open("wb") as out:
                proc = subprocess.Popen(
                    [str(binary), "-i", str(i), "-d", str(etc)],
                    cwd=folder, env=env, stdin=subprocess.DEVNULL, stdout=out,
                    stderr=subprocess.STDOUT, start_new_session=True,
                )  # fmt: skip
            swarm.instances.append(Px4Instance(i, folder, proc))
        yield swarm
    finally:
        for inst in swarm.instances:
            if inst.proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(inst.proc.pid, signal.SIGKILL)
            with contextlib.suppress(subprocess.TimeoutExpired):
                inst.proc.wait(10)


class Px4Monitor:
    """Watch PX4 instance ``instance`` from a thread on its onboard link (PX4
    sends it to UDP 14540 + i). PX4 ignores SET_MESSAGE_INTERVAL for
    HEARTBEAT there (measured: 1 Hz still), so the monitor asks for one
    HEARTBEAT every ``poll_s`` with MAV_CMD_REQUEST_MESSAGE (answered: 20 Hz
    measured), which times a mode change to ``poll_s``. System id 254, no
    HEARTBEAT and no setpoint of its own: it feeds no failsafe."""

    def __init__(self, instance: int, poll_s: float = 0.05) -> None:
        import socket
        import threading

        from pymavlink.dialects.v20 import ardupilotmega as mav

        self._mavmod = mav
        self.heartbeats: list[tuple[float, int, bool]] = []
        """(monotonic arrival time [s], custom_mode, armed)."""
        self.texts: list[tuple[float, str]] = []
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind(("127.0.0.1", 14540 + instance))
        self._sock.settimeout(poll_s / 2)
        self._peer = ("127.0.0.1", 14580 + instance)
        self._mav = mav.MAVLink(None, srcSystem=254, srcComponent=191)
        self._mav.robust_parsing = True
        self._ask = self._mav.command_long_encode(instance + 1, 1, 512, 0, 0, 0, 0, 0, 0, 0, 0)
        self._poll_s = poll_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        mav = self._mavmod
        asked = 0.0
        while not self._stop.is_set():
            if time.monotonic() - asked >= self._poll_s:
                asked = time.monotonic()
                self._sock.sendto(self._ask.pack(self._mav), self._peer)
            try:
                data, _ = self._sock.recvfrom(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            now = time.monotonic()
            for msg in self._mav.parse_buffer(data) or []:
                kind = msg.get_type()
                if kind == "HEARTBEAT" and msg.autopilot != mav.MAV_AUTOPILOT_INVALID:
                    armed = bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
                    self.heartbeats.append((now, int(msg.custom_mode), armed))
                elif kind == "STATUSTEXT":
                    self.texts.append((now, str(msg.text)))

    def first_mode_after(self, t0: float, modes: set[int]) -> float | None:
        """Arrival time of the first HEARTBEAT at or after ``t0`` in one of ``modes``."""
        for at, mode, _ in self.heartbeats:
            if at >= t0 and mode in modes:
                return at
        return None

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self._sock.close()
