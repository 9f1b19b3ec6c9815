"""Tile stores as other tools write them, on the shipped demo store's own tiles: a blank tile
stored as 0 bytes is no tile (as NULL is), rows counted from the north (metadata ``scheme``
``xyz``) are read as such, a store of tiles not 256 px is refused at open naming their size,
and a gdal2tiles TMS folder is refused as an XYZ folder, naming what it holds."""

from __future__ import annotations

import hashlib
import os
import shutil
import sqlite3
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.base import tile_centre_id
from c3_matcher.tilestore.mbtiles import MBTilesStore, TileDigestError
from c3_matcher.tilestore.mbtiles_form import SAMPLED_TILES, StoreFormError, stored_row
from c3_matcher.tilestore.xyz import XyzTileStore

REPO = Path(__file__).resolve().parents[2]
STORE = REPO / "data" / "flights" / "naip_demo" / "tiles.mbtiles"
ZOOM = 15


def _copy(tmp_path: Path, name: str = "s.mbtiles") -> Path:
    path = tmp_path / name
    shutil.copy(STORE, path)
    db = sqlite3.connect(path)
    db.execute("DROP TABLE IF EXISTS c3_tile_digest")
    db.commit()
    db.close()
    return path


def _sql(path: Path, *statements: tuple[str, tuple[object, ...]]) -> None:
    db = sqlite3.connect(path)
    for statement, args in statements:
        db.execute(statement, args)
    db.commit()
    db.close()


def _first_tile(path: Path) -> tuple[int, int]:
    """XYZ (x, y) of the shipped store's first stored tile at ``ZOOM``."""
    with MBTilesStore(path) as store:
        return next(iter(store.tiles(ZOOM)))


def _blank(path: Path, x: int, y: int, data: bytes | None, digest: str | None = None) -> None:
    """Store tile (ZOOM, x, y) as ``data``, with a digest table holding ``digest`` (or none)."""
    row = (1 << ZOOM) - 1 - y
    where = "zoom_level=? AND tile_column=? AND tile_row=?"
    _sql(path, (f"UPDATE tiles SET tile_data=? WHERE {where}", (data, ZOOM, x, row)))
    if digest is not None:
        _sql(
            path,
            ("CREATE TABLE c3_tile_digest (zoom_level, tile_column, tile_row, sha256)", ()),
            ("INSERT INTO c3_tile_digest VALUES (?, ?, ?, ?)", (ZOOM, x, row, digest)),
        )


@pytest.mark.parametrize("blank", [None, b""], ids=["null", "zero_bytes"])
def test_a_blank_tile_is_no_tile_and_a_window_over_it_is_stitched_from_the_others(
    tmp_path: Path, blank: bytes | None
) -> None:
    """A 0-byte blob was "no bytes to decode", which dropped every window touching it; it is
    no tile now, as NULL is: its pixels are nodata and the window's other tiles are served."""
    path = _copy(tmp_path)
    x, y = _first_tile(path)
    _blank(path, x, y, blank)
    with MBTilesStore(path) as store:
        assert store.tile_bytes(ZOOM, x, y) is None
        assert store.tile_bytes(ZOOM, x + 1, y) is not None
        window = store.handle(tile_centre_id(ZOOM, x, y), size_px=512).decode()
        assert not window[128:384, 128:384].any()  # the blank tile: nodata
        assert window[128:384, 384:].any()  # its neighbour east
        digest = store.handle(tile_centre_id(ZOOM, x, y), size_px=512)
        assert digest.content_digest().startswith("512:")  # type: ignore[attr-defined]


def test_a_zero_byte_tile_with_a_digest_is_blank_when_it_matches_and_corrupt_when_not(
    tmp_path: Path,
) -> None:
    """A store digested before 0 bytes were no tile holds sha256(b"") for them: still blank;
    a digest of other bytes says the tile was emptied since: the digest's error, as before."""
    path = _copy(tmp_path)
    x, y = _first_tile(path)
    _blank(path, x, y, b"", hashlib.sha256(b"").hexdigest())
    with MBTilesStore(path) as store:
        assert store.tile_bytes(ZOOM, x, y) is None
    other = _copy(tmp_path, "t.mbtiles")
    _blank(other, x, y, b"", hashlib.sha256(b"a tile").hexdigest())
    with MBTilesStore(other) as store, pytest.raises(TileDigestError, match="sha256 mismatch"):
        store.tile_bytes(ZOOM, x, y)


