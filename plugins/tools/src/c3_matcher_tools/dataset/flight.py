"""Render a simulated flight over a real orthophoto into a ``c3-flight/1`` dataset.

The frames are rendered (:class:`c3_matcher_tools.sim.NavCameraRenderer`, exact ground truth) from
``frames_geotiff``; the candidate tiles come from an MBTiles store (``c3-matcher tiles build``)
made from the same ground, possibly another date (NAIP 2010 frames against 2020 tiles: the real
cross-date case; the two GeoTIFF grids, whose origins differ by metres, are tied through WGS84).

Trajectory: ``orbit`` (a circle of ``orbit_radius_m`` around the orthophoto centre, flown
clockwise from bearing ``heading_deg``; every heading occurs) or ``line`` (straight along
``heading_deg``, centred on the orthophoto centre) at ``speed_mps``, one frame every
``frame_interval_s``, ``height_m`` above the flat ground. Attitude per frame: yaw = heading +
uniform jitter, and a tilt drawn uniformly in [0, ``max_tilt_deg``] in a random direction
(roll, pitch). Camera: ``image_size`` px, ``focal_px``, OpenCV ``distortion``; photometric shift
(colour, gamma, vignetting, blur, noise, JPEG) seeded per frame. The attitude's yaw is measured
from the frames orthophoto's grid north (UTM grid convergence: 0.11 deg for the NAIP tile).

Candidates: the true tile is the ``candidate_size_px`` window of the store centred on the
footprint's bounding box snapped to a ``grid_px`` grid of WORLD px (so consecutive frames share
tiles and the tile feature cache works) and holds the whole footprint; distractors are windows
of the same size on the same grid (:func:`pick_distractor_tiles` on the store's coverage) whose
centres are at least ``min_distractor_distance_m`` from the footprint's centre, that do not
contain that centre (dilated by 8 px) and hold at most ``max_distractor_nodata`` of nodata: they
may overlap part of the footprint (the hard case of C3-IT-04). A share ``absent_share`` of the
frames (chosen at random) gets three distractors that do not overlap the footprint at all (at
most 50 % nodata) and no true tile: those must yield InsufficientInliersError. Candidate
order is shuffled; scores are C2.5-like (0.9, 0.8, 0.7). Distractors are drawn from a generator
seeded by the true window's position: frames sharing a true tile share their distractors.
"""

from __future__ import annotations

import json
import math
import uuid
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.arrays import F64
from c3_matcher.dto import Attitude, CameraCalibration, TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.handles import mosaic_origin, stitch
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher_tools.dataset.format import (
    CandidateTruth,
    FrameRecord,
    check_candidate_size,
    write_dataset,
)
from c3_matcher_tools.sim.orthophotos import load_orthophoto
from c3_matcher_tools.sim.photometric import PhotometricShift
from c3_matcher_tools.sim.render import NavCameraRenderer, RenderedFrame, pick_distractor_tiles
from c3_matcher_tools.tilestore.geo import (
    TILE_PX,
    GeoGrid,
    Projection,
    lonlat_to_world_px,
    read_geotiff_grid,
    world_px_to_lonlat,
)

__all__ = ["FlightSpec", "render_flight", "store_reference"]

Progress = Callable[[int, int], None]
M_PER_DEG_LAT = 111_320.0


def _default_shift() -> PhotometricShift:
    return PhotometricShift(
        gain_range=(0.85, 1.15),
        brightness_range=(0.8, 1.2),
        gamma_range=(0.8, 1.25),
        vignetting=0.25,
        blur_sigma_range=(0.3, 0.9),
        noise_sigma=2.5,
        jpeg_quality=85,
    )


