"""Frame/tile preprocessing: geometry against hand-computed cases, masks, sizes, round trips."""

from __future__ import annotations

import math
import uuid

import cv2
import numpy as np
import pytest

from c3_matcher import camera as cam
from c3_matcher.dto import Attitude, CameraCalibration, NavCameraFrame
from c3_matcher.errors import InvalidInputError
from c3_matcher.prepared import InputRule, PreparedImage
from c3_matcher.preprocess import FramePreprocessor

W, H, F = 640, 480, 500.0
CX, CY = (W - 1) / 2, (H - 1) / 2
BARREL = (-0.12, 0.03, 0.0008, -0.0005, 0.0)


def _texture(w: int = W, h: int = H, seed: int = 0) -> np.ndarray:
    """Smooth random RGB texture with no zero pixel (values in [20, 235])."""
    noise = np.random.default_rng(seed).uniform(0, 1, (h // 8 + 2, w // 8 + 2, 3))
    smooth = cv2.resize(noise.astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
    return np.clip(20 + 215 * smooth, 20, 235).astype(np.uint8)


def _frame(
    image: np.ndarray, attitude: Attitude | None = None, height: float | None = None
) -> NavCameraFrame:
    return NavCameraFrame(uuid.uuid4(), image, 0, attitude, height)


def _peak(image: np.ndarray) -> np.ndarray:
    """Intensity-weighted centroid (x, y) of the bright blob around the brightest pixel."""
    grey = image.astype(np.float64).sum(axis=2) if image.ndim == 3 else image.astype(np.float64)
    y, x = np.unravel_index(np.argmax(grey), grey.shape)
    win = grey[y - 4 : y + 5, x - 4 : x + 5]
    win = np.clip(win - np.median(grey), 0, None)
    yy, xx = np.mgrid[y - 4 : y + 5, x - 4 : x + 5]
    return np.array([(xx * win).sum() / win.sum(), (yy * win).sum() / win.sum()])


def _dot_image(x: float, y: float, w: int = W, h: int = H) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w]
    blob = 200 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 1.5**2))
    return np.repeat((30 + blob).astype(np.uint8)[..., None], 3, axis=2)


# --------------------------------------------------------------------------- input rule
@pytest.mark.parametrize(
    ("rule", "size", "content", "final"),
    [
        (InputRule(1024, 16), (1000, 750), (1000, 750), (1008, 752)),
        (InputRule(1024, 16), (2000, 1500), (1024, 768), (1024, 768)),
        (InputRule(640, 32), (1000, 750), (640, 480), (640, 480)),
        (InputRule(1024, 16), (300, 200), (300, 200), (304, 208)),  # never upscale
        (InputRule(1000, 16), (1000, 500), (1000, 500), (992, 512)),  # crop, not > limit
    ],
)
def test_input_rule_sizes(
    rule: InputRule, size: tuple[int, int], content: tuple[int, int], final: tuple[int, int]
) -> None:
    assert rule.content_size(*size) == content
    assert rule.final_size(*size) == final
    assert final[0] % rule.multiple == 0 and final[1] % rule.multiple == 0
    assert max(final) <= rule.max_long_side


def test_input_rule_validation() -> None:
    with pytest.raises(InvalidInputError) as err:
        InputRule(0, 16)
    assert err.value.field == "input_rule.max_long_side"
    with pytest.raises(InvalidInputError):
        InputRule(8, 16)


# --------------------------------------------------------------------------- query geometry
def test_identity_keeps_pixels() -> None:
    img = _texture()
    cal = CameraCalibration.pinhole(W, H, F)
    prep = FramePreprocessor(InputRule(1024, 16)).prepare_query(_frame(img), cal, None)
    assert prep.image.shape == (480, 640, 3)
    np.testing.assert_array_equal(prep.image, img)
    np.testing.assert_allclose(prep.working_from_undistorted, np.eye(3), atol=1e-12)
    assert prep.working_size == (W, H)
    pts = np.array([[0.0, 0.0], [100.25, 200.75], [639.0, 479.0]])
    np.testing.assert_allclose(prep.to_working(pts), pts)
    np.testing.assert_allclose(prep.working_to_original(pts), pts, atol=1e-9)
    # eroded border: the image edge itself is not valid, the interior is
    assert not prep.valid[:, :4].any() and not prep.valid[:4].any()
    assert prep.valid[4:-4, 4:-4].all()


