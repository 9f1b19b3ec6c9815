"""An ``eval`` over two flights marks each flight's ``run.json`` as that flight was left, however
the evaluation ends: a write a full disk refused fails only the flight whose file it was (the
flight never reached is not complete, not failed, and keeps no earlier run's results under
this run's mark); a ``run.json`` that cannot be written is said and the other flight still
marked; a refused ``summary.json`` still prints what was done; stdout's reader gone marks the
flights done as complete; a stopped eval's ``run.json`` says it is not complete (the
``sift_magsac`` baseline on two two-frame flights; a full disk as a write that fails as one
does)."""

from __future__ import annotations

import errno
import json
import os
import signal
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

import c3_matcher_tools.eval_tables
import c3_matcher_tools.evaluate
import c3_matcher_tools.run.outputs
import c3_matcher_tools.run.run_mark
from c3_matcher.cli import main
from c3_matcher_tools.run.run_mark import RUN_MARK

SmallFlight = Callable[..., Path]  # the fixtures of conftest.py
FULL = os.strerror(errno.ENOSPC)


def _eval(small_flight: SmallFlight, tmp_path: Path, *extra: str) -> tuple[list[str], Path]:
    """The command line of an eval of two two-frame flights ``f1`` and ``f2`` into ``out``."""
    flights = [small_flight(name, where=name) for name in ("f1", "f2")]
    out = tmp_path / "out"
    args = ["eval", *map(str, flights), "--strategy", "sift_magsac", "--out", str(out)]
    return [*args, "--determinism-frames", "1", "--samples", "0", *extra], out


def _refusing(
    module: Any, monkeypatch: pytest.MonkeyPatch, refused: Callable[[Path], bool]
) -> None:
    """``module``'s ``write_text_atomically`` failing as on a full disk for the paths
    ``refused`` picks."""
    real = module.write_text_atomically

    def write(path: Path, text: str) -> Path:
        if refused(path):
            raise OSError(errno.ENOSPC, FULL, str(path))
        return real(path, text)

    monkeypatch.setattr(module, "write_text_atomically", write)


def _mark(out: Path, flight: str) -> dict[str, Any]:
    mark: dict[str, Any] = json.loads((out / flight / RUN_MARK).read_text())
    return mark


