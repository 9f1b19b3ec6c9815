"""Render nav-camera frames over a real north-up orthophoto, with exact ground truth.

Geometry. The ground is the flat plane of the orthophoto. ORTHO px (u, v) are 0-based, origin at
the centre of the top-left pixel; north-up (u grows east, v grows south) at ``gsd_m`` m/px. The
camera is ``height_m`` above the ground point at ORTHO px ``nadir_px = (x0, y0)``. In NED (x
north, y east, z down) the vector from the camera to the ground point (u, v) is
``M @ (u, v, 1)`` with::

    M = [[0, -g, g * y0],
         [g,  0, -g * x0],
         [0,  0,  h     ]]

so the plane-induced homography ORTHO px -> UNDISTORTED frame px is
``H = K @ R_world_from_camera.T @ M`` (attitude Z-Y-X, NED, mount as in
:mod:`c3_matcher.camera`). The image is rendered by inverse mapping: each ORIGINAL (distorted)
frame pixel is undistorted exactly (iterative + Newton refinement), mapped through ``H^-1`` to the
orthophoto and sampled bilinearly (after an area pre-downscale of the orthophoto when the frame is
much coarser than it). Pixels whose ray misses the ground or the orthophoto are 0 and outside
:attr:`RenderedFrame.coverage`.
"""

from __future__ import annotations

import math
import uuid
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from c3_matcher import camera as cam
from c3_matcher.arrays import F64
from c3_matcher.dto import Attitude, CameraCalibration, NavCameraFrame
from c3_matcher.errors import InvalidInputError
from c3_matcher.resample import area_downscale, remap_linear
from c3_matcher_tools.sim.photometric import PhotometricShift

__all__ = [
    "NAV_CAMERA_DISTORTION",
    "NavCameraRenderer",
    "OrthoTile",
    "RenderedFrame",
    "cut_tile",
    "draw_apart",
    "footprint_mask",
    "ortho_to_undistorted_homography",
    "pick_distractor_tiles",
    "render_nav_frame",
]

NAV_CAMERA_DISTORTION: tuple[float, ...] = (-0.12, 0.03, 0.0005, -0.0004, 0.0)
"""The simulated nav camera's lens (OpenCV k1, k2, p1, p2, k3): a mild barrel, as of a small
wide-angle camera, so that every rendered flight exercises undistortion."""


def ortho_to_undistorted_homography(
    calibration: CameraCalibration,
    attitude: Attitude,
    nadir_px: tuple[float, float],
    height_m: float,
    gsd_m: float,
) -> F64:
    """3x3 homography ORTHO px -> UNDISTORTED frame px for a flat ground (module docstring)."""
    x0, y0 = float(nadir_px[0]), float(nadir_px[1])
    g, h = float(gsd_m), float(height_m)
    m = np.array([[0.0, -g, g * y0], [g, 0.0, -g * x0], [0.0, 0.0, h]])
    r_wc = cam.rotation_world_from_camera(attitude, calibration)
    return np.asarray(calibration.K @ r_wc.T @ m, dtype=np.float64)


@dataclass(frozen=True)
class OrthoTile:
    """A north-up crop of an orthophoto: TILE px = ORTHO px - ``offset_px``.

    ``image`` uint8 RGB (H, W, 3); parts outside the orthophoto are 0 (nodata); ``gsd_m`` m/px.
    """

    image: NDArray[np.uint8]
    offset_px: tuple[int, int]
    gsd_m: float

    def ortho_to_tile(self, pts: ArrayLike) -> F64:
        """(N, 2) ORTHO px -> (N, 2) TILE px."""
        return np.asarray(pts, dtype=np.float64).reshape(-1, 2) - np.asarray(self.offset_px)

    def tile_to_ortho(self, pts: ArrayLike) -> F64:
        """(N, 2) TILE px -> (N, 2) ORTHO px."""
        return np.asarray(pts, dtype=np.float64).reshape(-1, 2) + np.asarray(self.offset_px)

    @property
    def size(self) -> tuple[int, int]:
        """(w, h) px."""
        return int(self.image.shape[1]), int(self.image.shape[0])


