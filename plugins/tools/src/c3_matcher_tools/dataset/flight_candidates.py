"""A simulated frame's candidate windows: the true one, its distractors, their ground truth."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.arrays import F64
from c3_matcher.dto import TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.handles import mosaic_origin
from c3_matcher_tools.dataset.flight_scene import Footprint, Scene, corner_sums, window_starts
from c3_matcher_tools.dataset.flight_spec import FlightSpec
from c3_matcher_tools.dataset.format import CandidateTruth
from c3_matcher_tools.sim.render import RenderedFrame, draw_apart, footprint_mask
from c3_matcher_tools.tilestore.geo import GeoGrid, world_px_to_lonlat

__all__ = ["candidate_truths", "distractor_origins", "shuffled", "true_window_origin"]


def true_window_origin(fp_world: F64, size: int, grid_px: int) -> tuple[int, int] | None:
    """Top-left WORLD px of the grid-aligned window (centre on the grid) nearest the
    footprint's bounding-box centre that contains the whole footprint, or None."""
    lo, hi = fp_world.min(axis=0), fp_world.max(axis=0)
    centre = (lo + hi) / 2
    base = np.floor(centre / grid_px) * grid_px
    options = [base + np.array([dx, dy]) * grid_px for dx in (0, 1, -1, 2) for dy in (0, 1, -1, 2)]
    options.sort(key=lambda c: float(np.linalg.norm(c - centre)))
    for c in options:
        x0, y0 = int(c[0]) - size // 2, int(c[1]) - size // 2
        if lo[0] >= x0 and lo[1] >= y0 and hi[0] <= x0 + size and hi[1] <= y0 + size:
            return x0, y0
    return None


def distractor_origins(
    spec: FlightSpec, scene: Scene, i: int, footprint: Footprint, is_absent: bool
) -> list[tuple[int, int]]:
    """Pick frame ``i``'s distractor windows (top-left WORLD px), naming the options if none fit."""
    cov = scene.cov
    fp_cov = footprint.world - np.asarray(cov.origin, dtype=np.float64)
    if not is_absent:  # present: distractors may overlap the footprint, not its centre
        fp_cov = np.repeat((footprint.centre - cov.origin)[None, :], 3, axis=0)
    # Distractors are drawn from a generator seeded by the true window's position, so
    # frames that share their true tile share their distractors (tile feature cache hits).
    drng = np.random.default_rng([spec.seed, int(is_absent), *footprint.true_origin])
    nodata = spec.max_distractor_nodata if not is_absent else 0.5
    try:
        picked = _pick_windows(spec, scene, fp_cov, 3 if is_absent else 2, drng, nodata)
    except InvalidInputError as exc:
        raise InvalidInputError(
            "distractors",
            f"frame {i}: {exc.reason}; the store is too "
            "small for this candidate size / distance: lower --candidate-size or "
            "--min-distractor-distance, raise --max-distractor-nodata, or build the store "
            f"at a finer zoom (tiles build --zoom {cov.zoom + 1}) or over more ground",
        ) from exc
    return [(cov.origin[0] + x, cov.origin[1] + y) for x, y in picked]


DISTRACTOR_MARGIN_PX = 8
"""How far (px) a distractor window stays from the footprint (or, for a frame whose true tile
is present, from its centre)."""


