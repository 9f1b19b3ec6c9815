"""One tile row's fault is that tile's, never the store's: a copy of the shipped demo flight's
store whose first tile row has a damaged record header (the row the old whole-store probe read),
or a tile_data of another SQL type than a BLOB (TEXT, an INTEGER, a REAL), fails that tile
alone, naming the store and the tile; every other tile is served at once, no outage is
declared. A store that really no longer answers still goes offline."""

from __future__ import annotations

import io
import shutil
import sqlite3
import struct
from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.logs import configure_logging
from c3_matcher.tilestore.base import tile_centre_id
from c3_matcher.tilestore.mbtiles import MBTilesStore, TileStoreUnusableError

STORE = Path(__file__).resolve().parents[2] / "data" / "flights" / "naip_demo" / "tiles.mbtiles"
PAGE = 4096


def _copy(tmp_path: Path) -> Path:
    path = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, path)
    return path


def _first_row(path: Path) -> tuple[int, int, int]:
    """XYZ (zoom, x, y) of the tiles table's first row (rowid order) of the TMS store ``path``."""
    with sqlite3.connect(path) as db:
        z, x, row = db.execute(
            "SELECT zoom_level, tile_column, tile_row FROM tiles ORDER BY rowid LIMIT 1"
        ).fetchone()
    db.close()
    return z, x, (1 << z) - 1 - row


def _damage_first_row(path: Path) -> None:
    """Overwrite the record header of the tiles table's first row, in its leaf page (its
    payload length and rowid kept: the page itself stays sound)."""
    with sqlite3.connect(path) as db:
        (page,) = db.execute(
            "SELECT pageno FROM dbstat WHERE name='tiles' AND pagetype='leaf' ORDER BY path"
        ).fetchone()
    db.close()
    data = bytearray(path.read_bytes())
    at = (page - 1) * PAGE
    (cell,) = struct.unpack(">H", data[at + 8 : at + 10])
    data[at + cell + 3 : at + cell + 9] = b"\xff" * 6
    path.write_bytes(bytes(data))


def _outages(fdr: InMemoryFdr) -> list[dict[str, object]]:
    return [p for p in fdr.of_kind("log.error") if p.get("kind") == "c3.tilestore.unusable"]


def test_a_damaged_first_row_fails_its_tile_alone_and_the_others_are_served(
    tmp_path: Path,
) -> None:
    path = _copy(tmp_path)
    damaged = _first_row(path)
    with MBTilesStore(path) as store:
        others = [(15, x, y) for x, y in store.tiles(15) if (15, x, y) != damaged]
    _damage_first_row(path)
    fdr = InMemoryFdr()
    logs = configure_logging(fdr, level="ERROR", stream=io.StringIO())
    try:
        with MBTilesStore(path) as store:
            z, x, y = damaged
            for _ in range(2):  # again at once: not an outage failing fast
                with pytest.raises(InvalidInputError) as failed:
                    store.tile_bytes(*damaged)
                assert not isinstance(failed.value, TileStoreUnusableError), failed.value
                assert f"tiles.mbtiles tile {z}/{x}/{y}" in str(failed.value)
                assert "malformed" in str(failed.value)
            served = [store.tile_bytes(*key) for key in others]
    finally:
        logs.close()
    assert len(others) == 34 and all(blob is not None and len(blob) for blob in served)
    assert _outages(fdr) == []


def test_a_store_that_no_longer_answers_still_goes_offline(tmp_path: Path) -> None:
    path = _copy(tmp_path)
    first = _first_row(path)
    fdr = InMemoryFdr()
    logs = configure_logging(fdr, level="ERROR", stream=io.StringIO())
    try:
        with MBTilesStore(path) as store:
            path.write_bytes(b"\0" * path.stat().st_size)  # clobbered in flight, same size
            for _ in range(2):
                with pytest.raises(TileStoreUnusableError, match="store unusable"):
                    store.tile_bytes(*first)
    finally:
        logs.close()
    assert len(_outages(fdr)) == 1


@pytest.mark.parametrize(
    ("value", "said"),
    [("'hello'", "TEXT"), ("12345", "an INTEGER"), ("1.5", "a REAL")],
)
def test_a_tile_data_of_another_type_is_its_tiles_error_naming_it(
    tmp_path: Path, value: str, said: str
) -> None:
    path = _copy(tmp_path)
    z, x, y = _first_row(path)
    with sqlite3.connect(path) as db:
        db.execute(
            f"UPDATE tiles SET tile_data = {value}"
            " WHERE zoom_level=? AND tile_column=? AND tile_row=?",
            (z, x, (1 << z) - 1 - y),
        )
    db.close()
    with MBTilesStore(path) as store:
        assert store.has_digests
        with pytest.raises(InvalidInputError) as failed:
            store.tile_bytes(z, x, y)
        assert type(failed.value) is InvalidInputError
        text = str(failed.value)
        assert f"tiles.mbtiles tile {z}/{x}/{y}" in text
        assert f"its tile_data is {said}, not a BLOB" in text
        with pytest.raises(InvalidInputError, match=f"its tile_data is {said}, not a BLOB"):
            store.handle(tile_centre_id(z, x, y), size_px=300).decode()  # a window over it
