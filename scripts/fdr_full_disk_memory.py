"""What a disk that refuses every write costs the FDR's process in memory, record by record.

    .venv/bin/python scripts/fdr_full_disk_memory.py [RECORDS ...]

For each count (default 20000 and 100000), in a fresh process: a recorder with the default
``[fdr]`` limits on a disk that answers every write with ENOSPC is given that many records of
the size of a ``matcher.frame_done`` (1.9 KB, the median on the shipped flights). Printed: how
many are held, how many were let go, the peak resident memory the records added, and the time
per refused record (each refusal rolls the segment back and fsyncs it).
"""

from __future__ import annotations

import contextlib
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from c3_matcher.compose import open_recorder
from c3_matcher.config import C3Settings
from c3_matcher.fdr import FdrWriteError
from c3_matcher.testing import FakeClock

RECORD_PAD = "x" * 1800  # with the envelope: 1.9 KB, a median matcher.frame_done


def _refuse(fd: int, data: object) -> int:
    raise OSError(28, "No space left on device")


def measure(count: int) -> str:
    with tempfile.TemporaryDirectory() as tmp:
        fdr = C3Settings().fdr
        rec = open_recorder(fdr, FakeClock(), path=Path(tmp) / "fdr.jsonl")
        os.write = _refuse
        base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        start = time.perf_counter()
        for i in range(count):
            with contextlib.suppress(FdrWriteError):
                rec.record("matcher.frame_done", {"i": i, "pad": RECORD_PAD})
        per_record_us = (time.perf_counter() - start) / count * 1e6
        grown_mib = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base) / 1024
        return (
            f"{count} records refused: {rec.pending} held, {rec.dropped} let go "
            f"(max_pending_bytes {fdr.max_pending_bytes}), peak RSS +{grown_mib:.0f} MiB, "
            f"{per_record_us:.0f} us a record"
        )


def main(argv: list[str]) -> int:
    if len(argv) == 1 and argv[0].startswith("--one="):
        print(measure(int(argv[0].removeprefix("--one="))))
        return 0
    for count in argv or ["20000", "100000"]:
        subprocess.run([sys.executable, __file__, f"--one={int(count)}"], check=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
