"""Tile stores and map-features sidecars that cannot be opened or hold malformed values say what
is wrong: a file without read permission is "cannot open (permission denied)" (not "not an
SQLite database", not SQLite's bare "unable to open database file"), a directory is "is a
directory, not an MBTiles file" / "not an image", and a ``window_sets`` row or window key that
is no value of its column is a damaged sidecar (``SidecarDamagedError``) wherever it is parsed:
refused for writing (the build moves it aside), said once in flight and then not served.

Permission problems are made without root's help: ``os.open`` refused with EACCES for the one
file (what a user without read permission gets), and ``sqlite3.connect`` failing with the
CANTOPEN error SQLite gives such a file."""

from __future__ import annotations

import os
import re
import shutil
import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.testing.permissions import cantopen, refuse_reading
from c3_matcher.tiles import read_image
from c3_matcher.tilestore.features import (
    FeatureRequest,
    FeatureSet,
    FeatureStoreUnavailableError,
    MapFeatureStore,
    WindowFeatures,
    features_only,
    served_window,
    sidecar_path,
)
from c3_matcher.tilestore.files import open_failure
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher.tilestore.sidecar import DEFAULT_RETRY_S, SidecarDamagedError
from c3_matcher.tilestore.xyz import XyzTileStore

REPO = Path(__file__).resolve().parents[2]
STORE = REPO / "data" / "flights" / "naip_demo" / "tiles.mbtiles"
TILE = REPO / "data" / "demo" / "tile_a.png"
ZOOM, WINDOW, STRIDE = 15, 256, 256
REQUEST = FeatureRequest("ab" * 32, 32, 1024, 4096, 4, "clahe", "CPUExecutionProvider")
FSET = FeatureSet(
    REQUEST.set_id(WINDOW), REQUEST.extractor_sha256, REQUEST.provider, 32, "clahe", 4,
    WINDOW, STRIDE, 64, "xfeat",
)  # fmt: skip


