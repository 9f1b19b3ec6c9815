"""Georeferencing a match: where the frame looked, in WGS84.

A candidate's ``TileId(zoom, lat, lon)`` names the centre of its image. TILE px (u, v) is the
centre of the image's pixel in column u, row v ((0, 0): the top-left pixel's centre); it lies at
WORLD px (web mercator at the id's zoom, 256 * 2**zoom across the world, a pixel's centre at
integer + 0.5) ``origin + scale * (u, v)`` (:func:`tile_px_origin`; :func:`candidate_placement`
gives both as JSON) and so at a lon/lat (:func:`tile_px_to_lonlat`), in one of two ways, told
apart by the ``tile_gsd_m`` given:

- None: the image is a tile store's window (:mod:`c3_matcher.tilestore.handles`): its pixels
  ARE the zoom's WORLD px (scale 1), the window's corner the id's centre rounded onto that grid
  (so the image's centre is up to half a pixel per axis from the id's);
- a ground sample distance (m/px): the image is one the user gives (``match --tile``), centred
  EXACTLY on its id (its centre pixel ((w - 1) / 2, (h - 1) / 2) is the id's lon/lat), its
  pixels that many metres (the zoom's own GSD when the image is of the zoom's scale).

Such a GSD is taken as web mercator's nominal one, spherical (:meth:`TileId.web_mercator_gsd_m`,
the equator's times cos(lat)), alike east and north: the scale is GSD over the zoom's. On the
WGS84 ellipsoid a WORLD px spans fewer ground metres north-south than that: 0.6 % fewer at 15
deg (0.02 % more east-west; at 47 deg 0.13 % fewer and 0.18 % more). At 15 deg an image whose GSD
was measured on the ground is thus placed off north-south by 0.6 % of a point's distance from
its centre: 0.28 px (2.7 cm) for the demo frame's centre, 46 px south of its tile's, 6 px at the
edge of a 2048 px image. The maths stays spherical: an image cut from web-mercator imagery has
that GSD exactly, and every fix stays as it was; a store window has none of this.

The best candidate gives the map from
UNDISTORTED query px to tile px (:func:`best_query_to_tile`), through which the frame's
principal point (the centre) and its image boundary (the footprint) land on the map: the
homography fitted by least squares over every inlier (:func:`fit_query_to_tile`: the ground is
a plane at this scale), or the geometric prior's similarity when the matcher kept that one.

Longitudes come out in [-180, 180) (:func:`wrap_longitude`), a window that straddles 180 deg
included. A footprint is one continuous ring around its centre: where it crosses the line, its
points beyond it lie beyond 180 deg (or -180 deg), as a GeoJSON reader draws a ring it is given
whole (RFC 7946 would cut it in two).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike

from c3_matcher import camera as cam
from c3_matcher.arrays import F64
from c3_matcher.dto import CameraCalibration, MatchResult, TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.geo import (
    MERCATOR_MAX_LAT,
    TILE_PX,
    lonlat_to_world_px,
    world_px_to_lonlat,
)

__all__ = [
    "EARTH_RADIUS_M",
    "best_query_to_tile",
    "candidate_placement",
    "fit_query_to_tile",
    "footprint_lonlat",
    "georeference_result",
    "haversine_m",
    "is_georeferenced",
    "lonlat_to_tile_px",
    "require_mercator_latitude",
    "tile_px_origin",
    "tile_px_to_lonlat",
    "wrap_longitude",
]

EARTH_RADIUS_M = 6_371_008.8


def wrap_longitude(lon: ArrayLike) -> F64:
    """Longitudes (degrees, any turn) in [-180, 180); one already there is kept exactly, and
    so is one that is not finite."""
    x = np.asarray(lon, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        wrapped = x - 360.0 * np.floor((x + 180.0) / 360.0)
    wrapped = np.where(wrapped < -180.0, wrapped + 360.0, wrapped)  # x + 180 rounded up to 360
    return np.asarray(np.where(np.isfinite(x), wrapped, x), np.float64)


def is_georeferenced(tile_id: TileId) -> bool:
    """False for the placeholder ids ``c3-matcher match`` gives tiles without ``--tile-id``
    (zoom 0 at 0 N): they name an input position, not a place."""
    return tile_id.zoom > 0


def require_mercator_latitude(tile_id: TileId) -> None:
    """Refuse (``InvalidInputError`` naming ``tile_id.lat``) an id centred beyond web mercator's
    latitude limit (+-85.0511 deg, where its square world ends): its pixels map to no place (a
    pole is infinitely far down the world's pixels), so it cannot be georeferenced."""
    if not abs(tile_id.lat) <= MERCATOR_MAX_LAT:
        raise InvalidInputError(
            "tile_id.lat",
            f"{tile_id.lat} is beyond web mercator's latitude limit, +-{MERCATOR_MAX_LAT:.4f} deg"
            ": a tile centred there cannot be georeferenced",
        )


def _scale(tile_id: TileId, tile_gsd_m: float | None) -> float:
    """WORLD px per tile px: 1 for a store window (``tile_gsd_m`` None), else the GSD given over
    the zoom's at the id's latitude."""
    if tile_gsd_m is None:
        return 1.0
    return float(tile_gsd_m) / tile_id.web_mercator_gsd_m()


def tile_px_origin(
    tile_id: TileId, size: tuple[int, int], tile_gsd_m: float | None = None
) -> tuple[float, float]:
    """WORLD px (at ``tile_id``'s zoom) of TILE px (0, 0), the centre of the top-left pixel of a
    ``size`` = (width, height) image centred on ``tile_id``: on the zoom's pixel grid for a store
    window (``tile_gsd_m`` None, the window of :mod:`c3_matcher.tilestore.handles`, its corner
    the id's centre rounded onto the grid), else where the image centred exactly on the id puts
    it. Which one is the meaning of the ``tile_gsd_m`` given, never a coincidence of its value:
    a GSD equal to the zoom's still centres the image exactly. An id beyond web mercator's
    latitudes is refused (:func:`require_mercator_latitude`)."""
    require_mercator_latitude(tile_id)
    (cx, cy) = lonlat_to_world_px([[tile_id.lon, tile_id.lat]], tile_id.zoom)[0]
    w, h = size
    if tile_gsd_m is None:
        return math.floor(cx - w / 2 + 0.5) + 0.5, math.floor(cy - h / 2 + 0.5) + 0.5
    scale = _scale(tile_id, tile_gsd_m)
    return cx - (w / 2 - 0.5) * scale, cy - (h / 2 - 0.5) * scale


def candidate_placement(
    tile_id: TileId, size: tuple[int, int], tile_gsd_m: float | None = None
) -> dict[str, Any]:
    """The JSON fields that place a candidate image's pixels on the map, so that a step
    downstream need not re-derive a store window's rounding onto the zoom's grid:
    ``tile_size_px`` [width, height], ``tile_origin_world_px`` [X, Y] (:func:`tile_px_origin`)
    and ``world_px_per_tile_px`` (1 for a store window, ``tile_gsd_m`` None): TILE px (u, v) is
    WORLD px ``tile_origin_world_px + world_px_per_tile_px * (u, v)`` at the id's zoom (an X
    beyond the world's 0 to 256 * 2**zoom px where the image straddles 180 deg: a turn away).
    Both null when ``tile_id`` names no place (:func:`is_georeferenced`)."""
    size_px = [int(size[0]), int(size[1])]
    if not is_georeferenced(tile_id):
        return {"tile_size_px": size_px, "tile_origin_world_px": None, "world_px_per_tile_px": None}
    x0, y0 = tile_px_origin(tile_id, size, tile_gsd_m)
    return {
        "tile_size_px": size_px,
        "tile_origin_world_px": [float(x0), float(y0)],
        "world_px_per_tile_px": _scale(tile_id, tile_gsd_m),
    }


def _continuous_lonlat(
    tile_id: TileId, size: tuple[int, int], pts: ArrayLike, tile_gsd_m: float | None
) -> F64:
    """:func:`tile_px_to_lonlat` before its longitudes are wrapped: continuous across the
    image (beyond 180 deg where the image straddles the line east of its centre)."""
    p = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    s = _scale(tile_id, tile_gsd_m)
    x0, y0 = tile_px_origin(tile_id, size, tile_gsd_m)
    world = np.stack([x0 + p[:, 0] * s, y0 + p[:, 1] * s], axis=1)
    return world_px_to_lonlat(world, tile_id.zoom)


def tile_px_to_lonlat(
    tile_id: TileId, size: tuple[int, int], pts: ArrayLike, tile_gsd_m: float | None = None
) -> F64:
    """(N, 2) TILE px (u, v) of a ``size`` = (width, height) image centred on ``tile_id`` ->
    (N, 2) (lon, lat) degrees, longitudes in [-180, 180). ``tile_gsd_m`` None: a store window;
    a GSD: an image centred exactly on its id (see the module docstring)."""
    lonlat = _continuous_lonlat(tile_id, size, pts, tile_gsd_m)
    lonlat[:, 0] = wrap_longitude(lonlat[:, 0])
    return lonlat


def lonlat_to_tile_px(
    tile_id: TileId, size: tuple[int, int], lonlat: ArrayLike, tile_gsd_m: float | None = None
) -> F64:
    """Inverse of :func:`tile_px_to_lonlat`: a point is taken on the turn of the globe nearest
    the image (a longitude across 180 deg from it lies beside it, not a world away)."""
    s = _scale(tile_id, tile_gsd_m)
    x0, y0 = tile_px_origin(tile_id, size, tile_gsd_m)
    world = lonlat_to_world_px(lonlat, tile_id.zoom)
    centre_x = lonlat_to_world_px([[tile_id.lon, tile_id.lat]], tile_id.zoom)[0, 0]
    span = TILE_PX * 2.0**tile_id.zoom
    world_x = world[:, 0] - span * np.round((world[:, 0] - centre_x) / span)
    return np.stack([(world_x - x0) / s, (world[:, 1] - y0) / s], axis=1)


def fit_query_to_tile(
    correspondences: ArrayLike, calibration: CameraCalibration | None
) -> F64 | None:
    """Least-squares homography UNDISTORTED query px -> tile px over inlier rows (x_query,
    y_query, x_tile, y_tile) in ORIGINAL pixels; None with fewer than 4 rows or degenerate."""
    corr = np.asarray(correspondences, dtype=np.float64).reshape(-1, 4)
    if corr.shape[0] < 4:
        return None
    q = corr[:, 0:2] if calibration is None else cam.undistort_points(corr[:, 0:2], calibration)
    found, _ = cv2.findHomography(q, corr[:, 2:4], 0)
    if found is None or not np.all(np.isfinite(found)):
        return None
    return np.asarray(found / found[2, 2], dtype=np.float64)


def best_query_to_tile(result: MatchResult, calibration: CameraCalibration | None) -> F64 | None:
    """The best candidate's map UNDISTORTED query px -> tile px; None when none fits.

    The matcher keeps the prior's similarity (``diagnostics["models"]``) exactly when the free
    homography of the inliers fails the prior's geometry check: inliers along one line or in one
    corner constrain a free homography poorly away from them. Refitting one over those inliers
    would bring back the extrapolation the prior refused, so the kept similarity
    (``diagnostics["query_to_tile"]``) is used. Otherwise: the least-squares homography over
    every inlier."""
    models = result.diagnostics.get("models") or ()
    kept = result.diagnostics.get("query_to_tile") or ()
    if models and models[0] == "similarity" and kept and kept[0] is not None:
        return np.asarray(kept[0], dtype=np.float64)
    return fit_query_to_tile(result.per_candidate[0].inlier_correspondences, calibration)


def footprint_lonlat(
    h_query_to_tile: ArrayLike,
    tile_id: TileId,
    tile_size: tuple[int, int],
    calibration: CameraCalibration,
    tile_gsd_m: float | None = None,
    samples_per_side: int = 8,
) -> tuple[tuple[float, float], F64] | None:
    """(centre (lon, lat), closed footprint polygon (N + 1, 2) lon/lat) of a frame whose
    UNDISTORTED px map to ``tile_id``'s image by ``h_query_to_tile`` (``tile_gsd_m``: see
    :func:`tile_px_to_lonlat`). The centre is the principal point, its longitude in [-180, 180);
    the footprint follows the image boundary (undistorted), one continuous ring around the
    centre (see the module docstring), wound counter-clockwise in lon/lat as RFC 7946 wants an
    exterior ring, whichever way the camera and the homography turn the boundary.

    The footprint is the frame's boundary cut where it passes
    :data:`~c3_matcher.camera.MAX_OFF_NADIR_DEG` from nadir, as the query is clipped before
    matching (:func:`_off_nadir_cosine` reads each ray's angle off the map; the cut is the
    straight line between the two boundary points at that angle, the query's own): the part of
    a tilted frame above the horizon maps through the homography to points behind the camera,
    and the part just below it to points without bound away, neither of them ground the frame
    matched. A frame wholly within the cone keeps its whole boundary, unchanged. None when the
    principal point is not within what is kept (it looks above the horizon, or at ground too
    grazing to place): no centre, no footprint."""
    hom = np.asarray(h_query_to_tile, dtype=np.float64)
    if hom.shape != (3, 3) or not np.isfinite(hom).all():
        raise InvalidInputError("h_query_to_tile", f"expected a finite 3x3 map, got {hom!r}")
    w, h = calibration.image_size
    k = calibration.K
    centre_px = np.array([[k[0, 2], k[1, 2]]])
    # always undistorted, as :func:`fit_query_to_tile` takes the inliers: without distortion a
    # skewed K still moves a pixel (the lens side ignores the skew, ``K @ ray`` does not)
    boundary = cam.undistort_points(cam.image_boundary(w, h, samples_per_side), calibration)
    cosine = _off_nadir_cosine(hom, k, np.concatenate([centre_px, boundary]))
    cos_max = math.cos(math.radians(cam.MAX_OFF_NADIR_DEG))
    kept = cam.clip_polygon(boundary, lambda px: cosine(px) - cos_max)
    if not cosine(centre_px)[0] >= cos_max or kept.shape[0] < 3:
        return None
    cut = not np.array_equal(kept, boundary)
    if cut and cv2.pointPolygonTest(kept.astype(np.float32), tuple(centre_px[0]), False) < 0:
        return None  # the centre lies beyond the cut: on ground the query did not keep
    boundary = kept
    pts = cam.apply_homography(hom, np.concatenate([centre_px, boundary]))
    lonlat = _continuous_lonlat(tile_id, tile_size, pts, tile_gsd_m)
    turns = np.round((wrap_longitude(lonlat[0, 0]) - lonlat[0, 0]) / 360.0)
    if np.isfinite(turns):
        lonlat[:, 0] += 360.0 * turns  # the centre in [-180, 180), the ring around it
    ring = _counter_clockwise(np.concatenate([lonlat[1:], lonlat[1:2]]))
    return (float(lonlat[0, 0]), float(lonlat[0, 1])), ring


def _off_nadir_cosine(hom: F64, k: F64, frame_px: F64) -> Callable[[F64], F64]:
    """The cosine of the angle from nadir of the ray of each (M, 2) UNDISTORTED px, read off the
    map UNDISTORTED px -> tile px ``hom`` and the camera's ``K`` alone.

    The map is ``S @ [r1 r2 t]^-1 @ K^-1`` up to scale (the tile an orthographic image of the
    ground, ``S`` its pixels' similarity), so the ground's normal in the camera frame lies along
    ``K.T @ hom[2]`` and a px's ray ``K^-1 @ (x, y, 1)`` meets it in the map's third
    coordinate ``w``: the cosine is ``w / (|ray| |K.T @ hom[2]|)``, its sign (ground in front,
    or sky behind) fixed by the map's overall sign, which a fit leaves free. The frame's own
    px (``frame_px``: its centre and boundary) tell it when they all lie on one side of the
    horizon: the inliers the map was fitted to lie among them, on the ground. When the horizon
    crosses the frame, the side is where the map keeps the orientation of a camera above a
    north-up map (``w`` of the sign of ``det(hom)``; a mirroring map is taken for a camera
    looking the other way)."""
    normal = k.T @ hom[2]
    k_inv = np.linalg.inv(k)

    def third(px: F64) -> F64:
        return np.asarray(px @ hom[2, :2] + hom[2, 2], dtype=np.float64)

    w_frame = np.sign(third(frame_px))
    side = w_frame[0] if bool(np.all(w_frame == w_frame[0])) else 0.0
    side = side or float(np.sign(np.linalg.det(hom)))
    scale = side / float(np.linalg.norm(normal))

    def cosine(px: F64) -> F64:
        rays = np.concatenate([px, np.ones((px.shape[0], 1))], axis=1) @ k_inv.T
        return np.asarray(scale * third(px) / np.linalg.norm(rays, axis=1), dtype=np.float64)

    return cosine


def _counter_clockwise(ring: F64) -> F64:
    """The closed lon/lat ``ring`` wound counter-clockwise (positive shoelace area, taken about
    its first point so that large longitudes cost no precision); the image boundary comes
    clockwise in lon/lat from a north-up tile, the other way through a mirroring map."""
    d = ring - ring[0]
    twice_area = float(np.sum(d[:-1, 0] * d[1:, 1] - d[1:, 0] * d[:-1, 1]))
    return ring if twice_area >= 0 else np.ascontiguousarray(ring[::-1])


def haversine_m(lonlat_a: ArrayLike, lonlat_b: ArrayLike) -> F64:
    """Great-circle distance (m) between (N, 2) lon/lat arrays (mean Earth radius)."""
    a = np.radians(np.asarray(lonlat_a, dtype=np.float64).reshape(-1, 2))
    b = np.radians(np.asarray(lonlat_b, dtype=np.float64).reshape(-1, 2))
    dlat, dlon = b[:, 1] - a[:, 1], b[:, 0] - a[:, 0]
    s = np.sin(dlat / 2) ** 2 + np.cos(a[:, 1]) * np.cos(b[:, 1]) * np.sin(dlon / 2) ** 2
    return np.asarray(2 * EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(s, 0, 1))), np.float64)


