"""Each frame of a simulated flight rendered along its trajectory and planned in memory."""

from __future__ import annotations

import math
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from c3_matcher.arrays import F64
from c3_matcher.dto import Attitude, CameraCalibration
from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher_tools.dataset.flight_candidates import (
    candidate_truths,
    distractor_origins,
    shuffled,
    true_window_origin,
)
from c3_matcher_tools.dataset.flight_scene import (
    Footprint,
    PlannedFrame,
    Scene,
    Shot,
    grid_convergence_deg,
    read_scene,
)
from c3_matcher_tools.dataset.flight_spec import FlightSpec
from c3_matcher_tools.dataset.format import CandidateTruth, FrameRecord
from c3_matcher_tools.tilestore.geo import TILE_PX, lonlat_to_world_px, world_px_to_lonlat

__all__ = ["Progress", "plan_flight"]

Progress = Callable[[int, int], None]


def plan_flight(
    spec: FlightSpec,
    store: MBTilesStore,
    name: str,
    attribution: str,
    progress: Progress | None,
) -> tuple[dict[str, Any], CameraCalibration, list[FrameRecord], dict[str, bytes]]:
    """Render every frame and choose its candidates, in memory: (dataset meta, calibration,
    frame records, {relative image path: JPEG bytes})."""
    scene = read_scene(spec, store)
    absent = _absent_frames(spec)
    frames: list[FrameRecord] = []
    images: dict[str, bytes] = {}
    worst_fit = 0.0
    for i, pose in enumerate(_trajectory(spec, scene.centre_en, scene.units_per_m)):
        planned = _plan_frame(spec, scene, i, pose, i in absent)
        worst_fit = max((worst_fit, *planned.fits))
        images[planned.record.image] = planned.jpeg
        frames.append(planned.record)
        if progress is not None:
            progress(i + 1, spec.n_frames)
    meta = _meta(spec, store, scene, name, attribution, worst_fit, absent)
    return meta, scene.calibration, frames, images


def _absent_frames(spec: FlightSpec) -> set[int]:
    """Draw (with the flight's seed) the ``absent_share`` of frames that get no true tile."""
    rng = np.random.default_rng(spec.seed)
    n_absent = round(spec.absent_share * spec.n_frames)
    return set(rng.choice(spec.n_frames, size=n_absent, replace=False).tolist())


def _plan_frame(
    spec: FlightSpec,
    scene: Scene,
    i: int,
    pose: tuple[float, float, float],
    is_absent: bool,
) -> PlannedFrame:
    """Render frame ``i`` at its pose and choose its candidates: its record, JPEG and fits."""
    frng = np.random.default_rng([spec.seed, i])
    shot = _shoot(spec, scene, i, pose, frng)
    footprint = _footprint(spec, scene, shot)
    if not is_absent:
        _check_store_under(scene, i, footprint)
    origins = [] if is_absent else [(footprint.true_origin, True)]
    origins += [(o, False) for o in distractor_origins(spec, scene, i, footprint, is_absent)]
    candidates, fits = candidate_truths(spec, scene, shot.frame, footprint.centre, origins)
    ordered = shuffled(candidates, frng)
    image_rel = f"frames/{i:06d}.jpg"
    jpeg = _jpeg(shot)
    return PlannedFrame(
        _record(spec, scene, shot, footprint.centre, ordered, image_rel), jpeg, fits
    )


def _trajectory(
    spec: FlightSpec, centre_en: tuple[float, float], units_per_m: tuple[float, float]
) -> list[tuple[float, float, float]]:
    """(east, north, heading deg from grid north) per frame, projected units of the frames'
    grid; speeds and radii are ground metres, ``units_per_m`` (east, north) the grid's projected
    units per ground metre at ``centre_en``."""
    step = spec.speed_mps * spec.frame_interval_s
    ue, un = units_per_m
    out = []
    for i in range(spec.n_frames):
        if spec.pattern == "orbit":
            bearing = math.radians(spec.heading_deg) + i * step / spec.orbit_radius_m
            e = centre_en[0] + spec.orbit_radius_m * math.sin(bearing) * ue
            n = centre_en[1] + spec.orbit_radius_m * math.cos(bearing) * un
            heading = math.degrees(bearing) + 90.0
        else:
            h = math.radians(spec.heading_deg)
            s = (i - (spec.n_frames - 1) / 2) * step
            e, n, heading = (
                centre_en[0] + s * math.sin(h) * ue,
                centre_en[1] + s * math.cos(h) * un,
                spec.heading_deg,
            )
        out.append((e, n, heading % 360.0))
    return out


