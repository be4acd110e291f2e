"""What the benchmark scripts share (imported as ``_common``: each script runs
with ``benchmarks/`` first on ``sys.path``)."""

from __future__ import annotations

import os


def pin(core: int) -> str:
    """Pin this process to ``core`` where the machine allows; says what was done."""
    if hasattr(os, "sched_setaffinity") and (os.cpu_count() or 1) > 1:
        os.sched_setaffinity(0, {core % (os.cpu_count() or 1)})
        return f"core {core}"
    return "not pinned"
