"""Nav-frame renderer, tiles, distractors, photometric shift and orthophoto loading."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import tifffile

from c3_matcher.dto import Attitude, CameraCalibration
from c3_matcher.errors import InvalidInputError
from c3_matcher.prepared import InputRule
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher_tools.sim import (
    PhotometricShift,
    cut_tile,
    load_orthophoto,
    pick_distractor_tiles,
    render_nav_frame,
)

IMAGERY = Path(__file__).resolve().parents[3] / "data" / "imagery"
GORINCHEM = IMAGERY / "open_orthophotos" / "test_tiled.tif"
NAIP_2010 = IMAGERY / "naip_timeseries" / "m_4709963_se_14_1_20100629.tif"
MANILA = IMAGERY / "open_orthophotos" / "5b90f92da0d7280005fab355_4310.tif"
CALITERRA = IMAGERY / "odm_caliterra" / "caliterra_odm_orthomosaic_preview.png"
W, H, F = 480, 360, 400.0
BARREL = (-0.12, 0.03, 0.0008, -0.0005, 0.0)


@pytest.fixture(scope="module")
def gorinchem() -> np.ndarray:
    return load_orthophoto(GORINCHEM).rgb


def _sample(img: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear samples (N, C) of ``img`` at (N, 2) float px."""
    n = pts.shape[0]
    rows = -(-n // 1024)
    m = np.zeros((rows * 1024, 2), np.float32)
    m[:n] = pts
    m = m.reshape(rows, 1024, 2)
    out = cv2.remap(img, m[..., 0], m[..., 1], cv2.INTER_LINEAR)
    return out.reshape(rows * 1024, -1)[:n].astype(np.float64)


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / math.sqrt((a * a).sum() * (b * b).sum()))


# --------------------------------------------------------------------------- orthophotos
def test_load_orthophoto_reads_gsd_from_geotiff() -> None:
    o = load_orthophoto(GORINCHEM)
    assert o.rgb.shape == (1000, 1000, 3) and o.rgb.dtype == np.uint8
    assert o.gsd_m == pytest.approx(0.25) and o.gsd_source == "geotiff"
    manila = load_orthophoto(MANILA)  # EPSG:3395 pixel scale 0.1 at 14.6 N
    assert manila.gsd_source == "geotiff"
    assert manila.gsd_m == pytest.approx(0.1 * math.cos(math.radians(14.6)), abs=5e-4)
    assert np.all(manila.rgb[:20, :20] == 0)  # its no-data corner stays 0


def test_load_naip_keeps_raw_rgb_bands() -> None:
    o = load_orthophoto(NAIP_2010)
    raw = tifffile.imread(NAIP_2010)
    assert o.rgb.shape == (723, 934, 3) and o.gsd_m == pytest.approx(5.0)
    np.testing.assert_array_equal(o.rgb, raw[..., :3])  # R, G, B; NIR dropped, not alpha


