"""What the benchmark scripts share (imported as ``_common``: each script runs
with ``benchmarks/`` first on ``sys.path``)."""

from __future__ import annotations

import os

# One BLAS thread, before any benchmark imports numpy: as the gcs-swarm and
# sim-vehicle commands run (gcs_swarm/cli.py; docs/architecture.md, "Threads").
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def pin(core: int) -> str:
    """Pin this process to ``core`` where the machine allows; says what was done.

    Every thread of it: ``sched_setaffinity(0)`` pins only the calling
    thread, and the BLAS worker threads numpy started at import kept both
    cores (measured 2026-12-04: a station's row products ran 0.37 core on
    the emulator's core)."""
    if hasattr(os, "sched_setaffinity") and (os.cpu_count() or 1) > 1:
        cpus = {core % (os.cpu_count() or 1)}
        tasks = os.listdir("/proc/self/task") if os.path.isdir("/proc/self/task") else ["0"]
        for tid in tasks:
            try:
                os.sched_setaffinity(int(tid), cpus)
            except OSError:  # a thread that ended meanwhile
                pass
        return f"core {core}"
    return "not pinned"
