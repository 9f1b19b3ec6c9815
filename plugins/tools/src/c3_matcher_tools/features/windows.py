"""Which windows a map-feature build covers: every grid window a store's tiles cover enough
(:func:`grid_windows`), or those a recorded flight's candidates are served from
(:func:`flight_grid`, :func:`flight_windows`). Windows are (zoom, gx, gy) on a ``stride_px``
grid of WORLD px; sizes in px."""

from __future__ import annotations

import math
from pathlib import Path

from c3_matcher.tilestore.features import covered_tiles, grid_index
from c3_matcher.tilestore.geo import TILE_PX

__all__ = ["WindowKey", "brief_set_id", "flight_grid", "flight_windows", "grid_windows"]

WindowKey = tuple[int, int, int]  # (zoom, gx, gy)


def brief_set_id(set_id: object) -> str:
    """A set's id as said to a user: its extractor's sha256 cut short (every set of one engine
    begins alike), then all that tells it from the others (provider, size multiple,
    photometric normalisation, erosion, window, upscale)."""
    sha, _, rest = str(set_id).partition(":")
    return f"{sha[:12]}...:{rest}"


def grid_windows(
    tiles: set[tuple[int, int, int]], window_px: int, stride_px: int, min_coverage: float
) -> list[WindowKey]:
    """Every (zoom, gx, gy) grid window whose area stored ``tiles`` (zoom, x, y) cover to at
    least ``min_coverage`` (0 < share <= 1), sorted."""
    out: list[WindowKey] = []
    for zoom in sorted({t[0] for t in tiles}):
        xs = [t[1] for t in tiles if t[0] == zoom]
        ys = [t[2] for t in tiles if t[0] == zoom]
        g0x, g0y = (
            (min(xs) * TILE_PX - window_px) // stride_px,
            (min(ys) * TILE_PX - window_px) // stride_px,
        )
        g1x, g1y = (max(xs) + 1) * TILE_PX // stride_px, (max(ys) + 1) * TILE_PX // stride_px
        for gy in range(g0y, g1y + 1):
            for gx in range(g0x, g1x + 1):
                x0, y0 = gx * stride_px, gy * stride_px
                covered = 0
                for z, tx, ty in covered_tiles(zoom, (x0, y0), (window_px, window_px)):
                    if (z, tx, ty) in tiles:
                        ax, ay = max(x0, tx * TILE_PX), max(y0, ty * TILE_PX)
                        bx = min(x0 + window_px, (tx + 1) * TILE_PX)
                        by = min(y0 + window_px, (ty + 1) * TILE_PX)
                        covered += max(0, bx - ax) * max(0, by - ay)
                if covered > 0 and covered >= min_coverage * window_px * window_px:
                    out.append((zoom, gx, gy))
    return out


def flight_grid(dataset_dir: Path) -> tuple[int, int]:
    """(window, stride) px for a recorded flight: its candidates' size, and the grid their
    windows lie on (the greatest common divisor of their top-left WORLD px, at least 16 and at
    most the window): a build on that grid holds every candidate's own window."""
    from c3_matcher.tilestore.handles import mosaic_origin
    from c3_matcher_tools.dataset.format import load_dataset

    dataset = load_dataset(dataset_dir)
    size = dataset.candidate_size_px
    grid = 0
    for f in dataset.frames:
        for c in f.candidates:
            x0, y0 = mosaic_origin(c.tile_id, size)
            grid = math.gcd(grid, x0, y0)
    return size, min(max(grid, 16), size) if grid else size


def flight_windows(dataset_dir: Path, stride_px: int) -> list[WindowKey]:
    """The grid windows a recorded flight's candidates are served from (their nearest grid
    window; the windows themselves when they lie on the grid), sorted."""
    from c3_matcher.tilestore.handles import mosaic_origin
    from c3_matcher_tools.dataset.format import load_dataset

    dataset = load_dataset(dataset_dir)
    size = dataset.candidate_size_px
    keys = {
        (c.tile_id.zoom, *grid_index(mosaic_origin(c.tile_id, size), stride_px))
        for f in dataset.frames
        for c in f.candidates
    }
    return sorted(keys)
