"""What ``c3-matcher eval`` refuses before anything runs (a strategy this build cannot run, a
missing frame image, datasets whose names cannot each name their own output directory, a
determinism subset below one frame, an output directory another run is writing), how it ends
when a strategy fails to run (every table and report written, exit status 1), and a frame image
damaged past its header (that frame's status); two-frame flights, mostly the ``sift_magsac``
baseline."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from c3_matcher.fdr import JsonlFdrRecorder
from c3_matcher.health import MonotonicClock
from c3_matcher_tools.run import exclusive_output_dir
from c3_matcher_tools.run.outputs import EVAL_RUN
from c3_matcher_tools.run.run_mark import RUN_MARK
from c3_matcher_tools.testing.cli import run_cli

SmallFlight = Callable[..., Path]  # the fixtures of conftest.py
C3 = Callable[..., subprocess.CompletedProcess[str]]
QUICK = ("--determinism-frames", "1", "--samples", "0")


def test_an_unknown_strategy_is_refused_before_anything_runs(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flight = small_flight("two_frames")
    out = tmp_path / "out"
    proc = c3("eval", str(flight), "--strategy", "no_such_strategy", "--out", str(out), *QUICK)
    assert proc.returncode == 2, proc.stderr
    assert "no_such_strategy" in proc.stderr and "not recognized" in proc.stderr
    assert proc.stdout == "" and not out.exists()


def test_a_strategy_that_failed_to_run_is_reported_and_the_exit_status_is_1(
    small_flight: SmallFlight, tmp_path: Path
) -> None:
    """xfeat cannot start (no engines where the configuration points); the baseline still runs."""
    flight = small_flight("two_frames")
    out = tmp_path / "out"
    no_engines = {"C3_MATCHER_ENGINES__DIRECTORY": str(tmp_path / "no-engines")}
    argv = ("eval", flight, "--strategy", "xfeat", "--out", out, *QUICK)
    proc = run_cli(*argv, cwd=tmp_path, settings=no_engines, timeout=600)
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert "xfeat" in proc.stdout and "failed to run" in proc.stdout  # the table
    assert ", max_keypoints each strategy its own" in proc.stdout  # no --max-keypoints given
    assert "failed to run: xfeat on two_frames" in proc.stderr
    rows = {r["strategy"]: r for r in json.loads((out / "eval.json").read_text())["strategies"]}
    assert "no valid xfeat" in rows["xfeat"]["error"] and "sift_magsac" in rows


def test_a_missing_frame_image_is_refused_before_anything_runs(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flight = small_flight("two_frames", without_image=0)
    out = tmp_path / "out"
    proc = c3("eval", str(flight), "--strategy", "sift_magsac", "--out", str(out), *QUICK)
    assert proc.returncode == 2 and "000000.jpg: no such image file" in proc.stderr, proc.stderr
    assert not out.exists()


def test_a_frame_image_damaged_past_its_header_is_that_frames_status(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flight = small_flight("two_frames")
    image = sorted((flight / "frames").iterdir())[0]
    image.write_bytes(image.read_bytes()[:2000])  # the header whole: the checks pass
    out = tmp_path / "out"
    proc = c3("eval", str(flight), "--strategy", "sift_magsac", "--out", str(out), *QUICK)
    assert proc.returncode == 0, proc.stderr[-2000:]
    results = (out / "sift_magsac" / "results.jsonl").read_text().splitlines()
    first, second = (json.loads(line) for line in results)
    assert first["status"] == "unreadable" and image.name in first["error"]
    assert second["status"] != "unreadable"
    said = "1 frame image(s) could not be read (the camera's loss, not the matcher's)"
    assert said in proc.stdout  # and no IT measure counts it:
    (row,) = json.loads((out / "eval.json").read_text())["strategies"]
    assert row["metrics"]["false_confident"]["of"] == 1


def test_several_datasets_of_one_name_are_refused_before_anything_runs(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    first = small_flight("two_frames", where="first")
    second = small_flight("two_frames", where="second")
    out = tmp_path / "out"
    proc = c3("eval", str(first), str(second), "--strategy", "sift_magsac", "--out", str(out))
    assert proc.returncode == 2 and "both named 'two_frames'" in proc.stderr, proc.stderr
    assert str(first) in proc.stderr and str(second) in proc.stderr
    assert not out.exists()


@pytest.mark.parametrize("name", ["../escaped", "/ABSOLUTE/escaped", ".."])
def test_a_dataset_name_that_is_not_one_path_component_is_refused_before_anything_runs(
    name: str, small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    plain = small_flight("plain", where="plain")
    odd = small_flight(name.replace("/ABSOLUTE", str(tmp_path)), where="odd")
    work = tmp_path / "work"
    work.mkdir()
    for datasets in ([str(odd)], [str(plain), str(odd)]):  # out/eval/<name>, <--out>/<name>
        proc = c3("eval", *datasets, "--strategy", "sift_magsac", *QUICK, cwd=work)
        assert proc.returncode == 2 and "one path component" in proc.stderr, proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["odd", "plain", "work"]
    assert list(work.iterdir()) == []


@pytest.mark.parametrize("frames", ["-1", "0"])
def test_a_determinism_subset_below_one_frame_is_a_usage_error(
    frames: str, small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flight = small_flight("two_frames")
    out = tmp_path / "out"
    proc = c3("eval", str(flight), "--determinism-frames", frames, "--out", str(out))
    assert proc.returncode == 2 and "--determinism-frames: must be >= 1" in proc.stderr
    assert not out.exists()


@pytest.mark.parametrize("datasets", [1, 2])
def test_an_eval_into_a_directory_another_replay_or_eval_holds_is_refused_and_writes_nothing(
    datasets: int, small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flights = [str(small_flight(f"f{n}", where=f"f{n}")) for n in range(datasets)]
    out = tmp_path / "out"
    held = out / "f0" if datasets > 1 else out  # a dataset's own directory, or --out itself
    with exclusive_output_dir(held):
        proc = c3("eval", *flights, "--strategy", "sift_magsac", "--out", str(out), *QUICK)
    assert proc.returncode == 2 and "another replay or eval" in proc.stderr, proc.stderr
    assert f"{held}:" in proc.stderr
    assert not [p for p in out.rglob("*") if p.is_file()]


def test_an_eval_into_a_directory_another_run_is_writing_is_refused_and_writes_nothing(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flight = small_flight("two_frames")
    out = tmp_path / "out"
    (out / "sift_magsac").mkdir(parents=True)
    (out / RUN_MARK).write_text(json.dumps(EVAL_RUN.mark))  # that run is an eval's
    running = JsonlFdrRecorder(out / "sift_magsac" / "fdr.jsonl", MonotonicClock())
    try:
        proc = c3("eval", str(flight), "--strategy", "sift_magsac", "--out", str(out), *QUICK)
        assert proc.returncode == 2 and "another process" in proc.stderr, proc.stderr
        assert sorted(p.name for p in out.iterdir()) == [RUN_MARK, "sift_magsac"]
    finally:
        running.close()


def test_an_eval_stopped_part_way_leaves_no_earlier_evals_figures_as_current(
    small_flight: SmallFlight, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A rerun into an evaluated directory, stopped before its own figures: the earlier run's
    eval.json, charts and match pictures are gone (not shown beside this run's strategy
    directories)."""
    import c3_matcher_tools.evaluate
    from c3_matcher.cli import main

    flight = small_flight("two_frames")
    out = tmp_path / "out"
    out.mkdir()
    (out / RUN_MARK).write_text(json.dumps(EVAL_RUN.mark))  # an earlier eval's directory
    for name in ("eval.json", "inliers.png", "error.png", "notes.txt"):
        (out / name).write_text("the earlier run's\n")
    (out / "matches").mkdir()
    (out / "matches" / "xfeat_0003.png").write_text("the earlier run's\n")

    def stopped(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(c3_matcher_tools.evaluate, "evaluate_strategy", stopped)
    assert (
        main(["eval", str(flight), "--strategy", "sift_magsac", "--out", str(out), *QUICK]) == 130
    )
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt", RUN_MARK]
