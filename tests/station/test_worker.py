"""``runtime.worker.run_cpu_job``: the interpreter's switch interval is short
while a CPU-bound job runs beside the event loop, and restored after the
last one (what it buys the setpoint stream is measured by
``benchmarks/bench_lookahead.py``, not here)."""

from __future__ import annotations

import asyncio
import sys
import threading

import pytest

from gcs_swarm.runtime.worker import JOB_SWITCH_INTERVAL_S, run_cpu_job


def test_the_switch_interval_is_short_during_jobs_and_restored_after_the_last() -> None:
    before = sys.getswitchinterval()
    release = threading.Event()
    seen: list[float] = []
    lock = threading.Lock()

    async def main() -> None:
        loop = asyncio.get_running_loop()
        both = asyncio.Event()

        def job() -> str:
            with lock:
                seen.append(sys.getswitchinterval())
                if len(seen) == 2:
                    loop.call_soon_threadsafe(both.set)
            release.wait(5.0)  # both run until the loop has looked
            return threading.current_thread().name

        first = asyncio.ensure_future(run_cpu_job(job))
        second = asyncio.ensure_future(run_cpu_job(job))
        await asyncio.wait_for(both.wait(), 5.0)
        assert sys.getswitchinterval() == JOB_SWITCH_INTERVAL_S
        release.set()
        names = await asyncio.gather(first, second)
        # Both in worker threads, not on the loop's.
        assert threading.main_thread().name not in names

    asyncio.run(main())
    assert seen == [JOB_SWITCH_INTERVAL_S, JOB_SWITCH_INTERVAL_S]
    assert sys.getswitchinterval() == before


def test_a_failing_job_restores_the_switch_interval_and_raises() -> None:
    before = sys.getswitchinterval()

    def job() -> None:
        raise ValueError("bad look-ahead")

    with pytest.raises(ValueError, match="bad look-ahead"):
        asyncio.run(run_cpu_job(job))
    assert sys.getswitchinterval() == before


def test_a_shorter_interval_already_set_is_kept() -> None:
    before = sys.getswitchinterval()
    sys.setswitchinterval(JOB_SWITCH_INTERVAL_S / 5)
    shorter = sys.getswitchinterval()  # as the interpreter keeps it (whole us)
    try:
        assert asyncio.run(run_cpu_job(sys.getswitchinterval)) == shorter
        assert sys.getswitchinterval() == shorter
    finally:
        sys.setswitchinterval(before)