def test_identity_with_padding_masks_the_pad() -> None:
    img = _texture(1000, 750)
    cal = CameraCalibration.pinhole(1000, 750, 800.0)
    prep = FramePreprocessor(InputRule(1024, 16)).prepare_query(_frame(img), cal, None)
    assert prep.image.shape == (752, 1008, 3)
    np.testing.assert_array_equal(prep.image[:750, :1000], img)
    assert not prep.valid[746:].any() and not prep.valid[:, 996:].any()
    assert (prep.image[750:] == 0).all() and (prep.image[:, 1000:] == 0).all()


def test_yaw_90_rotates_image_top_to_the_east() -> None:
    """Heading east, the image top (the nose) looks east: north-up, that is image right."""
    cal = CameraCalibration.pinhole(W, H, F)
    img = _dot_image(CX, CY - 100)
    prep = FramePreprocessor(InputRule(1024, 16), border_erode_px=0).prepare_query(
        _frame(img, Attitude(0, 0, math.pi / 2)), cal, None
    )
    nadir = np.array(prep.nadir_working_px)
    np.testing.assert_allclose(prep.original_to_working([[CX, CY]])[0], nadir, atol=1e-9)
    np.testing.assert_allclose(
        prep.original_to_working([[CX, CY - 100]])[0], nadir + np.array([100, 0]), atol=1e-9
    )
    np.testing.assert_allclose(
        prep.original_to_working([[CX + 50, CY]])[0], nadir + np.array([0, 50]), atol=1e-9
    )  # right wing -> south
    # pixel content: the dot is where the hand calculation says
    np.testing.assert_allclose(
        prep.to_working([_peak(prep.image)])[0], nadir + np.array([100, 0]), atol=0.15
    )


def test_pitch_20_moves_the_principal_point_by_f_tan() -> None:
    """Nose up 20 deg, heading north: the optical axis hits the ground f*tan(20) px north of
    nadir in the virtual camera (same focal)."""
    cal = CameraCalibration.pinhole(W, H, F)
    prep = FramePreprocessor(InputRule(2048, 16)).prepare_query(
        _frame(_texture(), Attitude(0, math.radians(20), 0)), cal, None
    )
    nadir = np.array(prep.nadir_working_px)
    pp = prep.original_to_working([[CX, CY]])[0]
    np.testing.assert_allclose(pp - nadir, [0.0, -F * math.tan(math.radians(20))], atol=1e-9)
    # roll 20 deg (right wing down) tilts the camera to the west: image left of nadir
    prep_r = FramePreprocessor(InputRule(2048, 16)).prepare_query(
        _frame(_texture(), Attitude(math.radians(20), 0, 0)), cal, None
    )
    pp_r = prep_r.original_to_working([[CX, CY]])[0] - np.array(prep_r.nadir_working_px)
    np.testing.assert_allclose(pp_r, [-F * math.tan(math.radians(20)), 0.0], atol=1e-9)


