"""Opening a tile store and its map-features sidecar: a folder named with ``#``, ``?`` or ``%``
opens the file it names, read-only, and creates nothing; a damaged page found while the store
is opened (its metadata's) is the store's documented error, with no connection left open."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.features import MapFeatureStore, sidecar_path
from c3_matcher.tilestore.mbtiles import MBTilesStore

ODD_FOLDERS = ["flight #3", "what?", "50%25off", "a%20b", "?mode=rw#"]


def _mbtiles(path: Path) -> Path:
    """A one-tile MBTiles file (spec 1.3 tables; metadata big enough for pages of its own)."""
    db = sqlite3.connect(path)
    db.execute("PRAGMA page_size=4096")
    db.execute("CREATE TABLE metadata (name TEXT, value TEXT)")
    db.execute("CREATE TABLE tiles (zoom_level INT, tile_column INT, tile_row INT, tile_data BLOB)")
    db.executemany(
        "INSERT INTO metadata VALUES (?, ?)",
        [("name", "t"), ("format", "png"), *((f"k{i}", "v" * 200) for i in range(40))],
    )
    db.execute("INSERT INTO tiles VALUES (1, 0, 1, ?)", (b"tile",))
    db.commit()
    db.close()
    return path


@pytest.mark.parametrize("folder", ODD_FOLDERS)
def test_a_store_in_a_folder_named_with_uri_characters_opens_read_only(
    tmp_path: Path, folder: str
) -> None:
    (tmp_path / folder).mkdir()
    path = _mbtiles(tmp_path / folder / "tiles.mbtiles")
    MapFeatureStore(sidecar_path(path), writable=True).close()
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    with MBTilesStore(path) as store:
        assert store.metadata["name"] == "t" and store.zooms() == [1]
        assert bytes(store.tile_bytes(1, 0, 0) or b"") == b"tile"
        sidecar = store.feature_store()
        assert sidecar is not None and sidecar.feature_sets() == []
        with pytest.raises(sqlite3.OperationalError, match="readonly"):
            store._db.execute("CREATE TABLE x (a)")
        with pytest.raises(sqlite3.OperationalError, match="readonly"):
            sidecar._db.execute("CREATE TABLE x (a)")
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


def test_a_damaged_metadata_page_is_the_stores_error_and_closes_its_connection(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """It used to escape as a raw sqlite3.DatabaseError, its connection left open."""
    path = _mbtiles(tmp_path / "tiles.mbtiles")
    db = sqlite3.connect(path)
    (root,) = db.execute("SELECT rootpage FROM sqlite_master WHERE name = 'metadata'").fetchone()
    db.close()
    with path.open("r+b") as fh:  # a bad sector: the metadata table's root page
        fh.seek((root - 1) * 4096)
        fh.write(b"\xff" * 4096)
    opened: list[sqlite3.Connection] = []
    connect = sqlite3.connect

    def recording(*args: object, **kwargs: object) -> sqlite3.Connection:
        opened.append(connect(*args, **kwargs))  # type: ignore[arg-type]
        return opened[-1]

    monkeypatch.setattr(sqlite3, "connect", recording)
    with pytest.raises(InvalidInputError, match="damaged SQLite database"):
        MBTilesStore(path)
    assert opened
    for conn in opened:
        with pytest.raises(sqlite3.ProgrammingError, match="closed"):
            conn.execute("SELECT 1")
