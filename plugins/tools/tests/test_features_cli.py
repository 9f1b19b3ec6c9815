"""``features build`` refuses what it cannot build from, with one line and exit code 2, and
replaces a damaged sidecar (kept aside); the grid of a recorded flight is the one its candidates
lie on."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
FLIGHT = REPO / "data" / "flights" / "naip_demo"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["no/such.mbtiles"], "no such store: no/such.mbtiles"),
        ([str(FLIGHT / "tiles.mbtiles"), "--flight-candidates"], "needs a flight dataset"),
        ([str(REPO / "data"), "--workers", "0"], "a directory without dataset.json"),
        ([str(FLIGHT), "--stride", "999", "--workers", "0"], "stride in [1, window]"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    flight = tmp_path / "naip_demo"  # never written: each case is refused before extracting
    shutil.copytree(FLIGHT, flight)
    argv = [a.replace(str(FLIGHT), str(flight)) for a in argv]
    assert main(["features", "build", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err
    assert err.startswith("c3-matcher: "), err  # as every other refusal: scripts match it
    assert not (flight / "tiles.mbtiles.features.sqlite").exists()


@pytest.mark.parametrize(
    ("option", "value", "bound"),
    [
        ("--batch", "0", ">= 1"),
        ("--batch", "-1", ">= 1"),
        ("--workers", "-1", ">= 0"),
        ("--window", "8", "in [16, 8192]"),
        ("--window", "0", "in [16, 8192]"),
        ("--stride", "0", ">= 1"),
    ],
)
def test_a_count_out_of_its_bounds_is_a_usage_error_naming_the_option(
    option: str, value: str, bound: str, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    with pytest.raises(SystemExit) as stop:  # refused while parsing, before the store is read
        main(["features", "build", "no/such.mbtiles", option, value])
    err = capsys.readouterr().err.strip()
    assert stop.value.code == 2 and len(err.splitlines()) == 1, err
    assert f"{option}: must be {bound}, got {value}" in err


@pytest.mark.parametrize("value", ["7", "0", "-0.5", "nan", "inf"])
def test_a_coverage_out_of_its_bounds_is_a_usage_error_naming_the_option(
    value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    with pytest.raises(SystemExit) as stop:  # refused while parsing, before the store is read
        main(["features", "build", str(FLIGHT), "--min-coverage", value, "--workers", "0"])
    err = capsys.readouterr().err.strip()
    assert stop.value.code == 2 and len(err.splitlines()) == 1, err
    assert err.startswith("c3-matcher features build: error: argument --min-coverage: "), err
    assert f"must be finite and in (0, 1], got {float(value)}" in err, err


@pytest.mark.slow
def test_build_over_a_damaged_sidecar_moves_it_aside_and_builds_a_new_one(
    small_flight: Callable[..., Path],
    engine_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from c3_matcher.cli import main

    flight = small_flight("damaged")
    sidecar = flight / "tiles.mbtiles.features.sqlite"
    sidecar.write_text("garbage\n")
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    argv = ["features", "build", str(flight), "--strategy", "xfeat", "--workers", "0"]
    assert main([*argv, "--flight-candidates"]) == 0
    assert f"moved aside to {sidecar}.damaged" in capsys.readouterr().err
    assert Path(f"{sidecar}.damaged").read_text() == "garbage\n"  # kept, not deleted
    assert main(["features", "info", str(flight), "--json"]) == 0  # a dataset: its store
    info = json.loads(capsys.readouterr().out)
    assert Path(info["store"]).resolve() == (flight / "tiles.mbtiles").resolve()
    assert [(s["strategy"], s["complete"]) for s in info["sets"]] == [("xfeat", True)]
    assert main(["features", "info", str(flight)]) == 0  # in words: no Python None or True
    line = capsys.readouterr().out
    assert "complete: yes" in line and "strategy: xfeat" in line
    assert "None" not in line and "True" not in line and "command:" not in line


def test_a_sidecar_path_that_cannot_be_opened_is_one_line_and_exit_2(
    small_flight: Callable[..., Path], capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    flight = small_flight("blocked")
    sidecar = flight / "tiles.mbtiles.features.sqlite"
    sidecar.mkdir()  # refused before any engine is loaded
    argv = ["features", "build", str(flight), "--workers", "0", "--flight-candidates"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert f"{sidecar}: cannot be opened for writing" in err and len(err.splitlines()) == 1, err
    assert err.startswith("c3-matcher: features build: "), err
    assert sidecar.is_dir() and not list(sidecar.iterdir())


def test_a_flight_is_built_on_the_grid_its_candidates_lie_on() -> None:
    from c3_matcher.tilestore.handles import mosaic_origin
    from c3_matcher_tools.dataset.format import load_dataset
    from c3_matcher_tools.features.build import flight_grid, flight_windows

    window, stride = flight_grid(FLIGHT)
    assert (window, stride) == (448, 32)  # the demo flight's candidates: 448 px on 32 px
    dataset = load_dataset(FLIGHT)
    origins = {mosaic_origin(c.tile_id, window) for f in dataset.frames for c in f.candidates}
    windows = flight_windows(FLIGHT, stride)
    assert {(gx * stride, gy * stride) for _, gx, gy in windows} == origins  # all exact


def test_info_on_an_unreadable_sidecar_says_rebuild_and_exits_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import sqlite3

    from c3_matcher.cli import main

    store = tmp_path / "tiles.mbtiles"
    shutil.copy(FLIGHT / "tiles.mbtiles", store)
    with sqlite3.connect(tmp_path / "tiles.mbtiles.features.sqlite") as db:  # an older layout
        db.execute("CREATE TABLE feature_sets (set_id INTEGER PRIMARY KEY, engine TEXT)")
    assert main(["features", "info", str(store)]) == 1  # damaged, not bad input
    err = capsys.readouterr().err.strip()
    assert f"features build {store} --strategy NAME" in err and len(err.splitlines()) == 1, err


@pytest.mark.parametrize("sidecar", ["garbage\n", "older layout"])
def test_info_json_on_an_unreadable_sidecar_prints_the_problem_and_the_rebuild_command(
    sidecar: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """As ``fdr --json`` and ``engines verify --json``: a document on stdout, saying what is
    wrong and the command that builds the sets again; the line on stderr as without --json."""
    import sqlite3

    from c3_matcher.cli import main

    store = tmp_path / "s4.mbtiles"
    shutil.copy(FLIGHT / "tiles.mbtiles", store)
    path = tmp_path / "s4.mbtiles.features.sqlite"
    if sidecar == "older layout":
        with sqlite3.connect(path) as db:
            db.execute("CREATE TABLE feature_sets (set_id INTEGER PRIMARY KEY, engine TEXT)")
    else:
        path.write_text(sidecar)
    assert main(["features", "info", str(store), "--verify"]) == 1
    said = capsys.readouterr()
    assert main(["features", "info", str(store), "--verify", "--json"]) == 1
    out, err = capsys.readouterr()
    assert err == said.err and said.out == "", err
    document = json.loads(out)
    assert document["store"] == str(store) and document["sidecar"] == str(path)
    assert document["sets"] is None  # they cannot be read
    assert err.strip() == f"c3-matcher: {document['problem']}", err
    assert document["command"] is None  # no line a script can run: NAME, W and S unknown
    assert f"c3-matcher features build {store} --strategy NAME" in document["problem"]