def cut_tile(
    ortho: NDArray[np.uint8], top_left: tuple[int, int], size: tuple[int, int], gsd_m: float
) -> OrthoTile:
    """Crop ``size`` (w, h) px of ``ortho`` whose top-left pixel is ORTHO px ``top_left``;
    what falls outside the orthophoto is 0 (nodata)."""
    x0, y0 = int(top_left[0]), int(top_left[1])
    w, h = int(size[0]), int(size[1])
    if w <= 0 or h <= 0:
        raise InvalidInputError("size", f"must be > 0, got {size}")
    oh, ow = ortho.shape[:2]
    out = np.zeros((h, w, *ortho.shape[2:]), dtype=np.uint8)
    sx0, sy0 = max(x0, 0), max(y0, 0)
    sx1, sy1 = min(x0 + w, ow), min(y0 + h, oh)
    if sx1 > sx0 and sy1 > sy0:
        out[sy0 - y0 : sy1 - y0, sx0 - x0 : sx1 - x0] = ortho[sy0:sy1, sx0:sx1]
    return OrthoTile(out, (x0, y0), float(gsd_m))


@dataclass(frozen=True)
class RenderedFrame:
    """A rendered nav-camera frame and its ground truth.

    ``image`` uint8 RGB (H, W, 3), ORIGINAL (distorted) pixels; ``coverage`` bool (H, W), True
    where the pixel sees the orthophoto; ``gt_homography_undistorted_to_ortho`` 3x3, UNDISTORTED
    frame px -> ORTHO px; pose: ``nadir_px`` (ORTHO px below the camera), ``height_m``,
    ``attitude``; ``ortho_gsd_m`` m/px; ``ortho_size`` (w, h).
    """

    image: NDArray[np.uint8]
    coverage: NDArray[np.bool_]
    gt_homography_undistorted_to_ortho: F64
    calibration: CameraCalibration
    attitude: Attitude
    nadir_px: tuple[float, float]
    height_m: float
    ortho_gsd_m: float
    ortho_size: tuple[int, int]

    @property
    def nadir_gsd_m(self) -> float:
        """The frame's ground sample distance at nadir, ``height / sqrt(fx * fy)`` (m/px)."""
        k = self.calibration.K
        return self.height_m / math.sqrt(k[0, 0] * k[1, 1])

    def undistorted_to_ortho(self, pts: ArrayLike) -> F64:
        """(N, 2) UNDISTORTED frame px -> (N, 2) ORTHO px (NaN where the ray misses the ground)."""
        h = self.gt_homography_undistorted_to_ortho
        p = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        q = p @ h[:, :2].T + h[:, 2]
        out = np.full_like(p, np.nan)
        hits = self._hits_ground(p)
        out[hits] = q[hits, :2] / q[hits, 2:3]
        return out

    def original_to_ortho(self, pts: ArrayLike) -> F64:
        """(N, 2) ORIGINAL (distorted) frame px -> (N, 2) ORTHO px: undistort, then the GT."""
        return self.undistorted_to_ortho(cam.undistort_points(pts, self.calibration))

    def ortho_to_undistorted(self, pts: ArrayLike) -> F64:
        """(N, 2) ORTHO px -> (N, 2) UNDISTORTED frame px (NaN behind the camera)."""
        h = np.linalg.inv(self.gt_homography_undistorted_to_ortho)
        p = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        q = p @ h[:, :2].T + h[:, 2]
        # H = K @ R_cw @ M: its third output is the ground point's camera depth (z_c).
        out = np.full_like(p, np.nan)
        front = q[:, 2] > 0
        out[front] = q[front, :2] / q[front, 2:3]
        return out

    def ortho_to_original(self, pts: ArrayLike) -> F64:
        """(N, 2) ORTHO px -> (N, 2) ORIGINAL (distorted) frame px (NaN behind the camera)."""
        und = self.ortho_to_undistorted(pts)
        out = np.full_like(und, np.nan)
        ok = np.all(np.isfinite(und), axis=1)
        if np.any(ok):
            out[ok] = cam.distort_points(und[ok], self.calibration)
        return out

    def footprint_ortho(self, samples_per_side: int = 32) -> F64:
        """The frame boundary on the ground, as a closed polygon (N, 2) of ORTHO px (the part of
        the boundary above the horizon is clipped at ~89 deg from nadir)."""
        w, h = self.calibration.image_size
        rays = cam.undistort_normalized(
            cam.image_boundary(w, h, samples_per_side), self.calibration
        )
        r_wc = cam.rotation_world_from_camera(self.attitude, self.calibration)
        d = np.concatenate([rays, np.ones((rays.shape[0], 1))], axis=1) @ r_wc.T
        cos_max = math.cos(math.radians(89.0))
        d = cam.clip_polygon(d, lambda v: v[:, 2] / np.linalg.norm(v, axis=1) - cos_max)
        if d.shape[0] == 0:
            return np.zeros((0, 2))
        t = self.height_m / d[:, 2]
        north, east = d[:, 0] * t, d[:, 1] * t
        g = self.ortho_gsd_m
        return np.stack([self.nadir_px[0] + east / g, self.nadir_px[1] - north / g], axis=1)

    def nav_frame(
        self,
        frame_id: uuid.UUID | None = None,
        captured_at_ns: int = 0,
        *,
        with_attitude: bool = True,
    ) -> NavCameraFrame:
        """The :class:`NavCameraFrame` a matcher would receive for this render."""
        return NavCameraFrame(
            frame_id=frame_id if frame_id is not None else uuid.UUID(int=0),
            image=self.image,
            captured_at_ns=captured_at_ns,
            attitude=self.attitude if with_attitude else None,
            height_above_ground_m=self.height_m,
        )

    def tile_around(
        self, ortho: NDArray[np.uint8], size: tuple[int, int], shift_px: tuple[int, int] = (0, 0)
    ) -> OrthoTile:
        """A north-up tile of ``size`` (w, h) px centred on the footprint's centroid plus
        ``shift_px`` (ORTHO px), cut from ``ortho`` (the orthophoto this frame was rendered on)."""
        fp = self.footprint_ortho()
        cx, cy = fp.mean(axis=0) if fp.shape[0] else self.nadir_px
        x0 = round(cx - (size[0] - 1) / 2) + int(shift_px[0])
        y0 = round(cy - (size[1] - 1) / 2) + int(shift_px[1])
        return cut_tile(ortho, (x0, y0), size, self.ortho_gsd_m)

    def _hits_ground(self, undistorted_px: F64) -> NDArray[np.bool_]:
        k_inv = np.linalg.inv(self.calibration.K)
        r_wc = cam.rotation_world_from_camera(self.attitude, self.calibration)
        rays = np.concatenate([undistorted_px, np.ones((undistorted_px.shape[0], 1))], axis=1)
        down = (rays @ (r_wc @ k_inv).T)[:, 2]
        return np.asarray(down > 1e-9)


