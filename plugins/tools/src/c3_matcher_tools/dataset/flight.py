"""Render a simulated flight over a real orthophoto into a ``c3-flight/1`` dataset.

The frames are rendered (:class:`c3_matcher_tools.sim.NavCameraRenderer`, exact ground truth) from
``frames_geotiff``; the candidate tiles come from an MBTiles store (``c3-matcher tiles build``)
made from the same ground, possibly another date (NAIP 2010 frames against 2020 tiles: the real
cross-date case; the two GeoTIFF grids, whose origins differ by metres, are tied through WGS84).

Trajectory: ``orbit`` (a circle of ``orbit_radius_m`` around the orthophoto centre, flown
clockwise from bearing ``heading_deg``; every heading occurs) or ``line`` (straight along
``heading_deg``, centred on the orthophoto centre) at ``speed_mps``, one frame every
``frame_interval_s``, ``height_m`` above the flat ground. Speeds and radii are ground metres on
any grid: they are converted to the frames GeoTIFF's projected units with its scale at the
flight centre (:func:`~.flight_scene.grid_units_per_m`: 1.47 units/m for web mercator at 47 N,
1.033 for the Manila EPSG:3395 tile, 0.9996 for the NAIP UTM tile), so the path is flown
straight in the grid. Attitude per frame: yaw = heading + uniform jitter, and a tilt drawn
uniformly in [0, ``max_tilt_deg``] in a random direction (roll, pitch). Camera: ``image_size``
px, ``focal_px``, OpenCV ``distortion``; photometric shift (colour, gamma, vignetting, blur,
noise, JPEG) seeded per frame.

North. Each frame is rendered in the frames orthophoto's grid, whose north is not true north:
``heading_deg`` and the drawn yaw are from GRID north. The records hold them from TRUE north,
as the matcher and an autopilot read a yaw: the grid convergence at the frame's nadir
(:func:`~.flight_scene.grid_convergence_deg`, measured through the GeoTIFF's georeference) is
added to the recorded yaw (``attitude_deg``) and heading (``pose.heading_deg``). It is -0.11 deg
for the NAIP tile (UTM 14N, west of the central meridian), -0.31 deg for Gorinchem (RD New),
+0.77 deg for Zurich (LV95), 0 on mercator grids, and up to 2-3 deg for UTM near a zone's edge;
over a flight of a few hundred metres it varies by under 0.01 deg. Flights rendered before this
(the shipped ones under data/flights/) recorded the grid yaw and their speed in projected units.

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

The spec is :class:`~c3_matcher_tools.dataset.flight_spec.FlightSpec`; the flight's scene is read
by :mod:`.flight_scene`, each frame rendered and planned by :mod:`.flight_plan`, its candidate
windows chosen by :mod:`.flight_candidates`; this module checks the inputs and writes the dataset.
"""

from __future__ import annotations

from pathlib import Path

from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher_tools.dataset.flight_plan import Progress, plan_flight
from c3_matcher_tools.dataset.flight_spec import FlightSpec
from c3_matcher_tools.dataset.format import dataset_name
from c3_matcher_tools.dataset.writing import write_dataset, write_file

__all__ = ["render_flight"]


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

    from c3_matcher_tools.dataset.atomic import atomic_directory, check_output_dir

    out = Path(out)
    check_output_dir(out, force=force, inputs=(spec.frames_geotiff, spec.store))
    label = dataset_name(name, out)
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
        plan = plan_flight(spec, store, label, attribution, progress)
    finally:
        store.close()
    meta, calibration, frames, images = plan
    with atomic_directory(out, force=force) as tmp:
        (tmp / "frames").mkdir()
        for rel, data in images.items():
            write_file(tmp / rel, data)
        write_dataset(tmp, meta, calibration, frames, store=spec.store)
    return out
