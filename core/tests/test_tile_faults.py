"""Fault injection on tile handles and stores: files that shrink after
the handle was made, a store used from another thread, a store that dies, a handle without
``encoded()``, decompression bombs, corrupt blobs caught by the per-tile digest."""

from __future__ import annotations

import hashlib
import sqlite3
import struct
import subprocess
import sys
import textwrap
import threading
import time
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from loguru import logger

from c3_matcher.dto import RerankCandidate, TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.tiles import (
    ImageDecodeError,
    decode_image,
    image_header_size,
)
from c3_matcher.tilestore.base import tile_centre_id
from c3_matcher.tilestore.mbtiles import MBTilesStore, TileDigestError, TileStoreUnusableError
from c3_matcher.tilestore.xyz import XyzTileStore

CORE_SRC = Path(__file__).resolve().parents[1] / "src"


def _png(seed: int = 0, size: int = 256) -> bytes:
    rng = np.random.default_rng(seed)
    ok, buf = cv2.imencode(".png", rng.integers(0, 255, (size, size, 3), dtype=np.uint8))
    assert ok
    return buf.tobytes()


def _jpeg(seed: int = 0, size: int = 256) -> bytes:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.integers(0, 255, (size, size, 3), dtype=np.uint8), (9, 9), 3)
    ok, buf = cv2.imencode(".jpg", img)
    assert ok
    return buf.tobytes()


def _mbtiles(path: Path, tiles: dict[tuple[int, int, int], bytes], *, digests: bool) -> Path:
    db = sqlite3.connect(path)
    db.execute("CREATE TABLE metadata (name TEXT, value TEXT)")
    db.execute("CREATE TABLE tiles (zoom_level INT, tile_column INT, tile_row INT, tile_data BLOB)")
    if digests:
        db.execute(
            "CREATE TABLE c3_tile_digest (zoom_level INT, tile_column INT, tile_row INT,"
            " sha256 TEXT)"
        )
    for (z, x, y), data in tiles.items():
        row = (1 << z) - 1 - y
        db.execute("INSERT INTO tiles VALUES (?,?,?,?)", (z, x, row, data))
        if digests:
            digest = hashlib.sha256(data).hexdigest()
            db.execute("INSERT INTO c3_tile_digest VALUES (?,?,?,?)", (z, x, row, digest))
    db.commit()
    db.close()
    return path


