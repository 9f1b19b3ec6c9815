"""Import a recorded flight (images, telemetry CSV, calibration) into a ``c3-flight/1`` dataset.

Telemetry CSV: one row per frame, a header naming the columns (case-insensitive, any order,
other columns ignored):

    ==================  ==========================================================  ===========
    column (aliases)    meaning                                                     unit
    ==================  ==========================================================  ===========
    time_s (time)       capture time                                                seconds
    image (file,        image file name, relative to IMAGES_DIR                     -
      filename,
      image_file)
    lat (latitude)      vehicle position, WGS84                                     degrees
    lon (longitude)     vehicle position, WGS84                                     degrees
    altitude_m          height ABOVE GROUND (AGL)                                   metres
      (altitude,
      height_m, agl_m,
      height_agl_m)
    altitude_msl_m      or: altitude above mean sea level (the DEM's / ground         metres
      (alt_msl_m,       elevation's datum); height above ground = this minus the
      altitude_amsl_m,  ground elevation (``ground_elevation_m``) or the DEM at
      amsl_m, msl_m)    (lat, lon) (``dem``), which must then be given
    roll_deg (roll)     attitude, aerospace Z-Y-X (yaw, pitch, roll), NED body      degrees
    pitch_deg (pitch)   idem                                                        degrees
    yaw_deg (yaw)       idem; yaw from TRUE north, clockwise positive               degrees
    ==================  ==========================================================  ===========

Candidates (a stand-in for the upstream re-ranker C2.5): at zoom ``zoom`` of the store (default
its finest), the ground point the camera's optical axis hits (from the telemetry position,
attitude, height and the calibration's camera mount; the nadir when the axis points above the
horizon) is located in a 256-px slippy tile; the candidates are the ``candidate_size_px`` windows
centred on (:func:`c3_matcher.tilestore.base.tile_centre_id`) that tile, the other tiles whose
square comes within ``uncertainty_m`` of the point, nearest first, then the nearest further
tiles (distractors) until there are ``candidates``; only tiles the store holds. Their order is
shuffled by a generator seeded by (``seed``, frame index), scores 0.9, 0.8, ... in that order.

Rows and images: every image in IMAGES_DIR without a telemetry row and every row whose image
is missing is skipped and reported (:class:`ImportReport`); a refused value names its CSV line.
Everything is checked before anything is written; the dataset is written into a temporary
sibling directory and renamed into place.
"""

from __future__ import annotations

import csv
import itertools
import math
import shutil
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.camera import rotation_world_from_camera
from c3_matcher.dto import MAX_HEIGHT_ABOVE_GROUND_M, Attitude, CameraCalibration, TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.serialize import load_calibration
from c3_matcher.tilestore.base import tile_centre_id
from c3_matcher.tilestore.geo import TILE_PX, lonlat_to_world_px
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher_tools.dataset.atomic import atomic_directory, check_output_dir
from c3_matcher_tools.dataset.format import CandidateTruth, FrameRecord, write_dataset
from c3_matcher_tools.dataset.sources.frames import ground_elevation_sampler
from c3_matcher_tools.dataset.sources.images import IMAGE_SUFFIXES
from c3_matcher_tools.dataset.sources.options import (
    MAX_SEARCH_TILES,
    ImportReport,
    check_proposal_options,
    max_uncertainty_m,
    number_ranges,
)
from c3_matcher_tools.dataset.sources.writer import image_problem

__all__ = [
    "COLUMNS",
    "HEIGHT_COLUMNS",
    "ImportSpec",
    "StoreProposals",
    "Telemetry",
    "TelemetryRow",
    "import_csv_flight",
    "import_flight",
    "imported_frame",
    "look_point",
    "propose_from_store",
    "read_telemetry",
    "shuffled_candidates",
]

#: canonical column -> accepted header names (case-insensitive)
COLUMNS: dict[str, tuple[str, ...]] = {
    "time_s": ("time_s", "time"),
    "image": ("image", "file", "filename", "image_file"),
    "lat": ("lat", "latitude"),
    "lon": ("lon", "longitude"),
    "roll_deg": ("roll_deg", "roll"),
    "pitch_deg": ("pitch_deg", "pitch"),
    "yaw_deg": ("yaw_deg", "yaw"),
}
#: the height columns, one of which must be present: above ground, or above mean sea level
HEIGHT_COLUMNS: dict[str, tuple[str, ...]] = {
    "altitude_m": ("altitude_m", "altitude", "height_m", "agl_m", "height_agl_m"),
    "altitude_msl_m": ("altitude_msl_m", "alt_msl_m", "altitude_amsl_m", "amsl_m", "msl_m"),
}
M_PER_DEG_LAT = 111_320.0
MAX_PROBLEMS = 10
MAX_ABS_TIME_S = 4e9  # |time_s| beyond this (126 years) is not a capture time (ns fit int64)
AGREE_M = 30.0  # both height columns given: altitude - height must be the ground to this