# -- the tile store -------------------------------------------------------------------------
def test_a_store_without_read_permission_is_said_so_not_called_no_database(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store = tmp_path / "nrs.mbtiles"
    shutil.copy(STORE, store)
    refuse_reading(monkeypatch, store)
    with pytest.raises(InvalidInputError) as refused:
        MBTilesStore(store)
    assert str(refused.value) == f"mbtiles: {store}: cannot open (permission denied)"


def test_sqlite_unable_to_open_a_store_is_cannot_open_not_no_database(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A store that opens for reading but not for SQLite (say, a WAL store on read-only media
    whose -shm cannot be made) is "cannot open", with SQLite's words."""
    store = tmp_path / "wal.mbtiles"
    shutil.copy(STORE, store)
    real_connect = sqlite3.connect

    def connect(database: Any, *args: Any, **kwargs: Any) -> sqlite3.Connection:
        if str(store) in str(database):
            raise cantopen()
        return real_connect(database, *args, **kwargs)

    monkeypatch.setattr(sqlite3, "connect", connect)
    with pytest.raises(InvalidInputError) as refused:
        MBTilesStore(store)
    assert str(refused.value) == f"mbtiles: {store}: cannot open (unable to open database file)"


def test_a_directory_is_not_an_mbtiles_file_nor_an_image(tmp_path: Path) -> None:
    with pytest.raises(InvalidInputError) as refused:
        MBTilesStore(tmp_path)
    assert str(refused.value) == f"mbtiles: {tmp_path}: is a directory, not an MBTiles file"
    with pytest.raises(InvalidInputError) as refused:
        read_image(tmp_path)
    assert str(refused.value) == f"{tmp_path}: is a directory, not an image"
    with pytest.raises(InvalidInputError, match="no such file: "):
        MBTilesStore(tmp_path / "absent.mbtiles")
    with pytest.raises(InvalidInputError, match="no such image file"):
        read_image(tmp_path / "absent.png")


def test_open_failure_names_each_case(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    fifo, file = tmp_path / "pipe", tmp_path / "f.mbtiles"
    os.mkfifo(fifo)  # never opened: opening a pipe would block
    file.write_bytes(b"x")
    assert open_failure(file, "an MBTiles file") is None
    assert open_failure(tmp_path / "absent", "an MBTiles file") == "no such file"
    assert open_failure(tmp_path, "an MBTiles file") == "is a directory, not an MBTiles file"
    assert open_failure(fifo, "an MBTiles file") == "is a FIFO, not an MBTiles file"
    refuse_reading(monkeypatch, file)
    assert open_failure(file, "an MBTiles file") == "cannot open (permission denied)"


def test_an_xyz_folder_lists_its_tiles_per_zoom(tmp_path: Path) -> None:
    for rel in ("15/3/7.png", "15/3/8.jpg", "15/4/7.jpeg", "16/1/1.png"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(TILE, tmp_path / rel)
    (tmp_path / "15" / "3" / "notes.txt").write_text("not a tile")
    (tmp_path / "15" / "3" / "x.png").write_text("not a tile")
    (tmp_path / "17").mkdir()
    store = XyzTileStore(tmp_path)
    assert store.zooms() == [15, 16, 17]
    assert list(store.tiles(15)) == [(3, 7), (3, 8), (4, 7)]
    assert list(store.tiles(16)) == [(1, 1)] and list(store.tiles(17)) == []
    assert list(store.tiles(3)) == []
    assert all(store.tile_bytes(15, x, y) is not None for x, y in store.tiles(15))


# -- the sidecar: cannot be opened ------------------------------------------------------------
def test_a_sidecar_without_read_permission_is_unavailable_naming_why(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = sidecar_path(tmp_path / "tiles.mbtiles")
    MapFeatureStore(path, writable=True).close()
    refuse_reading(monkeypatch, path)
    with pytest.raises(FeatureStoreUnavailableError) as refused:
        MapFeatureStore(path)
    assert str(refused.value) == f"{path}: cannot open (permission denied)"
    assert isinstance(refused.value.__cause__, sqlite3.OperationalError)


def test_the_flight_extracts_instead_of_an_unopenable_sidecar(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The flight's read path: the store opens, its sidecar does not: the candidate's stored
    features fail (the pipeline logs a WARNING and extracts), the tiles are still served."""
    path = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, path)
    MapFeatureStore(sidecar_path(path), writable=True).close()
    refuse_reading(monkeypatch, sidecar_path(path))
    with MBTilesStore(path) as source:
        x, y = min(source.tiles(ZOOM))
        with pytest.raises(FeatureStoreUnavailableError, match="permission denied"):
            features_only(
                served_window(source, REQUEST, ZOOM, (x * 256, y * 256), (WINDOW, WINDOW))
            )  # type: ignore[arg-type]
        assert source.tile_bytes(ZOOM, x, y) is not None


def test_an_unopenable_sidecar_is_said_once_an_outage_not_by_every_candidate(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each candidate of each frame asked the sidecar again, and each failure was a WARNING
    (and an FDR record): now the first says it, later ones extract silently until the next
    try ``DEFAULT_RETRY_S`` later, which is silent too while it fails, and serves once it
    opens."""
    path = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, path)
    MapFeatureStore(sidecar_path(path), writable=True).close()
    refuse_reading(monkeypatch, sidecar_path(path))
    now = [0.0]
    with MBTilesStore(path, clock=lambda: now[0]) as source:
        with pytest.raises(FeatureStoreUnavailableError):
            source.feature_store()
        assert source.feature_store() is None  # the same outage: extract, nothing said
        now[0] = DEFAULT_RETRY_S + 1
        assert source.feature_store() is None  # tried again, still refused: still silent
        monkeypatch.undo()  # readable again
        now[0] = 2 * DEFAULT_RETRY_S + 2
        assert source.feature_store() is not None


# -- the sidecar: malformed stored values -----------------------------------------------------
@pytest.fixture
def sidecar(tmp_path: Path) -> Iterator[Path]:
    """A store copy and its sidecar holding FSET (no windows)."""
    store = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, store)
    with MapFeatureStore(sidecar_path(store), writable=True) as side:
        side.ensure_set(FSET)
        side.mark(FSET.set_id, complete=True, windows=0)
    yield sidecar_path(store)


def _set_column(path: Path, column: str, value: object) -> None:
    with sqlite3.connect(path) as db:
        db.execute(f"UPDATE window_sets SET {column}=?", (value,))
    db.close()


MALFORMED = [
    ("window_px", "abc", "window_px 'abc' is not an integer"),
    ("stride_px", 0, "stride_px 0 is not >= 1"),
    ("stride_px", 2.5, "stride_px 2.5 is not an integer"),
    ("descriptor_dim", -64, "descriptor_dim -64 is not >= 1"),
    ("border_erode_px", -1, "border_erode_px -1 is not >= 0"),
    ("complete", 7, "complete 7 is not 0 or 1"),
    ("descriptor_dtype", "nope", "descriptor_dtype 'nope' is not a NumPy dtype"),
    ("strategy", b"\x00\x01", "strategy b'\\x00\\x01' is not a text"),
]


@pytest.mark.parametrize(("column", "value", "why"), MALFORMED, ids=[m[0] for m in MALFORMED])
def test_a_malformed_set_row_is_a_damaged_sidecar_wherever_it_is_read(
    sidecar: Path, column: str, value: object, why: str
) -> None:
    _set_column(sidecar, column, value)
    damaged = re.escape(f"{sidecar}: damaged (window_sets row {FSET.set_id[:12]}...: {why})")
    with MapFeatureStore(sidecar) as side, pytest.raises(SidecarDamagedError, match=damaged):
        side.feature_sets()  # `features info`
    before = sidecar.read_bytes()
    with pytest.raises(SidecarDamagedError, match=damaged):  # `features build`: moved aside
        MapFeatureStore(sidecar, writable=True)
    assert sidecar.read_bytes() == before  # left as it is (kept aside as it was found)


def test_the_flight_says_a_malformed_set_row_once_then_extracts(sidecar: Path) -> None:
    _set_column(sidecar, "window_px", "abc")
    with MBTilesStore(sidecar.with_name("tiles.mbtiles")) as source:
        x, y = min(source.tiles(ZOOM))
        origin = (x * 256, y * 256)
        with pytest.raises(SidecarDamagedError, match="window_px 'abc' is not an integer"):
            served_window(source, REQUEST, ZOOM, origin, (WINDOW, WINDOW))  # type: ignore[arg-type]
        for _ in range(3):  # said once: every later candidate extracts without a word
            assert (
                features_only(served_window(source, REQUEST, ZOOM, origin, (WINDOW, WINDOW)))
                is None
            )  # type: ignore[arg-type]


def test_an_intact_set_row_reads_as_written(sidecar: Path) -> None:
    with MapFeatureStore(sidecar) as side:
        assert side.feature_sets() == [dataclass_replace(FSET, complete=True)]
        assert side.feature_set(FSET.set_id) == dataclass_replace(FSET, complete=True)


def dataclass_replace(fset: FeatureSet, **changes: Any) -> FeatureSet:
    import dataclasses

    return dataclasses.replace(fset, **changes)


def test_a_window_key_that_is_no_integer_is_a_damaged_sidecar(sidecar: Path) -> None:
    n = 3
    window = WindowFeatures(
        "d" * 64,
        np.zeros((n, 2), np.float32),
        np.ones(n, np.float32),
        np.zeros((n, 64), np.float32),
    )
    with MapFeatureStore(sidecar, writable=True) as side:
        side.put_windows(FSET.set_id, [(ZOOM, 1, 2, window)])
        assert side.done_windows(FSET.set_id) == {(ZOOM, 1, 2): "d" * 64}
    with sqlite3.connect(sidecar) as db:
        db.execute("UPDATE window_features SET gx='one'")
    db.close()
    key = re.escape(f"{sidecar}: damaged (window_features row of set {FSET.set_id[:12]}...: key")
    with MapFeatureStore(sidecar, writable=True) as side:
        with pytest.raises(SidecarDamagedError, match=key):
            side.done_windows(FSET.set_id)
        with pytest.raises(SidecarDamagedError, match=key):
            side.checked_windows(FSET)
