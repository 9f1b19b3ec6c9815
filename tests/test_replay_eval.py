"""``c3-matcher replay`` and ``c3-matcher eval`` end to end on the built-in demo flight
(data/flights/naip_demo), in subprocesses, with the real engines: the C3-IT bars for the default
strategy, the outputs' shape, and stdout carrying only results."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from c3_matcher.fdr import read_fdr
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "data" / "flights" / "naip_demo"


def c3(args: list[str], engine_dir: Path) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=REPO, engine_dir=engine_dir, timeout=1200)


def test_demo_flight_is_in_the_project() -> None:
    ds = load_dataset(DEMO)
    assert 24 <= len(ds.frames) <= 60
    assert any(not f.true_tile_present for f in ds.frames)
    assert all(p.stat().st_size < 5_000_000 for p in DEMO.rglob("*") if p.is_file())
    assert (REPO / "data" / "flights" / "ATTRIBUTION.md").is_file()


def test_replay_writes_results_fdr_and_report(engine_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "replay"
    proc = c3(
        [
            "replay",
            str(DEMO),
            "--limit",
            "4",
            "--max-keypoints",
            "1024",
            "--out",
            str(out),
            "--json",
        ],
        engine_dir,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    report = json.loads(proc.stdout)  # stdout: exactly the report
    assert report["frames"] == 4 and report["strategy"] == "disk_lightglue"
    assert "replay naip_demo disk_lightglue [" in proc.stderr  # the progress bar
    lines = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines()]
    assert [r["index"] for r in lines] == [0, 1, 2, 3]
    ds = load_dataset(DEMO)
    for r, frame in zip(lines, ds.frames, strict=False):
        if frame.true_tile_present:
            assert r["status"] == "ok" and r["correct"]
            assert r["result"]["per_candidate"][0]["inlier_correspondences"]
        else:
            assert r["status"] == "insufficient"
    kinds = {rec["kind"] for rec in read_fdr(out / "fdr.jsonl")}
    assert "matcher.frame_done" in kinds
    assert json.loads((out / "report.json").read_text())["ok"] == report["ok"]
    assert report["settings"]["strategy"] == "disk_lightglue"
    assert report["settings"]["photometric"] is not None  # resolved: the strategy's own
    assert report["lightglue_settings"]["exit_matches"] == 8  # DISK's own, beside [matcher]
    assert "lightglue.exit_matches" in (out / "report.html").read_text()


def test_eval_meets_the_c3_it_bars_for_the_default_strategy(
    engine_dir: Path, tmp_path: Path
) -> None:
    out = tmp_path / "eval"
    proc = c3(
        [
            "eval",
            str(DEMO),
            "--strategy",
            "disk_lightglue",
            "--max-keypoints",
            "1024",
            "--determinism-frames",
            "4",
            "--samples",
            "2",
            "--out",
            str(out),
        ],
        engine_dir,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "C3-IT-01" in proc.stdout and "sift_magsac" in proc.stdout  # the table
    report = json.loads((out / "eval.json").read_text())
    rows = {r["strategy"]: r for r in report["strategies"]}
    assert set(rows) == {"disk_lightglue", "sift_magsac"}
    m = rows["disk_lightglue"]["metrics"]
    assert m["C3-IT-01"]["p5_best_inliers"] >= 80
    assert m["C3-IT-02"]["pass"] and m["C3-IT-02"]["frames_compared"] == 4
    assert m["C3-IT-03"]["p95_mean_error_px"] < 2.5
    assert m["C3-IT-04"]["correct_rate"] >= 0.95
    assert m["C3-IT-05"]["pass"] and m["C3-IT-05"]["absent_frames"] >= 1
    assert all(m[k]["pass"] for k in m)
    assert "metrics" in rows["sift_magsac"]  # the baseline ran through the same pipeline
    from c3_matcher.compose import build_plugin_host

    host = build_plugin_host()
    for name, row in rows.items():  # the settings each strategy ran with, its defaults resolved
        ran, defaults = row["settings"], host.resolve(name).defaults
        assert ran["strategy"] == name and ran["max_keypoints"] == 1024
        assert ran["photometric"] == defaults.photometric
        assert ran["refit_threshold_px"] == defaults.refit_threshold_px
        lightglue = row["lightglue_settings"]  # [lightglue], resolved the same way
        if name == "sift_magsac":  # matches without LightGlue: none of them applied
            assert lightglue == {}
            continue
        assert lightglue["exit_matches"] == defaults.exit_matches
        assert lightglue["filter_threshold"] == defaults.filter_threshold
    for name in ("inliers.png", "error.png"):
        assert (out / name).stat().st_size > 1000
    assert list((out / "matches").glob("disk_lightglue_*.png"))


@pytest.mark.parametrize("command", ["replay", "eval"])
def test_a_missing_dataset_is_a_usage_error(command: str, engine_dir: Path, tmp_path: Path) -> None:
    proc = c3([command, str(tmp_path / "nowhere")], engine_dir)
    assert proc.returncode == 2 and "dataset.json" in proc.stderr and proc.stdout == ""