@dataclass(frozen=True)
class TelemetryRow:
    """One telemetry record (see the module docstring); ``line`` is its CSV line number."""

    line: int
    time_s: float
    image: str
    lat: float
    lon: float
    altitude_m: float
    roll_deg: float
    pitch_deg: float
    yaw_deg: float
    altitude_msl_m: float | None = None  # the row's altitude above sea level, when given

    @property
    def attitude(self) -> Attitude:
        return Attitude.from_degrees(self.roll_deg, self.pitch_deg, self.yaw_deg)


@dataclass(frozen=True)
class ImportSpec:
    """What ``c3-matcher dataset import`` was given (lengths in metres, sizes in px)."""

    images_dir: Path
    telemetry_csv: Path
    calibration_json: Path
    store: Path
    uncertainty_m: float = 50.0
    candidates: int = 3
    zoom: int | None = None
    candidate_size_px: int = 512
    seed: int = 0
    ground_elevation_m: float | None = None  # the ground's altitude above sea level, m
    dem: Path | None = None  # a DEM GeoTIFF of the ground's altitude above sea level

    def __post_init__(self) -> None:
        if self.ground_elevation_m is not None and self.dem is not None:
            raise InvalidInputError("--ground-elevation", "give it or --dem, not both")
        if self.ground_elevation_m is not None and not (
            math.isfinite(self.ground_elevation_m) and abs(self.ground_elevation_m) <= 9000
        ):
            raise InvalidInputError(
                "--ground-elevation", f"must be in [-9000, 9000] m, got {self.ground_elevation_m}"
            )
        check_proposal_options(self.uncertainty_m, self.candidates, self.candidate_size_px)

    @property
    def inputs(self) -> tuple[Path | None, ...]:
        """The files and folders the import reads (``None``: no DEM)."""
        return (self.images_dir, self.telemetry_csv, self.calibration_json, self.store, self.dem)


def _find(lowered: dict[str, str], aliases: tuple[str, ...]) -> str | None:
    return next((lowered[a] for a in aliases if a in lowered), None)


def _repeated_columns(header: list[str]) -> list[str]:
    """The columns ``header`` gives more than once: a name repeated, or two aliases of one."""
    names = [h.strip().lower() for h in header]
    repeated = [f"{n!r} twice" for n in dict.fromkeys(names) if names.count(n) > 1]
    for aliases in (*COLUMNS.values(), *HEIGHT_COLUMNS.values()):
        given = [a for a in aliases if a in names]
        if len(given) > 1:
            repeated.append(" and ".join(repr(a) for a in given))
    return repeated


def _column_map(header: list[str], path: Path) -> dict[str, str]:
    """Canonical column -> header name; at least one of :data:`HEIGHT_COLUMNS`. A column given
    more than once is refused: which one holds the values would be a guess."""
    repeated = _repeated_columns(header)
    if repeated:
        raise InvalidInputError(
            str(path),
            f"telemetry CSV gives a column more than once ({'; '.join(repeated)}); "
            f"header: {header}",
        )
    lowered = {h.strip().lower(): h for h in header}
    found: dict[str, str] = {}
    missing = []
    for name, aliases in COLUMNS.items():
        hit = _find(lowered, aliases)
        if hit is None:
            missing.append(f"{name} (or {', '.join(aliases[1:])})" if aliases[1:] else name)
        else:
            found[name] = hit
    for name, aliases in HEIGHT_COLUMNS.items():
        hit = _find(lowered, aliases)
        if hit is not None:
            found[name] = hit
    if not any(k in found for k in HEIGHT_COLUMNS):
        missing.append(
            "a height: altitude_m (height above ground; or altitude, height_m, agl_m) or "
            "altitude_msl_m (above sea level, with --ground-elevation or --dem)"
        )
    if missing:
        raise InvalidInputError(
            str(path), f"telemetry CSV lacks column(s) {'; '.join(missing)}; header: {header}"
        )
    return found


