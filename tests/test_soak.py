"""A short but real soak: hundreds of frames of the shipped demo flight through the
XFeat strategy, the durable FDR rotating underneath. Memory must stay flat and the FDR's
sequence numbers contiguous across every segment, with no corrupt line.

The long soak is the same loop for longer: ``C3_SOAK_FRAMES=20000 .venv/bin/python -m pytest
tests/test_soak.py -q`` (README, "Guarantees")."""

from __future__ import annotations

import itertools
import os
import time
from pathlib import Path

from c3_matcher.config import C3Settings
from c3_matcher.errors import InsufficientInliersError
from c3_matcher.fdr import read_fdr

REPO = Path(__file__).resolve().parents[1]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
FRAMES = int(os.environ.get("C3_SOAK_FRAMES", "160"))
WARMUP = 40
RSS_GROWTH_LIMIT_MIB = 48.0


def _rss_mib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


def test_soak_xfeat_flat_memory_contiguous_fdr(engine_dir, tmp_path):
    from c3_matcher_tools.dataset.format import load_dataset
    from c3_matcher_tools.run import open_matcher

    dataset = load_dataset(FLIGHT)
    settings = C3Settings().model_copy(
        update={
            "engines": C3Settings().engines.model_copy(update={"directory": engine_dir}),
            "fdr": C3Settings().fdr.model_copy(update={"max_bytes": 128 * 1024}),
            # fewer keypoints keep the CI soak short; the long soak may use the defaults
            "matcher": C3Settings().matcher.model_copy(
                update={"max_keypoints": int(os.environ.get("C3_SOAK_KEYPOINTS", "1024"))}
            ),
        }
    )
    out = tmp_path / "soak"
    calibration = dataset.calibration
    ok = insufficient = 0
    rss_after_warmup = 0.0
    started = time.perf_counter()
    with open_matcher(settings, "xfeat", out, log_level="WARNING") as matcher:
        store = dataset.open_store()
        try:
            for i, record in enumerate(itertools.islice(itertools.cycle(dataset.frames), FRAMES)):
                frame = dataset.nav_frame(record)
                try:
                    matcher.match(frame, dataset.rerank(record, store), calibration)
                    ok += 1
                except InsufficientInliersError:
                    insufficient += 1
                if i + 1 == WARMUP:
                    rss_after_warmup = _rss_mib()
        finally:
            store.close()
    rss_end = _rss_mib()
    elapsed = time.perf_counter() - started
    assert ok + insufficient == FRAMES and ok > FRAMES // 3
    growth = rss_end - rss_after_warmup
    assert growth < RSS_GROWTH_LIMIT_MIB, (
        f"RSS grew {growth:.1f} MiB over {FRAMES - WARMUP} frames "
        f"({rss_after_warmup:.0f} -> {rss_end:.0f} MiB, {elapsed:.0f} s)"
    )
    segments = [
        *sorted(out.glob("fdr.[0-9]*.jsonl"), key=lambda p: int(p.name.split(".")[1])),
        out / "fdr.jsonl",
    ]
    assert len(segments) > 1  # rotation happened under load
    seqs: list[int] = []
    terminal = 0
    for seg in segments:
        result = read_fdr(seg)
        assert result.corrupt == [], f"{seg}: {result.corrupt[:2]}"
        seqs.extend(r["seq"] for r in result)
        terminal += sum(
            r["kind"] in ("matcher.frame_done", "matcher.insufficient_inliers") for r in result
        )
    assert seqs == list(range(1, len(seqs) + 1))
    assert terminal == FRAMES  # one terminal record per frame, none lost