def test_gsd_scaling_factor_is_h_over_f_over_g() -> None:
    cal = CameraCalibration.pinhole(W, H, F)
    h, g = 150.0, 0.5  # query GSD 0.3 m/px -> factor 0.6
    pre = FramePreprocessor(InputRule(2048, 16))
    prep = pre.prepare_query(_frame(_texture(), None, h), cal, g)
    assert prep.working_from_undistorted[0, 0] == pytest.approx((h / F) / g)
    assert prep.working_from_undistorted[1, 1] == pytest.approx((h / F) / g)
    assert prep.working_gsd_m == pytest.approx(g)
    # rectified: two ground points 40 m apart are 40 / g px apart in working px
    att = Attitude(math.radians(3), math.radians(-5), math.radians(30))
    prep = pre.prepare_query(_frame(_texture(), att, h), cal, g)
    nadir = np.array(prep.nadir_working_px)
    r_wc = cam.rotation_world_from_camera(att, cal)
    ground = np.array([20.0, -15.0, h])  # 20 m north, 15 m west of nadir, camera to point
    ray = r_wc.T @ ground
    px = cal.K @ (ray / ray[2])
    got = prep.original_to_working([px[:2]])[0]
    np.testing.assert_allclose(got - nadir, [-15.0 / g, -20.0 / g], atol=1e-9)
    # without a tile GSD or a height, no scaling
    prep = pre.prepare_query(_frame(_texture(), None, h), cal, None)
    assert prep.working_from_undistorted[0, 0] == pytest.approx(1.0)
    assert prep.working_gsd_m == pytest.approx(h / F)


@pytest.mark.parametrize("tile_gsd", [1e-100, 1e300])
@pytest.mark.parametrize("attitude", [None, Attitude(0.0, 0.0, 1.0)])
def test_a_scale_no_camera_and_map_pair_can_have_is_named(tile_gsd, attitude) -> None:
    """A million times or more between the frame's GSD and the tiles' is a height or GSD in
    the wrong units: named, instead of overflowing inside OpenCV."""
    pre = FramePreprocessor(InputRule(1024, 16))
    frame = _frame(_texture(), attitude, 150.0)
    with pytest.raises(InvalidInputError, match="check the height and the tiles' GSD") as err:
        pre.prepare_query(frame, CameraCalibration.pinhole(W, H, F), tile_gsd)
    assert err.value.field == "tile_gsd_m"
    assert max(pre.prepare_query(frame, CameraCalibration.pinhole(W, H, F), 3e-4).working_size)


@pytest.mark.parametrize("rule", [InputRule(1024, 16), InputRule(512, 32)])
def test_round_trip_and_forward_path_with_distortion(rule: InputRule) -> None:
    w, h = 1000, 750
    cal = CameraCalibration.pinhole(w, h, 800.0, BARREL)
    att = Attitude(math.radians(6), math.radians(-14), math.radians(128))
    img = _texture(w, h, seed=3)
    pre = FramePreprocessor(rule)
    frame = _frame(img, att, 200.0)
    prep = pre.prepare_query(frame, cal, 0.3)
    # round trip ORIGINAL -> WORKING -> ORIGINAL
    pts = np.random.default_rng(2).uniform([0, 0], [w - 1, h - 1], (500, 2))
    np.testing.assert_allclose(
        prep.working_to_original(prep.original_to_working(pts)), pts, atol=1e-6
    )
    # engine px -> ORIGINAL by the point functions == the remap the pixels went through
    geometry = pre.query_geometry(frame, cal, 0.3)
    mx, my = geometry.remap_maps(cal)
    ys, xs = np.nonzero(prep.valid)
    sel = np.random.default_rng(4).choice(xs.size, 2000, replace=False)
    eng = np.stack([xs[sel], ys[sel]], axis=1).astype(np.float64)
    via_points = prep.working_to_original(prep.to_working(eng))
    via_map = np.stack([mx[ys[sel], xs[sel]], my[ys[sel], xs[sel]]], axis=1)
    np.testing.assert_allclose(via_points, via_map, atol=0.05)
    assert prep.image.shape[0] % rule.multiple == 0 and prep.image.shape[1] % rule.multiple == 0
    assert max(prep.image.shape[:2]) <= rule.max_long_side
    # pixel content: the prepared image samples the original where the point functions say
    ex, ey = np.meshgrid(np.arange(prep.image.shape[1]), np.arange(prep.image.shape[0]))
    orig = prep.engine_to_original(np.stack([ex.ravel(), ey.ravel()], axis=1).astype(float))
    if geometry.nadir_shrink < 2.0:
        ref = cv2.remap(
            img,
            orig[:, 0].reshape(ex.shape).astype(np.float32),
            orig[:, 1].reshape(ex.shape).astype(np.float32),
            cv2.INTER_LINEAR,
        )
        diff = np.abs(ref.astype(int) - prep.image.astype(int))[prep.valid]
        assert diff.mean() < 1.0


