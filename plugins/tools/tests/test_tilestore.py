"""Tile store: georeferencing, MBTiles / XYZ reading, mosaics, the build command, failures as
candidate drops."""

from __future__ import annotations

import sqlite3
import uuid
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3_matcher.config import C3Settings
from c3_matcher.dto import Attitude, CameraCalibration, NavCameraFrame, RerankResult, TileId
from c3_matcher.errors import InsufficientInliersError, InvalidInputError
from c3_matcher.fdr import read_fdr
from c3_matcher.tilestore.base import tile_centre_id
from c3_matcher.tilestore.handles import (
    MosaicTileHandle,
    StoredTileHandle,
    TileNotFoundError,
    mosaic_origin,
    stitch,
)
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher.tilestore.xyz import XyzTileStore
from c3_matcher_tools.run import open_matcher
from c3_matcher_tools.testing.geotiff import projected_keys, write_geotiff
from c3_matcher_tools.tilestore.build import build_mbtiles
from c3_matcher_tools.tilestore.geo import (
    lonlat_to_world_px,
    read_geotiff_grid,
    world_px_to_lonlat,
)
from c3_matcher_tools.tilestore.projection import Projection
from c3_matcher_tools.tilestore.writer import MBTilesWriter

ZOOM = 15
E0, N0, GSD = 430_000.0, 5_210_000.0, 3.0  # EPSG:32633 (UTM 33N) grid, 3 m/px