@dataclass(frozen=True)
class FlightSpec:
    """How to render a flight (see the module docstring); lengths in metres, angles in degrees,
    sizes in px."""

    frames_geotiff: Path
    store: Path
    n_frames: int = 36
    pattern: str = "orbit"
    height_m: float = 780.0
    speed_mps: float = 30.0
    frame_interval_s: float = 2.0
    heading_deg: float = 0.0
    orbit_radius_m: float = 450.0
    max_tilt_deg: float = 20.0
    yaw_jitter_deg: float = 15.0
    image_size: tuple[int, int] = (320, 240)
    focal_px: float = 300.0
    distortion: tuple[float, ...] = (-0.12, 0.03, 0.0005, -0.0004, 0.0)
    candidate_size_px: int = 448
    grid_px: int = 32
    absent_share: float = 0.1
    min_distractor_distance_m: float = 350.0
    max_distractor_nodata: float = 0.35
    photometric: PhotometricShift = field(default_factory=_default_shift)
    reference_latlon: tuple[float, float] | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if self.pattern not in ("orbit", "line"):
            raise InvalidInputError("pattern", f"expected orbit or line, got {self.pattern!r}")
        if self.n_frames < 1:
            raise InvalidInputError("n_frames", f"must be >= 1, got {self.n_frames}")
        if not 0.0 <= self.absent_share <= 1.0:
            raise InvalidInputError("absent_share", f"must be in [0, 1], got {self.absent_share}")
        if not 0.0 <= self.max_tilt_deg <= 45.0:
            raise InvalidInputError("max_tilt_deg", f"must be in [0, 45], got {self.max_tilt_deg}")
        check_candidate_size(self.candidate_size_px)
        if self.candidate_size_px % self.grid_px or self.grid_px <= 0:
            raise InvalidInputError(
                "grid_px", f"{self.grid_px} must be > 0 and divide {self.candidate_size_px}"
            )

    def calibration(self) -> CameraCalibration:
        w, h = self.image_size
        k = np.array(
            [
                [self.focal_px, 0, (w - 1) / 2 + 2.5],
                [0, self.focal_px, (h - 1) / 2 - 1.5],
                [0, 0, 1],
            ],
            dtype=np.float64,
        )
        return CameraCalibration(k, np.asarray(self.distortion, dtype=np.float64), (w, h))

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        out["frames_geotiff"] = Path(self.frames_geotiff).name
        out["store"] = Path(self.store).name
        return out


@dataclass(frozen=True)
class _Coverage:
    """The store's whole coverage at one zoom as one image: COVERAGE px = WORLD px - origin."""

    image: NDArray[np.uint8]
    origin: tuple[int, int]
    zoom: int


def _coverage(store: MBTilesStore) -> _Coverage:
    zooms = store.zooms()
    if not zooms:
        raise InvalidInputError("store", f"{store.path}: holds no tiles")
    z = zooms[-1]
    keys = list(store.tiles(z))
    xs, ys = [k[0] for k in keys], [k[1] for k in keys]
    origin = (min(xs) * TILE_PX, min(ys) * TILE_PX)
    size = ((max(xs) - min(xs) + 1) * TILE_PX, (max(ys) - min(ys) + 1) * TILE_PX)
    return _Coverage(stitch(store, z, origin, size, store.name), origin, z)