def test_area_downscale_path_keeps_geometry() -> None:
    """A big shrink (high flight, small engine) pre-downscales the source; positions hold."""
    w, h = 1000, 750
    cal = CameraCalibration.pinhole(w, h, 800.0, BARREL)
    x0, y0 = 700.0, 200.0
    img = _dot_image(x0, y0, w, h)
    img = cv2.GaussianBlur(img, (0, 0), 3)
    img = np.clip(img.astype(int) * 3 - 60, 30, 255).astype(np.uint8)
    pre = FramePreprocessor(InputRule(256, 16), border_erode_px=1)
    frame = _frame(img, Attitude(0.05, -0.1, 2.0), 100.0)
    assert pre.query_geometry(frame, cal, None).nadir_shrink >= 2.0
    prep = pre.prepare_query(frame, cal, None)
    got = prep.engine_to_original([_peak(prep.image)])[0]
    np.testing.assert_allclose(got, [x0, y0], atol=4.0 * 0.5)  # ~0.5 engine px


def test_masks_exclude_warp_borders() -> None:
    w, h = 800, 600
    cal = CameraCalibration.pinhole(w, h, 600.0, BARREL)
    img = _texture(w, h, seed=5)  # no zero pixel anywhere
    erode = 3
    pre = FramePreprocessor(InputRule(1024, 16), border_erode_px=erode)
    prep = pre.prepare_query(_frame(img, Attitude(0.2, -0.25, 0.9), 120.0), cal, 0.25)
    assert prep.valid.any()
    # every valid pixel maps inside the original frame, clear of its edge
    ys, xs = np.nonzero(prep.valid)
    orig = prep.engine_to_original(np.stack([xs, ys], axis=1).astype(float))
    assert np.all(orig[:, 0] > 0) and np.all(orig[:, 0] < w - 1)
    assert np.all(orig[:, 1] > 0) and np.all(orig[:, 1] < h - 1)
    # pixels outside the warped image are black and at least `erode` px from any valid pixel
    black = np.all(prep.image == 0, axis=2).astype(np.uint8)
    assert black.any()
    near_black = cv2.dilate(black, np.ones((2 * erode - 1, 2 * erode - 1), np.uint8)) > 0
    assert not (near_black & prep.valid).any()
    # and the valid area is most of the warped image
    assert prep.valid.sum() > 0.8 * (1 - black.mean()) * black.size


def test_canvas_is_bounded_and_sky_is_refused() -> None:
    cal = CameraCalibration.pinhole(W, H, 300.0)  # wide: 94 deg horizontal
    pre = FramePreprocessor(InputRule(4096, 16), max_canvas_factor=3.0)
    prep = pre.prepare_query(_frame(_texture(), Attitude(0, math.radians(55), 0)), cal, None)
    assert max(prep.working_size) <= 3 * W
    assert prep.valid.any()
    narrow = CameraCalibration.pinhole(W, H, 3000.0)
    with pytest.raises(InvalidInputError) as err:
        pre.prepare_query(_frame(_texture(), Attitude(0, math.radians(85), 0)), narrow, None)
    assert err.value.field == "frame.attitude"


def test_behind_camera_points_map_to_nan() -> None:
    cal = CameraCalibration.pinhole(W, H, 300.0)
    prep = FramePreprocessor(InputRule(1024, 16)).prepare_query(
        _frame(_texture(), Attitude(0, math.radians(60), 0)), cal, None
    )
    # a working point far south of nadir is behind a camera pitched 60 deg up
    far = np.array(prep.nadir_working_px) + np.array([0.0, 50 * F])
    assert np.isnan(prep.working_to_original([far])).all()


