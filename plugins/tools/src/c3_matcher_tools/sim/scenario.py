"""Matching scenarios over real orthophotos: one rendered nav frame (attitude, lens distortion,
scale change, photometric shift), its true tile and distractor tiles that do not overlap the
frame's footprint, with the ground truth to score a match against.

Used by the real-path tests, the demo data (``scripts/make_demo_data.py``) and benchmarks.
Tile ids are synthetic but consistent: the tile centre's offset from the orthophoto centre in
metres, around a reference latitude/longitude, at the web-mercator zoom nearest the tile GSD.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from c3_matcher.dto import Attitude, CameraCalibration, TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.geodesy import flat_offset_latlon
from c3_matcher_tools.sim.orthophotos import Orthophoto, load_orthophoto
from c3_matcher_tools.sim.photometric import PhotometricShift
from c3_matcher_tools.sim.render import (
    NAV_CAMERA_DISTORTION,
    OrthoTile,
    RenderedFrame,
    cut_tile,
    pick_distractor_tiles,
    render_nav_frame,
)

__all__ = ["Scenario", "ScenarioSpec", "build_scenario", "inlier_errors_px"]


@dataclass(frozen=True)
class ScenarioSpec:
    """How to render one scenario. Angles in degrees; ``frame_gsd_ratio`` = frame nadir GSD /
    tile GSD (< 1: the nav frame is finer than the tiles, as at low altitude)."""

    orthophoto: Path
    yaw_deg: float
    pitch_deg: float
    roll_deg: float
    frame_gsd_ratio: float = 0.6
    tile_size: int = 448
    image_size: tuple[int, int] = (640, 480)
    focal_px: float = 560.0
    distortion: tuple[float, ...] = NAV_CAMERA_DISTORTION
    seed: int = 0
    distractors: int = 2
    photometric: PhotometricShift = field(default_factory=PhotometricShift)
    reference_latlon: tuple[float, float] = (47.0, 8.0)

    @property
    def name(self) -> str:
        return (
            f"{Path(self.orthophoto).stem}-yaw{self.yaw_deg:g}-p{self.pitch_deg:g}"
            f"-r{self.roll_deg:g}"
        )


@dataclass(frozen=True)
class Scenario:
    """A rendered frame and its candidate tiles; ``tiles[0]`` is the true one."""

    spec: ScenarioSpec
    ortho: Orthophoto
    frame: RenderedFrame
    calibration: CameraCalibration
    tiles: tuple[OrthoTile, ...]
    tile_ids: tuple[TileId, ...]

    @property
    def tile_gsd_m(self) -> float:
        return float(self.tiles[0].gsd_m)


def _tile_id(ortho: Orthophoto, tile: OrthoTile, ref: tuple[float, float]) -> TileId:
    w, h = tile.size
    cx = tile.offset_px[0] + (w - 1) / 2 - (ortho.size[0] - 1) / 2
    cy = tile.offset_px[1] + (h - 1) / 2 - (ortho.size[1] - 1) / 2
    lat, lon = flat_offset_latlon(ref[0], ref[1], -cy * tile.gsd_m, cx * tile.gsd_m)
    zoom = round(math.log2(TileId(0, lat, lon).web_mercator_gsd_m() / tile.gsd_m))
    return TileId(max(0, min(30, zoom)), lat, lon)


def _distractors(
    ortho: Orthophoto,
    footprint: NDArray[np.float64],
    size: int,
    count: int,
    rng: np.random.Generator,
) -> list[OrthoTile]:
    """Distinct tiles that avoid the footprint; unlike each other's, their areas may overlap."""
    assert ortho.gsd_m is not None
    picked: list[OrthoTile] = []
    for _ in range(20 * count):
        (tile,) = pick_distractor_tiles(
            ortho.rgb, footprint, (size, size), 1, rng, ortho.gsd_m, margin_px=8
        )
        if all(tile.offset_px != p.offset_px for p in picked):
            picked.append(tile)
        if len(picked) == count:
            return picked
    raise InvalidInputError("distractors", f"fewer than {count} distinct distractor tiles fit")


def build_scenario(spec: ScenarioSpec) -> Scenario:
    """Render the frame over a random (seeded) nadir point whose footprint fits in a tile, cut
    the true tile around it (randomly shifted, footprint kept inside) and pick distractors."""
    ortho = load_orthophoto(spec.orthophoto)
    if ortho.gsd_m is None:
        raise ValueError(f"{spec.orthophoto}: ground sample distance unknown")
    rng = np.random.default_rng(spec.seed)
    w, h = spec.image_size
    k = np.array(
        [[spec.focal_px, 0, (w - 1) / 2 + 3.5], [0, spec.focal_px, (h - 1) / 2 - 2.0], [0, 0, 1]],
        dtype=np.float64,
    )
    calibration = CameraCalibration(k, np.asarray(spec.distortion, dtype=np.float64), (w, h))
    attitude = Attitude.from_degrees(spec.roll_deg, spec.pitch_deg, spec.yaw_deg)
    height = spec.frame_gsd_ratio * ortho.gsd_m * spec.focal_px
    size = spec.tile_size
    ow, oh = ortho.size
    for _ in range(200):
        nadir = (
            float(rng.uniform(size / 2, ow - size / 2)),
            float(rng.uniform(size / 2, oh - size / 2)),
        )
        frame = render_nav_frame(
            ortho.rgb,
            ortho.gsd_m,
            nadir,
            height,
            attitude,
            calibration,
            photometric=spec.photometric,
            seed=spec.seed,
        )
        if frame.coverage.mean() < 0.995:
            continue  # the frame must see only orthophoto (no nodata border)
        fp = frame.footprint_ortho()
        lo, hi = fp.min(axis=0), fp.max(axis=0)
        slack = size - (hi - lo)
        if np.any(slack < 16):
            raise ValueError(f"{spec.name}: footprint {hi - lo} px does not fit a {size} px tile")
        x0 = round(lo[0] - rng.uniform(8, slack[0] - 8))
        y0 = round(lo[1] - rng.uniform(8, slack[1] - 8))
        if x0 < 0 or y0 < 0 or x0 + size > ow or y0 + size > oh:
            continue
        true_tile = cut_tile(ortho.rgb, (x0, y0), (size, size), ortho.gsd_m)
        if (true_tile.image == 0).all(axis=2).mean() > 0.02:
            continue
        try:
            distractors = _distractors(ortho, fp, size, spec.distractors, rng)
        except InvalidInputError:
            continue
        tiles = (true_tile, *distractors)
        ids = tuple(_tile_id(ortho, t, spec.reference_latlon) for t in tiles)
        return Scenario(spec, ortho, frame, calibration, tiles, ids)
    raise ValueError(f"{spec.name}: no placement found (orthophoto too small for the tiles?)")


def inlier_errors_px(
    scenario: Scenario, tile_index: int, correspondences: NDArray[np.float32]
) -> NDArray[np.float64]:
    """Per inlier, the distance in ORIGINAL (distorted) frame px between the reported query point
    and where the ground truth puts the reported tile point in the frame."""
    tile = scenario.tiles[tile_index]
    truth = scenario.frame.ortho_to_original(tile.tile_to_ortho(correspondences[:, 2:4]))
    return np.asarray(np.linalg.norm(truth - correspondences[:, 0:2], axis=1), dtype=np.float64)
