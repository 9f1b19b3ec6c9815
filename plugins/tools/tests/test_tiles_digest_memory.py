"""``tiles digest`` holds one tile's bytes at a time, whatever the size of the store: it read
every undigested tile's bytes at once (a store larger than the memory left ended in
"internal error: MemoryError"). The digests it adds are those of the tiles' bytes, as before."""

from __future__ import annotations

import hashlib
import os
import sqlite3
import tracemalloc
from pathlib import Path

from c3_matcher_tools.tilestore.writer import add_missing_digests

TILES, TILE_BYTES = 16, 2 << 20  # a 32 MiB store of 2 MiB tiles


def _store_without_digests(path: Path) -> dict[tuple[int, int, int], bytes]:
    """An MBTiles store of ``TILES`` random tiles of ``TILE_BYTES`` and no digest table; its
    tiles by (zoom, column, row)."""
    tiles = {(18, 1000 + n, 2000): os.urandom(TILE_BYTES) for n in range(TILES)}
    db = sqlite3.connect(path)
    db.executescript(
        "CREATE TABLE metadata (name TEXT, value TEXT);"
        "CREATE TABLE tiles (zoom_level INTEGER, tile_column INTEGER, tile_row INTEGER,"
        " tile_data BLOB);"
        "CREATE UNIQUE INDEX tile_index ON tiles (zoom_level, tile_column, tile_row);"
    )
    db.executemany("INSERT INTO tiles VALUES (?, ?, ?, ?)", [(*k, b) for k, b in tiles.items()])
    db.commit()
    db.close()
    return tiles


def test_digesting_a_store_holds_one_tile_at_a_time(tmp_path: Path) -> None:
    path = tmp_path / "big.mbtiles"
    tiles = _store_without_digests(path)
    expected = {k: hashlib.sha256(b).hexdigest() for k, b in tiles.items()}
    del tiles
    tracemalloc.start()
    try:
        report = add_missing_digests(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert (report.tiles, report.added, report.kept, report.empty) == (TILES, TILES, 0, 0)
    assert peak < 4 * TILE_BYTES, f"{peak} bytes held for a {TILES * TILE_BYTES} byte store"
    with sqlite3.connect(path) as db:
        found = db.execute("SELECT zoom_level, tile_column, tile_row, sha256 FROM c3_tile_digest")
        assert {(z, x, r): d for z, x, r, d in found} == expected