def test_grey_frames_are_converted_and_validation_names_the_field() -> None:
    grey = _texture()[..., 0].copy()
    cal = CameraCalibration.pinhole(W, H, F)
    pre = FramePreprocessor(InputRule(1024, 16))
    prep = pre.prepare_query(_frame(grey), cal, None)
    assert prep.image.shape == (H, W, 3)
    np.testing.assert_array_equal(prep.image[..., 0], grey)
    np.testing.assert_array_equal(prep.image[..., 2], grey)
    wrong = CameraCalibration.pinhole(W + 2, H, F)
    with pytest.raises(InvalidInputError) as err:
        pre.prepare_query(_frame(grey), wrong, None)
    assert err.value.field == "calibration.image_size"
    with pytest.raises(InvalidInputError) as err:
        pre.prepare_query(_frame(grey), cal, -1.0)
    assert err.value.field == "tile_gsd_m"


def test_prepare_query_is_deterministic() -> None:
    cal = CameraCalibration.pinhole(W, H, F, BARREL)
    frame = _frame(_texture(), Attitude(0.1, 0.1, 1.0), 90.0)
    a = FramePreprocessor(InputRule(512, 16)).prepare_query(frame, cal, 0.3)
    b = FramePreprocessor(InputRule(512, 16)).prepare_query(frame, cal, 0.3)
    assert a.image.tobytes() == b.image.tobytes()
    assert a.valid.tobytes() == b.valid.tobytes()