def georeference_result(
    result: MatchResult,
    calibration: CameraCalibration | None,
    tile_sizes: Sequence[tuple[int, int]] | None,
    tile_gsd_m: float | None = None,
) -> dict[str, Any]:
    """The JSON fields of the best candidate's georeference: ``best_homography`` (UNDISTORTED
    query px -> best tile px, row-major 3x3, :func:`best_query_to_tile`) and, when its tile id
    is georeferenced and the tiles' sizes (per INPUT position) are known, ``centre_lat``,
    ``centre_lon`` and ``footprint`` (a closed GeoJSON exterior ring of [lon, lat],
    counter-clockwise). ``tile_gsd_m`` None: the tiles are store windows; a GSD: images centred
    exactly on their ids (see the module docstring). Empty when no homography fits; without the
    centre and footprint when the frame's principal point sees no ground to place
    (:func:`footprint_lonlat`)."""
    best = result.per_candidate[0]
    hom = best_query_to_tile(result, calibration)
    if hom is None:
        return {}
    out: dict[str, Any] = {"best_homography": hom.tolist()}
    if calibration is None or tile_sizes is None or not is_georeferenced(best.tile_id):
        return out
    index = int(result.diagnostics.get("input_index", [0])[0])
    tw, th = tile_sizes[index]
    placed = footprint_lonlat(hom, best.tile_id, (int(tw), int(th)), calibration, tile_gsd_m)
    if placed is None:
        return out
    (lon, lat), ring = placed
    out.update(
        centre_lat=lat,
        centre_lon=lon,
        footprint=[[float(x), float(y)] for x, y in ring],
    )
    return out
