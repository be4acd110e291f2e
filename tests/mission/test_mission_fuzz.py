"""A fuzz of mission files through ``check``'s code path (issue 15): 10,000
seeded hostile documents (``missionfuzz``), each either a valid mission or
refused with ``fuzz.yaml:LINE: key.path: message`` lines; never another
exception, never a hang.

A watchdog (SIGALRM) fails the test if one document takes over
``DOC_LIMIT_S`` (generous: documents take milliseconds; it catches a hang,
it does not time anything). ``MISSION_FUZZ_DOCS`` and ``MISSION_FUZZ_SEED``
change the count and seed; the benchmark (benchmarks/bench_mission_fuzz.py)
runs more."""

from __future__ import annotations

import collections
import os
from pathlib import Path

from missionfuzz import check_document, documents, watchdog

N = int(os.environ.get("MISSION_FUZZ_DOCS", "10000"))
SEED = int(os.environ.get("MISSION_FUZZ_SEED", "15"))
DOC_LIMIT_S = 60


def test_hostile_mission_documents_give_a_mission_or_file_line_problems(
    tmp_path: Path,
) -> None:
    outcomes: collections.Counter[str] = collections.Counter()
    for i, text in enumerate(documents(SEED, N)):
        try:
            with watchdog(DOC_LIMIT_S):
                outcomes[check_document(text)] += 1
        except BaseException:
            kept = tmp_path / f"fuzz-{SEED}-{i}.yaml"
            kept.write_text(text, errors="surrogateescape")
            print(f"document {i} of seed {SEED} (kept in {kept}):\n{text[:2000]}")
            raise
    print(f"{N} documents, seed {SEED}: {dict(outcomes)}")
    assert sum(outcomes.values()) == N
    # Both outcomes are exercised: most documents are refused, some stay valid.
    assert outcomes["refused"] > N // 2 and outcomes["ok"] > N // 50, outcomes
