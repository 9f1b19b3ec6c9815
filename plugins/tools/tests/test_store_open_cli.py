"""``tiles digest|info|build``, ``features info|build`` and ``match`` over a store or sidecar
that cannot be opened, one with a malformed stored value, and a directory where a file is
expected: one line naming the file and what is wrong, exit 2 for bad input (never "internal
error"), exit 1 for a damaged sidecar, which ``features build`` keeps as ``.damaged`` and
builds anew. ``tiles info`` describes an XYZ folder.

Permission problems are made without root's help (see core/tests/test_store_open_refusals.py):
``os.open`` refused with EACCES for the one file and ``sqlite3.connect`` failing with SQLite's
CANTOPEN for it."""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.testing.permissions import refuse_reading
from c3_matcher.tilestore.features import FeatureSet, MapFeatureStore, sidecar_path

REPO = Path(__file__).resolve().parents[3]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
TILE = REPO / "data" / "demo" / "tile_a.png"
FSET = FeatureSet(
    "ab" * 32, "ab" * 32, "CPUExecutionProvider", 32, "none", 4, 256, 256, 64, "xfeat"
)


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    from c3_matcher.cli import main

    capsys.readouterr()
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err.strip()


@pytest.fixture
def store(tmp_path: Path) -> Path:
    path = tmp_path / "tiles.mbtiles"
    shutil.copy(FLIGHT / "tiles.mbtiles", path)
    return path


def _sidecar(store: Path) -> Path:
    """The store's sidecar holding FSET (no windows)."""
    with MapFeatureStore(sidecar_path(store), writable=True) as side:
        side.ensure_set(FSET)
    return sidecar_path(store)