@dataclass(frozen=True)
class Telemetry:
    """The checked rows (sorted by time) and how their heights above ground were obtained:
    ``height_source`` in words, ``columns`` canonical -> the CSV's header names."""

    rows: tuple[TelemetryRow, ...]
    height_source: str
    columns: dict[str, str]


def _refuse(path: Path, problems: list[tuple[int, str]]) -> None:
    """One line naming the first problems in full and every further line by number."""
    if not problems:
        return
    shown = "; ".join(text for _, text in problems[:MAX_PROBLEMS])
    rest = [n for n, _ in problems[MAX_PROBLEMS:]]
    more = f" (and {len(rest)} more, on lines {number_ranges(rest)})" if rest else ""
    raise InvalidInputError(str(path), shown + more)


def _row_problem(values: dict[str, float], col: dict[str, str]) -> str | None:
    """Why a row's (finite) values are refused, naming the CSV's column, or None."""
    t = values["time_s"]
    if abs(t) > MAX_ABS_TIME_S:
        return (
            f"{col['time_s']} {t:g} is not a capture time in seconds (|time_s| <= "
            f"{MAX_ABS_TIME_S:g}; milliseconds or nanoseconds?)"
        )
    if not -90.0 <= values["lat"] <= 90.0:
        return f"{col['lat']} {values['lat']:g} outside [-90, 90] deg"
    if not -180.0 <= values["lon"] <= 180.0:
        return f"{col['lon']} {values['lon']:g} outside [-180, 180] deg"
    for key in ("roll_deg", "pitch_deg"):
        if abs(values[key]) >= 90.0:
            return f"{col[key]} {values[key]:g}: |roll| and |pitch| must be < 90 deg (radians?)"
    if abs(values["yaw_deg"]) > 360.0:
        return f"{col['yaw_deg']} {values['yaw_deg']:g} outside [-360, 360] deg"
    return None


def _height(
    values: dict[str, float],
    col: dict[str, str],
    ground: Any,
    spec_ground: float | None,
) -> tuple[float | None, str | None]:
    """(height above ground m, None) or (None, why refused) for one row. An altitude above
    sea level beside the height above ground is checked against the ground when one is given
    (else the height is taken as it is: there is nothing to check it against)."""
    agl = values.get("altitude_m")
    msl = values.get("altitude_msl_m")
    if msl is not None and (agl is None or ground is not None or spec_ground is not None):
        g = spec_ground if ground is None else ground(values["lat"], values["lon"])
        if g is None:
            where = f"({values['lat']:.6f}, {values['lon']:.6f})"
            return None, f"the DEM has no ground elevation at {where}"
        if agl is None:
            agl = msl - g
            if agl <= 0:
                return None, (
                    f"{col['altitude_msl_m']} {msl:g} m is not above the ground ({g:g} m): "
                    "altitude above sea level?"
                )
        elif abs(msl - agl - g) > AGREE_M:
            return None, (
                f"{col['altitude_msl_m']} {msl:g} m minus {col['altitude_m']} {agl:g} m is "
                f"{msl - agl:g} m, but the ground is at {g:g} m"
            )
    assert agl is not None
    name = col.get("altitude_m", "height above ground")
    if agl <= 0:
        return None, f"{name} {agl:g} must be > 0 m above ground"
    if agl > MAX_HEIGHT_ABOVE_GROUND_M:
        return None, f"{name} {agl:g} m above ground is not a UAV's height"
    return agl, None


def read_telemetry(
    path: Path,
    *,
    ground_elevation_m: float | None = None,
    dem: Path | None = None,
) -> list[TelemetryRow]:
    """Read and check a telemetry CSV (see the module docstring), sorted by time; raises
    InvalidInputError naming the CSV line of every refused value."""
    return list(read_telemetry_table(path, ground_elevation_m=ground_elevation_m, dem=dem).rows)


def read_telemetry_table(
    path: Path,
    *,
    ground_elevation_m: float | None = None,
    dem: Path | None = None,
) -> Telemetry:
    """:func:`read_telemetry` with how the heights above ground were obtained."""
    path = Path(path)
    reader, header = _csv_reader(path)
    cols = _column_map(header, path)
    _check_ground_given(path, cols, ground_elevation_m, dem)
    ground = ground_elevation_sampler(dem) if dem is not None else None
    rows, problems = _read_rows(reader, _RowRules(cols, ground, ground_elevation_m))
    if not rows and not problems:
        problems.append((1, "no data rows"))
    problems += _repeated_images(rows)
    rows.sort(key=lambda r: (r.time_s, r.line))
    problems += _repeated_times(rows)
    _refuse(path, problems)
    return Telemetry(tuple(rows), _height_source(cols, ground_elevation_m, dem), cols)