def _xyz_rows(path: Path, scheme: str) -> None:
    """Rewrite every tile_row of ``path`` as its XYZ row and set the metadata ``scheme``."""
    _sql(
        path,
        ("UPDATE tiles SET tile_row = -1 - ((1 << zoom_level) - 1 - tile_row)", ()),
        ("UPDATE tiles SET tile_row = -1 - tile_row", ()),
        ("INSERT INTO metadata VALUES ('scheme', ?)", (scheme,)),
    )


@pytest.mark.parametrize("scheme", ["xyz", "XYZ "])
def test_a_store_whose_scheme_is_xyz_serves_the_same_tiles_as_its_tms_twin(
    tmp_path: Path, scheme: str
) -> None:
    """Its rows were read as TMS rows: every window was off the map ("no stored tile
    overlaps") and a dataset import "outside coverage", while ``tiles info`` said xyz."""
    tms = _copy(tmp_path, "tms.mbtiles")
    xyz = _copy(tmp_path, "xyz.mbtiles")
    _xyz_rows(xyz, scheme)
    with MBTilesStore(tms) as a, MBTilesStore(xyz) as b:
        tiles = list(a.tiles(ZOOM))
        assert sorted(b.tiles(ZOOM)) == sorted(tiles) and len(tiles) == 35
        assert list(b.tiles(ZOOM)) == tiles  # north first, as XYZ rows run
        for x, y in tiles:
            assert bytes(b.tile_bytes(ZOOM, x, y) or b"") == bytes(a.tile_bytes(ZOOM, x, y) or b"")
        xs, ys = [t[0] for t in tiles], [t[1] for t in tiles]
        ranges = ((min(xs) + 1, max(xs)), (min(ys) + 1, max(ys) - 1))
        assert sorted(b.stored_in(ZOOM, *ranges)) == sorted(a.stored_in(ZOOM, *ranges))
        assert len(b.stored_in(ZOOM, *ranges)) > 0
        centre = tile_centre_id(ZOOM, *tiles[17])
        window = b.handle(centre, size_px=448).decode()
        assert np.array_equal(window, a.handle(centre, size_px=448).decode())


def test_a_store_replaced_by_its_xyz_twin_serves_the_same_tiles(tmp_path: Path) -> None:
    """The rows of a running store are counted as the file read last counts them."""
    path = _copy(tmp_path)
    twin = _copy(tmp_path, "twin.mbtiles")
    _xyz_rows(twin, "xyz")
    with MBTilesStore(path, check_s=0.0) as store:
        tiles = list(store.tiles(ZOOM))
        before = [bytes(store.tile_bytes(ZOOM, x, y) or b"") for x, y in tiles]
        os.replace(twin, path)
        assert [bytes(store.tile_bytes(ZOOM, x, y) or b"") for x, y in tiles] == before
        assert list(store.tiles(ZOOM)) == tiles


def test_a_store_replaced_by_one_open_would_refuse_says_so_at_every_read(tmp_path: Path) -> None:
    """A running store whose file is replaced by one laid out as it is not read (a scheme it
    does not read) was read with the old file's settings (its rows the old way) until it
    changed again: every read now raises what open would have, and a store that is read
    again is served."""
    path = _copy(tmp_path)
    refused = _copy(tmp_path, "refused.mbtiles")
    _sql(refused, ("INSERT INTO metadata VALUES ('scheme', 'zxy')", ()))
    good = _copy(tmp_path, "good.mbtiles")
    with MBTilesStore(path, check_s=0.0) as store:
        x, y = next(iter(store.tiles(ZOOM)))
        before = bytes(store.tile_bytes(ZOOM, x, y) or b"")
        os.replace(refused, path)
        for _ in range(2):
            with pytest.raises(StoreFormError, match=r"its metadata 'scheme' is 'zxy'"):
                store.tile_bytes(ZOOM, x, y)
        os.replace(good, path)
        assert bytes(store.tile_bytes(ZOOM, x, y) or b"") == before


