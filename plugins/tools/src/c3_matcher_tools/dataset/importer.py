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
    altitude_m          height above ground (AGL, not above the ellipsoid / MSL)    metres
      (altitude,
      height_m, agl_m)
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

Everything is checked before anything is written; the dataset is written into a temporary
sibling directory and renamed into place.
"""

from __future__ import annotations

import csv
import itertools
import math
import shutil
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from c3_matcher.camera import rotation_world_from_camera
from c3_matcher.dto import Attitude, CameraCalibration, TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.serialize import load_calibration
from c3_matcher.tilestore.base import tile_centre_id
from c3_matcher.tilestore.geo import TILE_PX, lonlat_to_world_px
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher_tools.dataset.atomic import atomic_directory, check_output_dir
from c3_matcher_tools.dataset.format import CandidateTruth, FrameRecord, write_dataset

__all__ = ["COLUMNS", "ImportSpec", "TelemetryRow", "import_flight", "look_point", "read_telemetry"]

#: canonical column -> accepted header names (case-insensitive)
COLUMNS: dict[str, tuple[str, ...]] = {
    "time_s": ("time_s", "time"),
    "image": ("image", "file", "filename", "image_file"),
    "lat": ("lat", "latitude"),
    "lon": ("lon", "longitude"),
    "altitude_m": ("altitude_m", "altitude", "height_m", "agl_m"),
    "roll_deg": ("roll_deg", "roll"),
    "pitch_deg": ("pitch_deg", "pitch"),
    "yaw_deg": ("yaw_deg", "yaw"),
}
M_PER_DEG_LAT = 111_320.0
MAX_PROBLEMS = 10


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

    def __post_init__(self) -> None:
        if not (math.isfinite(self.uncertainty_m) and self.uncertainty_m >= 0):
            raise InvalidInputError("--uncertainty-m", f"must be >= 0, got {self.uncertainty_m}")
        if self.candidates < 1:
            raise InvalidInputError("--candidates", f"must be >= 1, got {self.candidates}")
        if not 64 <= self.candidate_size_px <= 4096:
            raise InvalidInputError(
                "--candidate-size", f"must be in [64, 4096], got {self.candidate_size_px}"
            )


def _column_map(header: list[str], path: Path) -> dict[str, str]:
    lowered = {h.strip().lower(): h for h in header}
    found: dict[str, str] = {}
    missing = []
    for name, aliases in COLUMNS.items():
        hit = next((lowered[a] for a in aliases if a in lowered), None)
        if hit is None:
            missing.append(f"{name} (or {', '.join(aliases[1:])})" if aliases[1:] else name)
        else:
            found[name] = hit
    if missing:
        raise InvalidInputError(
            str(path), f"telemetry CSV lacks column(s) {'; '.join(missing)}; header: {header}"
        )
    return found


def read_telemetry(path: Path) -> list[TelemetryRow]:
    """Read and check a telemetry CSV (see the module docstring), sorted by time; raises
    InvalidInputError naming up to ten bad lines."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InvalidInputError(str(path), f"unreadable telemetry CSV: {exc}") from None
    reader = csv.DictReader(text.splitlines())
    if not reader.fieldnames:
        raise InvalidInputError(str(path), "empty telemetry CSV (no header)")
    cols = _column_map(list(reader.fieldnames), path)
    rows: list[TelemetryRow] = []
    problems: list[str] = []
    for n, rec in enumerate(reader, start=2):
        try:
            values = {k: float(str(rec[cols[k]]).strip()) for k in COLUMNS if k != "image"}
            image = str(rec[cols["image"]] or "").strip()
        except (TypeError, ValueError) as exc:
            problems.append(f"line {n}: {exc}")
            continue
        bad = [k for k, v in values.items() if not math.isfinite(v)]
        if bad:
            problems.append(f"line {n}: not finite: {', '.join(bad)}")
            continue
        if not image:
            problems.append(f"line {n}: empty image name")
        elif not -90.0 <= values["lat"] <= 90.0 or not -180.0 <= values["lon"] <= 180.0:
            problems.append(f"line {n}: lat/lon out of range ({values['lat']}, {values['lon']})")
        elif values["altitude_m"] <= 0.0:
            problems.append(f"line {n}: altitude_m must be > 0 m above ground")
        elif abs(values["roll_deg"]) >= 90.0 or abs(values["pitch_deg"]) >= 90.0:
            problems.append(f"line {n}: |roll| and |pitch| must be < 90 deg (degrees, not rad?)")
        else:
            rows.append(TelemetryRow(n, image=image, **values))
    if not rows and not problems:
        problems.append("no data rows")
    seen: dict[str, int] = {}
    for r in rows:
        if r.image in seen:
            problems.append(f"line {r.line}: image {r.image!r} already on line {seen[r.image]}")
        seen[r.image] = r.line
    rows.sort(key=lambda r: (r.time_s, r.line))
    for a, b in itertools.pairwise(rows):
        if b.time_s == a.time_s:
            problems.append(f"lines {a.line} and {b.line}: same time_s {a.time_s}")
    if problems:
        more = f" (+{len(problems) - MAX_PROBLEMS} more)" if len(problems) > MAX_PROBLEMS else ""
        raise InvalidInputError(str(path), "; ".join(problems[:MAX_PROBLEMS]) + more)
    return rows


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


