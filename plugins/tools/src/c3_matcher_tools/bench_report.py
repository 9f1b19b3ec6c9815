"""The figures ``c3-matcher bench`` reports from its cases' results: each case judged against
the latency target C3-PT-01 (:func:`latency_target`), the ratios a run proves (speed-ups of
frame p50 and p95, slower / faster, >1 means the second case is faster; the median of the two
cases' ratios round by round, where both were timed in the same rounds; peak RSS of both sides,
MiB) and the table."""

from __future__ import annotations

import statistics
from typing import Any

from c3_matcher_tools.run.acceptance import Bar

__all__ = [
    "CANDIDATE_P95_BAR",
    "FRAME_P95_BAR",
    "GPU_MEMORY_BAR",
    "comparisons",
    "format_report",
    "latency_target",
    "paired_speedup",
    "text_report",
]

Result = dict[str, Any]
Pair = tuple[str, Result | None, Result | None]  # (what, slower side, faster side)

FRAME_P95_BAR = Bar("<=", 180)
"""C3-PT-01: the p95 of a frame's match (ms): 1 query and its candidate tiles."""
CANDIDATE_P95_BAR = Bar("<=", 60)
"""C3-PT-01: the p95 of a candidate's time (ms), every stage it went through."""
GPU_MEMORY_BAR = Bar("<=", 800)
"""C3-PT-01: the GPU memory the matcher holds (MB). Bench does not measure it: its peak MiB is
the worker's host memory (RSS)."""
GPU_CPU_ONLY = "not measured (every case ran on the CPU: no GPU memory held)"
GPU_NOT_MEASURED = "not measured by bench (its peak MiB is host memory, RSS)"


def latency_target(results: list[Result]) -> Result:
    """Each case (by label) judged against C3-PT-01: its frame p95 and candidate p95 (ms),
    each with ``"pass"`` True (bar met), False (missed) or None (no figure: no frame matched,
    so no candidate time); GPU memory is never measured here, neither passed nor missed, and
    ``gpu_memory`` says why (every case on the CPU, or bench measuring host memory only)."""
    cpu = all(r["provider"] == "CPUExecutionProvider" for r in results)
    return {
        "bars": {
            "frame_p95_ms": str(FRAME_P95_BAR),
            "per_candidate_p95_ms": str(CANDIDATE_P95_BAR),
            "gpu_memory_mb": str(GPU_MEMORY_BAR),
        },
        "gpu_memory": GPU_CPU_ONLY if cpu else GPU_NOT_MEASURED,
        "cases": {
            r["label"]: {
                "frame_p95_ms": _judged(FRAME_P95_BAR, r["frame_ms"]),
                "per_candidate_p95_ms": _judged(CANDIDATE_P95_BAR, r["per_candidate_ms"]),
                "gpu_memory_mb": {"value": None, "pass": None},
            }
            for r in results
        },
    }


def _judged(bar: Bar, ms: dict[str, float] | None) -> Result:
    """A p95 of ``ms`` and whether it meets ``bar`` (None without a figure)."""
    p95 = None if ms is None else ms["p95"]
    return {"value": p95, "pass": None if p95 is None else bar.judge(p95)}


def _p95_cell(bar: Bar, ms: dict[str, float] | None) -> str:
    """A p95 in ms as the table prints it, marked '!' where it misses ``bar``; n/a when there
    is none (no frame matched)."""
    if ms is None:
        return "n/a"
    return bar.figure(ms["p95"]) + ("!" if bar.judge(ms["p95"]) is False else "")


def _target_line(target: Result) -> str:
    """The C3-PT-01 bars the table's p95 columns are judged against, and GPU memory's state."""
    bars = target["bars"]
    return (
        f"C3-PT-01 bars: frame p95 {bars['frame_p95_ms']} ms, cand p95 "
        f"{bars['per_candidate_p95_ms']} ms ('!' = bar missed; n/a: nothing to measure), GPU "
        f"memory {bars['gpu_memory_mb']} MB: {target['gpu_memory']}"
    )


def _speedup(slow: dict[str, Any] | None, fast: dict[str, Any] | None, key: str = "p50") -> str:
    """``slow / fast`` of frame ``key`` as ``"2.50x"`` (>1: ``fast`` is faster); '' if absent."""
    if not slow or not fast or not fast["frame_ms"][key]:
        return ""
    return f"{slow['frame_ms'][key] / fast['frame_ms'][key]:.2f}x"