class NavCameraRenderer:
    """Renders frames through one calibration; computes the exact undistorted ray of every
    ORIGINAL pixel once (the costly part, ~0.3 s for 1000x750) and reuses it per frame. The
    orthophoto is area-downscaled first when the frame's nadir GSD is >= 1.5x the
    orthophoto's (anti-aliasing)."""

    def __init__(self, calibration: CameraCalibration) -> None:
        self.calibration = calibration
        self._rays: tuple[F64, F64] | None = None

    def pixel_rays(self) -> tuple[F64, F64]:
        """(x/z, y/z) of the normalised undistorted ray of every ORIGINAL pixel, two (H, W)
        arrays."""
        if self._rays is None:
            w, h = self.calibration.image_size
            xs, ys = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
            rays = cam.undistort_normalized(
                np.stack([xs.ravel(), ys.ravel()], axis=1), self.calibration
            )
            self._rays = (
                np.ascontiguousarray(rays[:, 0].reshape(h, w)),
                np.ascontiguousarray(rays[:, 1].reshape(h, w)),
            )
        return self._rays

    def render(
        self,
        ortho: NDArray[np.uint8],
        gsd_m: float,
        nadir_px: tuple[float, float],
        height_m: float,
        attitude: Attitude,
        *,
        photometric: PhotometricShift | None = None,
        seed: int | np.random.Generator = 0,
    ) -> RenderedFrame:
        """See :func:`render_nav_frame`."""
        _check_render_inputs(ortho, gsd_m, height_m)
        calibration = self.calibration
        h_o2u = ortho_to_undistorted_homography(calibration, attitude, nadir_px, height_m, gsd_m)
        h_u2o: F64 = np.asarray(np.linalg.inv(h_o2u), dtype=np.float64)
        pixels = self._ortho_px(h_u2o, attitude, ortho.shape[:2])
        src, offset, scale = self._source(ortho, pixels, height_m, gsd_m)
        img = _remap(src, offset, scale, pixels)
        img = _shifted_and_masked(img, pixels.inside, photometric, seed)
        oh, ow = ortho.shape[:2]
        return RenderedFrame(
            image=img,
            coverage=pixels.inside,
            gt_homography_undistorted_to_ortho=h_u2o,
            calibration=calibration,
            attitude=attitude,
            nadir_px=(float(nadir_px[0]), float(nadir_px[1])),
            height_m=float(height_m),
            ortho_gsd_m=float(gsd_m),
            ortho_size=(ow, oh),
        )

    def _ortho_px(self, h_u2o: F64, attitude: Attitude, ortho_hw: tuple[int, ...]) -> _PixelMap:
        """Map every ORIGINAL pixel's ray to ORTHO px (u, v); mark those that see the orthophoto."""
        calibration = self.calibration
        rx, ry = self.pixel_rays()
        r_wc = cam.rotation_world_from_camera(attitude, calibration)
        g = h_u2o @ calibration.K
        hits = (r_wc[2, 0] * rx + r_wc[2, 1] * ry + r_wc[2, 2]) > 1e-9  # ray points down
        qw = g[2, 0] * rx + g[2, 1] * ry + g[2, 2]
        qw[~hits] = 1.0
        u = (g[0, 0] * rx + g[0, 1] * ry + g[0, 2]) / qw
        v = (g[1, 0] * rx + g[1, 1] * ry + g[1, 2]) / qw
        oh, ow = ortho_hw[:2]
        inside = hits & (u >= -0.5) & (u <= ow - 0.5) & (v >= -0.5) & (v <= oh - 0.5)
        return _PixelMap(u, v, np.asarray(inside))

    def _source(
        self, ortho: NDArray[np.uint8], pixels: _PixelMap, height_m: float, gsd_m: float
    ) -> tuple[NDArray[np.uint8], F64, F64]:
        """Cut what the frame sees from the orthophoto, area-downscaled: (source, offset, scale)."""
        if not np.any(pixels.inside):
            return ortho, np.zeros(2), np.ones(2)
        oh, ow = ortho.shape[:2]
        ui, vi = pixels.u[pixels.inside], pixels.v[pixels.inside]
        lo = np.maximum(np.floor([ui.min(), vi.min()]) - 2, 0).astype(int)
        hi = np.minimum(np.ceil([ui.max(), vi.max()]) + 3, [ow, oh]).astype(int)
        src = ortho[lo[1] : hi[1], lo[0] : hi[0]]
        offset = lo.astype(np.float64)
        scale = np.ones(2)
        k = self.calibration.K
        ratio = (height_m / math.sqrt(k[0, 0] * k[1, 1])) / gsd_m
        if ratio >= 1.5:
            src, src_scale = area_downscale(src, ratio)
            scale = np.array(src_scale)
        return src, offset, scale