def _propose(
    store: MBTilesStore, zoom: int, lonlat: tuple[float, float], spec: ImportSpec
) -> list[tuple[TileId, float]] | None:
    """(tile id, distance m from the point to the tile square) of the candidates, the tile
    holding the point first; None when the store lacks that tile."""
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


def _check_image(path: Path, calibration: CameraCalibration) -> str | None:
    if not path.is_file():
        return "no such file"
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        return "not a readable image"
    h, w = image.shape[:2]
    if (w, h) != tuple(calibration.image_size):
        return f"is {w}x{h} px, the calibration says {calibration.image_size[0]}x" + str(
            calibration.image_size[1]
        )
    return None


def import_flight(
    spec: ImportSpec, out: Path, *, name: str | None = None, force: bool = False
) -> dict[str, Any]:
    """Check every input, then write the dataset ``out`` atomically; returns a summary.
    Raises InvalidInputError naming the input at fault (nothing is written then)."""
    out = Path(out)
    check_output_dir(out, force=force)
    images_dir = Path(spec.images_dir)
    if not images_dir.is_dir():
        raise InvalidInputError("IMAGES_DIR", f"{images_dir}: not a directory")
    if not Path(spec.store).is_file():
        raise InvalidInputError("STORE", f"{spec.store}: no such tile store")
    calibration = load_calibration(Path(spec.calibration_json))
    rows = read_telemetry(Path(spec.telemetry_csv))
    problems = []
    for r in rows:
        why = _check_image(images_dir / r.image, calibration)
        if why:
            problems.append(f"line {r.line}: {r.image}: {why}")
    if problems:
        raise InvalidInputError("IMAGES_DIR", f"{images_dir}: " + "; ".join(problems[:10]))
    with MBTilesStore(spec.store) as store:
        zooms = store.zooms()
        if not zooms:
            raise InvalidInputError("STORE", f"{spec.store}: holds no tiles")
        zoom = zooms[-1] if spec.zoom is None else spec.zoom
        if zoom not in zooms:
            raise InvalidInputError("--zoom", f"{zoom} not in the store's zooms {zooms}")
        proposals = []
        outside = []
        for r in rows:
            lonlat = look_point(r, calibration)
            cands = _propose(store, zoom, lonlat, spec)
            if cands is None:
                outside.append(f"line {r.line} ({r.lat:.6f}, {r.lon:.6f})")
            proposals.append((lonlat, cands))
        attribution = store.metadata.get("attribution", "")
        tiles_source = store.metadata.get("c3_source", "")
    if outside:
        raise InvalidInputError(
            "TELEMETRY",
            f"{len(outside)} frame(s) look outside the store's coverage at zoom {zoom}: "
            + ", ".join(outside[:10]),
        )
    frames: list[FrameRecord] = []
    t0 = rows[0].time_s
    base = uuid.uuid5(uuid.NAMESPACE_URL, f"c3-flight-import:{name or out.name}")
    for i, (r, (lonlat, cands)) in enumerate(zip(rows, proposals, strict=True)):
        assert cands is not None
        order = np.random.default_rng([spec.seed, i]).permutation(len(cands))
        ext = Path(r.image).suffix.lower() or ".jpg"
        frames.append(
            FrameRecord(
                index=i,
                frame_id=uuid.uuid5(base, r.image),
                image=f"frames/{i:06d}{ext}",
                captured_at_ns=round((r.time_s - t0) * 1e9),
                attitude_deg=(r.roll_deg, r.pitch_deg, r.yaw_deg),
                height_m=r.altitude_m,
                candidates=tuple(
                    CandidateTruth(cands[j][0], round(0.9 - 0.1 * k, 3))
                    for k, j in enumerate(order)
                ),
                telemetry={
                    "lat": r.lat,
                    "lon": r.lon,
                    "altitude_m": r.altitude_m,
                    "time_s": r.time_s,
                    "source_image": r.image,
                    "look_lat": lonlat[1],
                    "look_lon": lonlat[0],
                    "uncertainty_m": spec.uncertainty_m,
                },
            )
        )
    meta = {
        "name": name or out.name,
        "store": "tiles.mbtiles",
        "candidate_size_px": spec.candidate_size_px,
        "zoom": zoom,
        "tiles_source": tiles_source,
        "frames_source": f"imported: {Path(spec.telemetry_csv).name}",
        "spec": {
            "kind": "import",
            "images_dir": images_dir.name,
            "telemetry_csv": Path(spec.telemetry_csv).name,
            "calibration_json": Path(spec.calibration_json).name,
            "store": Path(spec.store).name,
            "uncertainty_m": spec.uncertainty_m,
            "candidates": spec.candidates,
            "candidate_size_px": spec.candidate_size_px,
            "zoom": zoom,
            "seed": spec.seed,
        },
        "attribution": attribution,
    }
    with atomic_directory(out, force=force) as tmp:
        (tmp / "frames").mkdir()
        for r, f in zip(rows, frames, strict=True):
            shutil.copyfile(images_dir / r.image, tmp / f.image)
        shutil.copyfile(spec.store, tmp / "tiles.mbtiles")
        write_dataset(tmp, meta, calibration, frames)
    return {"dataset": str(out), "frames": len(frames), "zoom": zoom}
