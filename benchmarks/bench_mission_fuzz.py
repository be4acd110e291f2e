"""The mission-file fuzz at scale (issue 15): many more seeded hostile
documents than the suite's 10,000 (``tests/mission/missionfuzz.py``) through
``check``'s code path, in process.

Run from the repository root: ``python benchmarks/bench_mission_fuzz.py
[--docs N] [--seeds S ...]`` (default 100,000 documents over seeds 101-110;
about 6 min of one core). Prints per seed how many documents were valid,
how many refused, the slowest document and the CPU time per document, and
exits 1 on the first document that raises anything but a ``MissionError``
with ``fuzz.yaml:LINE: key.path: message`` lines (the document is written
to ``fuzz-failure.yaml``).
"""

from __future__ import annotations

import argparse
import collections
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "mission"))

from _common import pin  # noqa: E402
from missionfuzz import check_document, documents  # noqa: E402


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--docs", type=int, default=100_000, help="documents in all (default 100000)")
    p.add_argument("--seeds", type=int, nargs="+", default=list(range(101, 111)))
    args = p.parse_args()
    print(f"mission fuzz: {args.docs} documents over seeds {args.seeds} ({pin(1)})")
    per_seed = max(1, args.docs // len(args.seeds))
    total: collections.Counter[str] = collections.Counter()
    for seed in args.seeds:
        outcomes: collections.Counter[str] = collections.Counter()
        slowest, cpu0 = (0.0, -1), time.process_time()
        for i, text in enumerate(documents(seed, per_seed)):
            t0 = time.perf_counter()
            try:
                outcomes[check_document(text)] += 1
            except BaseException as err:
                Path("fuzz-failure.yaml").write_text(text, errors="surrogateescape")
                print(f"seed {seed} document {i}: {type(err).__name__}: {err}"
                      " (written to fuzz-failure.yaml)")  # fmt: skip
                return 1
            slowest = max(slowest, (time.perf_counter() - t0, i))
        cpu_ms = 1e3 * (time.process_time() - cpu0) / per_seed
        print(f"seed {seed}: {per_seed} documents, {outcomes['ok']} valid, "
              f"{outcomes['refused']} refused; slowest {1e3 * slowest[0]:.1f} ms "
              f"(#{slowest[1]}); {cpu_ms:.2f} ms CPU per document")  # fmt: skip
        total += outcomes
    print(f"all: {sum(total.values())} documents, {total['ok']} valid, {total['refused']}"
          " refused, no other exception")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
