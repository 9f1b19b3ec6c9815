"""A ``replay`` or ``eval`` whose disk fills part-way: the partial results that stop taking
frames say so once on stderr, with why and how many they keep; a replay whose results cannot
then be written names only the files it wrote (the results "(not written)", with where the
frames kept as flown are), and its ``run.json`` says the run ended, failed, not that it is
still running (two frames of the demo flight, the ``sift_magsac`` baseline; a real file size
limit, ``ulimit -f``, or a write that fails as a full disk's does)."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

import c3_matcher_tools.evaluate
import c3_matcher_tools.run.outputs
import c3_matcher_tools.run.results_file
import c3_matcher_tools.run.run_mark
from c3_matcher.cli import main
from c3_matcher_tools.run.run_mark import RUN_MARK

from .conftest import C3, SmallFlight

PARTIAL = "results.jsonl.partial"


def _limit_after_first_frame(c3: C3, flight: Path, tmp_path: Path) -> int:
    """A file size limit that holds the first frame's result line but not the second's, nor the
    two frames' results (from a replay of ``flight`` with no limit; half the second line's
    length to spare either way: the time each frame took is written in digits that vary)."""
    first = tmp_path / "unlimited"
    ran = c3("replay", str(flight), "--strategy", "sift_magsac", "--out", str(first))
    assert ran.returncode == 0, ran.stderr
    lines = (first / "results.jsonl").read_text().splitlines(keepends=True)
    assert len(lines) == 2
    limit = len(lines[0].encode()) + len(lines[1].encode()) // 2
    held = [p for p in first.iterdir() if p.name not in ("results.jsonl", "report.html")]
    assert all(p.stat().st_size < limit for p in held)  # only the results outgrow it
    return limit


def _first_frame_only(partial: Path) -> None:
    """``partial`` keeps the first frame's result line, whole, and nothing more."""
    lines = partial.read_text().splitlines(keepends=True)
    assert len(lines) == 1 and lines[0].endswith("\n")
    assert json.loads(lines[0])["index"] == 0


def _said_stopped(stderr: str, partial: Path, why: str, kept: int) -> list[str]:
    """The lines of ``stderr`` that say the partial results stopped taking frames."""
    said = [line for line in stderr.splitlines() if f"{partial}: {why}" in line]
    assert all(f"it keeps the first {kept} frame(s) and takes no more" in s for s in said), said
    return said


def test_a_replay_on_a_full_disk_names_only_the_files_it_wrote(
    small_flight: SmallFlight, tmp_path: Path, c3: C3
) -> None:
    flight, out = small_flight("full_disk"), tmp_path / "out"
    limit = _limit_after_first_frame(c3, flight, tmp_path)
    args = ("replay", str(flight), "--strategy", "sift_magsac", "--out", str(out))
    ran = c3(*args, limit_file_bytes=limit)
    assert ran.returncode == 2, ran.stderr
    assert f"c3-matcher: {out / 'results.jsonl'}: File too large" in ran.stderr
    assert len(_said_stopped(ran.stderr, out / PARTIAL, "File too large", 1)) == 1, ran.stderr
    assert not (out / "results.jsonl").exists() and not (out / "report.json").exists()
    _first_frame_only(out / PARTIAL)
    said = ran.stdout
    assert "replay full_disk with sift_magsac: 2 frames" in said, said
    assert f"results (not written; the first 1 frame(s) in {out / PARTIAL})" in said, said
    assert "report (not written)" in said and "map (not written)" in said, said
    assert f"{out / 'results.jsonl'}," not in said and str(out / "report.json") not in said
    mark = json.loads((out / RUN_MARK).read_text())
    assert "running" not in mark  # it ended: not a run killed outright
    assert mark["failed"] == f"{out / 'results.jsonl'}: File too large"