def test_a_tms_store_reads_as_before_with_or_without_its_scheme(tmp_path: Path) -> None:
    path = _copy(tmp_path)
    _sql(path, ("INSERT INTO metadata VALUES ('scheme', 'tms')", ()))
    with MBTilesStore(STORE) as a, MBTilesStore(path) as b:
        assert list(a.tiles(ZOOM)) == list(b.tiles(ZOOM))
        assert a.tile_size == b.tile_size == (256, 256)
    assert stored_row(ZOOM, 0, False) == (1 << ZOOM) - 1 and stored_row(ZOOM, 7, True) == 7


def test_a_scheme_it_does_not_read_is_refused_at_open_naming_the_key(tmp_path: Path) -> None:
    path = _copy(tmp_path)
    _sql(path, ("INSERT INTO metadata VALUES ('scheme', 'wmts')", ()))
    with pytest.raises(StoreFormError, match=r"its metadata 'scheme' is 'wmts': .*'tms'.*'xyz'"):
        MBTilesStore(path)


def _resized(path: Path, px: int) -> None:
    """Every tile of ``path`` re-encoded at ``px`` x ``px`` (a "retina" store at 512)."""
    db = sqlite3.connect(path)
    for rowid, blob in db.execute("SELECT rowid, tile_data FROM tiles").fetchall():
        image = cv2.imdecode(np.frombuffer(blob, np.uint8), cv2.IMREAD_COLOR)
        ok, buf = cv2.imencode(".jpg", cv2.resize(image, (px, px)))
        assert ok
        db.execute("UPDATE tiles SET tile_data=? WHERE rowid=?", (buf.tobytes(), rowid))
    db.commit()
    db.close()


def test_a_store_of_512_px_tiles_is_refused_at_open_naming_their_size(tmp_path: Path) -> None:
    """It was opened, and then every window failed "expected 256x256 px, got 512x512"."""
    path = _copy(tmp_path)
    _resized(path, 512)
    with pytest.raises(StoreFormError, match=r"its tiles are 512x512 px .*256-px web-mercator"):
        MBTilesStore(path)


def test_the_tile_size_is_read_from_the_first_tile_whose_header_tells_it(tmp_path: Path) -> None:
    """Blank and undecodable tiles first are passed over; none among the first rows telling
    a size leaves it unknown (each tile's own error when it is read, as before)."""
    path = _copy(tmp_path)
    first = sqlite3.connect(path).execute("SELECT min(rowid) FROM tiles").fetchone()[0]
    _sql(
        path,
        ("UPDATE tiles SET tile_data=NULL WHERE rowid=?", (first,)),
        ("UPDATE tiles SET tile_data=x'' WHERE rowid=?", (first + 1,)),
        ("UPDATE tiles SET tile_data=x'00ff' WHERE rowid=?", (first + 2,)),
    )
    with MBTilesStore(path) as store:
        assert store.tile_size == (256, 256)
    _sql(path, ("UPDATE tiles SET tile_data=x'00ff' WHERE rowid < ?", (first + SAMPLED_TILES,)))
    with MBTilesStore(path) as store:
        assert store.tile_size is None


def test_a_gdal2tiles_tms_folder_is_refused_as_an_xyz_folder_naming_it(tmp_path: Path) -> None:
    root = tmp_path / "tiles"
    (root / "15" / "7358").mkdir(parents=True)
    (root / "15" / "7358" / "11520.jpg").write_bytes(b"jpeg")
    XyzTileStore(root)  # an XYZ folder
    (root / "tilemapresource.xml").write_text('<TileMap version="1.0.0"/>')
    with pytest.raises(InvalidInputError, match=r"holds tilemapresource.xml.*TMS.*--xyz"):
        XyzTileStore(root)