def test_a_refused_report_fails_its_flight_alone_and_the_next_is_not_reached(
    small_flight: SmallFlight,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    args, out = _eval(small_flight, tmp_path, "--json")
    assert main(args) == 0  # an earlier eval: f2's results are there
    assert (out / "f2" / "sift_magsac" / "results.jsonl").is_file()
    capsys.readouterr()
    _refusing(c3_matcher_tools.evaluate, monkeypatch, lambda p: p == out / "f1" / "eval.json")
    assert main(args) == 2
    failed = f"{out / 'f1' / 'eval.json'}: {FULL}"
    assert _mark(out, "f1")["failed"] == failed and "running" not in _mark(out, "f1")
    f2 = _mark(out, "f2")
    assert f2["complete"] is False and "failed" not in f2 and "running" not in f2, f2
    assert not (out / "f2" / "sift_magsac").exists()  # no earlier run's results under its mark
    said = capsys.readouterr()
    assert failed in said.err
    document = json.loads(said.out)  # what was done, said all the same: each flight named
    assert document["flights"] == []
    rows = {row["flight"]: row["stopped"] for row in document["summary"]}
    assert (
        rows["f1"] == f"ended by a write that failed as its files were written: see its {RUN_MARK}"
    )
    assert (
        rows["f2"] == "not run: the evaluation was ended by a write that failed before this flight"
    )


def test_a_refused_summary_still_prints_what_was_done(
    small_flight: SmallFlight,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    args, out = _eval(small_flight, tmp_path, "--json")
    _refusing(c3_matcher_tools.run.outputs, monkeypatch, lambda p: p.name == "summary.json")
    assert main(args) == 2
    said = capsys.readouterr()
    document = json.loads(said.out)
    assert [Path(f["dataset"]).name for f in document["flights"]] == ["f1", "f2"]
    assert [row["flight"] for row in document["summary"]] == ["f1", "f2"]
    assert f"{out / 'summary.json'}: {FULL}" in said.err
    for flight in ("f1", "f2"):  # each flight's own files are whole
        mark = _mark(out, flight)
        assert "running" not in mark and "failed" not in mark and "complete" not in mark, mark


def test_a_run_json_that_cannot_be_written_is_said_and_the_other_flight_still_marked(
    small_flight: SmallFlight,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    args, out = _eval(small_flight, tmp_path)
    _refusing(c3_matcher_tools.run.run_mark, monkeypatch, lambda p: p == out / "f1" / RUN_MARK)
    assert main(args) == 2  # a full disk, as replay's
    assert f"c3-matcher eval: {out / 'f1' / RUN_MARK} still says running: " in (
        capsys.readouterr().err
    )
    assert _mark(out, "f1")["running"] is True
    assert "running" not in _mark(out, "f2") and "failed" not in _mark(out, "f2")


def test_a_reader_gone_marks_the_flights_done_complete_and_the_rest_not(
    small_flight: SmallFlight, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Stdout's reader left as f2's table was to be printed (f2's files written): no flight
    failed, f2 complete too; the broken pipe answered as ever (141)."""
    args, out = _eval(small_flight, tmp_path)
    real = c3_matcher_tools.eval_tables.print_flight_table

    def gone(ctx: Any, args: Any, name: str, *rest: Any) -> None:
        if name == "f2":
            raise BrokenPipeError(errno.EPIPE, os.strerror(errno.EPIPE))
        real(ctx, args, name, *rest)

    monkeypatch.setattr(c3_matcher_tools.evaluate, "print_flight_table", gone)
    assert main(args) == 141
    for flight in ("f1", "f2"):
        mark = _mark(out, flight)
        assert "running" not in mark and "failed" not in mark and "complete" not in mark, mark


def test_a_stopped_eval_marks_its_run_not_complete(
    small_flight: SmallFlight, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C during f1: f1 stopped part-way and f2 never reached, both ``"complete": false``
    (a stopped eval's run.json read as a finished one's)."""
    args, out = _eval(small_flight, tmp_path)
    import c3_matcher_tools.geojson

    def interrupted(*args: object, **kwargs: object) -> Path:
        os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C, as the map is to be written
        raise AssertionError("the signal did not stop the run")

    monkeypatch.setattr(c3_matcher_tools.geojson, "write_geojson", interrupted)
    assert main(args) == 130
    for flight in ("f1", "f2"):
        mark = _mark(out, flight)
        assert mark["complete"] is False and "running" not in mark, mark


@pytest.mark.parametrize(
    ("at", "complete"),
    [("write_summary", True), ("eval_plots", False)],
    ids=["as-the-summary-is-written", "as-the-first-flights-plots-are-drawn"],
)
def test_a_stop_as_the_files_are_written_marks_each_flight_as_it_was_left(
    small_flight: SmallFlight,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    at: str,
    complete: bool,
) -> None:
    """Ctrl-C outside a strategy's frames: each run.json ended (complete where its eval.json was
    written whole, else not), never "running" as a killed run's; exit 130, said where."""
    args, out = _eval(small_flight, tmp_path)
    module: Any = c3_matcher_tools.evaluate
    if at == "eval_plots":
        import c3_matcher_tools.plots as module

    def interrupted(*args: object, **kwargs: object) -> Any:
        os.kill(os.getpid(), signal.SIGINT)
        raise AssertionError("the signal did not stop the run")

    monkeypatch.setattr(module, at, interrupted)
    assert main(args) == 130
    assert "c3-matcher: interrupted as its files were written" in capsys.readouterr().err
    f1, f2 = _mark(out, "f1"), _mark(out, "f2")
    assert "running" not in f1 and "running" not in f2
    assert ("complete" not in f1) is complete and ("complete" not in f2) is complete