def test_an_eval_says_once_that_its_partial_results_stopped_taking_frames(
    small_flight: SmallFlight, tmp_path: Path, c3: C3
) -> None:
    """The same partial results as replay's (the run layer's): eval says it too, marks its run
    failed and exits 2 (a full disk), as replay does."""
    flight, out = small_flight("full_disk_eval"), tmp_path / "out"
    limit = _limit_after_first_frame(c3, flight, tmp_path)
    args = ("eval", str(flight), "--strategy", "sift_magsac", "--samples", "0", "--out", str(out))
    ran = c3(*args, limit_file_bytes=limit)
    kept = out / "sift_magsac" / PARTIAL
    assert len(_said_stopped(ran.stderr, kept, "File too large", 1)) == 1, ran.stderr
    _first_frame_only(kept)
    mark = json.loads((out / RUN_MARK).read_text())  # ended, saying which write was refused
    assert "running" not in mark and "File too large" in mark["failed"], mark
    assert ran.returncode == 2 and f"c3-matcher eval: {mark['failed']}" in ran.stderr


class _FullDiskOs(SimpleNamespace):
    """The ``os`` module as the partial results see it on a disk with no room left: every
    ``write`` fails with ENOSPC; the rest is the real ``os``'s."""

    def __getattr__(self, name: str) -> Any:
        return getattr(os, name)

    @staticmethod
    def write(fd: int, data: object) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _no_room(path: Path, *args: object) -> Path:
    """``write_results`` on a full disk."""
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


def test_a_replay_on_a_full_disk_says_so_in_its_json_report_and_run_json(
    small_flight: SmallFlight,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Full from the first frame: the partial results keep none, said once of both frames."""
    monkeypatch.setattr(c3_matcher_tools.run.results_file, "os", _FullDiskOs())
    monkeypatch.setattr(c3_matcher_tools.run.outputs, "write_results", _no_room)
    flight, out = small_flight("full_disk_json"), tmp_path / "out"
    args = ["replay", str(flight), "--strategy", "sift_magsac", "--out", str(out), "--json"]
    assert main(args) == 2
    said = capsys.readouterr()
    full = os.strerror(errno.ENOSPC)
    assert len(_said_stopped(said.err, out / PARTIAL, full, 0)) == 1, said.err
    assert f"{out / 'results.jsonl'}: {full}" in said.err
    report = json.loads(said.out)
    assert report["results"] is None and report["geojson"] is None and report["html"] is None
    assert "kept_as_flown" not in report  # none kept
    assert report["frames_done"] == 2
    mark = json.loads((out / RUN_MARK).read_text())
    assert "running" not in mark and mark["failed"] == f"{out / 'results.jsonl'}: {full}"


def test_a_replay_whose_disk_is_too_full_for_run_json_says_it_still_says_running(
    small_flight: SmallFlight,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """No room left even to mark the run failed: ``run.json`` keeps ``running`` (what a killed
    run leaves), and stderr says so rather than leaving it to be read as a kill."""
    monkeypatch.setattr(c3_matcher_tools.run.outputs, "write_results", _no_room)

    def unmarkable(directory: Path, failed: str | None = None, **_: object) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(directory / RUN_MARK))

    monkeypatch.setattr(c3_matcher_tools.run.run_mark, "mark_ended", unmarkable)
    flight, out = small_flight("full_for_run_json"), tmp_path / "out"
    args = ["replay", str(flight), "--strategy", "sift_magsac", "--out", str(out)]
    assert main(args) == 2
    said = capsys.readouterr().err
    assert f"c3-matcher replay: {out / RUN_MARK} still says running: " in said, said
    assert json.loads((out / RUN_MARK).read_text())["running"] is True


def test_an_eval_whose_report_a_full_disk_refuses_marks_its_run_failed(
    small_flight: SmallFlight,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The strategies ran, then ``eval.json`` could not be written: ``run.json`` says the run
    ended, failed on that file, not that it is still running (what a killed run leaves)."""
    real = c3_matcher_tools.evaluate.write_text_atomically

    def no_room_for_the_report(path: Path, text: str) -> Path:
        if path.name == "eval.json":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return real(path, text)

    monkeypatch.setattr(c3_matcher_tools.evaluate, "write_text_atomically", no_room_for_the_report)
    flight, out = small_flight("full_for_eval_json"), tmp_path / "out"
    args = ["eval", str(flight), "--strategy", "sift_magsac", "--samples", "0", "--out", str(out)]
    assert main(args) == 2
    full = f"{out / 'eval.json'}: {os.strerror(errno.ENOSPC)}"
    assert full in capsys.readouterr().err
    assert not (out / "eval.json").exists()
    assert json.loads((out / RUN_MARK).read_text())["failed"] == full