# -- 4: SIGBUS ---------------------------------------------------------------------------------
def test_file_that_shrinks_after_the_handle_is_a_candidate_error_not_sigbus(tmp_path):
    path = tmp_path / "tile.png"
    path.write_bytes(_png() + b"\0" * 100_000)
    script = textwrap.dedent(f"""
        import sys, os
        sys.path.insert(0, {str(CORE_SRC)!r})
        from c3_matcher.tiles import MmapTileHandle
        from c3_matcher.errors import InvalidInputError
        h = MmapTileHandle({str(path)!r})
        h.encoded()
        os.truncate({str(path)!r}, 10)
        try:
            view = h.encoded()
            bytes(view[-4096:])  # touch the end of what we got
            h.decode()
        except InvalidInputError as exc:
            print("ERROR", exc)
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert proc.returncode == 0, f"process died (rc {proc.returncode}): {proc.stderr[-500:]}"
    assert "ERROR" in proc.stdout


def test_xyz_store_tile_that_shrinks_is_its_error(tmp_path):
    (tmp_path / "xyz" / "3" / "2").mkdir(parents=True)
    tile = tmp_path / "xyz" / "3" / "2" / "1.png"
    tile.write_bytes(_png())
    store = XyzTileStore(tmp_path / "xyz")
    assert store.tile_bytes(3, 2, 1) is not None
    tile.write_bytes(b"")
    with pytest.raises(InvalidInputError, match="empty"):
        store.tile_bytes(3, 2, 1)


# -- 5: threads, store-wide failure ------------------------------------------------------------
def test_mbtiles_store_opened_on_one_thread_serves_another(tmp_path):
    store = MBTilesStore(_mbtiles(tmp_path / "s.mbtiles", {(3, 2, 1): _png()}, digests=False))
    got: list[object] = []

    def use() -> None:
        try:
            got.append(bytes(store.tile_bytes(3, 2, 1) or b""))
        except Exception as exc:  # the old store: "SQLite objects created in a thread..."
            got.append(exc)

    t = threading.Thread(target=use)
    t.start()
    t.join()
    assert got == [_png()]
    store.close()


def test_store_wide_failure_is_reported_once_with_an_fdr_record(tmp_path):
    from c3_matcher.logs import configure_logging

    path = _mbtiles(tmp_path / "s.mbtiles", {(3, 2, 1): _png()}, digests=False)
    store = MBTilesStore(path)
    fdr = InMemoryFdr()
    handle = configure_logging(fdr, level="ERROR")
    try:
        path.write_bytes(b"\0" * path.stat().st_size)  # the store file is clobbered in flight
        for _ in range(3):
            with pytest.raises(InvalidInputError):
                store.tile_bytes(3, 2, 1)
    finally:
        handle.close()
        store.close()
    errors = [p for p in fdr.of_kind("log.error") if p.get("kind") == "c3.tilestore.unusable"]
    assert len(errors) == 1
    assert str(path) in errors[0]["message"]


# -- 6: handles --------------------------------------------------------------------------------
def test_handle_without_encoded_is_refused_at_construction():
    class DecodeOnly:
        def decode(self):
            return np.zeros((32, 32, 3), np.uint8)

    with pytest.raises(InvalidInputError, match=r"tile_pixels_handle.*encoded\(\)"):
        RerankCandidate(TileId(18, 1.0, 2.0), 1.0, DecodeOnly())


# -- 7: decompression bombs --------------------------------------------------------------------
def _png_claiming(width: int, height: int) -> bytes:
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    body = struct.pack(">I", len(ihdr)) + chunk + struct.pack(">I", zlib.crc32(chunk))
    idat = zlib.compress(b"\0" * 4096)
    chunk2 = b"IDAT" + idat
    body += struct.pack(">I", len(idat)) + chunk2 + struct.pack(">I", zlib.crc32(chunk2))
    body += struct.pack(">I", 0) + b"IEND" + struct.pack(">I", zlib.crc32(b"IEND"))
    return b"\x89PNG\r\n\x1a\n" + body  # whole, as a bomb made to be opened is


def test_decompression_bomb_is_refused_from_its_header():
    bomb = _png_claiming(25000, 25000)
    start = time.perf_counter()
    with pytest.raises(ImageDecodeError, match="25000x25000.*max_image_pixels"):
        decode_image(bomb, "bomb.png")
    assert time.perf_counter() - start < 0.5


def test_pixel_limit_is_configurable_and_headers_are_read():
    assert image_header_size(_png(size=64)) == (64, 64)
    assert image_header_size(_jpeg(size=96)) == (96, 96)
    _, tif = cv2.imencode(".tiff", np.zeros((40, 50, 3), np.uint8))
    assert image_header_size(tif.tobytes()) == (50, 40)
    with pytest.raises(ImageDecodeError, match="exceeds"):
        decode_image(_png(size=64), "t", max_pixels=64 * 64 - 1)
    assert decode_image(_png(size=64), "t").shape == (64, 64, 3)
    assert decode_image(_png(size=64), "t", max_pixels=64 * 64).shape == (64, 64, 3)


def test_the_configured_pixel_limit_reaches_the_handles_given_it(tmp_path):
    from c3_matcher.config import load_settings
    from c3_matcher.tiles import BytesTileHandle, MmapTileHandle, read_image

    limit = load_settings(env={"C3_MATCHER_MATCHER__MAX_IMAGE_PIXELS": "1000"}).matcher
    assert limit.max_image_pixels == 1000
    path = tmp_path / "t.png"
    path.write_bytes(_png(size=64))
    for decode in (
        lambda: read_image(path, limit.max_image_pixels),
        MmapTileHandle(path, max_pixels=limit.max_image_pixels).decode,
        BytesTileHandle(_png(size=64), "t", max_pixels=limit.max_image_pixels).decode,
    ):
        with pytest.raises(ImageDecodeError, match="64x64 px exceeds the limit of 1000"):
            decode()
    assert read_image(path).shape == (64, 64, 3)  # no process-wide limit was set


def test_an_image_header_declaring_no_pixels_is_not_an_image_and_an_empty_file_is_empty(tmp_path):
    from c3_matcher.tiles import BytesTileHandle, read_image

    png = bytearray(_png(size=64))
    png[16:24] = struct.pack(">II", 0, 0)  # IHDR width and height, and its CRC to match
    png[29:33] = struct.pack(">I", zlib.crc32(bytes(png[12:29])))
    with pytest.raises(ImageDecodeError, match="header declares 0x0 px: not an image"):
        BytesTileHandle(bytes(png), "frame.png").decode()
    empty = tmp_path / "frame.jpg"
    empty.touch()
    with pytest.raises(InvalidInputError, match="frame.jpg: cannot read image file: it is empty"):
        read_image(empty)


def test_a_pixel_limit_below_256_is_refused():
    from c3_matcher.errors import InvalidInputError
    from c3_matcher.tiles import BytesTileHandle

    with pytest.raises(InvalidInputError, match="max_image_pixels"):
        BytesTileHandle(b"x", max_pixels=255)


# -- 8: per-tile digest ------------------------------------------------------------------------
def test_corrupt_blob_fails_its_digest_and_names_the_tile(tmp_path):
    good = _jpeg(1)
    path = _mbtiles(tmp_path / "s.mbtiles", {(3, 2, 1): good, (3, 3, 1): _jpeg(2)}, digests=True)
    rng = np.random.default_rng(0)
    bad = bytearray(good)
    mid = len(bad) // 2
    bad[mid : mid + 200] = rng.integers(0, 200, 200, dtype=np.uint8).tobytes()
    db = sqlite3.connect(path)
    db.execute("UPDATE tiles SET tile_data=? WHERE tile_column=2", (bytes(bad),))
    db.commit()
    db.close()
    assert decode_image(bytes(bad), "x").shape == (256, 256, 3)  # it WOULD decode silently
    with MBTilesStore(path) as store:
        assert store.has_digests
        with pytest.raises(TileDigestError, match=r"s.mbtiles tile 3/2/1.*sha256"):
            store.tile_bytes(3, 2, 1)
        assert store.tile_bytes(3, 3, 1) is not None  # the others are fine


def test_a_tile_whose_data_is_gone_fails_its_digest(tmp_path):
    """A row left with NULL data where a sha256 is stored lost its tile: it is not a blank one."""
    tiles = {(3, 2, 1): _jpeg(1), (3, 3, 1): _jpeg(2)}
    path = _mbtiles(tmp_path / "s.mbtiles", tiles, digests=True)
    db = sqlite3.connect(path)
    db.execute("UPDATE tiles SET tile_data=NULL WHERE tile_column=2")
    db.commit()
    db.close()
    with MBTilesStore(path) as store:
        with pytest.raises(TileDigestError, match=r"s.mbtiles tile 3/2/1.*NULL"):
            store.tile_bytes(3, 2, 1)
        assert store.tile_bytes(3, 3, 1) is not None


def test_a_window_beyond_the_tiles_latitude_limit_is_refused_by_name(tmp_path):
    path = _mbtiles(tmp_path / "s.mbtiles", {(3, 2, 1): _png()}, digests=False)
    with MBTilesStore(path) as store:
        for lat in (-90.0, 90.0, 85.06):
            with pytest.raises(InvalidInputError, match="tile_id.lat.*web-mercator"):
                store.candidate(TileId(3, lat, 0.0), size_px=256)


def test_store_without_digests_still_reads(tmp_path):
    path = _mbtiles(tmp_path / "s.mbtiles", {(3, 2, 1): _png()}, digests=False)
    with MBTilesStore(path) as store:
        assert not store.has_digests and store.tile_bytes(3, 2, 1) is not None


def test_unusable_error_type_is_a_candidate_error():
    assert issubclass(TileStoreUnusableError, InvalidInputError)
    assert issubclass(TileDigestError, InvalidInputError)
    _ = logger  # loguru is the log bus the ERROR goes through


def test_a_stored_tile_not_256_px_is_refused_whole_as_in_a_mosaic(tmp_path):
    """512-px tiles in a store whose tile read at open is 256 px (a store of 512-px tiles is
    refused at open): the 256-px candidate that is exactly one such tile is refused as the
    mosaic refuses it (it was served 512x512 labelled 256 px: 2x off in tile px)."""
    tiles = {(3, 1, 1): _png(2), (3, 2, 1): _png(0, 512), (3, 3, 1): _png(1, 512)}
    path = _mbtiles(tmp_path / "s.mbtiles", tiles, digests=False)
    with MBTilesStore(path) as store:
        whole = store.handle(tile_centre_id(3, 2, 1), size_px=256)
        assert type(whole).__name__ == "StoredTileHandle"
        expected = r"s.mbtiles tile 3/2/1.*expected 256x256 px, got 512x512"
        with pytest.raises(InvalidInputError, match=expected):
            whole.decode()
        mosaic = store.handle(tile_centre_id(3, 2, 1), size_px=300)
        with pytest.raises(InvalidInputError, match=expected):
            mosaic.decode()