@dataclass(frozen=True)
class _PixelMap:
    """Where each ORIGINAL frame pixel's ray meets the ground: ORTHO px ``u``, ``v`` (H, W), and
    ``inside``, True where that point lies on the orthophoto."""

    u: F64
    v: F64
    inside: NDArray[np.bool_]


def _remap(src: NDArray[np.uint8], offset: F64, scale: F64, pixels: _PixelMap) -> NDArray[np.uint8]:
    """Sample ``src`` bilinearly at each pixel's ORTHO px, as RGB; 0 where it misses the ortho."""
    map_x = ((pixels.u - (offset[0] - 0.5)) * scale[0] - 0.5).astype(np.float32)
    map_y = ((pixels.v - (offset[1] - 0.5)) * scale[1] - 0.5).astype(np.float32)
    map_x[~pixels.inside] = -10.0
    map_y[~pixels.inside] = -10.0
    img = remap_linear(src, map_x, map_y)
    if img.ndim == 2:
        img = np.asarray(cv2.cvtColor(img, cv2.COLOR_GRAY2RGB), dtype=np.uint8)
    return img


def _check_render_inputs(ortho: NDArray[np.uint8], gsd_m: float, height_m: float) -> None:
    """Refuse an orthophoto that is not a uint8 image, or a GSD or height that is not > 0."""
    if not isinstance(ortho, np.ndarray) or ortho.dtype != np.uint8 or ortho.ndim not in (2, 3):
        raise InvalidInputError("ortho", "expected a uint8 (H, W) or (H, W, 3) array")
    if not (gsd_m > 0 and height_m > 0):
        raise InvalidInputError("gsd_m/height_m", f"must be > 0, got {gsd_m}, {height_m}")