def _attitude(spec: FlightSpec, heading: float, rng: np.random.Generator) -> Attitude:
    yaw = heading + rng.uniform(-spec.yaw_jitter_deg, spec.yaw_jitter_deg)
    yaw = (yaw + 180.0) % 360.0 - 180.0
    tilt = rng.uniform(0.0, spec.max_tilt_deg)
    direction = rng.uniform(0.0, 2 * math.pi)
    return Attitude.from_degrees(tilt * math.cos(direction), tilt * math.sin(direction), yaw)


def _shoot(
    spec: FlightSpec,
    scene: Scene,
    i: int,
    pose: tuple[float, float, float],
    frng: np.random.Generator,
) -> Shot:
    """Draw frame ``i``'s attitude and render it; refuse one that sees beyond the orthophoto."""
    east, north, heading = pose
    grid = scene.grid
    attitude = _attitude(spec, heading, frng)
    nadir = (
        (east - grid.origin_e) / grid.scale_x - 0.5,
        (grid.origin_n - north) / grid.scale_y - 0.5,
    )
    frame = scene.renderer.render(
        scene.rgb,
        scene.gsd,
        nadir,
        spec.height_m,
        attitude,
        photometric=spec.photometric,
        seed=frng,
    )
    if frame.coverage.mean() < 0.995:
        raise InvalidInputError(
            "trajectory",
            f"frame {i} (nadir E {east:.0f} N {north:.0f}) sees beyond the orthophoto "
            f"({100 * (1 - frame.coverage.mean()):.1f}% nodata): lower --height, "
            "--radius or --frames x --speed x --interval",
        )
    return Shot(i, heading, attitude, nadir, frame)


def _footprint(spec: FlightSpec, scene: Scene, shot: Shot) -> Footprint:
    """Place the footprint in WORLD px and find its true window; refuse one none can hold."""
    zoom, size = scene.cov.zoom, spec.candidate_size_px
    fp_world = lonlat_to_world_px(scene.grid.px_to_lonlat(shot.frame.footprint_ortho()), zoom)
    _refuse_footprint_across_antimeridian(shot.index, fp_world, zoom)
    centre_world = fp_world.mean(axis=0)
    true_origin = true_window_origin(fp_world, size, spec.grid_px)
    if true_origin is None:
        lo, hi = fp_world.min(axis=0), fp_world.max(axis=0)
        raise InvalidInputError(
            "candidate_size_px",
            f"frame {shot.index}: the footprint spans {(hi - lo).round(1)} WORLD px, more than a "
            f"{size} px candidate on a {spec.grid_px} px grid holds: raise "
            "--candidate-size or lower --height / --max-tilt",
        )
    return Footprint(fp_world, centre_world, true_origin)


def _refuse_footprint_across_antimeridian(i: int, fp_world: F64, zoom: int) -> None:
    """Refuse frame ``i`` when its footprint (WORLD px) crosses the 180th meridian: its corners
    lie at both ends of the map's WORLD px (or beyond them), and no candidate window of the
    store's tiles holds it."""
    world = TILE_PX * 2**zoom
    lo, hi = float(fp_world[:, 0].min()), float(fp_world[:, 0].max())
    if lo < 0 or hi > world or hi - lo > world / 2:
        raise InvalidInputError(
            "trajectory",
            f"frame {i}: its footprint crosses the 180th meridian (the antimeridian), where no "
            "candidate tile can hold it: fly on one side of it (lower --radius, --height or "
            "--frames x --speed x --interval, or build the store, whose centre the flight is "
            "flown round, farther from it)",
        )


MAX_TRUE_NODATA = 0.05
"""The largest share of a frame's footprint its true tile may lack (the store's nodata, or no
tile): a true tile that does not show what the frame sees would score the matcher against a
match nobody could make. 5 %: the rim of a coverage, not a frame flown off it."""