def _csv_reader(path: Path) -> tuple[csv.DictReader[str], list[str]]:
    """A reader of the CSV's records and its header; refused when the file cannot be read as
    UTF-8 or has no header."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InvalidInputError(str(path), f"unreadable telemetry CSV: {exc}") from None
    reader = csv.DictReader(text.splitlines())
    if not reader.fieldnames:
        raise InvalidInputError(str(path), "empty telemetry CSV (no header)")
    return reader, list(reader.fieldnames)


def _check_ground_given(
    path: Path, cols: dict[str, str], ground_elevation_m: float | None, dem: Path | None
) -> None:
    """Refuse a ground elevation or DEM for a CSV without an altitude above sea level, and
    an altitude above sea level alone without either."""
    has_msl, has_agl = "altitude_msl_m" in cols, "altitude_m" in cols
    given = ground_elevation_m is not None or dem is not None
    if given and not has_msl:
        raise InvalidInputError(
            "--ground-elevation" if dem is None else "--dem",
            f"{path}: column {cols['altitude_m']!r} already is the height above ground; a ground "
            "elevation is for an altitude above sea level column (altitude_msl_m)",
        )
    if has_msl and not has_agl and not given:
        raise InvalidInputError(
            "--ground-elevation",
            f"{path}: column {cols['altitude_msl_m']!r} is an altitude above sea level: give "
            "the ground's (--ground-elevation M, same datum) or a DEM (--dem DEM.tif) to get "
            "the height above ground",
        )


@dataclass(frozen=True)
class _RowRules:
    """How a CSV record becomes a :class:`TelemetryRow`: canonical column -> the header's
    name, and the ground an altitude above sea level is measured from (the DEM's sampler, or
    the given ground elevation)."""

    cols: dict[str, str]
    ground: Callable[[float, float], float | None] | None
    ground_elevation_m: float | None

    @property
    def numeric(self) -> list[str]:
        """The canonical columns given, bar the image name: each must hold a number."""
        return [k for k in (*COLUMNS, *HEIGHT_COLUMNS) if k in self.cols and k != "image"]


def _read_rows(
    reader: csv.DictReader[str], rules: _RowRules
) -> tuple[list[TelemetryRow], list[tuple[int, str]]]:
    """The accepted rows in line order, and (line, why) of each refused one."""
    rows: list[TelemetryRow] = []
    problems: list[tuple[int, str]] = []
    for n, rec in enumerate(reader, start=2):
        row = _row(n, rec, rules)
        if isinstance(row, str):
            problems.append((n, f"line {n}: {row}"))
        else:
            rows.append(row)
    return rows, problems


def _row(n: int, rec: dict[str, str], rules: _RowRules) -> TelemetryRow | str:
    """CSV line ``n`` as a row, or why it is refused: its values that are not finite numbers,
    else an empty image name, else the first value out of range, else its height."""
    cols = rules.cols
    values, bad = _numbers(rec, rules)
    image = str(rec.get(cols["image"]) or "").strip()
    why = "; ".join(bad) if bad else None
    if why is None and not image:
        why = f"{cols['image']} is empty"
    why = why or _row_problem(values, cols)
    if why is not None:
        return why
    height, why = _height(values, cols, rules.ground, rules.ground_elevation_m)
    if height is None:
        return str(why)
    return TelemetryRow(
        n,
        values["time_s"],
        image,
        values["lat"],
        values["lon"],
        height,
        values["roll_deg"],
        values["pitch_deg"],
        values["yaw_deg"],
        values.get("altitude_msl_m"),
    )


def _numbers(rec: dict[str, str], rules: _RowRules) -> tuple[dict[str, float], list[str]]:
    """The record's numeric columns as floats, and what is wrong with each that is not a
    finite number (naming the CSV's column)."""
    values: dict[str, float] = {}
    bad: list[str] = []
    for k in rules.numeric:
        name = rules.cols[k]
        raw = str(rec.get(name) or "").strip()
        try:
            values[k] = float(raw)
        except ValueError:
            bad.append(f"{name} {raw!r} is not a number")
            continue
        if not math.isfinite(values[k]):
            bad.append(f"{name} {raw} is not finite")
    return values, bad


def _repeated_images(rows: Sequence[TelemetryRow]) -> list[tuple[int, str]]:
    """(line, why) of each row naming an image an earlier row names."""
    problems: list[tuple[int, str]] = []
    seen: dict[str, int] = {}
    for r in rows:
        if r.image in seen:
            problems.append(
                (r.line, f"line {r.line}: image {r.image!r} already on line {seen[r.image]}")
            )
        seen[r.image] = r.line
    return problems


def _repeated_times(rows: Sequence[TelemetryRow]) -> list[tuple[int, str]]:
    """(line, why) of each row at the time of the row before it (``rows`` sorted by time)."""
    return [
        (b.line, f"lines {a.line} and {b.line}: same time_s {a.time_s}")
        for a, b in itertools.pairwise(rows)
        if b.time_s == a.time_s
    ]


def _height_source(cols: dict[str, str], ground_elevation_m: float | None, dem: Path | None) -> str:
    """How the heights above ground were obtained, in words."""
    has_msl, has_agl = "altitude_msl_m" in cols, "altitude_m" in cols
    if has_agl and has_msl and (dem is not None or ground_elevation_m is not None):
        return f"column {cols['altitude_m']!r} (checked against {cols['altitude_msl_m']!r})"
    if has_agl:
        return f"column {cols['altitude_m']!r} read as height above ground"
    if dem is not None:
        return f"column {cols['altitude_msl_m']!r} minus the DEM {Path(dem).name}"
    return f"column {cols['altitude_msl_m']!r} minus ground elevation {ground_elevation_m:g} m"


def look_point(row: TelemetryRow, calibration: CameraCalibration) -> tuple[float, float]:
    """(lon, lat) where the optical axis meets flat ground ``altitude_m`` below the vehicle
    (the telemetry position itself when the axis does not point down)."""
    axis = rotation_world_from_camera(row.attitude, calibration) @ np.array([0.0, 0.0, 1.0])
    north, east, down = (float(v) for v in axis)
    if down < 0.2:  # about 78 deg off nadir or worse: the hit point means nothing
        return row.lon, row.lat
    dn, de = row.altitude_m * north / down, row.altitude_m * east / down
    lat = row.lat + dn / M_PER_DEG_LAT
    lon = row.lon + de / (M_PER_DEG_LAT * math.cos(math.radians(row.lat)))
    return lon, lat


def store_zoom(store: MBTilesStore, path: object, zoom: int | None) -> int:
    """The zoom candidates are proposed at: ``zoom`` if the store holds it, else its finest;
    ``InvalidInputError`` for an empty store or a zoom it does not hold."""
    zooms = store.zooms()
    if not zooms:
        raise InvalidInputError("STORE", f"{path}: holds no tiles")
    chosen = zooms[-1] if zoom is None else zoom
    if chosen not in zooms:
        raise InvalidInputError("--zoom", f"{chosen} not in the store's zooms {zooms}")
    return chosen


def _propose(
    store: MBTilesStore, zoom: int, lonlat: tuple[float, float], spec: ImportSpec
) -> list[tuple[TileId, float]] | None:
    """(tile id, distance m from the point to the tile square) of the candidates, the tile
    holding the point first; None when the store lacks that tile. Refuses an uncertainty
    beyond :func:`max_uncertainty_m` there."""
    reach_m = max_uncertainty_m(zoom, lonlat[1])
    if spec.uncertainty_m > reach_m:
        raise InvalidInputError(
            "--uncertainty-m",
            f"{spec.uncertainty_m:g} m reaches beyond {MAX_SEARCH_TILES} tiles of the store's "
            f"zoom {zoom} ({reach_m:.0f} m at latitude {lonlat[1]:.2f}): give at most that",
        )
    p = lonlat_to_world_px([lonlat], zoom)[0]
    m_per_px = TileId(zoom, lonlat[1], lonlat[0]).web_mercator_gsd_m()
    tx, ty = int(p[0] // TILE_PX), int(p[1] // TILE_PX)
    if store.tile_bytes(zoom, tx, ty) is None:
        return None
    ring = max(2, math.ceil(spec.uncertainty_m / (m_per_px * TILE_PX)) + 1)
    ring = max(ring, math.ceil(math.sqrt(spec.candidates)) + 1)
    near: list[tuple[float, float, int, int]] = []
    for x in range(tx - ring, tx + ring + 1):
        for y in range(ty - ring, ty + ring + 1):
            if (x, y) == (tx, ty) or store.tile_bytes(zoom, x, y) is None:
                continue
            dx = max(x * TILE_PX - p[0], 0.0, p[0] - (x + 1) * TILE_PX)
            dy = max(y * TILE_PX - p[1], 0.0, p[1] - (y + 1) * TILE_PX)
            edge_m = math.hypot(dx, dy) * m_per_px
            centre_m = math.hypot((x + 0.5) * TILE_PX - p[0], (y + 0.5) * TILE_PX - p[1])
            # within the uncertainty first (nearest centre first), then the nearest others
            near.append((0.0 if edge_m <= spec.uncertainty_m else 1.0, centre_m, x, y))
    near.sort()
    picked = [(tile_centre_id(zoom, tx, ty), 0.0)]
    for _, _, x, y in near[: spec.candidates - 1]:
        dx = max(x * TILE_PX - p[0], 0.0, p[0] - (x + 1) * TILE_PX)
        dy = max(y * TILE_PX - p[1], 0.0, p[1] - (y + 1) * TILE_PX)
        picked.append((tile_centre_id(zoom, x, y), math.hypot(dx, dy) * m_per_px))
    return picked


@dataclass(frozen=True)
class StoreProposals:
    """The candidates proposed from a store for each telemetry row, in row order.

    ``looks``: (look point (lon, lat) deg, candidates as (tile id, distance m) or None where
    the store lacks the tile under the look point); ``outside``: the rows whose look point the
    store does not cover; ``attribution`` and ``tiles_source``: the store's metadata.
    """

    zoom: int
    looks: list[tuple[tuple[float, float], list[tuple[TileId, float]] | None]]
    outside: list[TelemetryRow]
    attribution: str
    tiles_source: str

    def refuse_outside(
        self, where: str, label: Callable[[TelemetryRow], str], *, hint: str = "", shown: int = 10
    ) -> None:
        """``InvalidInputError`` naming ``where`` when any row looks outside the store: how many,
        then the first ``shown`` as ``label(row)`` and their (lat, lon); ``hint`` follows the
        zoom."""
        if self.outside:
            names = [f"{label(r)} ({r.lat:.6f}, {r.lon:.6f})" for r in self.outside]
            more = f" and {len(names) - shown} more" if len(names) > shown else ""
            raise InvalidInputError(
                where,
                f"{len(names)} frame(s) look outside the store's coverage at zoom {self.zoom}"
                f"{hint}: " + ", ".join(names[:shown]) + more,
            )


def propose_from_store(
    rows: Sequence[TelemetryRow], calibration: CameraCalibration, spec: ImportSpec
) -> StoreProposals:
    """Propose ``spec.candidates`` tiles of ``spec.store`` around each row's look point."""
    with MBTilesStore(spec.store) as store:
        zoom = store_zoom(store, spec.store, spec.zoom)
        looks: list[tuple[tuple[float, float], list[tuple[TileId, float]] | None]] = []
        outside: list[TelemetryRow] = []
        for r in rows:
            lonlat = look_point(r, calibration)
            cands = _propose(store, zoom, lonlat, spec)
            if cands is None:
                outside.append(r)
            looks.append((lonlat, cands))
        return StoreProposals(
            zoom,
            looks,
            outside,
            store.metadata.get("attribution", ""),
            store.metadata.get("c3_source", ""),
        )


def shuffled_candidates(
    cands: list[tuple[TileId, float]] | None, seed: int, index: int
) -> tuple[CandidateTruth, ...]:
    """Frame ``index``'s candidates in a seeded order, priors 0.9, 0.8, ... (the truth tile is
    not always first); ``cands`` is never None once the coverage check passed."""
    assert cands is not None
    order = np.random.default_rng([seed, index]).permutation(len(cands))
    return tuple(CandidateTruth(cands[j][0], round(0.9 - 0.1 * k, 3)) for k, j in enumerate(order))


def imported_frame(
    index: int,
    row: TelemetryRow,
    t0_s: float,
    base: uuid.UUID,
    suffix: str,
    proposal: tuple[tuple[float, float], list[tuple[TileId, float]] | None],
    spec: ImportSpec,
    *,
    heights: dict[str, Any],
    extra: dict[str, Any] | None = None,
) -> FrameRecord:
    """The dataset record of imported frame ``index`` (image ``frames/<index><suffix>``, id from
    ``base`` and the source image name, time from ``t0_s``, the first row's time in s) with its
    ``proposal`` (look point (lon, lat) deg, candidates) in seeded order. Telemetry: position,
    ``heights`` (the height keys a source knows), time, source image, look point, uncertainty
    m, then ``extra``."""
    look, cands = proposal
    return FrameRecord(
        index=index,
        frame_id=uuid.uuid5(base, row.image),
        image=f"frames/{index:06d}{suffix}",
        captured_at_ns=round((row.time_s - t0_s) * 1e9),
        attitude_deg=(row.roll_deg, row.pitch_deg, row.yaw_deg),
        height_m=row.altitude_m,
        candidates=shuffled_candidates(cands, spec.seed, index),
        telemetry={
            "lat": row.lat,
            "lon": row.lon,
            "altitude_m": row.altitude_m,
            **heights,
            "time_s": row.time_s,
            "source_image": row.image,
            "look_lat": look[1],
            "look_lon": look[0],
            "uncertainty_m": spec.uncertainty_m,
            **(extra or {}),
        },
    )


def _check_image(path: Path, calibration: CameraCalibration) -> str | None:
    """Why ``path`` cannot be a frame, as every import checks its images, or None."""
    if not path.is_file():
        return "no such file"
    return image_problem(path.read_bytes(), calibration.image_size)


def _pair_images(
    images_dir: Path, rows: list[TelemetryRow]
) -> tuple[list[TelemetryRow], list[tuple[str, str]]]:
    """(rows whose image exists, skipped (name, why)): every image in ``images_dir`` without a
    row and every row without its image, in name / line order."""
    on_disk = {
        p.name
        for p in images_dir.iterdir()
        if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in IMAGE_SUFFIXES
    }
    named = {r.image for r in rows}
    kept = [r for r in rows if (images_dir / r.image).is_file()]
    skipped = [(n, "no telemetry row") for n in sorted(on_disk - named)]
    skipped += [
        (r.image, f"line {r.line}: no such image")
        for r in sorted(rows, key=lambda r: r.line)
        if not (images_dir / r.image).is_file()
    ]
    return kept, skipped


def import_flight(
    spec: ImportSpec, out: Path, *, name: str | None = None, force: bool = False
) -> dict[str, Any]:
    """:func:`import_csv_flight`'s report as JSON (``dataset``, ``frames``, ``zoom``,
    ``skipped``, ...)."""
    return import_csv_flight(spec, out, name=name, force=force).to_json()


def import_csv_flight(
    spec: ImportSpec, out: Path, *, name: str | None = None, force: bool = False
) -> ImportReport:
    """Check every input (``out`` must not be or hold one, ``force`` or not), then write the
    dataset ``out`` atomically; returns what was done (frames, every image or row skipped and
    why, where the heights came from). Raises InvalidInputError naming the input at fault
    (nothing is written then)."""
    out = Path(out)
    check_output_dir(out, force=force, inputs=spec.inputs)
    checked = _check_csv_inputs(spec)
    frames = _csv_frames(checked, spec, name or out.name)
    meta = _csv_meta(checked, spec, name or out.name)
    with atomic_directory(out, force=force) as tmp:
        (tmp / "frames").mkdir()
        for r, f in zip(checked.rows, frames, strict=True):
            shutil.copyfile(checked.images_dir / r.image, tmp / f.image)
        shutil.copyfile(spec.store, tmp / "tiles.mbtiles")
        write_dataset(tmp, meta, checked.calibration, frames)
    return _csv_report(checked, spec, out, len(frames))


@dataclass(frozen=True)
class _CheckedCsv:
    """A telemetry-CSV import's inputs once checked: the images folder, the calibration, the
    telemetry, the rows whose image is there (in time order) with the images and rows
    skipped, and the candidates proposed for each row."""

    images_dir: Path
    calibration: CameraCalibration
    table: Telemetry
    rows: list[TelemetryRow]
    skipped: list[tuple[str, str]]
    proposed: StoreProposals


def _check_csv_inputs(spec: ImportSpec) -> _CheckedCsv:
    """Check the images folder, store, calibration, telemetry, each image named and the
    store's coverage of every frame, in that order; raises InvalidInputError naming the
    input at fault."""
    images_dir = Path(spec.images_dir)
    if not images_dir.exists():
        raise InvalidInputError("IMAGES_DIR", f"{images_dir}: no such file or folder")
    if not images_dir.is_dir():
        raise InvalidInputError("IMAGES_DIR", f"{images_dir}: not a directory")
    if not Path(spec.store).is_file():
        raise InvalidInputError("STORE", f"{spec.store}: no such tile store")
    calibration = load_calibration(Path(spec.calibration_json), field="CALIBRATION")
    table = read_telemetry_table(
        Path(spec.telemetry_csv), ground_elevation_m=spec.ground_elevation_m, dem=spec.dem
    )
    rows, skipped = _pair_images(images_dir, list(table.rows))
    if not rows:
        raise InvalidInputError(
            "IMAGES_DIR",
            f"{images_dir}: no telemetry row names an image there "
            f"({len(table.rows)} row(s), e.g. {table.rows[0].image!r})",
        )
    _refuse(images_dir, _image_problems(images_dir, rows, calibration))
    proposed = propose_from_store(rows, calibration, spec)
    proposed.refuse_outside("TELEMETRY", lambda r: f"line {r.line}")
    return _CheckedCsv(images_dir, calibration, table, rows, skipped, proposed)


def _image_problems(
    images_dir: Path, rows: Sequence[TelemetryRow], calibration: CameraCalibration
) -> list[tuple[int, str]]:
    """(line, why) of each row whose image cannot be a frame."""
    problems = []
    for r in rows:
        why = _check_image(images_dir / r.image, calibration)
        if why:
            problems.append((r.line, f"line {r.line}: {r.image}: {why}"))
    return problems


def _csv_frames(checked: _CheckedCsv, spec: ImportSpec, name: str) -> list[FrameRecord]:
    """The dataset record of each row, its frame ids derived from the dataset's ``name``."""
    frames: list[FrameRecord] = []
    t0 = checked.rows[0].time_s
    base = uuid.uuid5(uuid.NAMESPACE_URL, f"c3-flight-import:{name}")
    for i, (r, proposal) in enumerate(zip(checked.rows, checked.proposed.looks, strict=True)):
        ext = Path(r.image).suffix.lower() or ".jpg"
        known: dict[str, Any] = {}
        if r.altitude_msl_m is not None:
            known["altitude_msl_m"] = r.altitude_msl_m
        known["height_source"] = checked.table.height_source
        frames.append(imported_frame(i, r, t0, base, ext, proposal, spec, heights=known))
    return frames


def _csv_meta(checked: _CheckedCsv, spec: ImportSpec, name: str) -> dict[str, Any]:
    """The dataset's ``dataset.json``: the store's zoom and sources, and the import's inputs
    (by file name) and options in ``spec``."""
    zoom = checked.proposed.zoom
    return {
        "name": name,
        "store": "tiles.mbtiles",
        "candidate_size_px": spec.candidate_size_px,
        "zoom": zoom,
        "tiles_source": checked.proposed.tiles_source,
        "frames_source": f"imported: {Path(spec.telemetry_csv).name}",
        "spec": {
            "kind": "import",
            "images_dir": checked.images_dir.name,
            "telemetry_csv": Path(spec.telemetry_csv).name,
            "calibration_json": Path(spec.calibration_json).name,
            "store": Path(spec.store).name,
            "uncertainty_m": spec.uncertainty_m,
            "candidates": spec.candidates,
            "candidate_size_px": spec.candidate_size_px,
            "zoom": zoom,
            "seed": spec.seed,
            **(
                {}
                if spec.ground_elevation_m is None
                else {"ground_elevation_m": spec.ground_elevation_m}
            ),
            **({} if spec.dem is None else {"dem": Path(spec.dem).name}),
        },
        "attribution": checked.proposed.attribution,
    }


def _csv_report(checked: _CheckedCsv, spec: ImportSpec, out: Path, frames: int) -> ImportReport:
    """What the import of ``frames`` frames into ``out`` did."""
    heights = [r.altitude_m for r in checked.rows]
    return ImportReport(
        dataset=str(out),
        source=Path(spec.telemetry_csv).name,
        kind="telemetry CSV",
        frames=frames,
        skipped=tuple(checked.skipped),
        time_source=f"column {checked.table.columns['time_s']!r}",
        time_offset_s=0.0,
        height_sources={checked.table.height_source: frames},
        attitude_assumed=(),
        height_assumed=(),
        gnss_degraded=(),
        zoom=checked.proposed.zoom,
        notes=(
            f"heights above ground {min(heights):.1f} to {max(heights):.1f} m; altitudes above "
            "sea level go in a column altitude_msl_m, with --ground-elevation or --dem",
        ),
    )