def _shifted_and_masked(
    img: NDArray[np.uint8],
    inside: NDArray[np.bool_],
    photometric: PhotometricShift | None,
    seed: int | np.random.Generator,
) -> NDArray[np.uint8]:
    """Apply ``photometric`` (drawn from ``seed``), then zero the pixels outside ``inside``."""
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    if photometric is not None:
        img = photometric.apply(img, rng)
    return np.asarray(cv2.bitwise_and(img, img, mask=inside.astype(np.uint8)), dtype=np.uint8)


def render_nav_frame(
    ortho: NDArray[np.uint8],
    gsd_m: float,
    nadir_px: tuple[float, float],
    height_m: float,
    attitude: Attitude,
    calibration: CameraCalibration,
    *,
    photometric: PhotometricShift | None = None,
    seed: int | np.random.Generator = 0,
) -> RenderedFrame:
    """Render the nav-camera frame of a flat ground textured by ``ortho`` (uint8 RGB or grey,
    north-up, ``gsd_m`` m/px) seen from ``height_m`` m above ORTHO px ``nadir_px`` with
    ``attitude``, through ``calibration`` (lens distortion included), then apply
    ``photometric`` with a generator seeded by ``seed`` (an int or a Generator, advanced).
    Deterministic for a given seed. For many frames, reuse one :class:`NavCameraRenderer`."""
    return NavCameraRenderer(calibration).render(
        ortho, gsd_m, nadir_px, height_m, attitude, photometric=photometric, seed=seed
    )


