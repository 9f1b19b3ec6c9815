"""``c3-matcher match`` names each dropped candidate (input position, tile id, why) in its JSON
whether the frame gets a fix (exit 0) or not (exit 3), and the FDR's terminal record names the
same ones in the same words, with the matcher's label, each kept candidate's input position and,
without a fix as with one, the frame's stage timings (real engines, the shipped demo flight's
frames and store)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

from c3_matcher.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[2]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
FRAMES = [json.loads(line) for line in (FLIGHT / "frames.jsonl").read_text().splitlines()]


def _match(
    tmp_path: Path, engine_dir: Path, frame: dict[str, Any]
) -> subprocess.CompletedProcess[str]:
    """The frame against windows of the store at its first three candidates, with its pose."""
    tile_ids = [",".join(map(str, c["tile_id"])) for c in frame["candidates"][:3]]
    return run_cli(
        *("match", "--query", FLIGHT / frame["image"]),
        *("--calibration", FLIGHT / "calibration.json"),
        *("--attitude", ",".join(map(str, frame["attitude_deg"])), "--height", frame["height_m"]),
        *("--store", FLIGHT / "tiles.mbtiles", "--window", "448", "--no-correspondences"),
        *(arg for tile_id in tile_ids for arg in ("--tile-id", tile_id)),
        cwd=tmp_path,
        engine_dir=engine_dir,
        settings={"C3_MATCHER_FDR__PATH": str(tmp_path / "fdr.jsonl")},
    )


def _terminal(tmp_path: Path, kind: str) -> dict[str, Any]:
    records = [json.loads(x) for x in (tmp_path / "fdr.jsonl").read_text().splitlines()]
    (payload,) = (r["payload"] for r in records if r["kind"] == kind)
    return dict(payload)


def _fdr_dropped(record: dict[str, Any]) -> list[tuple[int, list[float], str]]:
    return [(d["candidate_index"], d["tile_id"], d["reason"]) for d in record["dropped"]]


def _json_dropped(out: dict[str, Any]) -> list[tuple[int, list[float], str]]:
    return [(d["tile_index"], d["tile_id"], d["reason"]) for d in out["dropped"]]


def test_a_frame_without_a_fix_says_why_each_candidate_was_dropped(engine_dir, tmp_path):
    """Frame 13 flies over no tile of its re-rank: every candidate is dropped (no inliers, or
    refused on geometry), exit 3. The JSON error object and the FDR record name each one."""
    frame = FRAMES[13]
    assert not frame["true_tile_present"]
    proc = _match(tmp_path, engine_dir, frame)
    assert proc.returncode == 3, proc.stderr[-2000:]
    out = json.loads(proc.stdout)
    assert out["error"] == "InsufficientInliersError" and out["candidates_dropped"] == 3
    assert [d["tile_index"] for d in out["dropped"]] == [0, 1, 2]
    assert [d["tile_id"] for d in out["dropped"]] == [c["tile_id"] for c in frame["candidates"][:3]]
    assert all(d["reason"] for d in out["dropped"])
    record = _terminal(tmp_path, "matcher.insufficient_inliers")
    assert _fdr_dropped(record) == _json_dropped(out)  # the same account, in the same words
    assert record["matcher_label"] == out["matcher_label"] == "disk_lightglue"
    timings = record["timings_ms"]
    stages = timings["query_preprocess"] + timings["query_extract"]
    stages += sum(v for t in record["per_candidate_timings_ms"] for v in t.values())
    assert 0.9 * timings["total"] <= stages <= timings["total"]  # the frame's time accounted for


def test_a_frame_with_a_fix_ties_each_fdr_row_to_its_input_position(engine_dir, tmp_path):
    frame = FRAMES[0]
    proc = _match(tmp_path, engine_dir, frame)
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout)
    done = _terminal(tmp_path, "matcher.frame_done")
    assert done["matcher_label"] == out["matcher_label"] == "disk_lightglue"
    kept = [(c["tile_index"], c["tile_id"], c["inlier_count"]) for c in out["per_candidate"]]
    rows = [(r["candidate_index"], r["tile_id"], r["inlier_count"]) for r in done["per_candidate"]]
    assert rows == kept
    assert _fdr_dropped(done) == _json_dropped(out)
    assert len(kept) + len(done["dropped"]) == done["candidates_input"] == 3