def test_load_png_with_alpha_and_table_fallback(tmp_path: Path) -> None:
    o = load_orthophoto(CALITERRA)
    assert o.rgb.shape == (861, 756, 3) and o.gsd_m is None and o.gsd_source == "unknown"
    bgr = cv2.imread(str(CALITERRA), cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(o.rgb, bgr[..., ::-1])  # RGB order
    rgba = np.zeros((20, 30, 4), np.uint8)
    rgba[..., :3] = (10, 20, 30)  # B, G, R as cv2 writes it
    rgba[:, 15:, 3] = 255
    cv2.imwrite(str(tmp_path / "a.png"), rgba)
    masked = load_orthophoto(tmp_path / "a.png").rgb
    assert not masked[:, :15].any()
    assert np.all(masked[:, 15:] == (30, 20, 10))
    # a TIFF without geotags named like a fixture falls back to the ATTRIBUTION table
    plain = tmp_path / "test_tiled.tif"
    cv2.imwrite(str(plain), np.full((32, 32, 3), 9, np.uint8))
    fallback = load_orthophoto(plain)
    assert fallback.gsd_source == "table" and fallback.gsd_m == pytest.approx(0.25)
    assert load_orthophoto(plain, gsd_m=0.3).gsd_m == pytest.approx(0.3)
    with pytest.raises(InvalidInputError):
        load_orthophoto(tmp_path / "missing.tif")


def _noise_tiff(path: Path, **kwargs: Any) -> Path:
    """A 32 x 32 px RGB TIFF of noise, written by tifffile with ``kwargs``."""
    noise = np.random.default_rng(0).integers(1, 255, (32, 32, 3), dtype=np.uint8)
    tifffile.imwrite(path, noise, photometric="rgb", **kwargs)
    return path


def test_truncated_tiff_is_refused_naming_the_file(tmp_path: Path) -> None:
    tif = _noise_tiff(tmp_path / "cut.tif", compression="zlib")
    tif.write_bytes(tif.read_bytes()[: tif.stat().st_size // 2])  # the pixel data cut short
    with pytest.raises(InvalidInputError, match=r"cut\.tif: damaged TIFF.*decompress"):
        load_orthophoto(tif)


def test_text_named_tif_says_why_it_cannot_be_decoded(tmp_path: Path) -> None:
    text = tmp_path / "notes.tif"
    text.write_text("hello")
    with pytest.raises(InvalidInputError, match=r"cannot decode .*notes\.tif \(not a TIFF"):
        load_orthophoto(text)


def test_negative_pixel_scale_is_refused_naming_the_file(tmp_path: Path) -> None:
    keys = (1, 1, 0, 3, 1024, 0, 1, 2, 1025, 0, 1, 1, 2048, 0, 1, 4326)  # WGS84 lon/lat
    tif = _noise_tiff(
        tmp_path / "flipped.tif",
        extratags=[
            (33550, "d", 3, (-1e-5, 1e-5, 0.0), True),
            (33922, "d", 6, (0.0, 0.0, 0.0, 10.0, 50.0, 0.0), True),
            (34735, "H", len(keys), keys, True),
        ],
    )
    with pytest.raises(InvalidInputError, match=r"flipped\.tif: not a north-up grid"):
        load_orthophoto(tif)
    assert load_orthophoto(tif, gsd_m=0.5).gsd_m == 0.5  # a given GSD needs no grid


# --------------------------------------------------------------------------- geometry
def test_nadir_render_ground_truth_by_hand(gorinchem: np.ndarray) -> None:
    cal = CameraCalibration.pinhole(W, H, F)
    g, h, x0, y0 = 0.25, 80.0, 500.0, 400.0
    r = render_nav_frame(gorinchem, g, (x0, y0), h, Attitude(0, 0, 0), cal)
    cx, cy = (W - 1) / 2, (H - 1) / 2
    np.testing.assert_allclose(r.undistorted_to_ortho([[cx, cy]])[0], [x0, y0], atol=1e-9)
    # 10 m north of nadir is f * 10 / h px above the principal point
    north = r.ortho_to_undistorted([[x0, y0 - 10 / g]])[0]
    np.testing.assert_allclose(north, [cx, cy - F * 10 / h], atol=1e-9)
    east = r.ortho_to_undistorted([[x0 + 10 / g, y0]])[0]
    np.testing.assert_allclose(east, [cx + F * 10 / h, cy], atol=1e-9)
    assert r.nadir_gsd_m == pytest.approx(h / F)
    # yaw 90 (heading east): east of nadir appears at the image top
    r90 = render_nav_frame(gorinchem, g, (x0, y0), h, Attitude(0, 0, math.pi / 2), cal)
    np.testing.assert_allclose(
        r90.ortho_to_undistorted([[x0 + 10 / g, y0]])[0], [cx, cy - F * 10 / h], atol=1e-9
    )


def test_rendered_pixels_sample_the_ortho_where_the_ground_truth_says(
    gorinchem: np.ndarray,
) -> None:
    cal = CameraCalibration.pinhole(W, H, F, BARREL)
    att = Attitude(math.radians(4), math.radians(-9), math.radians(63))
    r = render_nav_frame(gorinchem, 0.25, (480.0, 520.0), 45.0, att, cal)  # 0.11 m/px
    assert r.coverage.all()
    rng = np.random.default_rng(0)
    px = np.stack([rng.integers(0, W, 3000), rng.integers(0, H, 3000)], axis=1).astype(float)
    expected = _sample(gorinchem, r.original_to_ortho(px))
    got = r.image[px[:, 1].astype(int), px[:, 0].astype(int)].astype(np.float64)
    diff = np.abs(expected - got)
    assert diff.mean() < 0.6 and diff.max() <= 3
    # a 1 px error in the ground truth would be visible
    shifted = _sample(gorinchem, r.original_to_ortho(px) + np.array([1.0, 0.0]))
    assert np.abs(shifted - got).mean() > 3 * diff.mean()


def test_projected_ortho_points_land_on_their_dots() -> None:
    ortho = np.full((800, 800, 3), 40, np.uint8)
    dots = np.array(
        [[400.0, 400.0], [330.0, 360.0], [470.0, 430.0], [380.0, 470.0], [455.0, 345.0]]
    )
    yy, xx = np.mgrid[0:800, 0:800]
    for x, y in dots:
        blob = 200 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 2.0**2))
        ortho = np.maximum(ortho, (40 + blob).astype(np.uint8)[..., None])
    cal = CameraCalibration.pinhole(W, H, F, BARREL)
    att = Attitude(math.radians(-5), math.radians(12), math.radians(-140))
    r = render_nav_frame(ortho, 0.2, (405.0, 395.0), 70.0, att, cal)
    grey = r.image[..., 0].astype(np.float64) - 40
    for expected in r.ortho_to_original(dots):
        ex, ey = np.rint(expected).astype(int)
        win = np.clip(grey[ey - 5 : ey + 6, ex - 5 : ex + 6], 0, None)
        wy, wx = np.mgrid[ey - 5 : ey + 6, ex - 5 : ex + 6]
        centroid = np.array([(wx * win).sum(), (wy * win).sum()]) / win.sum()
        np.testing.assert_allclose(centroid, expected, atol=0.3)
    # ORIGINAL -> ORTHO -> ORIGINAL is exact
    pts = np.random.default_rng(1).uniform([0, 0], [W - 1, H - 1], (200, 2))
    np.testing.assert_allclose(r.ortho_to_original(r.original_to_ortho(pts)), pts, atol=1e-6)


def test_footprint_maps_onto_the_frame_boundary(gorinchem: np.ndarray) -> None:
    cal = CameraCalibration.pinhole(W, H, F, BARREL)
    r = render_nav_frame(gorinchem, 0.25, (500.0, 500.0), 60.0, Attitude(0.1, -0.15, 2.5), cal)
    fp = r.footprint_ortho(samples_per_side=16)
    back = r.ortho_to_original(fp)
    on_edge = np.minimum.reduce(
        [
            np.abs(back[:, 0]),
            np.abs(back[:, 0] - (W - 1)),
            np.abs(back[:, 1]),
            np.abs(back[:, 1] - (H - 1)),
        ]
    )
    assert on_edge.max() < 1e-6


def test_rectified_render_is_a_similarity_of_the_ortho(gorinchem: np.ndarray) -> None:
    """Rectifying a rendered frame with its own attitude at the ortho's GSD leaves a pure
    translation to the ortho: no rotation, no scale (ground truth and pixel content)."""
    g = 0.25
    cal = CameraCalibration.pinhole(W, H, F, BARREL)
    att = Attitude(math.radians(7), math.radians(-15), math.radians(118))
    r = render_nav_frame(
        gorinchem, g, (520.0, 470.0), 70.0, att, cal, photometric=PhotometricShift(), seed=5
    )
    prep = FramePreprocessor(InputRule(1024, 16)).prepare_query(r.nav_frame(), cal, g)
    # ground truth: WORKING px -> ORTHO px is x_o = x_w + t
    work = np.random.default_rng(2).uniform([0, 0], prep.working_size, (300, 2))
    ortho_pts = r.original_to_ortho(prep.working_to_original(work))
    ok = np.all(np.isfinite(ortho_pts), axis=1)
    a = np.concatenate([work[ok], np.ones((ok.sum(), 1))], axis=1)
    affine, *_ = np.linalg.lstsq(a, ortho_pts[ok], rcond=None)
    np.testing.assert_allclose(affine[:2].T, np.eye(2), atol=1e-9)
    t = np.array(r.nadir_px) - np.array(prep.nadir_working_px)
    np.testing.assert_allclose(affine[2], t, atol=1e-6)
    # pixel content: the rectified image looks like the ortho shifted by t
    ys, xs = np.nonzero(prep.valid)
    eng = np.stack([xs, ys], axis=1).astype(np.float64)
    rect = prep.image[ys, xs].astype(np.float64).mean(axis=1)
    ortho_grey = gorinchem.astype(np.float64).mean(axis=2).astype(np.float32)
    same = _sample(ortho_grey, prep.to_working(eng) + t)[:, 0]
    assert _ncc(rect, same) > 0.85
    rot = prep.to_working(eng)
    centre = rot.mean(axis=0)
    rotated = (rot - centre) @ np.array([[0.0, -1.0], [1.0, 0.0]]).T + centre  # 90 deg off
    assert _ncc(rect, _sample(ortho_grey, rotated + t)[:, 0]) < 0.3


def test_render_is_deterministic(gorinchem: np.ndarray) -> None:
    cal = CameraCalibration.pinhole(W, H, F, BARREL)
    att = Attitude(0.05, -0.1, 1.2)
    shift = PhotometricShift(vignetting=0.3)
    a = render_nav_frame(
        gorinchem, 0.25, (500.0, 500.0), 60.0, att, cal, photometric=shift, seed=11
    )
    b = render_nav_frame(
        gorinchem, 0.25, (500.0, 500.0), 60.0, att, cal, photometric=shift, seed=11
    )
    c = render_nav_frame(
        gorinchem, 0.25, (500.0, 500.0), 60.0, att, cal, photometric=shift, seed=12
    )
    assert a.image.tobytes() == b.image.tobytes()
    assert a.image.tobytes() != c.image.tobytes()


def test_antialiased_high_render_keeps_geometry(gorinchem: np.ndarray) -> None:
    """Frame GSD 4x the ortho's: the area pre-downscale must not move anything."""
    cal = CameraCalibration.pinhole(W, H, F)
    r = render_nav_frame(gorinchem, 0.25, (500.0, 500.0), 400.0, Attitude(0, 0, 0.3), cal)
    small = cv2.resize(gorinchem, (250, 250), interpolation=cv2.INTER_AREA)
    px = np.random.default_rng(3).uniform([0, 0], [W - 1, H - 1], (2000, 2))
    px = np.rint(px)
    ortho_pts = r.original_to_ortho(px)
    inside = np.all((ortho_pts > 4) & (ortho_pts < 995), axis=1)
    expected = _sample(small, (ortho_pts[inside] + 0.5) / 4 - 0.5)
    got = r.image[px[inside, 1].astype(int), px[inside, 0].astype(int)].astype(np.float64)
    assert np.abs(expected - got).mean() < 4.0
    assert r.coverage.mean() < 1.0 and not r.image[~r.coverage].any()


# --------------------------------------------------------------------------- photometric
def test_photometric_identity_and_vignetting() -> None:
    img = np.full((100, 160, 3), 128, np.uint8)
    rng = np.random.default_rng(0)
    np.testing.assert_array_equal(PhotometricShift.identity().apply(img, rng), img)
    vig = PhotometricShift((1, 1), (1, 1), (1, 1), 0.5, (0, 0), 0.0, None).apply(img, rng)
    assert vig[50, 80].mean() > 120 and vig[0, 0].mean() < 70
    shifted = PhotometricShift().apply(img, np.random.default_rng(1))
    assert shifted.shape == img.shape and not np.array_equal(shifted, img)
    grey = PhotometricShift().apply(img[..., 0].copy(), np.random.default_rng(1))
    assert grey.shape == (100, 160)
    with pytest.raises(InvalidInputError):
        PhotometricShift(gamma_range=(2.0, 1.0))


# --------------------------------------------------------------------------- tiles
def test_cut_tile_offsets_and_nodata(gorinchem: np.ndarray) -> None:
    tile = cut_tile(gorinchem, (900, -50), (200, 150), 0.25)
    assert tile.size == (200, 150) and tile.offset_px == (900, -50)
    np.testing.assert_array_equal(tile.image[50:, :100], gorinchem[:100, 900:1000])
    assert not tile.image[:50].any() and not tile.image[:, 100:].any()
    np.testing.assert_allclose(tile.ortho_to_tile([[950.0, 20.0]]), [[50.0, 70.0]])
    np.testing.assert_allclose(tile.tile_to_ortho(tile.ortho_to_tile([[1.5, 2.5]])), [[1.5, 2.5]])


def test_tile_around_and_distractors(gorinchem: np.ndarray) -> None:
    cal = CameraCalibration.pinhole(W, H, F, BARREL)
    r = render_nav_frame(gorinchem, 0.25, (300.0, 300.0), 40.0, Attitude(0.05, 0.1, 0.7), cal)
    fp = r.footprint_ortho()
    tile = r.tile_around(gorinchem, (256, 256))
    inside = tile.ortho_to_tile(fp.mean(axis=0)[None])[0]
    np.testing.assert_allclose(inside, [127.5, 127.5], atol=0.5)
    tiles = pick_distractor_tiles(
        gorinchem,
        fp,
        (200, 200),
        3,
        np.random.default_rng(4),
        0.25,
        margin_px=10,
        min_distance_px=300,
    )
    assert len(tiles) == 3
    fp_cv = fp.astype(np.float32).reshape(-1, 1, 2)
    for t in tiles:
        x0, y0 = t.offset_px
        assert 0 <= x0 <= 800 and 0 <= y0 <= 800
        np.testing.assert_array_equal(t.image, gorinchem[y0 : y0 + 200, x0 : x0 + 200])
        gx, gy = np.meshgrid(np.arange(x0, x0 + 200, 5.0), np.arange(y0, y0 + 200, 5.0))
        for p in zip(gx.ravel(), gy.ravel(), strict=True):
            assert cv2.pointPolygonTest(fp_cv, (float(p[0]), float(p[1])), True) < -10
        assert np.hypot(x0 + 99.5 - fp[:, 0].mean(), y0 + 99.5 - fp[:, 1].mean()) >= 300
    offsets = {t.offset_px for t in tiles}
    assert len(offsets) == 3
    again = pick_distractor_tiles(
        gorinchem,
        fp,
        (200, 200),
        3,
        np.random.default_rng(4),
        0.25,
        margin_px=10,
        min_distance_px=300,
    )
    assert [t.offset_px for t in again] == [t.offset_px for t in tiles]
    with pytest.raises(InvalidInputError):
        pick_distractor_tiles(gorinchem, fp, (600, 600), 3, np.random.default_rng(0), 0.25)
