"""``replay`` and ``eval`` replace an earlier run of their own in ``--out`` and refuse, touching
nothing, an existing directory that is not empty and holds no such run: a recorded flight-data
log (its rotated segments and ``.meta`` made by the recorder), a user's own ``report.html`` or
``results.jsonl``, or another command's output. Reruns into one directory (``--out``, the
default ``out/replay/<name>``, an ``eval`` of several flights' root) go on working, as does an
empty directory. Real runs: the shipped demo flight (one frame for ``replay``, a two-frame cut
for ``eval``), the ``sift_magsac`` baseline; the command line in a subprocess where a recorded
log is at stake, in this process (``main``) for the rest."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from c3_matcher.fdr import JsonlFdrRecorder, read_fdr
from c3_matcher.fdr.files import rotated_segments
from c3_matcher.health import MonotonicClock
from c3_matcher_tools.run.run_mark import RUN_MARK

SmallFlight = Callable[..., Path]  # the fixtures of conftest.py
C3 = Callable[..., subprocess.CompletedProcess[str]]
DEMO = Path(__file__).resolve().parents[3] / "data" / "flights" / "naip_demo"
REPLAY = ("--limit", "1", "--strategy", "sift_magsac")
EVAL = ("--strategy", "sift_magsac", "--determinism-frames", "1", "--samples", "0")


@pytest.fixture()
def cli(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> C3:
    """``cli(*args, cwd=tmp_path)``: ``c3-matcher ARGS`` in this process (quicker than a
    subprocess), run from ``cwd``."""
    from c3_matcher.cli import main

    def run(*args: str, cwd: Path = tmp_path) -> subprocess.CompletedProcess[str]:
        monkeypatch.chdir(cwd)
        capsys.readouterr()
        status = main(list(args))
        said = capsys.readouterr()
        return subprocess.CompletedProcess(args, status, said.out, said.err)

    return run


def _tree(directory: Path) -> dict[str, bytes | None]:
    """Every path under ``directory``: a file's bytes, None for a folder."""
    return {
        str(p.relative_to(directory)): p.read_bytes() if p.is_file() else None
        for p in sorted(directory.rglob("*"))
    }


def _recorded_flight(folder: Path) -> Path:
    """``folder`` holding a flight-data log the recorder wrote, rotated once (a segment and its
    ``.meta``), beside a user's own report and results."""
    folder.mkdir()
    log = folder / "fdr.jsonl"
    recorder = JsonlFdrRecorder(log, MonotonicClock(), max_bytes=1024)
    try:
        for n in range(8):
            recorder.record("matcher.frame_done", {"frame": n, "note": "x" * 200})
    finally:
        recorder.close()
    assert rotated_segments(log) and (folder / "fdr.jsonl.meta").is_file()
    (folder / "report.html").write_text("<p>my notes on flight 42</p>\n")
    (folder / "results.jsonl").write_text('{"mine": true}\n')
    return folder


def _refused(proc: subprocess.CompletedProcess[str], out: Path, holds: str) -> str:
    """The one line a refused ``--out`` gives: exit 2, naming ``out``, what it ``holds`` and
    what to give instead."""
    line = proc.stderr.strip()
    assert proc.returncode == 2 and len(line.splitlines()) == 1, proc.stderr
    assert line.startswith(f"c3-matcher: --out: {out} holds ") and holds in line, line
    assert line.endswith("give an empty or new directory"), line
    assert proc.stdout == ""
    return line