def _trajectory(
    spec: FlightSpec, centre_en: tuple[float, float]
) -> list[tuple[float, float, float]]:
    """(east, north, heading deg) per frame, projected metres of the frames' grid."""
    step = spec.speed_mps * spec.frame_interval_s
    out = []
    for i in range(spec.n_frames):
        if spec.pattern == "orbit":
            bearing = math.radians(spec.heading_deg) + i * step / spec.orbit_radius_m
            e = centre_en[0] + spec.orbit_radius_m * math.sin(bearing)
            n = centre_en[1] + spec.orbit_radius_m * math.cos(bearing)
            heading = math.degrees(bearing) + 90.0
        else:
            h = math.radians(spec.heading_deg)
            s = (i - (spec.n_frames - 1) / 2) * step
            e, n, heading = (
                centre_en[0] + s * math.sin(h),
                centre_en[1] + s * math.cos(h),
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


def _flight_centre(store: MBTilesStore, grid: GeoGrid) -> tuple[float, float]:
    """Projected metres (frames grid) of the store's ``center`` (a fixed ground point, so
    flights rendered from different dates of the same ground fly the same path), else of the
    frames orthophoto's centre."""
    centre = store.metadata.get("center", "")
    try:
        lon, lat = (float(v) for v in centre.split(",")[:2])
    except ValueError:
        lon, lat = grid.centre_lonlat()
    e, n = grid.projection.from_lonlat([lon], [lat])
    return float(e[0]), float(n[0])


def _true_origin(fp_world: F64, size: int, grid_px: int) -> tuple[int, int] | None:
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


def render_flight(
    spec: FlightSpec,
    out: Path,
    *,
    name: str | None = None,
    attribution: str = "",
    progress: Progress | None = None,
    force: bool = False,
) -> Path:
    """Render ``spec`` into the dataset directory ``out`` (the store is copied in as
    ``tiles.mbtiles``). Every input is checked, and every frame rendered and its candidates
    chosen, before anything is written (frames are held JPEG-encoded in memory); then the
    dataset is written into a hidden sibling directory and renamed into place, so a failure
    leaves no directory behind. An existing ``out`` is refused unless ``force``, one that is or
    holds the GeoTIFF or the store always. Raises InvalidInputError naming the option that
    makes the flight impossible (leaving the imagery, footprint larger than a candidate, too
    few distractor positions)."""
    import shutil

    from c3_matcher_tools.dataset.atomic import atomic_directory, check_output_dir

    out = Path(out)
    check_output_dir(out, force=force, inputs=(spec.frames_geotiff, spec.store))
    if not Path(spec.frames_geotiff).is_file():
        raise InvalidInputError("FRAMES_GEOTIFF", f"no such file: {spec.frames_geotiff}")
    if not Path(spec.store).is_file():
        raise InvalidInputError("STORE", f"no such file: {spec.store}")
    try:
        store = MBTilesStore(spec.store)
    except InvalidInputError as exc:
        raise InvalidInputError("STORE", exc.reason) from exc
    except Exception as exc:  # sqlite3 / format errors: name the argument
        raise InvalidInputError(
            "STORE", f"{spec.store}: not a readable MBTiles store: {exc}"
        ) from exc
    try:
        plan = _plan(spec, store, name or out.name, attribution, progress)
    finally:
        store.close()
    meta, calibration, frames, images = plan
    with atomic_directory(out, force=force) as tmp:
        (tmp / "frames").mkdir()
        shutil.copyfile(spec.store, tmp / "tiles.mbtiles")
        for rel, data in images.items():
            (tmp / rel).write_bytes(data)
        write_dataset(tmp, meta, calibration, frames)
    return out


def _check_coverage(spec: FlightSpec, cov: _Coverage, m_per_px: float) -> None:
    """Refuse a store too small for a candidate window plus distractors at the requested
    distance before any frame is rendered (names the command-line options)."""
    h, w = cov.image.shape[:2]
    size = spec.candidate_size_px
    need = size + spec.min_distractor_distance_m / m_per_px
    if w < need and h < need:
        raise InvalidInputError(
            "--candidate-size",
            f"the store covers {w}x{h} px at zoom {cov.zoom} ({m_per_px:.2f} m/px), too small "
            f"for a {size} px candidate plus distractors {spec.min_distractor_distance_m:.0f} m "
            "away: lower --candidate-size or --min-distractor-distance, or build the store at "
            f"a finer zoom (tiles build --zoom {cov.zoom + 1})",
        )


def store_reference(metadata: Mapping[str, str], store: Path) -> tuple[float, float] | None:
    """The (lat, lon) reference a tile store was built around when its GeoTIFF's grid was
    treated as a local tangent plane (``c3_georeference``, written by ``tiles build``), so
    frames rendered from the same grid land on its tiles; None for any other store.
    ``InvalidInputError`` naming the store when that metadata cannot be read."""
    text = metadata.get("c3_georeference")
    if text is None:
        return None
    try:
        built = Projection.from_dict(json.loads(text))
    except (ValueError, KeyError, TypeError, IndexError) as exc:
        raise InvalidInputError(
            str(store), f"unreadable c3_georeference metadata ({exc}): rebuild the store"
        ) from None
    return (built.ref_lat, built.ref_lon) if built.kind == "local_tangent_plane" else None


@dataclass(frozen=True)
class _Scene:
    """What every frame of a flight is rendered from and placed on: the frames' orthophoto, its
    grid and GSD (m/px), the store's coverage and its m/WORLD px, the camera, and the centre of the
    flight (projected metres of the frames' grid)."""

    grid: GeoGrid
    rgb: NDArray[np.uint8]
    gsd: float
    cov: _Coverage
    m_per_px: float
    calibration: CameraCalibration
    renderer: NavCameraRenderer
    centre_en: tuple[float, float]


@dataclass(frozen=True)
class _Shot:
    """One frame rendered along the trajectory: its index, heading (deg), attitude, the ORTHO px
    below the camera, and the rendered frame."""

    index: int
    heading: float
    attitude: Attitude
    nadir: tuple[float, float]
    frame: RenderedFrame


@dataclass(frozen=True)
class _Footprint:
    """A frame's ground footprint (WORLD px of the store's zoom), its centre, and the top-left
    WORLD px of the true candidate window that holds it."""

    world: F64
    centre: F64
    true_origin: tuple[int, int]


@dataclass(frozen=True)
class _PlannedFrame:
    """One frame planned: its record, its JPEG bytes, and the homography fit residual (px) of
    each of its candidates."""

    record: FrameRecord
    jpeg: bytes
    fits: tuple[float, ...]


def _plan(
    spec: FlightSpec,
    store: MBTilesStore,
    name: str,
    attribution: str,
    progress: Progress | None,
) -> tuple[dict[str, Any], CameraCalibration, list[FrameRecord], dict[str, bytes]]:
    """Render every frame and choose its candidates, in memory: (dataset meta, calibration,
    frame records, {relative image path: JPEG bytes})."""
    scene = _scene(spec, store)
    absent = _absent_frames(spec)
    frames: list[FrameRecord] = []
    images: dict[str, bytes] = {}
    worst_fit = 0.0
    for i, pose in enumerate(_trajectory(spec, scene.centre_en)):
        planned = _plan_frame(spec, scene, i, pose, i in absent)
        worst_fit = max((worst_fit, *planned.fits))
        images[planned.record.image] = planned.jpeg
        frames.append(planned.record)
        if progress is not None:
            progress(i + 1, spec.n_frames)
    meta = _meta(spec, store, scene, name, attribution, worst_fit, absent)
    return meta, scene.calibration, frames, images


def _scene(spec: FlightSpec, store: MBTilesStore) -> _Scene:
    """Read the frames' orthophoto, its grid and the store's coverage; set up the camera."""
    reference = spec.reference_latlon or store_reference(store.metadata, store.path)
    grid = read_geotiff_grid(spec.frames_geotiff, reference=reference)
    photo = load_orthophoto(spec.frames_geotiff)
    gsd = photo.gsd_m or math.sqrt(grid.scale_x * grid.scale_y)
    cov = _coverage(store)
    centre_lon, centre_lat = grid.centre_lonlat()
    m_per_px = TileId(cov.zoom, centre_lat, centre_lon).web_mercator_gsd_m()
    _check_coverage(spec, cov, m_per_px)
    calibration = spec.calibration()
    renderer = NavCameraRenderer(calibration)
    centre_en = _flight_centre(store, grid)
    return _Scene(grid, photo.rgb, gsd, cov, m_per_px, calibration, renderer, centre_en)


def _absent_frames(spec: FlightSpec) -> set[int]:
    """Draw (with the flight's seed) the ``absent_share`` of frames that get no true tile."""
    rng = np.random.default_rng(spec.seed)
    n_absent = round(spec.absent_share * spec.n_frames)
    return set(rng.choice(spec.n_frames, size=n_absent, replace=False).tolist())


def _plan_frame(
    spec: FlightSpec,
    scene: _Scene,
    i: int,
    pose: tuple[float, float, float],
    is_absent: bool,
) -> _PlannedFrame:
    """Render frame ``i`` at its pose and choose its candidates: its record, JPEG and fits."""
    frng = np.random.default_rng([spec.seed, i])
    shot = _shoot(spec, scene, i, pose, frng)
    footprint = _footprint(spec, scene, shot)
    origins = [] if is_absent else [(footprint.true_origin, True)]
    origins += [(o, False) for o in _distractor_origins(spec, scene, i, footprint, is_absent)]
    candidates, fits = _candidates(spec, scene, shot.frame, footprint.centre, origins)
    ordered = _shuffled(candidates, frng)
    image_rel = f"frames/{i:06d}.jpg"
    jpeg = _jpeg(shot)
    return _PlannedFrame(
        _record(spec, scene, shot, footprint.centre, ordered, image_rel), jpeg, fits
    )


def _shoot(
    spec: FlightSpec,
    scene: _Scene,
    i: int,
    pose: tuple[float, float, float],
    frng: np.random.Generator,
) -> _Shot:
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
    return _Shot(i, heading, attitude, nadir, frame)


def _footprint(spec: FlightSpec, scene: _Scene, shot: _Shot) -> _Footprint:
    """Place the footprint in WORLD px and find its true window; refuse one none can hold."""
    zoom, size = scene.cov.zoom, spec.candidate_size_px
    fp_world = lonlat_to_world_px(scene.grid.px_to_lonlat(shot.frame.footprint_ortho()), zoom)
    centre_world = fp_world.mean(axis=0)
    true_origin = _true_origin(fp_world, size, spec.grid_px)
    if true_origin is None:
        lo, hi = fp_world.min(axis=0), fp_world.max(axis=0)
        raise InvalidInputError(
            "candidate_size_px",
            f"frame {shot.index}: the footprint spans {(hi - lo).round(1)} WORLD px, more than a "
            f"{size} px candidate on a {spec.grid_px} px grid holds: raise "
            "--candidate-size or lower --height / --max-tilt",
        )
    return _Footprint(fp_world, centre_world, true_origin)


def _distractor_origins(
    spec: FlightSpec, scene: _Scene, i: int, footprint: _Footprint, is_absent: bool
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


def _candidates(
    spec: FlightSpec,
    scene: _Scene,
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


def _shuffled(cands: list[CandidateTruth], frng: np.random.Generator) -> tuple[CandidateTruth, ...]:
    """Shuffle the candidates and score them C2.5-like (0.9, 0.8, 0.7, ...)."""
    order = frng.permutation(len(cands))
    return tuple(
        CandidateTruth(
            c.tile_id, round(0.9 - 0.1 * k, 3), c.is_true, c.distance_m, c.h_tile_to_undistorted
        )
        for k, c in enumerate(cands[j] for j in order)
    )


def _jpeg(shot: _Shot) -> bytes:
    """Encode the frame's image as JPEG (quality 95)."""
    ok, jpeg = cv2.imencode(".jpg", shot.frame.image[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
    if not ok:
        raise InvalidInputError("frames", f"frame {shot.index}: cannot encode the image")
    return jpeg.tobytes()


def _record(
    spec: FlightSpec,
    scene: _Scene,
    shot: _Shot,
    centre_world: F64,
    candidates: tuple[CandidateTruth, ...],
    image_rel: str,
) -> FrameRecord:
    """Write down the frame's record: id, time, attitude, height, candidates and true pose."""
    i, attitude = shot.index, shot.attitude
    nadir_lon, nadir_lat = scene.grid.px_to_lonlat([shot.nadir])[0]
    c_lon, c_lat = world_px_to_lonlat(centre_world[None, :], scene.cov.zoom)[0]
    return FrameRecord(
        index=i,
        frame_id=uuid.UUID(int=(spec.seed << 32) + i + 1),
        image=image_rel,
        captured_at_ns=round(i * spec.frame_interval_s * 1e9),
        attitude_deg=(
            math.degrees(attitude.roll),
            math.degrees(attitude.pitch),
            math.degrees(attitude.yaw),
        ),
        height_m=spec.height_m,
        candidates=candidates,
        pose={
            "nadir_lat": float(nadir_lat),
            "nadir_lon": float(nadir_lon),
            "footprint_centre_lat": float(c_lat),
            "footprint_centre_lon": float(c_lon),
            "heading_deg": shot.heading,
            "frame_nadir_gsd_m": shot.frame.nadir_gsd_m,
        },
    )


def _meta(
    spec: FlightSpec,
    store: MBTilesStore,
    scene: _Scene,
    name: str,
    attribution: str,
    worst_fit: float,
    absent: set[int],
) -> dict[str, Any]:
    """Describe the planned flight: the dataset's meta (dataset.json)."""
    return {
        "name": name,
        "store": "tiles.mbtiles",
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