def _check_store_under(scene: Scene, i: int, footprint: Footprint) -> None:
    """Refuse frame ``i`` when the store holds nodata (all channels 0, or no tile) under more
    than :data:`MAX_TRUE_NODATA` of its footprint."""
    cov = scene.cov
    poly = footprint.world - np.asarray(cov.origin, dtype=np.float64)
    lo = np.floor(poly.min(axis=0)).astype(int)
    hi = np.ceil(poly.max(axis=0)).astype(int) + 1
    inside = np.zeros((hi[1] - lo[1], hi[0] - lo[0]), np.uint8)
    cv2.fillPoly(inside, [np.round(poly - lo).astype(np.int32)], (1,))
    data = np.zeros(inside.shape, bool)  # outside the coverage: no tile
    x0, y0 = max(lo[0], 0), max(lo[1], 0)
    x1, y1 = min(hi[0], cov.size[0]), min(hi[1], cov.size[1])
    if x1 > x0 and y1 > y0:
        window = cov.window(x0, y0, x1, y1).any(axis=2)
        data[y0 - lo[1] : y1 - lo[1], x0 - lo[0] : x1 - lo[0]] = window
    share = 1.0 - float(data[inside > 0].mean())
    if share > MAX_TRUE_NODATA:
        raise InvalidInputError(
            "trajectory",
            f"frame {i}: the store holds no imagery under {100 * share:.0f}% of its footprint, "
            "so its true tile would not show what it sees: lower --radius, --height or "
            "--frames x --speed x --interval, or build the store over more ground",
        )


def _jpeg(shot: Shot) -> bytes:
    """Encode the frame's image as JPEG (quality 95)."""
    ok, jpeg = cv2.imencode(".jpg", shot.frame.image[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
    if not ok:
        raise InvalidInputError("frames", f"frame {shot.index}: cannot encode the image")
    return jpeg.tobytes()


def _record(
    spec: FlightSpec,
    scene: Scene,
    shot: Shot,
    centre_world: F64,
    candidates: tuple[CandidateTruth, ...],
    image_rel: str,
) -> FrameRecord:
    """Write down the frame's record: id, time, attitude, height, candidates and true pose. The
    frame was rendered with its yaw and heading from the grid's north; both are recorded from
    true north (the grid convergence at the nadir added), as an autopilot reports them."""
    i, attitude = shot.index, shot.attitude
    convergence = grid_convergence_deg(scene.grid, shot.nadir)
    yaw = (math.degrees(attitude.yaw) + convergence + 180.0) % 360.0 - 180.0
    nadir_lon, nadir_lat = scene.grid.px_to_lonlat([shot.nadir])[0]
    c_lon, c_lat = world_px_to_lonlat(centre_world[None, :], scene.cov.zoom)[0]
    return FrameRecord(
        index=i,
        frame_id=uuid.UUID(int=(spec.seed << 32) + i + 1),
        image=image_rel,
        captured_at_ns=round(i * spec.frame_interval_s * 1e9),
        attitude_deg=(math.degrees(attitude.roll), math.degrees(attitude.pitch), yaw),
        height_m=spec.height_m,
        candidates=candidates,
        pose={
            "nadir_lat": float(nadir_lat),
            "nadir_lon": float(nadir_lon),
            "footprint_centre_lat": float(c_lat),
            "footprint_centre_lon": float(c_lon),
            "heading_deg": (shot.heading + convergence) % 360.0,
            "frame_nadir_gsd_m": shot.frame.nadir_gsd_m,
        },
    )


def _meta(
    spec: FlightSpec,
    store: MBTilesStore,
    scene: Scene,
    name: str,
    attribution: str,
    worst_fit: float,
    absent: set[int],
) -> dict[str, Any]:
    """Describe the planned flight: the dataset's meta (dataset.json)."""
    return {
        "name": name,
        "candidate_size_px": spec.candidate_size_px,
        "zoom": scene.cov.zoom,
        "tiles_source": store.metadata.get("c3_source", ""),
        "frames_source": Path(spec.frames_geotiff).name,
        "georeference": scene.grid.projection.describe(),
        "gt_fit_max_residual_px": worst_fit,
        "absent_frames": sorted(int(a) for a in absent),
        "spec": spec.to_json(),
        "attribution": attribution,
    }