@pytest.mark.parametrize("command", ["replay", "eval"])
def test_a_recorded_flight_log_and_a_users_files_in_out_are_refused_and_left_byte_for_byte(
    command: str, small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    out = _recorded_flight(tmp_path / "flight42")
    before = _tree(out)
    if command == "replay":
        proc = c3("replay", str(DEMO), *REPLAY, "--out", str(out))
    else:
        proc = c3("eval", str(small_flight("two_frames")), *EVAL, "--out", str(out))
    line = _refused(proc, out, "fdr.000001.jsonl")
    assert f"not known as an earlier {command}'s output" in line, line
    assert _tree(out) == before  # nothing removed, replaced or made
    assert len(read_fdr(out / "fdr.jsonl")) >= 1


def test_a_folder_that_never_held_a_run_is_refused(cli: C3, tmp_path: Path) -> None:
    out = tmp_path / "userdir"
    out.mkdir()
    for name in ("notes.txt", "report.html", "results.jsonl"):
        (out / name).write_text(f"the user's {name}\n")
    before = _tree(out)
    proc = cli("replay", str(DEMO), *REPLAY, "--out", str(out))
    _refused(proc, out, "notes.txt, report.html, results.jsonl")
    assert _tree(out) == before


def test_a_replay_reruns_into_its_own_out_and_into_the_default_one(cli: C3, tmp_path: Path) -> None:
    out = tmp_path / "out"
    for _ in range(3):  # a new directory, then twice its own output
        proc = cli("replay", str(DEMO), *REPLAY, "--out", str(out))
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert len((out / "results.jsonl").read_text().splitlines()) == 1
    assert json.loads((out / RUN_MARK).read_text()) == {
        "command": "c3-matcher replay",
        "dataset": str(DEMO),
        "name": "naip_demo",
        "strategy": "sift_magsac",
    }
    for _ in range(2):  # out/replay/<name>-<strategy>
        proc = cli("replay", str(DEMO), *REPLAY)
        assert proc.returncode == 0, proc.stderr[-2000:]
    assert (tmp_path / "out" / "replay" / "naip_demo-sift_magsac" / "report.json").is_file()


def test_an_empty_directory_is_taken(cli: C3, tmp_path: Path) -> None:
    out = tmp_path / "empty"
    out.mkdir()
    proc = cli("replay", str(DEMO), *REPLAY, "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (out / "report.json").is_file() and (out / RUN_MARK).is_file()


def test_a_replay_stopped_part_way_and_one_written_before_the_mark_are_replaced(
    cli: C3, tmp_path: Path
) -> None:
    """A run stopped part-way leaves its mark, FDR and log; a finished run of this layout
    written before the mark is known by its ``report.json``."""
    out = tmp_path / "out"
    assert cli("replay", str(DEMO), *REPLAY, "--out", str(out)).returncode == 0
    for name in ("report.json", "results.jsonl", "flight.geojson", "report.html"):
        (out / name).unlink()  # what a run stopped while flying leaves
    proc = cli("replay", str(DEMO), *REPLAY, "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    (out / RUN_MARK).unlink()  # a finished run written before the mark
    proc = cli("replay", str(DEMO), *REPLAY, "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (out / RUN_MARK).is_file()


def test_a_report_json_that_is_no_replays_report_is_not_taken_for_one(
    cli: C3, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "report.json").write_text(json.dumps({"dataset": "mine", "strategy": "by hand"}))
    (out / "fdr.jsonl").write_text('{"seq": 1, "kind": "matcher.frame_done"}\n')
    before = _tree(out)
    _refused(cli("replay", str(DEMO), *REPLAY, "--out", str(out)), out, "fdr.jsonl, report.json")
    assert _tree(out) == before


def test_one_commands_output_is_refused_to_the_other(
    small_flight: SmallFlight, cli: C3, tmp_path: Path
) -> None:
    flight = str(small_flight("two_frames"))
    replayed, evaluated = tmp_path / "replayed", tmp_path / "evaluated"
    assert cli("replay", str(DEMO), *REPLAY, "--out", str(replayed)).returncode == 0
    assert cli("eval", flight, *EVAL, "--out", str(evaluated)).returncode == 0
    for out in (replayed, evaluated):
        (out / RUN_MARK).unlink()  # also known without the mark, by its report
    mine = _tree(replayed), _tree(evaluated)
    line = _refused(cli("eval", flight, *EVAL, "--out", str(replayed)), replayed, "fdr.jsonl")
    assert "not known as an earlier eval's output" in line
    line = _refused(cli("replay", str(DEMO), *REPLAY, "--out", str(evaluated)), evaluated, "eval")
    assert "not known as an earlier replay's output" in line
    assert (_tree(replayed), _tree(evaluated)) == mine
    again = cli("eval", flight, *EVAL, "--out", str(evaluated))  # its eval.json tells it
    assert again.returncode == 0, again.stderr[-2000:]
    assert (evaluated / RUN_MARK).is_file()


def test_an_eval_of_several_flights_reruns_into_its_root_and_refuses_a_foreign_one(
    small_flight: SmallFlight, cli: C3, tmp_path: Path
) -> None:
    flights = [str(small_flight(name, where=name)) for name in ("north", "south")]
    work = tmp_path / "work"
    work.mkdir()
    single = cli("eval", flights[0], *EVAL, cwd=work)  # out/eval/north: the same layout
    assert single.returncode == 0, single.stderr[-2000:]
    for _ in range(2):  # the default root out/eval, which the single eval made
        proc = cli("eval", *flights, *EVAL, cwd=work)
        assert proc.returncode == 0, proc.stderr[-2000:]
    root = work / "out" / "eval"
    assert sorted(p.name for p in root.iterdir()) == ["north", "south", "summary.json"]
    (root / "notes.txt").write_text("the user's\n")
    before = _tree(root)
    _refused(cli("eval", *flights, *EVAL, cwd=work), Path("out", "eval"), "notes.txt")
    single = cli("eval", flights[0], *EVAL, "--out", str(root / "south"))  # a flight's own
    assert single.returncode == 0, single.stderr[-2000:]
    assert "summary.json" in before and "summary.json" not in _tree(root)  # south's is north's
    _refused(cli("eval", flights[0], *EVAL, "--out", str(root)), root, "north")
    (root / "notes.txt").unlink()  # an eval of several flights alone: said so
    line = _refused(cli("eval", flights[0], *EVAL, "--out", str(root)), root, "north")
    assert "it holds eval's output for several flights: give a flight's folder)" in line, line