# -- defect: "internal error: OperationalError: unable to open database file" ----------------
def test_tiles_digest_of_an_unreadable_store_is_one_line_and_exit_2(
    store: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    before = store.read_bytes()
    refuse_reading(monkeypatch, store)
    code, out, err = run(capsys, "tiles", "digest", str(store))
    assert (code, out) == (2, ""), err
    assert err == f"c3-matcher: store: {store}: cannot open (permission denied)"
    assert store.read_bytes() == before


def test_tiles_digest_when_sqlite_cannot_open_the_store_is_exit_2(
    store: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """SQLite failing to open a file the system lets us read (the old code's connect was
    outside the error handling: "internal error", exit 1)."""
    real_connect = sqlite3.connect

    def connect(database: Any, *args: Any, **kwargs: Any) -> sqlite3.Connection:
        if str(database) == str(store):
            raise sqlite3.OperationalError("unable to open database file")
        return real_connect(database, *args, **kwargs)

    monkeypatch.setattr(sqlite3, "connect", connect)
    code, _, err = run(capsys, "tiles", "digest", str(store))
    assert code == 2, err
    assert err == f"c3-matcher: store: {store}: cannot open (unable to open database file)"


@pytest.mark.parametrize("verify", [(), ("--verify",)], ids=["info", "verify"])
def test_features_info_of_an_unreadable_sidecar_is_one_line_and_exit_2(
    verify: tuple[str, ...],
    store: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    side = _sidecar(store)
    refuse_reading(monkeypatch, side)
    code, out, err = run(capsys, "features", "info", str(store), *verify)
    assert (code, out) == (2, ""), err
    assert err.startswith(f"c3-matcher: {side}: cannot open (permission denied); "), err
    assert "internal error" not in err and "Rebuild" not in err and len(err.splitlines()) == 1


@pytest.mark.parametrize("command", ["tiles info", "features info", "tiles digest"])
def test_an_unreadable_store_is_said_so_not_called_no_database(
    command: str, store: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    refuse_reading(monkeypatch, store)
    code, _, err = run(capsys, *command.split(), str(store))
    assert code == 2 and len(err.splitlines()) == 1, err
    assert err.endswith(f"{store}: cannot open (permission denied)"), err
    assert "not an SQLite database" not in err


# -- defect: a malformed window_sets value ---------------------------------------------------
def test_features_info_of_a_malformed_set_row_reports_damage(
    store: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    side = _sidecar(store)
    with sqlite3.connect(side) as db:
        db.execute("UPDATE window_sets SET window_px='abc'")
    db.close()
    code, out, err = run(capsys, "features", "info", str(store))
    assert (code, out) == (1, ""), err
    assert err == (
        f"c3-matcher: {side}: damaged (window_sets row {FSET.set_id[:12]}...: window_px 'abc' "
        f"is not an integer); the flight extracts instead where it is. Its sets cannot be read "
        "from it: build each again with the strategy, window and stride it was built with (the "
        f"build keeps this file as {side.name}.damaged): c3-matcher features build {store} "
        "--strategy NAME --window W --stride S (a set does not record whether it was built for "
        "a flight: for one that was, give that flight's directory and --flight-candidates "
        "instead of the store)."
    )


@pytest.mark.slow
def test_features_build_keeps_a_malformed_sidecar_aside_and_builds_anew(
    store: Path,
    engine_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    build = ("features", "build", str(store), "--strategy", "xfeat", "--workers", "0")
    assert run(capsys, *build)[0] == 0
    side = sidecar_path(store)
    with sqlite3.connect(side) as db:
        db.execute("UPDATE window_sets SET window_px='abc'")
    db.close()
    damaged = side.read_bytes()
    code, _, err = run(capsys, *build, "--json")
    assert code == 0, err
    assert "window_px 'abc' is not an integer" in err and "moved aside" in err, err
    aside = side.with_name(side.name + ".damaged")
    assert aside.read_bytes() == damaged  # kept as it was
    code, out, err = run(capsys, "features", "info", str(store), "--json", "--verify")
    assert code == 0, err
    (built,) = json.loads(out)["sets"]
    assert built["window_px"] == 256 and built["complete"] and built["damaged"] == 0


@pytest.mark.slow
def test_features_build_of_an_unreadable_sidecar_says_why(
    store: Path,
    engine_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """As the readers say it: "cannot open (permission denied)", not SQLite's "unable to open
    database file"; exit 2, the sidecar untouched."""
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    side = _sidecar(store)
    before = side.read_bytes()
    refuse_reading(monkeypatch, side)
    code, _, err = run(
        capsys, "features", "build", str(store), "--strategy", "xfeat", "--workers", "0"
    )
    assert code == 2 and "cannot be opened for writing: cannot open (permission denied)" in err, err
    assert "unable to open database file" not in err
    monkeypatch.undo()
    assert side.read_bytes() == before


# -- defect: a directory called "no such file"; tiles info of an XYZ folder -------------------
def test_a_directory_where_a_file_is_expected_is_said_to_be_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "folder"
    folder.mkdir()
    cases = [
        (("tiles", "info", str(folder)), f"store: {folder}: is a directory, not an MBTiles file"),
        (("tiles", "digest", str(folder)), f"store: {folder}: is a directory, not an MBTiles file"),
        (
            ("tiles", "build", str(folder), str(tmp_path / "out.mbtiles")),
            f"geotiff: {folder}: is a directory, not a GeoTIFF",
        ),
        (
            ("match", "--query", str(folder), "--tile", str(TILE)),
            f"{folder}: is a directory, not an image",
        ),
    ]
    for argv, message in cases:
        code, out, err = run(capsys, *argv)
        assert (code, out) == (2, ""), (argv, err)
        assert err.startswith(f"c3-matcher: {message}") and len(err.splitlines()) == 1, err
        assert "no such" not in err
    assert not (tmp_path / "out.mbtiles").exists()


def test_geotiff_reader_fallback_says_directory_too(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.errors import InvalidInputError
    from c3_matcher_tools.tilestore.raster import RasterioSource, rasterio_available

    assert rasterio_available()
    with pytest.raises(InvalidInputError, match="is a directory, not a GeoTIFF"):
        RasterioSource(tmp_path)
    monkeypatch.setenv("C3_MATCHER_TOOLS_NO_RASTERIO", "1")
    code, _, err = run(capsys, "tiles", "build", str(tmp_path), str(tmp_path / "o.mbtiles"))
    assert code == 2 and "is a directory, not a GeoTIFF" in err, err


def test_tiles_info_describes_an_xyz_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = tmp_path / "xyz"
    for rel in ("15/3/7.png", "15/3/8.jpg", "16/6/14.png"):
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(TILE, root / rel)
    code, out, err = run(capsys, "tiles", "info", str(root), "--json")
    assert code == 0, err
    assert json.loads(out) == {
        "path": str(root),
        "format": "xyz",
        "metadata": {},
        "tiles": {"15": 2, "16": 1},
    }
    code, out, _ = run(capsys, "tiles", "info", str(root))
    assert (code, out.strip()) == (0, f"{root} (XYZ folder): zoom 15: 2 tiles, zoom 16: 1 tiles")
    code, out, _ = run(capsys, "tiles", "info", str(FLIGHT / "tiles.mbtiles"), "--json")
    assert code == 0 and json.loads(out)["format"] == "mbtiles"