def _sources(r: dict[str, Any]) -> str:
    counts = r.get("feature_sources") or {}
    total = sum(counts.values())
    if not total:
        return ""
    return " ".join(f"{k} {v}/{total}" for k, v in sorted(counts.items()) if k != "none") or ""


def comparisons(results: list[Result]) -> list[Result]:
    """The ratios a run proves, per strategy: stored vs extracted tiles, adaptive vs full
    LightGlue, cached vs new tiles, each engine case vs the PyTorch reference (speed-ups of
    frame p50 and p95, the paired speed-up (:func:`paired_speedup`) where there is one, peak
    RSS of both sides); a tile-source comparison whose faster case drew no features from that
    source says so (``not_compared``) instead of a ratio."""
    out: list[Result] = []
    for strategy in dict.fromkeys(r["case"]["strategy"] for r in results):
        for what, slow, fast in _pairs(results, strategy):
            if slow is None or fast is None:
                continue
            unserved = _unserved(what, fast)
            if unserved:  # the faster side's features never came from where it is named for
                out.append({"strategy": strategy, "comparison": what, "not_compared": unserved})
                continue
            out.append(
                {
                    "strategy": strategy,
                    "comparison": what,
                    "speedup_p50": slow["frame_ms"]["p50"] / fast["frame_ms"]["p50"],
                    "speedup_p95": slow["frame_ms"]["p95"] / fast["frame_ms"]["p95"],
                    **_paired(slow, fast),
                    "peak_rss_mib": (fast["peak_rss_mib"], slow["peak_rss_mib"]),
                }
            )
    return out


def paired_speedup(slow: Result, fast: Result) -> float | None:
    """The median over the rounds of ``slow``'s match time / ``fast``'s of the same round
    (``frame_ms_runs``: the two were timed one after the other in every round, on the same
    frame), which load drifting during the run moves far less than a ratio of medians; None
    unless both have a time for every round."""
    slow_ms, fast_ms = slow.get("frame_ms_runs") or [], fast.get("frame_ms_runs") or []
    if not slow_ms or len(slow_ms) != len(fast_ms) or not all(fast_ms):
        return None
    return statistics.median(s / f for s, f in zip(slow_ms, fast_ms, strict=True))


def _paired(slow: Result, fast: Result) -> Result:
    """``speedup_paired`` and its number of rounds, where :func:`paired_speedup` has one."""
    paired = paired_speedup(slow, fast)
    return (
        {} if paired is None else {"speedup_paired": paired, "rounds": len(fast["frame_ms_runs"])}
    )


_SERVED_FROM = {
    "cached vs new tiles": ("cached", "the cache (no tile recurs between the frames timed)"),
    "stored features vs extraction": ("stored", "the store (its features missing or stale)"),
}


def _unserved(what: str, fast: Result) -> str | None:
    """Why comparison ``what`` would measure nothing: none of its faster case's tile features
    came from where that case is named for; else None."""
    source, where = _SERVED_FROM.get(what, (None, ""))
    if source is None or (fast.get("feature_sources") or {}).get(source):
        return None
    return f"not compared: no tile features came from {where}"


def _first(results: list[Result], strategy: str, kind: str, **fields: Any) -> Result | None:
    """The first result of ``strategy``'s ``kind`` case whose fields are ``fields`` (a
    callable value: a test of the field)."""
    for r in results:
        c = r["case"]
        if c["strategy"] != strategy or c["kind"] != kind:
            continue
        if all(v(c.get(k)) if callable(v) else c.get(k) == v for k, v in fields.items()):
            return r
    return None


def _pairs(results: list[Result], strategy: str) -> list[Pair]:
    base = dict(stored_features=False, lightglue_mode=None, intra_op_threads=None)
    new = _first(results, strategy, "engine", tile_cache_size=0, **base)
    cached = _first(results, strategy, "engine", tile_cache_size=lambda n: n > 0)
    stored = _first(results, strategy, "engine", stored_features=True)
    other = _first(results, strategy, "engine", lightglue_mode=bool)
    torch_ref = _first(results, strategy, "pytorch")
    pairs: list[Pair] = [
        ("cached vs new tiles", new, cached),
        ("stored features vs extraction", new, stored),
    ]
    if other is not None:
        full = other["case"]["lightglue_mode"] == "full"
        pairs.append(("adaptive vs full LightGlue", *((other, new) if full else (new, other))))
    for r in (new, cached, stored, other):
        if r is not None:
            pairs.append((f"{r['label']} vs PyTorch", torch_ref, r))
    return pairs