def _texture(h: int, w: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.integers(30, 230, size=(h // 8, w // 8, 3), dtype=np.uint8)
    return np.ascontiguousarray(cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC))


def _geotiff(path: Path, image: np.ndarray, epsg: int = 32633) -> Path:
    return write_geotiff(
        path, image, scale=(GSD, GSD), top_left=(E0, N0), keys=projected_keys(epsg)
    )


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, np.ndarray]:
    root = tmp_path_factory.mktemp("tiles")
    image = _texture(600, 700)
    image[300:304, 350:354] = 255  # a white marker at ORTHO px (351.5, 301.5)
    tif = _geotiff(root / "ortho.tif", image)
    store = root / "ortho.mbtiles"
    seen: list[tuple[int, int]] = []
    report = build_mbtiles(tif, store, zoom=ZOOM, progress=lambda d, n: seen.append((d, n)))
    assert report.tiles > 0 and seen[-1] == (report.candidates, report.candidates)
    return tif, store, image


def test_utm_matches_known_values_and_round_trips(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("C3_MATCHER_TOOLS_NO_PYPROJ", "1")  # the hand-written fallback
    utm14 = Projection.from_epsg(32614)
    e, n = utm14.from_lonlat([-99.0, -99.0], [0.0, 45.0])
    assert e[0] == pytest.approx(500_000.0, abs=1e-6) and n[0] == pytest.approx(0.0, abs=1e-6)
    # meridian arc to 45 deg on WGS84 is 4984944.378 m, scaled by k0 = 0.9996
    assert n[1] == pytest.approx(4984944.378 * 0.9996, abs=0.05)
    lon, lat = utm14.to_lonlat(*utm14.from_lonlat([-100.7, -97.4], [47.3, 12.1]))
    np.testing.assert_allclose(lon, [-100.7, -97.4], atol=1e-8)
    np.testing.assert_allclose(lat, [47.3, 12.1], atol=1e-8)
    assert Projection.from_epsg(26914).kind == "utm"  # NAD83 UTM 14N


def test_unknown_crs_needs_a_reference(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("C3_MATCHER_TOOLS_NO_PYPROJ", "1")  # pyproj knows every EPSG grid
    with pytest.raises(InvalidInputError, match="--ref-latlon"):
        Projection.from_epsg(28992)
    ltp = Projection.from_epsg(28992, reference=(51.83, 4.97), ref_en=(100.0, 200.0))
    lon, lat = ltp.to_lonlat([100.0], [200.0 + 111_319.49])
    assert lat[0] == pytest.approx(52.83, abs=1e-3) and lon[0] == pytest.approx(4.97)


@pytest.mark.parametrize(
    ("epsg", "centre"),
    [(32614, (-99.0, 47.0)), (32733, (15.0, -12.0)), (3857, (8.5, 47.4)), (3395, (121.0, 14.6)),
     (4326, (-70.0, -33.0)), (28992, (4.97, 51.83))],
)  # fmt: skip
def test_every_projection_round_trips_and_survives_its_dict(
    monkeypatch: pytest.MonkeyPatch, epsg: int, centre: tuple[float, float]
) -> None:
    monkeypatch.setenv("C3_MATCHER_TOOLS_NO_PYPROJ", "1")  # the hand-written formulas
    projection = Projection.from_epsg(epsg, reference=(centre[1], centre[0]))
    assert Projection.from_dict(projection.to_dict()) == projection
    lon, lat = centre[0] + np.array([-1.5, 0.0, 1.2]), centre[1] + np.array([0.7, 0.0, -1.1])
    back = projection.to_lonlat(*projection.from_lonlat(lon, lat))
    np.testing.assert_allclose(back, [lon, lat], atol=1e-8)


def test_an_unknown_projection_kind_is_refused_when_read() -> None:
    with pytest.raises(InvalidInputError, match="unknown projection 'lambert'.*utm"):
        Projection.from_dict({"kind": "lambert"})


def test_world_px_round_trip() -> None:
    np.testing.assert_allclose(lonlat_to_world_px([[0.0, 0.0]], 0), [[128.0, 128.0]])
    pts = np.array([[8.55, 47.37], [-99.15, 47.02], [120.98, 14.59]])
    np.testing.assert_allclose(world_px_to_lonlat(lonlat_to_world_px(pts, 17), 17), pts, atol=1e-9)


def test_mbtiles_schema_tms_rows_and_metadata(built: tuple[Path, Path, np.ndarray]) -> None:
    tif, store_path, _ = built
    db = sqlite3.connect(store_path)
    tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    assert {"metadata", "tiles"} <= tables
    rows = db.execute("SELECT zoom_level, tile_column, tile_row FROM tiles").fetchall()
    db.close()
    with MBTilesStore(store_path) as store:
        xyz = sorted(store.tiles(ZOOM))
        assert sorted((c, (1 << ZOOM) - 1 - r) for _, c, r in rows) == xyz
        meta = store.metadata
        assert meta["format"] == "png" and meta["minzoom"] == str(ZOOM)
        assert '"utm"' in meta["c3_georeference"] and meta["c3_source"] == tif.name
        x, y = xyz[0]
        tile = StoredTileHandle(store, ZOOM, x, y).decode()
        assert tile.shape == (256, 256, 3) and tile.dtype == np.uint8


def test_georeference_puts_the_marker_where_the_grid_says(
    built: tuple[Path, Path, np.ndarray],
) -> None:
    tif, store_path, _ = built
    grid = read_geotiff_grid(tif)
    lonlat = grid.px_to_lonlat([[351.5, 301.5]])
    world = lonlat_to_world_px(lonlat, ZOOM)[0]
    tid = TileId(ZOOM, float(lonlat[0, 1]), float(lonlat[0, 0]))
    with MBTilesStore(store_path) as store:
        img = store.handle(tid, 96).decode()
    x0, y0 = mosaic_origin(tid, 96)
    grey = img.astype(np.float64).mean(axis=2)
    ys, xs = np.nonzero(grey > 240)
    assert xs.size > 0
    # TILE px u is WORLD px x0 + u + 0.5
    assert xs.mean() + x0 + 0.5 == pytest.approx(world[0], abs=1.0)
    assert ys.mean() + y0 + 0.5 == pytest.approx(world[1], abs=1.0)


def test_handle_serves_stored_tile_or_mosaic_lazily(built: tuple[Path, Path, np.ndarray]) -> None:
    _, store_path, _ = built
    with MBTilesStore(store_path) as store:
        x, y = sorted(store.tiles(ZOOM))[len(list(store.tiles(ZOOM))) // 2]
        tid = tile_centre_id(ZOOM, x, y)
        exact = store.handle(tid, 256)
        assert isinstance(exact, StoredTileHandle)
        assert bytes(exact.encoded()) == bytes(store.tile_bytes(ZOOM, x, y) or b"")
        mosaic = store.handle(tid, 320)
        assert isinstance(mosaic, MosaicTileHandle)
        pixels = mosaic.decode()
        assert pixels.shape == (320, 320, 3)
        ox, oy = mosaic.origin_world_px
        assert (ox, oy) == (x * 256 - 32, y * 256 - 32)
        np.testing.assert_array_equal(pixels[32:288, 32:288], exact.decode())
        png = cv2.imdecode(np.frombuffer(mosaic.encoded(), np.uint8), cv2.IMREAD_COLOR)
        np.testing.assert_array_equal(png[:, :, ::-1], pixels)  # lossless
        cand = store.candidate(tid, 0.5, 320)
        assert cand.gsd_m_per_px == pytest.approx(tid.web_mercator_gsd_m())


def test_a_mosaic_is_keyed_by_its_stored_tiles_without_stitching_or_encoding(
    built: tuple[Path, Path, np.ndarray], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The tile cache keys a store's mosaic by the stored tiles it covers: the same key for the
    same tiles, another once one of them is rewritten (its digest with it, as a store update
    does), and no tile decoded nor the window encoded on the way: a window seen before costs a
    few tile reads, not a stitch and a PNG."""
    import hashlib
    import shutil

    from c3_matcher.protocols import DigestedTileHandle
    from c3_matcher.tile_cache import tile_cache_key
    from c3_matcher.tilestore import handles

    path = tmp_path / "copy.mbtiles"
    shutil.copy(built[1], path)
    with MBTilesStore(path) as store:
        x, y = sorted(store.tiles(ZOOM))[len(list(store.tiles(ZOOM))) // 2]
        tid = tile_centre_id(ZOOM, x, y)
        west = bytes(store.tile_bytes(ZOOM, x - 1, y) or b"")
        pixels = store.handle(tid, 320).decode()

    def must_not_run(*args: object, **kwargs: object) -> None:
        raise AssertionError("a cache key decoded or encoded the window")

    monkeypatch.setattr(handles, "decode_image", must_not_run)
    monkeypatch.setattr(handles.cv2, "imencode", must_not_run)
    with MBTilesStore(path) as store:
        mosaic = store.handle(tid, 320)
        assert isinstance(mosaic, DigestedTileHandle)
        key = tile_cache_key(tid, mosaic)
        assert key == tile_cache_key(tid, store.handle(tid, 320))
        assert key != tile_cache_key(tid, store.handle(tid, 448))  # another window
    monkeypatch.undo()
    tile = cv2.imdecode(np.frombuffer(west, np.uint8), cv2.IMREAD_COLOR)
    tile[100, 240] = 255 - tile[100, 240]  # the west tile, one pixel in the window, rewritten
    blob = cv2.imencode(".png", tile)[1].tobytes()
    with sqlite3.connect(path) as db:
        row = (1 << ZOOM) - 1 - y
        where = "WHERE zoom_level=? AND tile_column=? AND tile_row=?"
        db.execute(f"UPDATE tiles SET tile_data=? {where}", (blob, ZOOM, x - 1, row))
        sha = hashlib.sha256(blob).hexdigest()
        db.execute(f"UPDATE c3_tile_digest SET sha256=? {where}", (sha, ZOOM, x - 1, row))
    db.close()
    with MBTilesStore(path) as store:
        rewritten = store.handle(tid, 320)
        assert tile_cache_key(tid, rewritten) != key
        assert not np.array_equal(rewritten.decode(), pixels)


def test_xyz_folder_is_zero_copy(built: tuple[Path, Path, np.ndarray], tmp_path: Path) -> None:
    _, store_path, _ = built
    with MBTilesStore(store_path) as store:
        keys = list(store.tiles(ZOOM))
        for x, y in keys:
            (tmp_path / str(ZOOM) / str(x)).mkdir(parents=True, exist_ok=True)
            (tmp_path / str(ZOOM) / str(x) / f"{y}.png").write_bytes(
                bytes(store.tile_bytes(ZOOM, x, y) or b"")
            )
        x, y = keys[0]
        xyz = XyzTileStore(tmp_path)
        view = xyz.tile_bytes(ZOOM, x, y)
        assert view is not None and view.readonly  # read under a size check: no mmap, no SIGBUS
        assert bytes(view) == bytes(store.tile_bytes(ZOOM, x, y) or b"")
        assert xyz.zooms() == [ZOOM] and xyz.tile_bytes(ZOOM, x + 1000, y) is None
        tid = tile_centre_id(ZOOM, x, y)
        np.testing.assert_array_equal(
            xyz.handle(tid, 200).decode(), store.handle(tid, 200).decode()
        )


def test_missing_and_corrupt_tiles_raise_from_the_handle(tmp_path: Path) -> None:
    path = tmp_path / "bad.mbtiles"
    with MBTilesWriter(path) as w:
        w.put_tile(ZOOM, 100, 200, b"not an image")
        w.put_metadata({"name": "bad", "format": "png"})
    with MBTilesStore(path) as store:
        corrupt = store.handle(tile_centre_id(ZOOM, 100, 200), 256)
        with pytest.raises(InvalidInputError, match="decodable"):
            corrupt.decode()
        missing = store.handle(tile_centre_id(ZOOM, 5, 5), 300)
        with pytest.raises(TileNotFoundError):
            missing.encoded()
        with pytest.raises(TileNotFoundError):
            stitch(store, ZOOM, (0, 0), (10, 10), "nowhere")
    with pytest.raises(InvalidInputError, match="exists"):
        MBTilesWriter(path)
    (tmp_path / "junk.mbtiles").write_bytes(b"junk" * 100)
    with pytest.raises(InvalidInputError, match="SQLite"):
        MBTilesStore(tmp_path / "junk.mbtiles")


def test_bad_tiles_are_candidate_drops_not_crashes(tmp_path: Path) -> None:
    path = tmp_path / "bad.mbtiles"
    with MBTilesWriter(path) as w:
        w.put_tile(ZOOM, 100, 200, b"\x89PNG broken")
    frame = NavCameraFrame(uuid.UUID(int=9), _texture(240, 320), 1, Attitude(0.0, 0.0, 0.0), 300.0)
    calibration = CameraCalibration.pinhole(320, 240, 300.0)
    with MBTilesStore(path) as store:
        rerank = RerankResult(
            frame.frame_id,
            (
                store.candidate(tile_centre_id(ZOOM, 100, 200), 0.9, 256),  # corrupt
                store.candidate(tile_centre_id(ZOOM, 7, 7), 0.8, 256),  # missing
                store.candidate(tile_centre_id(ZOOM, 7, 7), 0.7, 320),  # missing mosaic
            ),
        )
        with (
            open_matcher(C3Settings(), "sift_magsac", tmp_path / "run") as matcher,
            pytest.raises(InsufficientInliersError) as info,
        ):
            matcher.match(frame, rerank, calibration)
    assert info.value.candidates_dropped == 3
    records = [r for r in read_fdr(tmp_path / "run" / "fdr.jsonl")]
    drops = [r for r in records if r["kind"] == "matcher.backbone_error"]
    assert [d["payload"]["phase"] for d in drops] == ["tile_decode"] * 3
