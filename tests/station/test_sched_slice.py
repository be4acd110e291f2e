"""The station's processes ask for a shorter scheduler slice (runtime.sched):
in child processes, so that this one's scheduling is left alone; read back
from the kernel (``se.slice`` of ``/proc/PID/task/TID/sched``). Skipped,
with the reason, where the kernel has no custom slices (before Linux 6.12,
or not Linux)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gcs_swarm.runtime.sched import ENV_SLICE_US, SLICE_S, thread_slices_ns

ROOT = Path(__file__).resolve().parents[2]

_CHILD = """
import json, sys, threading
from gcs_swarm.runtime import sched
inherited = sched.thread_slices_ns()
if "--from-default" in sys.argv:  # a parent's short slice is inherited: start from the kernel's
    sched.default_slice()
before = sched.thread_slices_ns()
stop = threading.Event()
early = threading.Thread(target=stop.wait); early.start()
took = sched.short_slice()
late = threading.Thread(target=stop.wait); late.start()
short = sched.thread_slices_ns()
back = sched.default_slice()
after = sched.thread_slices_ns()
stop.set(); early.join(); late.join()
print(json.dumps({"before": list(before.values()), "took": took, "short": list(short.values()),
                  "back": back, "after": list(after.values())}))
"""


def _kernel_has_slices() -> None:
    if not thread_slices_ns():
        pytest.skip("no se.slice in /proc/self/task/*/sched: no custom scheduler slices here")


def _child(env: dict[str, str], *args: str) -> dict[str, object]:
    run = subprocess.run([sys.executable, "-c", _CHILD, *args], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=60, check=True)  # fmt: skip
    out: dict[str, object] = json.loads(run.stdout)
    return out


def test_every_thread_gets_the_short_slice_and_the_kernels_back() -> None:
    _kernel_has_slices()
    env = {k: v for k, v in os.environ.items() if k != ENV_SLICE_US}
    r = _child(env, "--from-default")
    default = r["before"]
    assert isinstance(default, list) and len(set(default)) == 1
    assert r["took"] is True
    # Three threads: the main one, one started before the call, one after it.
    assert r["short"] == [round(SLICE_S * 1e9)] * 3
    assert r["back"] is True and r["after"] == default * 3


def test_the_environment_sets_the_slice_or_leaves_the_scheduler_alone() -> None:
    _kernel_has_slices()
    r = _child(dict(os.environ, **{ENV_SLICE_US: "500"}))
    assert r["took"] is True and r["short"] == [500_000] * 3
    r = _child(dict(os.environ, **{ENV_SLICE_US: "0"}))
    assert r["took"] is False and r["short"] == r["before"] * 3


def test_a_shard_process_runs_on_the_short_slice() -> None:
    """``gcs-swarm shard`` asks for it at start (it waits for a controller
    that is not there; stopped here by its PID)."""
    _kernel_has_slices()
    env = {k: v for k, v in os.environ.items() if k != ENV_SLICE_US}
    proc = subprocess.Popen([sys.executable, "-m", "gcs_swarm", "shard", "--connect",
                             "tcp/127.0.0.1:9"], cwd=ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        want = round(SLICE_S * 1e9)
        seen: list[int] = []
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and proc.poll() is None:
            seen = []
            for tid in os.listdir(f"/proc/{proc.pid}/task"):
                try:
                    text = Path(f"/proc/{proc.pid}/task/{tid}/sched").read_text()
                except OSError:
                    continue
                lines = text.splitlines()
                seen += [int(x.split(":")[1]) for x in lines if x.startswith("se.slice")]
            if seen and all(s == want for s in seen) and len(seen) > 1:
                break
            time.sleep(0.1)
        assert seen and all(s == want for s in seen), seen
    finally:
        proc.kill()
        proc.wait(timeout=10)