def _pick_windows(
    spec: FlightSpec,
    scene: Scene,
    fp: F64,
    count: int,
    rng: np.random.Generator,
    max_nodata: float,
) -> list[tuple[int, int]]:
    """``count`` windows (top-left COVERAGE px) drawn as :func:`pick_distractor_tiles` draws
    them over the whole coverage (the same grid of windows, the same tests, the same draw), from
    the coverage's window nodata and the footprint's surroundings alone: clear of the footprint
    (COVERAGE px, dilated by :data:`DISTRACTOR_MARGIN_PX`) and of each other, centres
    ``min_distractor_distance_m`` from its centroid, at most ``max_nodata`` nodata."""
    cov, size = scene.cov, spec.candidate_size_px
    xs = window_starts(cov.size[0], size, spec.grid_px)
    ys = window_starts(cov.size[1], size, spec.grid_px)
    ok = cov.window_nodata <= max_nodata * size * size
    ok &= _clear_of(fp, xs, ys, size, cov.size)
    ok &= _far_from(fp.mean(axis=0), xs, ys, size, spec.min_distractor_distance_m / scene.m_per_px)
    allowed = np.flatnonzero(ok)
    at_x, at_y = xs[allowed % xs.size], ys[allowed // xs.size]
    chosen = draw_apart(at_x, at_y, np.arange(allowed.size), (size, size), count, rng)
    if len(chosen) < count:
        raise InvalidInputError(
            "count",
            f"only {len(chosen)} non-overlapping {size}x{size} px "
            f"distractor tiles fit, {count} requested",
        )
    return chosen


def _clear_of(
    fp: F64, xs: NDArray[np.int64], ys: NDArray[np.int64], size: int, cov_size: tuple[int, int]
) -> NDArray[np.bool_]:
    """(rows, cols): the window at (xs[c], ys[r]) holds no px of the footprint ``fp``
    (COVERAGE px) dilated by :data:`DISTRACTOR_MARGIN_PX`, rasterised within the coverage over
    its neighbourhood only."""
    clear = np.ones((ys.size, xs.size), bool)
    reach = DISTRACTOR_MARGIN_PX + 2
    lo = np.maximum(np.floor(fp.min(axis=0)).astype(np.int64) - reach, 0)
    hi = np.minimum(np.ceil(fp.max(axis=0)).astype(np.int64) + reach, cov_size)
    if np.any(hi <= lo) or not clear.size:
        return clear
    (w, h), (x0, y0) = hi - lo, lo
    mask = footprint_mask(fp - lo, (int(h), int(w)), DISTRACTOR_MARGIN_PX)
    integral = np.asarray(cv2.integral(mask), dtype=np.int64)
    rows = (np.clip(ys - y0, 0, h), np.clip(ys + size - y0, 0, h))
    cols = (np.clip(xs - x0, 0, w), np.clip(xs + size - x0, 0, w))
    clear &= corner_sums(integral, rows, cols) == 0
    return clear


def _far_from(
    centre: F64, xs: NDArray[np.int64], ys: NDArray[np.int64], size: int, distance: float
) -> NDArray[np.bool_]:
    """(rows, cols): the centre of the window at (xs[c], ys[r]) is ``distance`` px or more from
    ``centre``; measured only where it may be nearer (the windows within ``distance`` + 1 px of
    it along both axes), the rest being farther along one axis alone."""
    dx = xs + (size - 1) / 2 - centre[0]
    dy = ys + (size - 1) / 2 - centre[1]
    far = np.ones((ys.size, xs.size), bool)
    near_x, near_y = np.flatnonzero(abs(dx) < distance + 1), np.flatnonzero(abs(dy) < distance + 1)
    if near_x.size and near_y.size:
        c = slice(near_x[0], near_x[-1] + 1)
        r = slice(near_y[0], near_y[-1] + 1)
        far[r, c] = np.hypot(dx[None, c], dy[r, None]) >= distance
    return far


def candidate_truths(
    spec: FlightSpec,
    scene: Scene,
    frame: RenderedFrame,
    centre_world: F64,
    origins: list[tuple[tuple[int, int], bool]],
) -> tuple[list[CandidateTruth], tuple[float, ...]]:
    """Ground truth of the window at each (WORLD px origin, is true), and each one's fit (px)."""
    size = spec.candidate_size_px
    cands, fits = [], []
    for origin, is_true in origins:
        cand, fit = _candidate(
            frame, scene.grid, scene.cov.zoom, origin, size, centre_world, scene.m_per_px, is_true
        )
        fits.append(fit)
        assert mosaic_origin(cand.tile_id, size) == origin, "tile id does not round-trip"
        cands.append(cand)
    return cands, tuple(fits)


def _tile_to_ortho(
    grid: GeoGrid, origin_world: tuple[int, int], zoom: int, size: int
) -> tuple[F64, float]:
    """Homography candidate TILE px -> frames ORTHO px, least squares on a 9x9 grid through the
    exact chain (WORLD px -> lon/lat -> projected metres -> ORTHO px), and its max residual px."""
    s = np.linspace(0.0, size - 1.0, 9)
    uu, vv = np.meshgrid(s, s)
    tile = np.stack([uu.ravel(), vv.ravel()], axis=1)
    world = tile + np.asarray(origin_world, dtype=np.float64) + 0.5
    ortho = grid.lonlat_to_px(world_px_to_lonlat(world, zoom))
    h, _ = cv2.findHomography(tile, ortho, 0)
    if h is None:
        raise InvalidInputError("geometry", "cannot fit the tile -> orthophoto homography")
    q = tile @ h[:, :2].T + h[:, 2]
    residual = float(np.max(np.linalg.norm(q[:, :2] / q[:, 2:3] - ortho, axis=1)))
    return np.asarray(h / h[2, 2], dtype=np.float64), residual


def _candidate(
    frame: RenderedFrame,
    grid: GeoGrid,
    zoom: int,
    origin_world: tuple[int, int],
    size: int,
    centre_world: F64,
    m_per_px: float,
    is_true: bool,
) -> tuple[CandidateTruth, float]:
    h_t2o, fit = _tile_to_ortho(grid, origin_world, zoom, size)
    h_o2u = np.linalg.inv(frame.gt_homography_undistorted_to_ortho)
    h = h_o2u @ h_t2o
    c_world = np.asarray(origin_world, dtype=np.float64) + size / 2
    lon, lat = world_px_to_lonlat(c_world[None, :], zoom)[0]
    distance = float(np.linalg.norm(c_world - centre_world)) * m_per_px
    tile_id = TileId(zoom, float(lat), float(lon))
    return CandidateTruth(tile_id, 0.0, is_true, distance, np.asarray(h / h[2, 2])), fit


def shuffled(cands: list[CandidateTruth], frng: np.random.Generator) -> tuple[CandidateTruth, ...]:
    """Shuffle the candidates and score them C2.5-like (0.9, 0.8, 0.7, ...)."""
    order = frng.permutation(len(cands))
    return tuple(
        CandidateTruth(
            c.tile_id, round(0.9 - 0.1 * k, 3), c.is_true, c.distance_m, c.h_tile_to_undistorted
        )
        for k, c in enumerate(cands[j] for j in order)
    )
