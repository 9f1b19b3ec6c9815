"""An eval rerun into an earlier eval's folder with fewer strategies leaves only what it wrote:
the folder of a strategy the earlier eval ran and this one does not (its results, report, map,
FDR, log and second run) is removed before the run, as eval.json and the charts are; a file of
the user's inside it, and a folder no eval.json names, are left as they were."""

from __future__ import annotations

import json
from pathlib import Path

from c3_matcher_tools.testing.cli import run_cli

from .conftest import SmallFlight

QUICK = ("--determinism-frames", "1", "--samples", "0")


def _eval(flight: Path, out: Path, *strategies: str, engine_dir: Path) -> None:
    chosen = [a for s in strategies for a in ("--strategy", s)]
    proc = run_cli(
        "eval", flight, *chosen, "--no-baseline", *QUICK, "--out", out,
        cwd=out.parent, engine_dir=engine_dir, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]


def test_a_rerun_with_fewer_strategies_leaves_no_earlier_strategys_folder(
    small_flight: SmallFlight, engine_dir: Path, tmp_path: Path
) -> None:
    flight, out = small_flight("two_frames"), tmp_path / "ev"
    _eval(flight, out, "xfeat", "sift_magsac", engine_dir=engine_dir)
    assert (out / "sift_magsac" / "results.jsonl").is_file()
    assert (out / "sift_magsac" / "run2" / "fdr.jsonl").is_file()
    _eval(flight, out, "xfeat", engine_dir=engine_dir)
    report = json.loads((out / "eval.json").read_text())
    assert [e["strategy"] for e in report["strategies"]] == ["xfeat"]
    assert not (out / "sift_magsac").exists()
    assert (out / "xfeat" / "results.jsonl").is_file()


def test_a_users_file_in_an_earlier_strategys_folder_is_kept_and_its_results_go(
    small_flight: SmallFlight, engine_dir: Path, tmp_path: Path
) -> None:
    flight, out = small_flight("two_frames"), tmp_path / "ev"
    _eval(flight, out, "xfeat", "sift_magsac", engine_dir=engine_dir)
    (out / "sift_magsac" / "notes.txt").write_text("the user's\n")
    (out / "mine").mkdir()  # a folder no eval.json names
    (out / "mine" / "results.jsonl").write_text("the user's\n")
    _eval(flight, out, "xfeat", engine_dir=engine_dir)
    assert sorted(p.name for p in (out / "sift_magsac").iterdir()) == ["notes.txt"]
    assert (out / "sift_magsac" / "notes.txt").read_text() == "the user's\n"
    assert (out / "mine" / "results.jsonl").read_text() == "the user's\n"
