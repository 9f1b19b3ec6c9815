"""``features build|info`` and ``bench`` over damaged sidecars and bad input: a build verifies
the rows already stored (a damaged one is named and extracted again; a sidecar whose pages
SQLite finds malformed is moved aside and built anew), an interrupted build never leaves its set
marked complete, and a store with nothing to build, a missing or non-MBTiles store, a locked
sidecar or an unknown strategy is one line and exit 2."""

from __future__ import annotations

import json
import shutil
import sqlite3
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.tilestore.sidecar import PAGE_BYTES

REPO = Path(__file__).resolve().parents[3]
FLIGHT = REPO / "data" / "flights" / "naip_demo"


def _build(flight: Path, engine_dir: Path, monkeypatch: pytest.MonkeyPatch) -> int:
    from c3_matcher.cli import main

    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    argv = ["features", "build", str(flight), "--strategy", "xfeat", "--workers", "0"]
    return main([*argv, "--flight-candidates"])


def _sets(
    store: Path, capsys: pytest.CaptureFixture[str], *verify: str, code: int = 0
) -> list[dict[str, Any]]:
    from c3_matcher.cli import main

    capsys.readouterr()
    assert main(["features", "info", str(store), "--json", *verify]) == code
    sets: list[dict[str, Any]] = json.loads(capsys.readouterr().out)["sets"]
    return sets


def _all_intact(sidecar: Path) -> int:
    """How many windows the sidecar holds, asserting each verifies as the flight verifies it."""
    from c3_matcher.tilestore.features import MapFeatureStore

    with MapFeatureStore(sidecar, writable=True) as side:
        (fset,) = side.feature_sets()
        intact, damaged = side.checked_windows(fset)
    assert not damaged, damaged
    return len(intact)


