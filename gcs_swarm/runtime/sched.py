"""A shorter scheduler time slice for the station's processes (Linux 6.12+).

The station's work comes in bursts: a network's reports arrive, a step, its
setpoints leave; a sharded step crosses three processes. On a machine whose
cores are busy (the emulator or SITL beside the station, another shard) a
process that wakes waits for the running one's slice to end, 1.4 ms by
default on this machine's kernel (6.18, EEVDF), and each hop of a sharded
step showed a tail of 3-4 ms at p99 against 0.1-1.3 ms at p50
(benchmarks/README.md, "Scale, 2026-12-06 (eleventh session)"). Since Linux
6.12 a SCHED_OTHER thread may ask for a shorter slice of its own
(``sched_setattr``'s ``sched_runtime``; no privilege needed): its virtual
deadline comes sooner, so it runs sooner when it wakes. It changes no
priority or share of the CPU.

``short_slice`` asks for ``SLICE_S`` for every thread of this process (the
threads it starts later inherit it); the ``gcs-swarm run`` and ``gcs-swarm
shard`` commands call it. ``GCS_SWARM_SLICE_US`` overrides the slice (in
microseconds; 0 leaves the scheduler alone). Elsewhere (another OS, an
older kernel: no ``se.slice`` in ``/proc/self/sched``, an architecture whose
system call number is not known here) it does nothing and says so.
"""

from __future__ import annotations

import ctypes
import logging
import os
import platform
import struct
import sys

__all__ = ["ENV_SLICE_US", "SLICE_S", "default_slice", "short_slice", "thread_slices_ns"]

_log = logging.getLogger("gcs_swarm.sched")

SLICE_S = 0.3e-3
"""The slice asked for [s]: through one shard at 500 and 750 vehicles, 0.3 ms
for the shard and the controller gave a lower p99 than the default 1.4 ms
in 11 of 16 alternated runs, medians 10.85 against 12.36 ms at 750 and 6.61
against 8.27 ms at 500; at 1,500 (a saturated shard) 2 of 4
(benchmarks/README.md, "Scale, 2026-12-06 (eleventh session)")."""

ENV_SLICE_US = "GCS_SWARM_SLICE_US"

_SYS_SCHED_SETATTR = {"x86_64": 314, "aarch64": 274}
_SCHED_OTHER = 0
_ATTR = struct.Struct("=IIQiIQQQ")  # struct sched_attr, first version (48 bytes)


def thread_slices_ns() -> dict[int, int]:
    """Each thread of this process and its slice [ns] (``se.slice`` of
    ``/proc/self/task/TID/sched``); {} where the kernel shows none."""
    out: dict[int, int] = {}
    try:
        tids = os.listdir("/proc/self/task")
    except OSError:
        return out
    for tid in tids:
        try:
            with open(f"/proc/self/task/{tid}/sched") as f:
                for line in f:
                    if line.startswith("se.slice"):
                        out[int(tid)] = int(line.split(":")[1])
                        break
        except (OSError, ValueError):
            continue
    return out


def short_slice(slice_s: float | None = None) -> bool:
    """Ask for a ``slice_s`` (default: ``GCS_SWARM_SLICE_US``, else
    ``SLICE_S``) time slice for every thread of this process; True when the
    kernel took it for all of them (module docstring)."""
    if slice_s is None:
        env = os.environ.get(ENV_SLICE_US)
        try:
            slice_s = SLICE_S if env is None else float(env) * 1e-6
        except ValueError:
            _log.warning("%s=%r is not a number of microseconds: the default slice", ENV_SLICE_US,
                         env)  # fmt: skip
            slice_s = SLICE_S
    if slice_s <= 0.0:
        return False
    return _set_slice(round(slice_s * 1e9))


def default_slice() -> bool:
    """Give every thread of this process the kernel's own slice again (a
    process started by one that asked for ``short_slice`` inherits it: the
    benchmarks' emulator, which stands for vehicles of their own)."""
    return _set_slice(0)


def _set_slice(ns: int) -> bool:
    number = _SYS_SCHED_SETATTR.get(platform.machine())
    threads = thread_slices_ns() if sys.platform.startswith("linux") else {}
    if number is None or not threads:
        _log.debug("no custom scheduler slice here (%s %s)", sys.platform, platform.machine())
        return False
    libc = ctypes.CDLL(None, use_errno=True)
    # SCHED_OTHER keeps the thread's nice value only if it is passed again;
    # sched_runtime 0 is the kernel's own slice.
    nice = os.getpriority(os.PRIO_PROCESS, 0)
    attr = ctypes.create_string_buffer(_ATTR.pack(_ATTR.size, _SCHED_OTHER, 0, nice, 0, ns, 0, 0))
    ok = True
    for tid in threads:
        if libc.syscall(number, tid, attr, 0) != 0:
            ok = False
            _log.debug("sched_setattr(%d): %s", tid, os.strerror(ctypes.get_errno()))
    return ok