def pick_distractor_tiles(
    ortho: NDArray[np.uint8],
    footprint_ortho: ArrayLike,
    size: tuple[int, int],
    count: int,
    rng: np.random.Generator,
    gsd_m: float,
    *,
    margin_px: int = 0,
    min_distance_px: float = 0.0,
    max_nodata_fraction: float = 0.05,
    stride_px: int | None = None,
) -> list[OrthoTile]:
    """``count`` north-up tiles of ``size`` (w, h) px inside ``ortho`` that do not overlap the
    frame's ground footprint (polygon of ORTHO px, dilated by ``margin_px``) nor each other,
    whose centres are at least ``min_distance_px`` from the footprint's centroid and whose
    nodata (all channels 0) fraction is at most ``max_nodata_fraction``. Positions lie on a grid
    of ``stride_px`` (default size/8) and are drawn with ``rng``. Raises InvalidInputError when
    fewer than ``count`` fit."""
    tw, th = int(size[0]), int(size[1])
    oh, ow = ortho.shape[:2]
    fp = np.asarray(footprint_ortho, dtype=np.float64).reshape(-1, 2)
    xs, ys = _grid_positions((ow, oh), (tw, th), stride_px or max(1, min(tw, th) // 8))
    ok = _window_sums(footprint_mask(fp, (oh, ow), margin_px), xs, ys, (tw, th)) == 0
    nodata = np.all(ortho == 0, axis=2) if ortho.ndim == 3 else ortho == 0
    ok &= _window_sums(nodata.astype(np.uint8), xs, ys, (tw, th)) <= max_nodata_fraction * tw * th
    centre = fp.mean(axis=0) if fp.shape[0] else np.array([-1e9, -1e9])
    ok &= np.hypot(xs + (tw - 1) / 2 - centre[0], ys + (th - 1) / 2 - centre[1]) >= min_distance_px
    chosen = draw_apart(xs, ys, np.flatnonzero(ok), (tw, th), count, rng)
    if len(chosen) < count:
        raise InvalidInputError(
            "count",
            f"only {len(chosen)} non-overlapping {tw}x{th} px "
            f"distractor tiles fit, {count} requested",
        )
    return [cut_tile(ortho, c, (tw, th), gsd_m) for c in chosen]


def _grid_positions(
    ortho_size: tuple[int, int], size: tuple[int, int], stride: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """List the top-left (x, y) of each (w, h) window inside the orthophoto on a stride grid."""
    (ow, oh), (tw, th) = ortho_size, size
    ys, xs = np.mgrid[0 : max(oh - th + 1, 0) : stride, 0 : max(ow - tw + 1, 0) : stride]
    return xs.ravel(), ys.ravel()


def footprint_mask(fp: F64, shape: tuple[int, int], margin_px: int) -> NDArray[np.uint8]:
    """Rasterize the footprint polygon (ORTHO px, dilated by ``margin_px``): 1 where occupied."""
    occupied = np.zeros(shape, dtype=np.uint8)
    if fp.shape[0] >= 3:
        pts = np.round(np.clip(fp, -1e6, 1e6) * 16).astype(np.int32).reshape(-1, 1, 2)
        cv2.fillPoly(occupied, [pts], (1,), lineType=cv2.LINE_8, shift=4)
        if margin_px > 0:
            k = np.ones((2 * margin_px + 1, 2 * margin_px + 1), dtype=np.uint8)
            occupied = np.asarray(cv2.dilate(occupied, k), dtype=np.uint8)
    return occupied


def _window_sums(
    mask: NDArray[np.uint8], xs: NDArray[np.int64], ys: NDArray[np.int64], size: tuple[int, int]
) -> NDArray[np.int64]:
    """Sum ``mask`` over the (w, h) window at each top-left (x, y), through its integral image."""
    tw, th = size
    integral = np.asarray(cv2.integral(mask), dtype=np.int64)
    return np.asarray(
        integral[ys + th, xs + tw]
        - integral[ys, xs + tw]
        - integral[ys + th, xs]
        + integral[ys, xs],
        dtype=np.int64,
    )


def draw_apart(
    xs: NDArray[np.int64],
    ys: NDArray[np.int64],
    allowed: NDArray[np.intp],
    size: tuple[int, int],
    count: int,
    rng: np.random.Generator,
) -> list[tuple[int, int]]:
    """Draw up to ``count`` allowed windows in ``rng``'s order, each clear of those drawn before."""
    tw, th = size
    order = rng.permutation(allowed.size)
    chosen: list[tuple[int, int]] = []
    for idx in allowed[order]:
        x, y = int(xs[idx]), int(ys[idx])
        if all(abs(x - cx) >= tw or abs(y - cy) >= th for cx, cy in chosen):
            chosen.append((x, y))
            if len(chosen) == count:
                break
    return chosen
