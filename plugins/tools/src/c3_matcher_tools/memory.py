"""The memory of this process, as the benchmarks report it (MiB)."""

from __future__ import annotations

import resource
from pathlib import Path

__all__ = ["current_rss_mib", "peak_rss_mib"]


def _proc_status_mib(field: str) -> float | None:
    """``field`` (``VmHWM``, ``VmRSS``: kB) of /proc/self/status in MiB; None where it is not."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(f"{field}:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def peak_rss_mib() -> float:
    """This process's peak resident memory: ``VmHWM``, its own program's high-water mark, where
    /proc has it; else ``ru_maxrss``, which also counts what the parent held when it forked this
    process (Linux keeps it across ``exec``: a worker started by a 4 GB test process reported
    4 GB)."""
    peak = _proc_status_mib("VmHWM")
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0 if peak is None else peak


def current_rss_mib() -> float:
    """This process's resident memory now (NaN where /proc does not say)."""
    current = _proc_status_mib("VmRSS")
    return float("nan") if current is None else current
