"""What ``c3-matcher replay`` leaves in an output directory when it cannot run or cannot finish:
another run's files untouched when that run holds the directory or the strategy is unknown, the
previous results whole when writing fails part-way, and nothing outside the default output
directory whatever the dataset's name (two-frame flights, the ``sift_magsac`` baseline)."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.fdr import JsonlFdrRecorder, read_fdr
from c3_matcher.health import MonotonicClock
from c3_matcher_tools.run import exclusive_output_dir
from c3_matcher_tools.run.outputs import REPLAY_RUN
from c3_matcher_tools.run.run_mark import RUN_MARK

SmallFlight = Callable[..., Path]  # the fixtures of conftest.py
C3 = Callable[..., subprocess.CompletedProcess[str]]


def _files(directory: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(directory.iterdir()) if p.is_file()}


def test_a_replay_into_a_directory_another_run_is_writing_is_refused_leaving_its_files(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flight = small_flight("two_frames")
    out = tmp_path / "out"
    out.mkdir()
    (out / RUN_MARK).write_text(json.dumps(REPLAY_RUN.mark))  # the first run, still going
    (out / "matcher.log").write_text('{"kind": "c3.matcher.ready"}\n')
    running = JsonlFdrRecorder(out / "fdr.jsonl", MonotonicClock())
    try:
        running.record("matcher.frame_done", {"frame": 0})
        proc = c3("replay", str(flight), "--strategy", "sift_magsac", "--out", str(out))
        assert proc.returncode == 2 and "another process" in proc.stderr, proc.stderr
        assert [r["kind"] for r in read_fdr(out / "fdr.jsonl")] == ["matcher.frame_done"]
        assert (out / "matcher.log").read_text() == '{"kind": "c3.matcher.ready"}\n'
    finally:
        running.close()


def test_a_replay_into_a_directory_another_replay_or_eval_holds_is_refused_leaving_its_files(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    """Between its FDR's close and its reports' writing, a run holds its directory still."""
    flight, out = _replayed_once(small_flight, c3, tmp_path)
    before = _files(out)
    with exclusive_output_dir(out):
        proc = c3("replay", str(flight), "--strategy", "sift_magsac", "--out", str(out))
    assert proc.returncode == 2 and "another replay or eval" in proc.stderr, proc.stderr
    assert str(out) in proc.stderr
    assert _files(out) == before


def _replayed_once(small_flight: SmallFlight, c3: C3, tmp_path: Path) -> tuple[Path, Path]:
    """A two-frame flight and the output directory of one replay of it that went well."""
    flight = small_flight("two_frames")
    out = tmp_path / "out"
    first = c3("replay", str(flight), "--strategy", "sift_magsac", "--out", str(out))
    assert first.returncode == 0, first.stderr[-2000:]
    return flight, out


def test_a_replay_with_an_unknown_strategy_leaves_an_existing_output_directory_alone(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flight, out = _replayed_once(small_flight, c3, tmp_path)
    before = _files(out)
    proc = c3("replay", str(flight), "--strategy", "no_such_strategy", "--out", str(out))
    assert proc.returncode == 2 and "no_such_strategy" in proc.stderr, proc.stderr
    assert _files(out) == before


def test_a_replay_that_cannot_finish_writing_leaves_no_torn_and_no_earlier_results(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flight, out = _replayed_once(small_flight, c3, tmp_path)
    results = (out / "results.jsonl").read_bytes()
    assert len(results) > 4096  # the limit below cuts it, not the FDR or the log
    again = c3(
        "replay",
        str(flight),
        "--strategy",
        "sift_magsac",
        "--out",
        str(out),
        limit_file_bytes=4096,
    )
    assert again.returncode != 0 and "File too large" in again.stderr, again.stderr
    # the FDR and log are this run's: the earlier run's results are not left beside them
    assert not (out / "results.jsonl").exists() and not (out / "report.json").exists()
    assert not [p.name for p in out.iterdir() if ".tmp" in p.name]


@pytest.mark.parametrize("name", ["../escaped", "/ABSOLUTE/escaped", "..", ""])
def test_a_dataset_name_that_is_not_one_path_component_cannot_name_the_default_output(
    name: str, small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    name = name.replace("/ABSOLUTE", str(tmp_path))
    flight = small_flight(name)
    work = tmp_path / "work"
    work.mkdir()
    proc = c3("replay", str(flight), "--strategy", "sift_magsac", cwd=work)
    assert proc.returncode == 2 and "one path component" in proc.stderr, proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flight", "work"]
    assert list(work.iterdir()) == []


def _replay_table(outcomes: list[Any]) -> str:
    from c3_matcher_tools.replay import _report_lines
    from c3_matcher_tools.run import summarize

    report = {"strategy": "xfeat", "wall_s": 1.0, "startup_s": 0.1}
    report |= {"results": "r", "fdr": "f", "geojson": "g", "html": None}
    return "\n".join(_report_lines("myflight", report, summarize(outcomes), Path("out")))


@pytest.mark.parametrize(("ok", "hinted"), [(0, True), (1, False)])
def test_a_replay_where_no_frame_matched_says_what_to_check(ok: int, hinted: bool) -> None:
    from c3_matcher_tools.testing.outcomes import frame_outcome

    said = _replay_table(
        [
            frame_outcome(i, status="ok" if i < ok else "insufficient", has_truth=False)
            for i in range(6)
        ]
    )
    assert ("no frame matched" in said) is hinted
    assert ("c3-matcher eval" in said) is hinted


@pytest.mark.parametrize(
    ("last", "hinted"), [(None, False), ("unreadable", False), ("insufficient", True)]
)
def test_frames_without_their_true_tile_that_raised_are_no_alarm(
    last: str | None, hinted: bool
) -> None:
    """Frames without their true tile that raised did right (IT-05), and an unreadable image
    never reached the matcher: neither is a store or attitude problem. A read frame whose
    true tile was there and that raised is."""
    from c3_matcher_tools.testing.outcomes import frame_outcome

    outcomes = [frame_outcome(i, status="insufficient", true_present=False) for i in range(3)]
    outcomes += [frame_outcome(3, status=last)] if last else []
    said = _replay_table(outcomes)
    assert ("no frame matched" in said) is hinted
    assert "raised on 3/3 frames without their true tile" in said


def test_a_frame_whose_image_cannot_be_decoded_is_recorded_and_the_flight_goes_on(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    """A damaged image body (its header whole, so the checks before the run pass) is the
    camera's loss: that frame is ``unreadable`` with the reason, the others are flown."""
    import json

    flight = small_flight("damaged")
    images = sorted((flight / "frames").iterdir())
    images[1].write_bytes(images[1].read_bytes()[:2000])
    out = tmp_path / "out"
    proc = c3("replay", str(flight), "--strategy", "sift_magsac", "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    assert [r["status"] for r in rows][1] == "unreadable" and rows[0]["status"] != "unreadable"
    assert images[1].name in rows[1]["error"] and "decod" in rows[1]["error"]
    assert "unreadable images 1" in proc.stdout
    assert json.loads((out / "report.json").read_text())["unreadable"] == 1
    done = [r for r in read_fdr(out / "fdr.jsonl") if r["kind"] == "matcher.frame_done"]
    assert len(done) == 1  # the matcher never saw the damaged frame
    assert (out / "report.html").stat().st_size > 0