# --------------------------------------------------------------------------- tiles
def test_tile_resize_mask_nodata_and_coordinates() -> None:
    tile = _texture(1500, 900, seed=7)
    tri = np.tri(300, 300, dtype=bool)[::-1]  # top-left corner triangle of nodata
    tile[:300, :300][tri] = 0
    prep = FramePreprocessor(InputRule(1024, 16), border_erode_px=2).prepare_tile(tile)
    assert isinstance(prep, PreparedImage)
    assert prep.image.shape == (624, 1024, 3)  # content 1024x614 padded to 624
    assert not prep.valid[614 - 2 :].any()
    sx, sy = 1500 / 1024, 900 / 614  # area-aligned: x_w = (x_e + 0.5) * s - 0.5
    np.testing.assert_allclose(
        prep.to_working([[0.0, 0.0], [10.0, 20.0]]),
        [[0.5 * sx - 0.5, 0.5 * sy - 0.5], [10.5 * sx - 0.5, 20.5 * sy - 0.5]],
        atol=1e-12,
    )
    pts = np.array([[3.0, 4.0], [1000.0, 800.0]])
    np.testing.assert_array_equal(prep.working_to_original(pts), pts)
    np.testing.assert_allclose(prep.to_engine(prep.to_working(pts)), pts)
    # nodata: no valid engine pixel maps onto a nodata tile pixel
    ys, xs = np.nonzero(prep.valid)
    work = np.rint(prep.to_working(np.stack([xs, ys], axis=1).astype(float))).astype(int)
    assert not np.all(tile[work[:, 1], work[:, 0]] == 0, axis=1).any()
    assert not prep.valid[:100, :100].any()
    assert prep.valid[300:600, 300:1000].all()
    ref = cv2.resize(tile, (1024, 614), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(prep.image[:614], ref)


def test_small_grey_tile_is_not_upscaled() -> None:
    tile = _texture(200, 150, seed=8)[..., 1].copy()
    prep = FramePreprocessor(InputRule(1024, 32)).prepare_tile(tile)
    assert prep.image.shape == (160, 224, 3)
    np.testing.assert_array_equal(prep.image[:150, :200, 0], tile)
    np.testing.assert_allclose(prep.to_working([[5.0, 7.0]]), [[5.0, 7.0]])
    with pytest.raises(InvalidInputError):
        FramePreprocessor(InputRule(1024, 32)).prepare_tile(tile.astype(np.float32))


# --------------------------------------------------------------------------- photometry (13)
@pytest.mark.parametrize("mode", ["grey", "clahe"])
def test_photometric_normalisation_is_grey_masked_and_applied_to_query_and_tile(mode) -> None:
    pre = FramePreprocessor(InputRule(1024, 16), photometric=mode)
    tile = pre.prepare_tile(_texture(300, 200, seed=1))
    assert tile.image.shape[:2] == (208, 304)
    assert tile.image[200:].max() == 0 and tile.image[:, 300:].max() == 0  # padding stays 0
    query = pre.prepare_query(_frame(_texture()), CameraCalibration.pinhole(W, H, F), None)
    for prepared in (tile, query):
        img = prepared.image
        assert np.array_equal(img[..., 0], img[..., 1]) and np.array_equal(img[..., 1], img[..., 2])
    plain = FramePreprocessor(InputRule(1024, 16)).prepare_tile(_texture(300, 200, seed=1))
    grey = cv2.cvtColor(plain.image, cv2.COLOR_RGB2GRAY)
    if mode == "grey":
        assert np.array_equal(tile.image[..., 0], grey)
    else:  # local contrast stretched: a wider spread of grey levels than plain luminance
        assert tile.image[..., 0].std() > grey.std()


def test_photometric_mode_is_validated() -> None:
    with pytest.raises(InvalidInputError, match="photometric"):
        FramePreprocessor(InputRule(1024, 16), photometric="sepia")


def test_clahe_cells_cover_the_same_working_px_in_a_shrunk_image_and_a_whole_one(
    monkeypatch,
) -> None:
    """A 2048x1536 frame's engine image is half its WORKING px each way (1024 long side) and a
    512-px tile's is its own: CLAHE cells were counted in engine px, so the query's covered 4x
    the ground of the tile's. Both are now 64 WORKING px."""
    import c3_matcher.preprocess as module
    from c3_matcher.photometry import CLAHE_CELL_PX

    grids: list[tuple[int, int]] = []
    real = module.normalise_photometry

    def seen(image, valid, mode, working_per_engine=1.0):
        h, w = image.shape[:2]
        cell = CLAHE_CELL_PX / working_per_engine  # engine px
        grids.append((round(w / cell), round(h / cell)))
        return real(image, valid, mode, working_per_engine)

    monkeypatch.setattr(module, "normalise_photometry", seen)
    pre = FramePreprocessor(InputRule(1024, 16), photometric="clahe")
    pre.prepare_tile(_texture(512, 512, seed=1))
    big = NavCameraFrame(uuid.uuid4(), cv2.resize(_texture(), (2048, 1536)), 1)
    pre.prepare_query(big, CameraCalibration.pinhole(2048, 1536, 1800.0), None)
    assert grids == [(8, 8), (32, 24)]  # 512 / 64 and 2048 x 1536 / 64 WORKING px


@pytest.mark.parametrize("distortion", [(0.0,) * 7 + (5.0,), (5.0,) * 14])
@pytest.mark.parametrize("attitude", [None, Attitude(0.0, 0.0, 1.0)])
def test_distortion_that_maps_the_frame_edge_nowhere_is_named(distortion, attitude) -> None:
    """Coefficients under which the frame's edge has no undistorted position (the iteration
    gives NaN) name ``calibration.distortion``, not a NaN deep inside the canvas sums."""
    k = np.array([[F, 0.0, CX], [0.0, F, CY], [0.0, 0.0, 1.0]])
    cal = CameraCalibration(k, np.array(distortion), (W, H))
    pre = FramePreprocessor(InputRule(1024, 16))
    with pytest.raises(InvalidInputError, match="undistorted") as err:
        pre.prepare_query(_frame(_texture(), attitude, 150.0), cal, 0.3)
    assert err.value.field == "calibration.distortion"
