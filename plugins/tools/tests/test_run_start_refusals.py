"""``replay`` and ``eval`` refused at start-up touch nothing: everything that can refuse a run (a
missing engine, a noisy attitude out of range, a frame image that cannot be read, an ``--out``
that is, holds or lies inside the input dataset, a bad ``--samples``) is checked before
``--out`` is touched, so an existing output directory is left byte for byte as it was and a new
one is never made. ``bench --data`` checks every frame image up front, and a worker's bad input
is one line and exit 2, never a traceback; ``--threads`` is bounded. Real path: the shipped demo
flight cut to two frames, the built xfeat engines, the ``sift_magsac`` baseline."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from c3_matcher.config import C3Settings
from c3_matcher_tools.testing.cli import run_cli

SmallFlight = Callable[..., Path]  # the fixtures of conftest.py
C3 = Callable[..., subprocess.CompletedProcess[str]]
REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
NO_ENGINES = {"C3_MATCHER_ENGINES__DIRECTORY": "/nonexistent-engine-dir"}
QUICK_EVAL = ("--determinism-frames", "1", "--samples", "0")


def _tree(directory: Path) -> dict[str, bytes]:
    """Every file under ``directory`` (relative path -> bytes)."""
    return {
        str(p.relative_to(directory)): p.read_bytes()
        for p in sorted(directory.rglob("*"))
        if p.is_file()
    }


def _one_line(proc: subprocess.CompletedProcess[str]) -> str:
    err = proc.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


def _replay(
    flight: Path, out: Path, *args: str, cwd: Path, engine_dir: Path | None = None, **settings: str
) -> subprocess.CompletedProcess[str]:
    return run_cli(
        "replay",
        flight,
        "--out",
        out,
        *args,
        cwd=cwd,
        engine_dir=engine_dir,
        settings=settings,
        timeout=600,
    )


# --- defect 1: a replay or eval that cannot start leaves --out as it was ----------------------


def test_a_replay_whose_engines_are_missing_leaves_the_previous_run_whole_and_makes_no_directory(
    small_flight: SmallFlight, engine_dir: Path, tmp_path: Path
) -> None:
    flight = small_flight("two_frames")
    out = tmp_path / "out"
    good = _replay(flight, out, "--strategy", "xfeat", cwd=tmp_path, engine_dir=engine_dir)
    assert good.returncode == 0, good.stderr[-2000:]
    before = _tree(out)
    assert before["fdr.jsonl"] and "results.jsonl" in before and "report.json" in before
    for where in (out, tmp_path / "fresh"):
        proc = _replay(flight, where, "--strategy", "xfeat", cwd=tmp_path, **NO_ENGINES)
        assert proc.returncode == 1, proc.stderr
        assert "no valid xfeat" in _one_line(proc)
    assert _tree(out) == before  # the FDR not emptied, the results not removed
    assert not (tmp_path / "fresh").exists()


def test_an_eval_whose_strategy_cannot_start_leaves_that_strategys_directory_as_it_was(
    small_flight: SmallFlight, engine_dir: Path, tmp_path: Path
) -> None:
    flight = small_flight("two_frames")
    out = tmp_path / "out"
    argv = ("eval", flight, "--strategy", "xfeat", "--no-baseline", "--out", out, *QUICK_EVAL)
    good = run_cli(*argv, cwd=tmp_path, engine_dir=engine_dir, timeout=600)
    assert good.returncode == 0, good.stderr[-2000:]
    before = _tree(out / "xfeat")
    assert before["fdr.jsonl"] and "results.jsonl" in before
    failed = run_cli(*argv, cwd=tmp_path, settings=NO_ENGINES, timeout=600)
    assert failed.returncode == 1 and "failed to run: xfeat" in failed.stderr, failed.stderr
    assert _tree(out / "xfeat") == before


def test_open_matcher_that_cannot_compose_touches_no_file(tmp_path: Path) -> None:
    from c3_matcher.errors import C3Error
    from c3_matcher_tools.run import open_matcher

    previous = tmp_path / "previous"
    previous.mkdir()
    for name in ("fdr.jsonl", "matcher.log", "results.jsonl"):
        (previous / name).write_text(f"the previous run's {name}\n")
    before = _tree(previous)
    settings = C3Settings(engines={"directory": tmp_path / "no-engines"})
    for out in (previous, tmp_path / "new"):
        with pytest.raises(C3Error, match="no valid xfeat"), open_matcher(settings, "xfeat", out):
            pass
    assert _tree(previous) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["previous"]


def test_what_the_matcher_logged_while_composing_lands_in_its_runs_log(tmp_path: Path) -> None:
    from c3_matcher_tools.run import prepare_matcher

    with prepare_matcher(C3Settings(), "sift_magsac") as prepared:
        assert not tmp_path.joinpath("run").exists()  # composed: nothing touched yet
        prepared.start(tmp_path / "run")
        assert prepared.matcher.health_snapshot() is not None
    log = (tmp_path / "run" / "matcher.log").read_text()
    assert "c3.matcher.ready" in log  # logged while composing, before the log file existed
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == [
        "fdr.jsonl",
        "fdr.jsonl.lock",
        "matcher.log",
    ]


def test_a_replay_with_a_frame_image_missing_mid_flight_is_refused_before_out_is_touched(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flight = small_flight("two_frames")
    out = tmp_path / "out"
    assert c3("replay", str(flight), "--strategy", "sift_magsac", "--out", str(out)).returncode == 0
    before = _tree(out)
    (flight / "frames" / "000001.jpg").unlink()  # the second frame: the first one reads
    for where in (out, tmp_path / "fresh"):
        proc = c3("replay", str(flight), "--strategy", "sift_magsac", "--out", str(where))
        assert proc.returncode == 2
        assert _one_line(proc).endswith("frames/000001.jpg: no such image file")
    assert _tree(out) == before
    assert not (tmp_path / "fresh").exists()


@pytest.mark.parametrize("command", ["replay", "eval"])
def test_a_run_whose_tile_store_is_damaged_is_refused_before_out_is_touched(
    command: str, small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flight = small_flight("two_frames")
    out = tmp_path / "out"
    extra = ("--no-baseline", *QUICK_EVAL) if command == "eval" else ()
    argv = (command, str(flight), "--strategy", "sift_magsac", "--out", str(out), *extra)
    assert c3(*argv).returncode == 0
    before = _tree(out)
    store = flight / "tiles.mbtiles"
    store.write_bytes(store.read_bytes()[:4096])  # cut short: its tables are gone
    proc = c3(*argv)
    assert proc.returncode == 2
    assert "tiles.mbtiles" in _one_line(proc)
    assert _tree(out) == before  # the previous results, FDR and reports all kept


# --- defect 2: --attitude-noise-deg refused up front, naming itself, the frame, degrees -----


@pytest.mark.parametrize("command", ["replay", "eval"])
def test_attitude_noise_pushing_an_attitude_out_of_range_is_refused_before_anything_is_written(
    command: str, small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flight = small_flight("two_frames")
    out = tmp_path / "out"
    first = ("--strategy", "sift_magsac", "--out", str(out))
    extra = ("--no-baseline", *QUICK_EVAL) if command == "eval" else ()
    assert c3(command, str(flight), *first, *extra).returncode == 0
    before = _tree(out)
    for where in (out, tmp_path / "fresh"):
        proc = c3(
            command,
            str(flight),
            "--strategy",
            "sift_magsac",
            "--out",
            str(where),
            "--attitude-noise-deg",
            "1e308",
            *extra,
        )
        assert proc.returncode == 2, proc.stderr
        err = _one_line(proc)
        assert err.startswith("c3-matcher: --attitude-noise-deg: 1e+308 deg (1 sigma) puts frame")
        assert "deg (recorded" in err and "outside [-90, 90]" in err
    assert _tree(out) == before
    assert not (tmp_path / "fresh").exists()


def test_attitude_noise_wraps_a_yaw_past_a_full_turn_instead_of_refusing_it() -> None:
    import dataclasses

    from c3_matcher_tools.args import apply_attitude_noise
    from c3_matcher_tools.dataset.format import load_dataset, with_attitude_noise

    flight = load_dataset(DEMO)
    north = dataclasses.replace(
        flight,
        frames=tuple(
            dataclasses.replace(f, attitude_deg=(*f.attitude_deg[:2], 359.9)) for f in flight.frames
        ),
    )
    noisy, raw = apply_attitude_noise(north, 2.0), with_attitude_noise(north, 2.0)
    assert any(f.attitude_deg[2] > 360 for f in raw.frames)  # the case: past a full turn
    for got, was in zip(noisy.frames, raw.frames, strict=True):
        got.attitude  # noqa: B018 - the matcher takes it
        assert got.attitude_deg[:2] == was.attitude_deg[:2]
        assert got.attitude_deg[2] % 360 == pytest.approx(was.attitude_deg[2] % 360)
    assert noisy.meta["attitude_noise"] == {"sigma_deg": 2.0, "seed": 0}
    assert apply_attitude_noise(north, 0.0) is north


def test_attitude_noise_checks_only_the_frames_a_limited_replay_flies() -> None:
    from c3_matcher.errors import InvalidInputError
    from c3_matcher_tools.args import apply_attitude_noise
    from c3_matcher_tools.dataset.format import load_dataset

    flight = load_dataset(DEMO)
    with pytest.raises(InvalidInputError, match=r"--attitude-noise-deg: 90 deg .* frame 9 "):
        apply_attitude_noise(flight, 90.0)
    apply_attitude_noise(flight, 90.0, first=9)  # frames 0..8 stay in range at this seed


# --- defect 6: --out that is, holds or lies inside the input dataset ---------------------------


@pytest.mark.parametrize("command", ["replay", "eval"])
@pytest.mark.parametrize("where", ["is", "inside", "holds"])
def test_an_out_over_the_input_dataset_is_refused_and_the_dataset_left_alone(
    command: str, where: str, small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flight = small_flight("two_frames", where="data/flight")
    before = _tree(tmp_path / "data")
    out = {"is": flight, "inside": flight / "results", "holds": tmp_path / "data"}[where]
    extra = ("--no-baseline", *QUICK_EVAL) if command == "eval" else ()
    proc = c3(command, str(flight), "--strategy", "sift_magsac", "--out", str(out), *extra)
    assert proc.returncode == 2, proc.stderr
    assert _one_line(proc).startswith("c3-matcher: --out: ")
    assert str(flight) in proc.stderr
    assert _tree(tmp_path / "data") == before
    assert not (flight / "results").exists()


# --- defect 5: eval --samples ------------------------------------------------------------------


def test_eval_refuses_a_negative_samples_count(c3: C3, tmp_path: Path) -> None:
    proc = c3("eval", str(DEMO), "--samples", "-1", "--out", str(tmp_path / "out"))
    assert proc.returncode == 2
    assert "--samples: must be >= 0, got -1" in _one_line(proc)
    assert not (tmp_path / "out").exists()


# --- defects 3 and 4: bench --data checked up front, worker refusals, --threads bound ---------


def _flight_copy(tmp_path: Path) -> Path:
    flight = shutil.copytree(DEMO, tmp_path / "flight")
    for sidecar in flight.glob("*.features.sqlite*"):
        sidecar.unlink()
    return flight


def _calibration_for_another_size(flight: Path) -> None:
    path = flight / "calibration.json"
    calibration = json.loads(path.read_text())
    calibration["image_size"] = [640, 480]
    path.write_text(json.dumps(calibration))


@pytest.mark.parametrize(
    ("spoil", "message"),
    [
        (lambda f: (f / "frames" / "000003.jpg").unlink(), "000003.jpg: no such image file"),
        (lambda f: (f / "frames" / "000003.jpg").write_bytes(b"not a picture"), "not a decodable"),
        (lambda f: (f / "frames" / "000003.jpg").write_bytes(b""), "it is empty"),
        (_calibration_for_another_size, "image_size is 640x480 px but frame"),
    ],
    ids=["missing", "not-an-image", "empty", "calibration-size"],
)
def test_bench_refuses_data_whose_frames_cannot_be_timed_before_any_case_runs(
    spoil: Callable[[Path], object],
    message: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    no_bench_case: None,
) -> None:
    from c3_matcher.cli import main

    flight = _flight_copy(tmp_path)
    spoil(flight)
    argv = ["bench", "--runs", "1", "--strategy", "xfeat", "--no-baseline", "--no-reference"]
    assert main([*argv, "--data", str(flight)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith(f"c3-matcher: --data: {flight}") and message in err, err


def test_bench_refuses_a_demo_directory_whose_tile_is_missing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    demo = shutil.copytree(REPO / "data" / "demo", tmp_path / "demo")
    tile = json.loads((demo / "demo.json").read_text())["tiles"][1]["file"]
    (demo / tile).unlink()
    assert main(["bench", "--runs", "1", "--no-reference", "--data", str(demo)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("c3-matcher: --data: "), err
    assert tile in err


def test_bench_names_a_demo_directorys_bad_calibration_as_its_data(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The directory's own calibration.json is blamed on --data, not on a --calibration
    option bench does not have."""
    from c3_matcher.cli import main

    demo = shutil.copytree(REPO / "data" / "demo", tmp_path / "demo")
    (demo / "calibration.json").write_text('{"K": 1}')
    assert main(["bench", "--runs", "1", "--no-reference", "--data", str(demo)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("c3-matcher: --data: ") and "calibration.json" in err, err
    assert "--calibration" not in err


def test_a_workers_bad_input_is_one_line_and_exit_2_never_a_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A frame that goes missing after the up-front check (here: the check skipped): the worker
    says what, in one line; bench exits 2 with it."""
    import c3_matcher_tools.bench
    from c3_matcher.cli import main

    flight = _flight_copy(tmp_path)
    (flight / "frames" / "000000.jpg").unlink()
    monkeypatch.setattr(c3_matcher_tools.bench, "_checked_data", lambda data, *_: data)
    argv = ["bench", "--runs", "1", "--strategy", "xfeat", "--no-baseline", "--no-reference"]
    assert main([*argv, "--no-modes", "--data", str(flight)]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("bench:")]
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert err[0].startswith(f"c3-matcher: {flight}/frames/000000.jpg: no such image file")
    assert "(bench case xfeat (new tiles" in err[0]


def test_bench_threads_is_bounded_by_the_machines_cores(capsys: pytest.CaptureFixture[str]) -> None:
    from c3_matcher.cli import main
    from c3_matcher_tools.bench import THREADS_PER_CORE, max_threads

    most = max_threads()
    assert most == min(THREADS_PER_CORE * (os.cpu_count() or 1), 1024)
    with pytest.raises(SystemExit) as stop:  # refused while parsing: no case runs, no hang
        main(["bench", "--threads", "100000", "--data", str(DEMO)])
    err = capsys.readouterr().err.strip()
    assert stop.value.code == 2 and len(err.splitlines()) == 1, err
    assert f"--threads: must be <= {most} ({THREADS_PER_CORE}x this machine's" in err
    assert "got 100000" in err
