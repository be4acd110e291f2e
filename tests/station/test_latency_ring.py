"""``LatencyRing.add_since`` (one datagram's setpoints at once) keeps the
ring exactly as one ``add`` per setpoint does: samples, count, maximum; and
the ring holds the last latencies, the very floats."""

from __future__ import annotations

import random

from gcs_swarm.runtime.endpoints import LatencyRing


def test_add_since_is_add_for_each_arrival_time_in_order() -> None:
    rng = random.Random(7)
    for size in (1, 5, 64):
        one, many = LatencyRing(size), LatencyRing(size)
        every: list[float] = []  # each latency, as Python computes it
        for _ in range(300):
            now = rng.uniform(0.0, 100.0)
            k = rng.choice([0, 1, 3, size - 1, size, size + 2, 2 * size + 1])
            since = [rng.choice([None, now - rng.uniform(0.0, 0.05)]) for _ in range(k)]
            for t0 in since:
                if t0 is not None:
                    one.add(now - t0)
                    every.append(now - t0)
            many.add_since(now, since)
            assert many.samples() == one.samples()
            assert (many.count, many.max_s) == (one.count, one.max_s)
            assert one.samples() == every[-size:]  # the same floats, the last ``size``
            if every:
                assert one.percentile(100) == max(every[-size:])