@pytest.mark.slow
def test_a_damaged_row_is_named_and_extracted_again(
    small_flight: Callable[..., Path],
    engine_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from c3_matcher.cli import main

    flight = small_flight("rows")
    sidecar = flight / "tiles.mbtiles.features.sqlite"
    assert _build(flight, engine_dir, monkeypatch) == 0
    windows = _all_intact(sidecar)
    with sqlite3.connect(sidecar) as db:  # a blob cut short, its row still SQLite's
        z, gx, gy = db.execute("SELECT zoom, gx, gy FROM window_features LIMIT 1").fetchone()
        db.execute(
            "UPDATE window_features SET descriptors=substr(descriptors, 1, 1000) "
            "WHERE zoom=? AND gx=? AND gy=?",
            (z, gx, gy),
        )
    (found,) = _sets(flight / "tiles.mbtiles", capsys, "--verify", code=1)
    assert (found["intact"], found["damaged"]) == (windows - 1, 1)
    assert list(found["damage"]) == [f"{z}/{gx}/{gy}"]
    assert "undecodable" in found["damage"][f"{z}/{gx}/{gy}"]
    assert main(["features", "info", str(flight / "tiles.mbtiles"), "--verify"]) == 1
    assert f"{sidecar}: 1 damaged windows" in capsys.readouterr().err
    assert _build(flight, engine_dir, monkeypatch) == 0
    err = capsys.readouterr().err
    assert f"{sidecar}: 1 stored windows of set" in err
    assert f"damaged (1 extracted again, 0 dropped): {z}/{gx}/{gy}: undecodable" in err
    assert f"{windows - 1} already done, 1 to extract" in err
    assert _all_intact(sidecar) == windows
    (rebuilt,) = _sets(flight / "tiles.mbtiles", capsys, "--verify")
    assert (rebuilt["complete"], rebuilt["intact"], rebuilt["damaged"]) == (True, windows, 0)


@pytest.mark.slow
def test_a_sidecar_with_malformed_pages_is_moved_aside_and_built_anew(
    small_flight: Callable[..., Path],
    engine_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from c3_matcher.cli import main

    flight = small_flight("pages")
    sidecar = flight / "tiles.mbtiles.features.sqlite"
    assert _build(flight, engine_dir, monkeypatch) == 0
    windows = _all_intact(sidecar)
    data = bytearray(sidecar.read_bytes())  # the last row's overflow chain points off the file
    start = (len(data) // PAGE_BYTES - 3) * PAGE_BYTES
    data[start : start + 4] = b"\xff" * 4
    sidecar.write_bytes(bytes(data))
    capsys.readouterr()
    assert main(["features", "info", str(flight / "tiles.mbtiles"), "--verify"]) == 1
    said = capsys.readouterr().err
    assert f"{sidecar}: database disk image is malformed" in said
    assert f"c3-matcher features build {flight / 'tiles.mbtiles'} --strategy NAME" in said
    assert _build(flight, engine_dir, monkeypatch) == 0
    err = capsys.readouterr().err
    assert f"{sidecar}: database disk image is malformed: moved aside to {sidecar}.damaged" in err
    aside = Path(f"{sidecar}.damaged").read_bytes()  # kept: its pages as they were (SQLite's
    assert aside[100:] == bytes(data)[100:]  # 100-byte header counts the writer's visit)
    assert _all_intact(sidecar) == windows
    assert [s["complete"] for s in _sets(flight / "tiles.mbtiles", capsys)] == [True]


@pytest.mark.slow
def test_an_interrupted_build_leaves_its_set_incomplete_and_resumes(
    small_flight: Callable[..., Path],
    engine_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from c3_matcher.config import load_settings
    from c3_matcher_tools.features import build

    flight = small_flight("interrupted")
    store = flight / "tiles.mbtiles"
    assert _build(flight, engine_dir, monkeypatch) == 0  # a complete set of the candidates
    done = _sets(store, capsys)[0]["windows"]
    real_task, calls = build.task, []

    def killed_after_one_batch(*args: Any) -> Any:
        calls.append(args)
        if len(calls) > 1:
            raise KeyboardInterrupt  # the build is stopped (Ctrl-C, kill) mid-way
        return real_task(*args)

    monkeypatch.setattr(build, "task", killed_after_one_batch)
    with pytest.raises(KeyboardInterrupt):  # the same set, extended to the whole grid
        build.build_features(
            store, ["xfeat"], load_settings(None), window_px=448, stride_px=32, batch_size=2,
            workers=0, progress=lambda line: None,
        )  # fmt: skip
    (s,) = _sets(store, capsys)
    assert s["complete"] is False and s["windows"] == done + 2  # and the one batch that ended
    monkeypatch.setattr(build, "task", real_task)
    assert _build(flight, engine_dir, monkeypatch) == 0  # rerun: resumed, complete again
    assert f"{done} already done, 0 to extract" in capsys.readouterr().err
    assert [s["complete"] for s in _sets(store, capsys)] == [True]


def test_a_store_without_tiles_is_refused_and_no_sidecar_is_made(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    store = tmp_path / "empty.mbtiles"
    with sqlite3.connect(store) as db:
        db.executescript(
            "CREATE TABLE metadata (name TEXT, value TEXT);"
            "CREATE TABLE tiles (zoom_level INTEGER, tile_column INTEGER, tile_row INTEGER,"
            " tile_data BLOB);"
        )
    assert main(["features", "build", str(store), "--workers", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert f"{store}: the store holds no tiles: nothing to build" in err, err
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "empty.mbtiles.features.sqlite").exists()


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda p: None, "no such store: {store}"),
        (lambda p: p.mkdir(), "{store}: a directory without dataset.json: no store, no dataset"),
        (lambda p: p.write_text("not tiles\n"), "{store}: not an SQLite database"),
    ],
    ids=["missing", "directory", "text"],
)
def test_info_refuses_what_is_no_tile_store(
    make: Callable[[Path], None], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    store = tmp_path / "tiles.mbtiles"
    make(store)
    assert main(["features", "info", str(store)]) == 2
    err = capsys.readouterr().err.strip()
    assert message.format(store=store) in err and len(err.splitlines()) == 1, err


def test_info_on_a_locked_sidecar_says_it_is_locked_not_to_rebuild(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main
    from c3_matcher.testing.locks import exclusive_lock
    from c3_matcher.tilestore.features import MapFeatureStore, sidecar_path

    store = tmp_path / "tiles.mbtiles"
    shutil.copy(FLIGHT / "tiles.mbtiles", store)
    MapFeatureStore(sidecar_path(store), writable=True).close()
    with exclusive_lock(sidecar_path(store)):
        assert main(["features", "info", str(store)]) == 2
    err = capsys.readouterr().err.strip()
    assert f"{sidecar_path(store)}: locked by another process" in err, err
    assert "Rebuild" not in err and len(err.splitlines()) == 1


def test_bench_refuses_an_unknown_strategy_before_any_case(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from c3_matcher.cli import main

    argv = ["bench", "--strategy", "nosuch", "--data", str(FLIGHT), "--runs", "1"]
    assert main([*argv, "--no-baseline", "--no-reference"]) == 2
    err = capsys.readouterr().err.strip()
    assert "strategy 'nosuch' is not recognized" in err and len(err.splitlines()) == 1, err


@pytest.mark.slow
def test_a_sidecar_that_cannot_be_written_mid_build_is_one_line_and_exit_2(
    small_flight: Callable[..., Path],
    engine_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from c3_matcher.tilestore.sidecar import MapFeatureStore

    flight = small_flight("full")

    def disk_full(*args: Any) -> None:
        raise sqlite3.OperationalError("database or disk is full")

    monkeypatch.setattr(MapFeatureStore, "put_windows", disk_full)
    assert _build(flight, engine_dir, monkeypatch) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    sidecar = flight / "tiles.mbtiles.features.sqlite"
    assert f"{sidecar}: cannot be written: database or disk is full" in err, err
    monkeypatch.undo()
    assert [s["complete"] for s in _sets(flight / "tiles.mbtiles", capsys)] == [False]


@pytest.mark.slow
def test_a_strategy_with_no_extractor_engine_is_refused_before_the_sidecar_is_touched(
    tmp_path: Path,
    engine_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
    capfd: pytest.CaptureFixture[str],
) -> None:
    """SIFT extracts with OpenCV: nothing to store. Refused in one line (no worker's traceback),
    and nothing built for the strategy before it, even on a cluster."""
    from c3_matcher.cli import main

    store = tmp_path / "tiles.mbtiles"
    shutil.copy(FLIGHT / "tiles.mbtiles", store)
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    argv = ["features", "build", str(store), "--strategy", "xfeat", "--strategy", "sift_magsac"]
    assert main([*argv, "--workers", "1", "--window", "128"]) == 2
    err = capfd.readouterr().err.strip()
    assert "strategy 'sift_magsac' names no extractor engine its features come from" in err, err
    assert len(err.splitlines()) == 1, err
    assert not (tmp_path / "tiles.mbtiles.features.sqlite").exists()


def test_an_unknown_strategy_is_refused_before_any_worker_starts(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    import dask.distributed

    from c3_matcher.cli import main

    store = tmp_path / "tiles.mbtiles"
    shutil.copy(FLIGHT / "tiles.mbtiles", store)
    monkeypatch.setattr(dask.distributed, "LocalCluster", lambda **kw: pytest.fail("started"))
    assert main(["features", "build", str(store), "--strategy", "nosuch", "--workers", "1"]) == 2
    err = capfd.readouterr().err.strip()
    assert "strategy 'nosuch' is not recognized" in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "tiles.mbtiles.features.sqlite").exists()
