"""Frame and tile preprocessing shared by every strategy.

Query (nav-camera frame), in order: undistort with the calibration; if the attitude is known,
ONE rotation homography to a virtual nadir north-up camera about the camera centre; if the
height above ground and the candidate's GSD are known, scale to that GSD; resize to the
engine's :class:`InputRule`. All four steps are composed into one ``cv2.remap`` whose map comes
from ``cv2.initUndistortRectifyMap`` (exact forward lens model per output pixel), so the frame is
resampled once. Tiles are resized (area averaging) and padded.

The coordinate frames (ORIGINAL, UNDISTORTED, WORKING, ENGINE) are defined in
:mod:`c3_matcher.prepared`.

Rectifying homography (UNDISTORTED -> WORKING) when the attitude is known::

    R_vc = R_world_from_virtual.T @ R_world_from_body(attitude) @ R_body_from_camera
    H_w  = T @ diag(f_w, f_w, 1) @ R_vc @ K^-1

with ``f_w = height / tile_gsd`` when both are known (working GSD = tile GSD), else
``f_w = sqrt(fx * fy)``; ``T`` translates the bounding box of the rectified footprint (the
image boundary's rays, clipped to ``max_off_nadir_deg`` from nadir) to the canvas origin. The
canvas is bounded: if the footprint's box is longer than ``max_canvas_factor`` times the
frame's long side (at the working scale), a window of that size centred on the optical axis's
ground point is kept. The nadir point (vehicle position on the ground) lies at working pixel
``(T[0, 2], T[1, 2])``. Without attitude, ``H_w = T @ diag(s, s, 1) @ K_sq @ K^-1`` (``K_sq``
= K with square pixels ``sqrt(fx * fy)``, ``s = (height / sqrt(fx * fy)) / tile_gsd`` or 1), the
identity for a distortion-free square-pixel camera.

ENGINE -> WORKING is ``x_w = (x_e + 0.5) * sx - 0.5`` (same for y), ``sx = working_w /
content_w``: the area-aligned convention of ``cv2.resize``. The final size is padded (masked) up
to a multiple of ``rule.multiple``, or cropped down when padding would exceed
``rule.max_long_side``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher import camera as cam
from c3_matcher.arrays import F64
from c3_matcher.dto import CameraCalibration, NavCameraFrame
from c3_matcher.errors import InvalidInputError
from c3_matcher.photometry import PHOTOMETRIC_MODES, normalise_photometry, to_rgb
from c3_matcher.prepared import InputRule, PreparedImage, engine_to_working
from c3_matcher.query_geometry import QueryGeometry
from c3_matcher.resample import area_downscale, check_pixels, remap_linear

__all__ = ["MAX_QUERY_SCALE", "FramePreprocessor"]

# The farthest the frame's scale may be from the tiles' (``f_w / sqrt(fx * fy)``, either way):
# a million times means a height or a tile GSD in the wrong units or a sensor glitch, never a
# pairing of camera and map (a frame shrunk that far is under a pixel), and it keeps the
# rectifying homography's products inside floating point.
MAX_QUERY_SCALE = 1e6


@dataclass(frozen=True)
class _LensCache:
    key: tuple[bytes, bytes, tuple[int, int]]
    boundary_rays: F64  # (N, 2) normalised undistorted rays of the image boundary


class FramePreprocessor:
    """Prepares query frames and candidate tiles for one engine's :class:`InputRule`.

    Single-threaded: it caches the undistorted image boundary of the last few
    calibrations. ``border_erode_px`` (engine px) erodes the valid mask so no keypoint sits on
    a warp, padding or nodata edge; ``max_off_nadir_deg`` clips the rectified footprint to rays
    at most that far from nadir; ``max_canvas_factor`` bounds the working canvas (see the module
    docstring); the source frame is area-downscaled first when the composed warp shrinks it by
    more than ``area_downscale_threshold``; ``photometric`` is the normalisation applied to
    query and tiles alike (:func:`normalise_photometry`).
    """

    def __init__(
        self,
        rule: InputRule,
        *,
        border_erode_px: int = 4,
        max_off_nadir_deg: float = cam.MAX_OFF_NADIR_DEG,
        max_canvas_factor: float = 3.0,
        boundary_samples_per_side: int = 64,
        area_downscale_threshold: float = 2.0,
        photometric: str = "none",
    ) -> None:
        if not isinstance(rule, InputRule):
            raise InvalidInputError("rule", f"expected InputRule, got {type(rule).__name__}")
        if border_erode_px < 0:
            raise InvalidInputError("border_erode_px", f"must be >= 0, got {border_erode_px}")
        if not 0.0 < max_off_nadir_deg < 90.0:
            raise InvalidInputError(
                "max_off_nadir_deg", f"must be in (0, 90), got {max_off_nadir_deg}"
            )
        if max_canvas_factor < 1.0:
            raise InvalidInputError("max_canvas_factor", f"must be >= 1, got {max_canvas_factor}")
        if photometric not in PHOTOMETRIC_MODES:
            raise InvalidInputError(
                "photometric", f"must be one of {PHOTOMETRIC_MODES}, got {photometric!r}"
            )
        self.rule = rule
        self.photometric = photometric
        self.border_erode_px = int(border_erode_px)
        self.max_off_nadir_deg = float(max_off_nadir_deg)
        self.max_canvas_factor = float(max_canvas_factor)
        self.boundary_samples_per_side = int(boundary_samples_per_side)
        self.area_downscale_threshold = float(area_downscale_threshold)
        self._lens_cache: list[_LensCache] = []

    # ------------------------------------------------------------------ query
    def prepare_query(
        self, frame: NavCameraFrame, calibration: CameraCalibration, tile_gsd_m: float | None
    ) -> PreparedImage:
        """Undistort, rectify to north-up nadir (if attitude), scale to ``tile_gsd_m`` m/px (if
        height and GSD) and resize the nav frame to the rule, in one resampling."""
        return self.render_query(
            frame, calibration, self.query_geometry(frame, calibration, tile_gsd_m)
        )

    def render_query(
        self, frame: NavCameraFrame, calibration: CameraCalibration, geometry: QueryGeometry
    ) -> PreparedImage:
        """The frame's pixels resampled once into ``geometry``'s engine image (exact lens model
        per pixel), masked to its footprint and normalised (:func:`normalise_photometry`)."""
        image = check_pixels(frame.image, "frame.image")
        # Source anti-aliasing: area-downscale first if the warp shrinks the frame a lot.
        src: NDArray[np.uint8] = image
        source_scale = (1.0, 1.0)
        shrink = geometry.nadir_shrink
        if shrink >= self.area_downscale_threshold:
            src, source_scale = area_downscale(image, shrink)
        map1, map2 = geometry.remap_maps(calibration, source_scale, cv2.CV_16SC2)
        warped = remap_linear(src, map1, map2)
        inside = self._polygon_mask(geometry.footprint_engine(), geometry.final_size)
        warped = np.asarray(cv2.bitwise_and(warped, warped, mask=inside), dtype=np.uint8)
        scale = geometry.working_per_engine()
        rgb = normalise_photometry(to_rgb(warped), inside, self.photometric, scale)
        return PreparedImage(
            image=np.ascontiguousarray(rgb),
            valid=self._erode(inside),
            working_from_engine=geometry.working_from_engine,
            working_size=geometry.working_size,
            working_from_undistorted=geometry.working_from_undistorted,
            calibration=calibration,
            working_gsd_m=geometry.working_gsd_m,
            nadir_working_px=geometry.nadir_working_px,
        )

    def query_geometry(
        self, frame: NavCameraFrame, calibration: CameraCalibration, tile_gsd_m: float | None
    ) -> QueryGeometry:
        """The geometry :meth:`prepare_query` uses (no pixels touched): the rectifying
        homography, the canvas, the engine sizes and the footprint."""
        image = check_pixels(frame.image, "frame.image")
        h, w = image.shape[:2]
        if tuple(calibration.image_size) != (w, h):
            raise InvalidInputError(
                "calibration.image_size",
                f"calibration is for {calibration.image_size[0]}x{calibration.image_size[1]} px "
                f"but the frame is {w}x{h} px",
            )
        if tile_gsd_m is not None:
            g = float(tile_gsd_m)
            if not math.isfinite(g) or g <= 0:
                raise InvalidInputError("tile_gsd_m", f"must be finite and > 0, got {tile_gsd_m}")
        k = calibration.K
        f_ref = math.sqrt(k[0, 0] * k[1, 1])
        height = frame.height_above_ground_m
        f_w = f_ref
        if height is not None and tile_gsd_m:
            f_w = height / float(tile_gsd_m)
            if not 1 / MAX_QUERY_SCALE <= f_w / f_ref <= MAX_QUERY_SCALE:
                raise InvalidInputError(
                    "tile_gsd_m",
                    f"{tile_gsd_m:g} m/px would scale the frame by {f_w / f_ref:.3g} (height "
                    f"{height:g} m, focal {f_ref:.1f} px, its own GSD {height / f_ref:.3g} m/px):"
                    " check the height and the tiles' GSD",
                )

        # H0: UNDISTORTED px -> working px before the canvas translation.
        if frame.attitude is not None:
            r_vc = cam.virtual_from_camera(frame.attitude, calibration)
            h0 = np.diag([f_w, f_w, 1.0]) @ r_vc @ np.linalg.inv(k)
        else:
            k_sq = np.array([[f_ref, 0.0, k[0, 2]], [0.0, f_ref, k[1, 2]], [0.0, 0.0, 1.0]])
            s = f_w / f_ref
            h0 = np.diag([s, s, 1.0]) @ k_sq @ np.linalg.inv(k)

        poly, centre = self._footprint(calibration, h0, f_w, frame.attitude is not None)
        t, working_size = self._canvas(poly, centre, max(w, h) * f_w / f_ref)
        content = self.rule.content_size(*working_size)
        return QueryGeometry(
            working_from_undistorted=t @ h0,
            working_size=working_size,
            content_size=content,
            final_size=self.rule.final_size(*working_size),
            working_from_engine=engine_to_working(working_size, content),
            footprint_working=cam.apply_homography(t, poly),
            nadir_working_px=(
                (float(t[0, 2]), float(t[1, 2])) if frame.attitude is not None else None
            ),
            working_gsd_m=height / f_w if height is not None else None,
            nadir_shrink=(working_size[0] / content[0]) * (f_ref / f_w),
        )

    def refined_geometry(
        self, geometry: QueryGeometry, tile_from_working: F64, tile_size: tuple[int, int]
    ) -> QueryGeometry | None:
        """``geometry`` re-rendered into a tile's pixel grid (the refine pass): the
        engine image shows the query's footprint as ``tile_from_working`` (a first match's
        homography, WORKING -> tile px) places it in the ``tile_size`` tile, at the tile's
        scale and orientation, cropped to the tile. WORKING px stay the query's own, so
        correspondences, the prior and ``working_to_original`` are unchanged. None when the
        footprint lands on no tile pixel or the homography is degenerate there."""
        h1 = np.asarray(tile_from_working, dtype=np.float64)
        if h1.shape != (3, 3) or not np.isfinite(h1).all() or abs(np.linalg.det(h1)) < 1e-12:
            return None
        q = (
            np.concatenate(
                [geometry.footprint_working, np.ones((len(geometry.footprint_working), 1))], axis=1
            )
            @ h1.T
        )
        if not (q[:, 2] > 1e-9).all():  # the footprint crosses the homography's horizon
            return None
        poly = q[:, :2] / q[:, 2:3]
        lo = np.maximum(np.floor(poly.min(axis=0)), 0.0)
        hi = np.minimum(np.ceil(poly.max(axis=0)), np.asarray(tile_size, dtype=np.float64) - 1)
        if (hi - lo < 2 * self.rule.multiple).any():
            return None
        size = (int(hi[0] - lo[0]) + 1, int(hi[1] - lo[1]) + 1)
        content = self.rule.content_size(*size)
        shift = np.array([[1.0, 0.0, lo[0]], [0.0, 1.0, lo[1]], [0.0, 0.0, 1.0]])
        tile_from_engine = shift @ engine_to_working(size, content)
        refined = dataclasses.replace(
            geometry,
            content_size=content,
            final_size=self.rule.final_size(*size),
            working_from_engine=np.linalg.inv(h1) @ tile_from_engine,
        )  # the source is shrunk for this image's own scale (the first's blurred it 3x)
        shrink = geometry.original_per_working() * refined.working_per_engine()
        return dataclasses.replace(refined, nadir_shrink=shrink)

    def _boundary_rays(self, calibration: CameraCalibration) -> F64:
        w, h = calibration.image_size
        key = (calibration.K.tobytes(), calibration.distortion.tobytes(), (int(w), int(h)))
        for entry in self._lens_cache:
            if entry.key == key:
                return entry.boundary_rays
        rays = cam.undistort_normalized(
            cam.image_boundary(w, h, self.boundary_samples_per_side), calibration
        )
        if not np.isfinite(rays).all():
            raise InvalidInputError(
                "calibration.distortion",
                f"{calibration.distortion.tolist()} leaves the edge of a {w}x{h} px frame with "
                "no undistorted position: not a lens this image was taken through",
            )
        self._lens_cache = [_LensCache(key, rays), *self._lens_cache[:3]]
        return rays

    def _footprint(
        self, calibration: CameraCalibration, h0: F64, f_w: float, rectified: bool
    ) -> tuple[F64, F64]:
        """The frame's boundary in pre-translation working px (clipped to the off-nadir cone
        when rectified) and the working position of the optical axis (canvas centre hint)."""
        rays = self._boundary_rays(calibration)
        g = h0 @ calibration.K  # normalised ray (x, y, 1) -> homogeneous working px
        q = np.concatenate([rays, np.ones((rays.shape[0], 1))], axis=1) @ g.T
        axis = g[:, 2]
        if rectified:
            cos_max = math.cos(math.radians(self.max_off_nadir_deg))

            def cone(v: F64) -> F64:
                d = np.stack([v[:, 0] / f_w, v[:, 1] / f_w, v[:, 2]], axis=1)
                return np.asarray(v[:, 2] / np.linalg.norm(d, axis=1) - cos_max)

            q = cam.clip_polygon(q, cone)
            if q.shape[0] < 3:
                raise InvalidInputError(
                    "frame.attitude",
                    f"the camera sees no ground within {self.max_off_nadir_deg} deg of nadir",
                )
            axis_ok = bool(cone(axis[None, :])[0] >= 0)
        else:
            axis_ok = True
        poly = q[:, :2] / q[:, 2:3]
        centre = axis[:2] / axis[2] if axis_ok else poly.mean(axis=0)
        return poly, centre

    def _canvas(
        self, poly: F64, centre: F64, long_side_working: float
    ) -> tuple[F64, tuple[int, int]]:
        lo = np.floor(poly.min(axis=0) + 1e-6)
        hi = np.ceil(poly.max(axis=0) - 1e-6)
        limit = math.floor(self.max_canvas_factor * long_side_working)
        origin = [0, 0]
        size = [0, 0]
        for i in range(2):
            extent = int(hi[i] - lo[i]) + 1
            if extent <= limit:
                origin[i], size[i] = int(lo[i]), extent
            else:
                start = math.floor(centre[i] - limit / 2)
                start = min(max(start, int(lo[i])), int(hi[i]) + 1 - limit)
                origin[i], size[i] = start, limit
        t = np.array([[1.0, 0.0, -origin[0]], [0.0, 1.0, -origin[1]], [0.0, 0.0, 1.0]])
        return t, (max(1, size[0]), max(1, size[1]))

    @staticmethod
    def _polygon_mask(poly_engine: F64, size: tuple[int, int]) -> NDArray[np.uint8]:
        mask = np.zeros((size[1], size[0]), dtype=np.uint8)
        shift = 4
        pts = np.clip(poly_engine, -1e6, 1e6) * (1 << shift)
        cv2.fillPoly(
            mask,
            [np.round(pts).astype(np.int32).reshape(-1, 1, 2)],
            (255,),
            lineType=cv2.LINE_8,
            shift=shift,
        )
        return mask

    def _erode(self, mask: NDArray[np.uint8]) -> NDArray[np.bool_]:
        if self.border_erode_px > 0:
            ksize = 2 * self.border_erode_px + 1
            kernel = np.ones((ksize, ksize), dtype=np.uint8)
            mask = np.asarray(
                cv2.erode(mask, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=(0,)),
                dtype=np.uint8,
            )
        return np.asarray(mask > 0)

    # ------------------------------------------------------------------ tiles
    def tile_geometry(self, width: int, height: int) -> PreparedImage | None:
        """The :class:`PreparedImage` geometry of a ``width`` x ``height`` tile served with
        precomputed features (no pixels: ``image`` and ``valid`` are read-only zero-stride
        views), or None when the rule would resize or pad it (its features then come from
        extraction)."""
        if self.rule.content_size(width, height) != (width, height) or self.rule.final_size(
            width, height
        ) != (width, height):
            return None
        image = np.broadcast_to(np.zeros((1, 1, 3), dtype=np.uint8), (height, width, 3))
        valid = np.broadcast_to(np.ones((1, 1), dtype=np.bool_), (height, width))
        return PreparedImage(
            image=image,
            valid=valid,
            working_from_engine=engine_to_working((width, height), (width, height)),
            working_size=(width, height),
        )

    def prepare_tile(self, tile_rgb: NDArray[np.uint8]) -> PreparedImage:
        """Resize a north-up tile (uint8 RGB (H, W, 3) or grey (H, W)) to the rule (area
        averaging, never upscaling) and pad it; nodata (all channels 0) is masked. WORKING px are
        the tile's full-resolution px."""
        tile = to_rgb(check_pixels(tile_rgb, "tile"))
        h, w = tile.shape[:2]
        content = self.rule.content_size(w, h)
        final = self.rule.final_size(w, h)
        # 255 where all channels are 0 (nodata)
        nodata = np.asarray(cv2.inRange(tile, np.zeros(3), np.zeros(3)), dtype=np.uint8)
        if content != (w, h):
            small = np.asarray(
                cv2.resize(tile, content, interpolation=cv2.INTER_AREA), dtype=np.uint8
            )
            nodata = np.asarray(
                cv2.resize(nodata, content, interpolation=cv2.INTER_AREA), dtype=np.uint8
            )
        else:
            small = tile
        cw, ch = content
        fw, fh = final
        image = np.zeros((fh, fw, 3), dtype=np.uint8)
        inside = np.zeros((fh, fw), dtype=np.uint8)
        uw, uh = min(cw, fw), min(ch, fh)
        image[:uh, :uw] = small[:uh, :uw]
        inside[:uh, :uw] = np.where(nodata[:uh, :uw] == 0, np.uint8(255), np.uint8(0))
        return PreparedImage(
            image=normalise_photometry(image, inside, self.photometric, w / cw),
            valid=self._erode(inside),
            working_from_engine=engine_to_working((w, h), content),
            working_size=(w, h),
        )