def format_report(report: dict[str, Any]) -> str:
    """The table: a row a case (its frame and candidate p95 marked '!' where they miss
    C3-PT-01's bars), the line naming those bars, the speed-ups and the stage times."""
    results = report["results"]
    sift = next((r for r in results if r["case"]["kind"] == "sift"), None)
    torch_ref = {r["case"]["strategy"]: r for r in results if r["case"]["kind"] == "pytorch"}
    m = report["machine"]
    lines = [
        f"machine: {m['platform']}, {m['cpus']} CPUs, onnxruntime {m['onnxruntime']} "
        f"(providers {', '.join(m['available_providers'])}); {report['runs']} runs per "
        f"case; data {report.get('data', '?')}; frame = 1 query + its candidate tiles",
        f"{'case':66} {'provider (EP)':18} {'frame p50':>9} {'frame p95':>9} {'cand p95':>8} "
        f"{'peak MiB':>8} {'inliers':>7} {'vs torch':>8} {'vs SIFT':>7}  tile features",
    ]
    for r in results:
        ref = torch_ref.get(r["case"]["strategy"])
        vs_torch = _speedup(ref, r) if r["case"]["kind"] == "engine" else ""
        vs_sift = _speedup(sift, r) if sift and r is not sift else ""
        lines.append(
            f"{r['label']:66} {r['provider'].removesuffix('ExecutionProvider'):18} "
            f"{r['frame_ms']['p50']:9.0f} "
            f"{_p95_cell(FRAME_P95_BAR, r['frame_ms']):>9} "
            f"{_p95_cell(CANDIDATE_P95_BAR, r['per_candidate_ms']):>8} "
            f"{r['peak_rss_mib']:8.0f} {r['best_inliers']:7d} {vs_torch:>8} "
            f"{vs_sift:>7}  {_sources(r)}"
        )
    lines.append(_target_line(report.get("latency_target") or latency_target(results)))
    lines.append(
        "speed-ups (frame p50 and p95, slower / faster; paired: the median of the two cases' "
        "ratios round by round; peak MiB faster vs slower side):"
    )
    for c in report.get("comparisons") or comparisons(results):
        if "not_compared" in c:
            lines.append(f"  {c['strategy']}: {c['comparison']}: {c['not_compared']}")
            continue
        fast_mib, slow_mib = c["peak_rss_mib"]
        paired = (
            f", {c['speedup_paired']:.2f}x paired (median of {c['rounds']} rounds)"
            if "speedup_paired" in c
            else ""
        )
        lines.append(
            f"  {c['strategy']}: {c['comparison']}: {c['speedup_p50']:.2f}x p50, "
            f"{c['speedup_p95']:.2f}x p95{paired}; peak {fast_mib:.0f} vs {slow_mib:.0f} MiB"
        )
    lines.append("per stage, ms (p50/p95):")
    for r in results:
        parts = [f"{k} {v['p50']:.0f}/{v['p95']:.0f}" for k, v in r["stages_ms"].items()]
        lines.append(f"  {r['label']}: " + ", ".join(parts))
    return "\n".join(lines)


def text_report(report: dict[str, Any]) -> str:
    """:func:`format_report`'s table, then a note for each case whose timed frames raised
    InsufficientInliersError: their times count in the frame columns, but candidate and stage
    times come only from frames that matched, so a case where none did has no candidate time
    (n/a); then why the PyTorch reference was not timed, where the run would have timed it;
    which cases were timed in turn, round by round; last, each case that failed and why."""
    lines = [format_report(report)]
    for r in report["results"]:
        raised = r.get("frames_raised", 0)
        if not raised:
            continue
        matched = r["runs"] - raised
        lines.append(
            f"note: {r['label']}: {raised}/{r['runs']} timed frames raised "
            "InsufficientInliersError (in frame p50/p95, inliers 0); cand p95 and stage times: "
            + (f"the {matched} that matched" if matched else "n/a (none matched)")
        )
    if why := (report.get("pytorch_reference") or {}).get("reason"):
        lines.append(f"note: the PyTorch reference was not timed (no vs torch): {why}")
    for group in report.get("interleaved", ()):
        lines.append(f"timed in turn, one match each a round: {'; '.join(group)}")
    lines += [f"failed: {f['label']}: {f['error']}" for f in report["failed"]]
    return "\n".join(lines)
