"""Every shipped tile store carries a sha256 per tile, so the flight read path's corruption
check acts on the demo data; ``tiles digest`` adds them to a store made elsewhere without
touching a tile's bytes and never re-blesses a tile that already fails its digest."""

from __future__ import annotations

import hashlib
import shutil
import sqlite3
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.mbtiles import MBTilesStore, TileDigestError
from c3_matcher_tools.tilestore.writer import add_missing_digests

REPO = Path(__file__).resolve().parents[3]
STORES = sorted((REPO / "data" / "flights").glob("*/tiles.mbtiles"))


def _tiles(path: Path) -> dict[tuple[int, int, int], bytes]:
    db = sqlite3.connect(path)
    try:
        rows = db.execute("SELECT zoom_level, tile_column, tile_row, tile_data FROM tiles")
        return {(z, x, r): bytes(b) for z, x, r, b in rows}
    finally:
        db.close()


def _digests(path: Path) -> dict[tuple[int, int, int], str]:
    db = sqlite3.connect(path)
    try:
        rows = db.execute("SELECT zoom_level, tile_column, tile_row, sha256 FROM c3_tile_digest")
        return {(z, x, r): d for z, x, r, d in rows}
    finally:
        db.close()


def test_there_are_shipped_stores() -> None:
    assert {p.parent.name for p in STORES} >= {"naip_demo", "naip_cross_date"}


@pytest.mark.parametrize("store", STORES, ids=lambda p: p.parent.name)
def test_every_shipped_tile_has_its_digest_and_passes_it(store: Path) -> None:
    tiles = _tiles(store)
    assert tiles
    assert _digests(store) == {k: hashlib.sha256(b).hexdigest() for k, b in tiles.items()}
    with MBTilesStore(store) as reader:  # the flight read path, which checks each digest
        for zoom in reader.zooms():
            for x, y in reader.tiles(zoom):
                assert reader.tile_bytes(zoom, x, y) is not None


def test_tiles_digest_adds_what_is_missing_and_keeps_tile_bytes(tmp_path: Path) -> None:
    store = tmp_path / "tiles.mbtiles"
    shutil.copy(REPO / "data" / "flights" / "naip_demo" / "tiles.mbtiles", store)
    before = _tiles(store)
    db = sqlite3.connect(store)
    with db:
        db.execute("DROP TABLE c3_tile_digest")  # a store made by another tool
    db.close()
    exe = Path(sys.executable).with_name("c3-matcher")
    proc = subprocess.run(
        [str(exe), "tiles", "digest", str(store)], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert f"{len(before)} digests added" in proc.stdout
    assert _tiles(store) == before  # not one tile byte changed
    assert _digests(store) == {k: hashlib.sha256(b).hexdigest() for k, b in before.items()}

    # a tile corrupted after digesting: a second run keeps the digest, the reader refuses it
    (z, x, row), blob = next(iter(before.items()))
    db = sqlite3.connect(store)
    with db:
        db.execute(
            "UPDATE tiles SET tile_data=? WHERE zoom_level=? AND tile_column=? AND tile_row=?",
            (blob[:-64] + bytes(64), z, x, row),
        )
    db.close()
    again = add_missing_digests(store)
    assert (again.added, again.kept, again.tiles) == (0, len(before), len(before))
    with MBTilesStore(store) as reader, pytest.raises(TileDigestError):
        reader.tile_bytes(z, x, (1 << z) - 1 - row)


def test_tiles_digest_refuses_a_missing_store(tmp_path: Path) -> None:
    with pytest.raises(InvalidInputError, match="no such MBTiles file"):
        add_missing_digests(tmp_path / "absent.mbtiles")


def _empty_file(path: Path) -> None:
    path.write_bytes(b"")


def _other_database(path: Path) -> None:
    db = sqlite3.connect(path)
    with db:
        db.execute("CREATE TABLE notes (text TEXT)")
    db.close()


@pytest.mark.parametrize("make", [_empty_file, _other_database], ids=["empty", "other-sqlite"])
def test_tiles_digest_refuses_a_file_that_is_not_an_mbtiles_store_and_leaves_it_as_it_was(
    make: Callable[[Path], None], tmp_path: Path
) -> None:
    path = tmp_path / "store.mbtiles"
    make(path)
    before = path.read_bytes()
    with pytest.raises(InvalidInputError, match="not an MBTiles store"):
        add_missing_digests(path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["store.mbtiles"]  # no journal left


def _demo_store(tmp_path: Path, *statements: str) -> Path:
    """A copy of the demo's store with ``statements`` run on it (another tool's doing)."""
    store = tmp_path / "tiles.mbtiles"
    shutil.copy(REPO / "data" / "flights" / "naip_demo" / "tiles.mbtiles", store)
    db = sqlite3.connect(store)
    with db:
        for statement in statements:
            db.execute(statement)
    db.close()
    return store


def test_tiles_digest_replaces_digest_rows_whose_sha256_is_null(tmp_path: Path) -> None:
    """Another tool's half-written digest table: its NULL rows are no digests (it once failed
    on SQLite's "UNIQUE constraint failed"); each is replaced, and none counted as kept."""
    store = _demo_store(tmp_path, "UPDATE c3_tile_digest SET sha256 = NULL WHERE tile_column % 2")
    before = _tiles(store)
    nulls = sum(1 for d in _digests(store).values() if d is None)
    assert 0 < nulls < len(before)
    done = add_missing_digests(store)
    assert (done.added, done.kept, done.empty) == (nulls, len(before) - nulls, 0)
    assert _digests(store) == {k: hashlib.sha256(b).hexdigest() for k, b in before.items()}


def test_tiles_digest_counts_tiles_without_data_apart(tmp_path: Path) -> None:
    """A tile whose data is NULL is no tile to the flight read path: it gets no digest and
    is said as such, never counted as a digest already there."""
    store = _demo_store(
        tmp_path, "DROP TABLE c3_tile_digest", "UPDATE tiles SET tile_data = NULL WHERE rowid <= 5"
    )
    tiles = len(_tiles_or_null(store))
    done = add_missing_digests(store)
    assert (done.tiles, done.added, done.kept, done.empty) == (tiles, tiles - 5, 0, 5)
    exe = Path(sys.executable).with_name("c3-matcher")
    proc = subprocess.run(
        [str(exe), "tiles", "digest", str(store)], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert f"0 digests added, {tiles - 5} already there, 5 with no data" in proc.stdout


def _tiles_or_null(path: Path) -> list[tuple[int, ...]]:
    db = sqlite3.connect(path)
    try:
        return db.execute("SELECT zoom_level, tile_column, tile_row FROM tiles").fetchall()
    finally:
        db.close()


@pytest.mark.parametrize(("value", "kind"), [("7", "INTEGER"), ("'abc'", "TEXT")])
def test_tiles_digest_refuses_tile_data_that_is_not_bytes_naming_the_tile(
    tmp_path: Path, value: str, kind: str
) -> None:
    store = _demo_store(
        tmp_path, "DROP TABLE c3_tile_digest", f"UPDATE tiles SET tile_data = {value}"
    )
    (z, x, row), *_ = sorted(_tiles_or_null(store))
    before = store.read_bytes()
    exe = Path(sys.executable).with_name("c3-matcher")
    proc = subprocess.run(
        [str(exe), "tiles", "digest", str(store)], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 2, proc.stderr
    assert f"zoom_level {z}, tile_column {x}, tile_row {row} holds {kind} data" in proc.stderr
    assert "internal error" not in proc.stderr
    assert store.read_bytes() == before  # the store left as it was
