"""A simulated frame's candidate windows: the true one, its distractors, their ground truth."""

from __future__ import annotations

import cv2
import numpy as np

from c3_matcher.arrays import F64
from c3_matcher.dto import TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.handles import mosaic_origin
from c3_matcher_tools.dataset.flight_scene import Footprint, Scene
from c3_matcher_tools.dataset.flight_spec import FlightSpec
from c3_matcher_tools.dataset.format import CandidateTruth
from c3_matcher_tools.sim.render import RenderedFrame, pick_distractor_tiles
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
    cov, size = scene.cov, spec.candidate_size_px
    count = 3 if is_absent else 2
    fp_cov = footprint.world - np.asarray(cov.origin, dtype=np.float64)
    if not is_absent:  # present: distractors may overlap the footprint, not its centre
        fp_cov = np.repeat((footprint.centre - cov.origin)[None, :], 3, axis=0)
    # Distractors are drawn from a generator seeded by the true window's position, so
    # frames that share their true tile share their distractors (tile feature cache hits).
    drng = np.random.default_rng([spec.seed, int(is_absent), *footprint.true_origin])
    try:
        picked = pick_distractor_tiles(
            cov.image,
            fp_cov,
            (size, size),
            count,
            drng,
            scene.m_per_px,
            margin_px=8,
            min_distance_px=spec.min_distractor_distance_m / scene.m_per_px,
            max_nodata_fraction=spec.max_distractor_nodata if not is_absent else 0.5,
            stride_px=spec.grid_px,
        )
    except InvalidInputError as exc:
        raise InvalidInputError(
            "distractors",
            f"frame {i}: {exc.reason}; the store is too "
            "small for this candidate size / distance: lower --candidate-size or "
            "--min-distractor-distance, raise --max-distractor-nodata, or build the store "
            f"at a finer zoom (tiles build --zoom {cov.zoom + 1}) or over more ground",
        ) from exc
    return [(cov.origin[0] + t.offset_px[0], cov.origin[1] + t.offset_px[1]) for t in picked]


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
