"""The flight dataset format (``c3-flight/1``): simulated or recorded frames, their attitude and
calibration, per frame a RerankResult of candidate tile ids in a tile store, and ground truth.

Layout of a dataset directory::

    dataset.json       {"format": "c3-flight/1", "name", "store": "tiles.mbtiles",
                        "candidate_size_px", "calibration": "calibration.json",
                        "frames": "frames.jsonl", "spec": {how, by what}, "attribution"}
    calibration.json   {"K", "distortion", "image_size"} (the ``c3-matcher match`` format)
    frames.jsonl       one JSON object per frame, see :class:`FrameRecord`
    frames/*.jpg       the nav-camera frames as captured (distorted), RGB JPEG
    tiles.mbtiles      the tile store the candidates' ids refer to (MBTiles, web mercator)

A frame record: ``index``, ``frame_id`` (UUID), ``image`` (path relative to the dataset),
``captured_at_ns``, ``attitude_deg`` [roll, pitch, yaw] (Z-Y-X, NED, yaw from true north),
``height_m`` above ground, ``true_tile_present``, ``candidates`` in C2.5's order, each
``{"tile_id": [zoom, lat, lon], "score", "is_true", "distance_m" (candidate centre to the
footprint centre), "h_tile_to_undistorted": 3x3}``: the ground-truth homography from the
candidate image's pixels (``candidate_size_px`` square, centred on the id, see
:mod:`c3_matcher.tilestore.handles`) to UNDISTORTED frame pixels (apply the calibration's
distortion to get ORIGINAL frame pixels), and ``pose`` (nadir lat/lon, ground centre, ...).

Ground truth is optional (a recorded flight has none): a candidate may carry only ``tile_id``
and ``score``; a frame whose candidates all lack ``is_true`` has no truth (``has_truth``
False) and is replayed without scoring. ``telemetry`` (optional) holds what the vehicle
reported: ``lat``, ``lon``, ``altitude_m``, the candidates' search radius ``uncertainty_m``.
"""

from __future__ import annotations

import dataclasses
import math
import unicodedata
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher import dto
from c3_matcher.errors import InvalidInputError, describe
from c3_matcher.file_kinds import special_kind
from c3_matcher.json_text import loads_json
from c3_matcher.serialize import load_calibration
from c3_matcher.tiles import DEFAULT_MAX_IMAGE_PIXELS, read_image
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher_tools.dataset.image_names import is_utf8
from c3_matcher_tools.dataset.inside import (
    META_PATHS,
    check_meta_paths,
    inside_name,
    leads_outside,
    real_root,
)
from c3_matcher_tools.dataset.json_values import (
    json_integer,
    json_number,
    json_object,
    json_text,
    pose_values,
    telemetry_values,
)
from c3_matcher_tools.dataset.provenance import ImportFault, import_faults

__all__ = [
    "CALIBRATION_FILE",
    "CANDIDATE_SIZE_PX",
    "FORMAT",
    "FRAMES_FILE",
    "META_FILE",
    "STORE_FILE",
    "CandidateTruth",
    "FlightDataset",
    "FrameRecord",
    "check_candidate_size",
    "dataset_name",
    "is_flight_dataset",
    "load_dataset",
    "name_problem",
    "with_attitude_noise",
]

FORMAT = "c3-flight/1"
META_FILE = "dataset.json"
"""A dataset directory's description: its format, its files, how it was made."""
STORE_FILE = "tiles.mbtiles"
CALIBRATION_FILE = "calibration.json"
FRAMES_FILE = "frames.jsonl"
CANDIDATE_SIZE_PX = (64, 4096)
"""The side (px) of a dataset's candidate windows: import and render write, and a load accepts,
only sizes in this range."""
_INT64_MAX = 2**63 - 1  # frame indices and capture times are recorded as int64


def is_flight_dataset(path: str | Path) -> bool:
    """``path`` is a directory that describes a dataset (holds :data:`META_FILE`)."""
    return (Path(path) / META_FILE).is_file()


def name_problem(name: str) -> str | None:
    """Why ``name`` cannot name a dataset (it names the dataset's default output directory), or
    None: it must be one plain path component, so that it never puts a run's files outside the
    directory they are meant for, of UTF-8 text without control characters (C0, DEL and C1:
    ESC, CR, LF, BEL among them), so that it prints as what it says."""
    if name in ("", ".", "..") or any(c in name for c in "/\\\0"):
        return (
            "cannot name an output directory: it must be one path component "
            "(not empty, '.' or '..'; no '/', '\\' or NUL)"
        )
    if not is_utf8(name):
        return (
            "is not UTF-8 text: it holds a byte of another encoding (a file name's) or a lone "
            "surrogate"
        )
    controls = sorted({f"U+{ord(c):04X}" for c in name if unicodedata.category(c) == "Cc"})
    if controls:
        return (
            f"holds control characters ({', '.join(controls)}): a name is written into folder "
            "names and progress lines, where they would move the cursor or end the line"
        )
    return None


def dataset_name(given: str | None, out: Path) -> str:
    """The name of the dataset written to ``out``: ``given`` (``--name``, checked as it was
    read) or ``out``'s own name, refused (``InvalidInputError`` naming OUT, quoted with its
    escapes: the message is printed) where that cannot name a dataset (:func:`name_problem`): a
    name is JSON text in ``dataset.json`` and drawn in charts, which a byte that is no UTF-8 is
    not."""
    if given:
        return given
    why = name_problem(out.name)
    if why:
        raise InvalidInputError(
            "OUT", f"{str(out)!r}: its name {why}; give the dataset one with --name"
        )
    return out.name


def check_candidate_size(size_px: int, field: str = "--candidate-size") -> None:
    """InvalidInputError naming ``field`` unless ``size_px`` is in :data:`CANDIDATE_SIZE_PX`."""
    low, high = CANDIDATE_SIZE_PX
    if not low <= size_px <= high:
        raise InvalidInputError(field, f"must be in [{low}, {high}] px, got {size_px}")


@dataclass(frozen=True)
class CandidateTruth:
    """One candidate of a frame and its ground truth (see the module docstring)."""

    tile_id: dto.TileId
    score: float
    is_true: bool | None = None
    distance_m: float | None = None
    h_tile_to_undistorted: NDArray[np.float64] | None = None

    @property
    def has_truth(self) -> bool:
        return self.is_true is not None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"tile_id": self.tile_id.as_list(), "score": self.score}
        if self.is_true is not None:
            out["is_true"] = self.is_true
        if self.distance_m is not None:
            out["distance_m"] = round(self.distance_m, 3)
        if self.h_tile_to_undistorted is not None:
            out["h_tile_to_undistorted"] = self.h_tile_to_undistorted.tolist()
        return out

    @classmethod
    def from_json(cls, data: object) -> CandidateTruth:
        """A candidate as ``frames.jsonl`` holds it, every value checked (InvalidInputError
        naming the key)."""
        cand = json_object(data, "candidate")
        tile = cand["tile_id"]
        if not isinstance(tile, list) or len(tile) != 3:
            raise InvalidInputError("candidate.tile_id", f"expected [zoom, lat, lon], got {tile!r}")
        is_true = cand.get("is_true")
        if is_true is not None and not isinstance(is_true, bool):
            raise InvalidInputError("candidate.is_true", f"expected true or false, got {is_true!r}")
        distance = cand.get("distance_m")
        h = cand.get("h_tile_to_undistorted")
        homography = None if h is None else np.asarray(h, dtype=np.float64).reshape(3, 3)
        if homography is not None and not np.isfinite(homography).all():
            raise InvalidInputError("candidate.h_tile_to_undistorted", "not finite")
        if homography is not None and not np.linalg.cond(homography) < 1e12:
            raise InvalidInputError(
                "candidate.h_tile_to_undistorted", "singular: it places the tile on no frame"
            )
        return cls(
            dto.TileId(*tile),
            json_number(cand.get("score", 1.0), "candidate.score"),
            is_true,
            None if distance is None else json_number(distance, "candidate.distance_m", low=0.0),
            homography,
        )


@dataclass(frozen=True)
class FrameRecord:
    """One frame of a flight (see the module docstring); angles in degrees. ``recorded_deg``:
    the attitude the flight recorded, where a run replaced it by a noisy one (else None)."""

    index: int
    frame_id: uuid.UUID
    image: str
    captured_at_ns: int
    attitude_deg: tuple[float, float, float]
    height_m: float
    candidates: tuple[CandidateTruth, ...]
    pose: dict[str, Any] = field(default_factory=dict)
    telemetry: dict[str, Any] = field(default_factory=dict)
    recorded_deg: tuple[float, float, float] | None = None

    @property
    def has_truth(self) -> bool:
        """The record says which candidate is the true tile (a simulated flight)."""
        return bool(self.candidates) and all(c.has_truth for c in self.candidates)

    @property
    def true_tile_present(self) -> bool:
        """The true tile is among the candidates (False as well when there is no truth, as in
        a frame whose candidates are only partly labelled)."""
        return self.has_truth and any(bool(c.is_true) for c in self.candidates)

    @property
    def true_index(self) -> int | None:
        """Input position of the true candidate, None when it is absent."""
        return next((i for i, c in enumerate(self.candidates) if c.is_true), None)

    @property
    def attitude(self) -> dto.Attitude:
        return dto.Attitude.from_degrees(*self.attitude_deg)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "index": self.index,
            "frame_id": str(self.frame_id),
            "image": self.image,
            "captured_at_ns": self.captured_at_ns,
            "attitude_deg": [round(a, 6) for a in self.attitude_deg],
            "height_m": self.height_m,
        }
        if self.has_truth:
            out["true_tile_present"] = self.true_tile_present
        out["candidates"] = [c.to_json() for c in self.candidates]
        out["pose"] = self.pose
        if self.telemetry:
            out["telemetry"] = self.telemetry
        return out

    @classmethod
    def from_json(cls, data: object) -> FrameRecord:
        """A record as ``frames.jsonl`` holds it, every value replay uses checked as the
        matcher would check it (InvalidInputError naming the key)."""
        record = json_object(data, "record")
        angles = record["attitude_deg"]
        if not isinstance(angles, list) or len(angles) != 3:
            raise InvalidInputError("attitude_deg", f"expected [roll, pitch, yaw], got {angles!r}")
        roll, pitch, yaw = (json_number(a, "attitude_deg") for a in angles)
        try:  # the matcher's bounds on each angle
            dto.Attitude.from_degrees(roll, pitch, yaw)
        except InvalidInputError as exc:
            raise InvalidInputError(
                "attitude_deg", f"{angles} out of range ({exc}, in rad)"
            ) from exc
        height, highest = json_number(record["height_m"], "height_m"), dto.MAX_HEIGHT_ABOVE_GROUND_M
        if not 0.0 < height <= highest:
            why = f"must be > 0 and <= {highest:g} m above ground, got {height:g}"
            raise InvalidInputError("height_m", why)
        candidates = record["candidates"]
        if not isinstance(candidates, list) or not candidates:
            raise InvalidInputError("candidates", f"expected a non-empty list, got {candidates!r}")
        return cls(
            json_integer(record["index"], "index", 0, _INT64_MAX),
            uuid.UUID(json_text(record["frame_id"], "frame_id")),
            inside_name(record["image"], "image"),
            json_integer(record["captured_at_ns"], "captured_at_ns", 0, _INT64_MAX),
            (roll, pitch, yaw),
            height,
            tuple(CandidateTruth.from_json(c) for c in candidates),
            pose_values(record.get("pose", {})),
            telemetry_values(record.get("telemetry", {})),
        )


@dataclass(frozen=True)
class FlightDataset:
    """A loaded dataset: its directory, metadata, calibration and frame records;
    ``max_image_pixels``: the largest frame (width x height) ``nav_frame`` decodes
    (``[matcher] max_image_pixels``); ``import_faults``: what the importer that made it is known
    to have got wrong, fixed since (:mod:`c3_matcher_tools.dataset.provenance`)."""

    root: Path
    meta: dict[str, Any]
    calibration: dto.CameraCalibration
    frames: tuple[FrameRecord, ...]
    max_image_pixels: int = DEFAULT_MAX_IMAGE_PIXELS
    import_faults: tuple[ImportFault, ...] = ()

    @property
    def name(self) -> str:
        return str(self.meta.get("name", self.root.name))

    @property
    def candidate_size_px(self) -> int:
        return int(self.meta["candidate_size_px"])

    @property
    def store_path(self) -> Path:
        return self.root / str(self.meta["store"])

    def open_store(self) -> MBTilesStore:
        return MBTilesStore(self.store_path)

    def nav_frame(self, frame: FrameRecord) -> dto.NavCameraFrame:
        """The frame as C1 delivers it: pixels read from the dataset, attitude and height."""
        return dto.NavCameraFrame(
            frame.frame_id,
            read_image(self.root / frame.image, self.max_image_pixels),
            frame.captured_at_ns,
            frame.attitude,
            frame.height_m,
        )

    def rerank(self, frame: FrameRecord, store: MBTilesStore) -> dto.RerankResult:
        """The frame's RerankResult: lazy handles on ``store`` in the recorded order."""
        return dto.RerankResult(
            frame.frame_id,
            tuple(
                dto.RerankCandidate(
                    c.tile_id,
                    c.score,
                    store.handle(c.tile_id, self.candidate_size_px),
                    c.tile_id.web_mercator_gsd_m(),
                )
                for c in frame.candidates
            ),
        )


def with_attitude_noise(dataset: FlightDataset, sigma_deg: float, seed: int = 0) -> FlightDataset:
    """``dataset`` as an IMU with ``sigma_deg`` (1-sigma, each of roll, pitch and yaw) of
    attitude error would report it: every frame's recorded attitude plus Gaussian noise drawn
    from a generator seeded with (``seed``, frame index), so a frame gets the same error in
    every run and every subset. Pixels and ground truth stay those of the true pose; the
    dataset's ``meta`` records the noise. 0 returns ``dataset`` itself."""
    if not math.isfinite(sigma_deg) or sigma_deg < 0:
        raise ValueError(f"attitude noise must be finite and >= 0 deg, got {sigma_deg}")
    if sigma_deg == 0:
        return dataset
    frames = []
    for frame in dataset.frames:
        noise = np.random.default_rng([seed, frame.index]).normal(0.0, sigma_deg, 3)
        roll, pitch, yaw = (a + float(n) for a, n in zip(frame.attitude_deg, noise, strict=True))
        recorded = frame.recorded_deg or frame.attitude_deg
        frames.append(
            dataclasses.replace(frame, attitude_deg=(roll, pitch, yaw), recorded_deg=recorded)
        )
    meta = {**dataset.meta, "attitude_noise": {"sigma_deg": sigma_deg, "seed": seed}}
    return dataclasses.replace(dataset, meta=meta, frames=tuple(frames))


_MAX_ZOOM = 30  # a tile id's zoom range, see dto.TileId


def _meta(path: Path) -> dict[str, Any]:
    """``dataset.json`` read and checked, every key a run or ``dataset info`` reads, once: a
    ``c3-flight/1`` object with its keys, the files it names as paths inside the dataset and a
    candidate size in :data:`CANDIDATE_SIZE_PX`; where present, a ``name`` a run can name its
    output directory after (:func:`name_problem`), a ``zoom`` in [0, 30], ``absent_frames`` as a
    list of frame indices, the sources and credits as strings, the fit residual a number >= 0
    and ``spec`` / ``import`` / ``attitude_noise`` as objects (InvalidInputError naming the file
    and key)."""
    try:
        meta = json_object(loads_json(path.read_text(encoding="utf-8")), "top level")
        if meta.get("format") != FORMAT:
            raise InvalidInputError("format", f"{meta.get('format')!r}, expected {FORMAT!r}")
        for key in META_PATHS:  # each a file inside the dataset (dataset.inside)
            inside_name(meta[key], key)
        json_integer(meta["candidate_size_px"], "candidate_size_px", *CANDIDATE_SIZE_PX)
        _optional_meta(meta)
    except (KeyError, OSError, ValueError) as exc:  # JSON and UTF-8 errors among them
        raise InvalidInputError("dataset", f"{path}: {_why(exc)}") from exc
    return meta


def _optional_meta(meta: dict[str, Any]) -> None:
    """The optional keys of ``dataset.json`` checked where present (see :func:`_meta`)."""
    if "name" in meta:
        name = meta["name"]
        why = name_problem(name) if isinstance(name, str) else "expected a string"
        if why:
            raise InvalidInputError("name", f"{name!r}: {why}")
    if "zoom" in meta:
        json_integer(meta["zoom"], "zoom", 0, _MAX_ZOOM)
    if "absent_frames" in meta:
        absent = meta["absent_frames"]
        if not isinstance(absent, list):
            why = f"expected a list of frame indices, got {absent!r}"
            raise InvalidInputError("absent_frames", why)
        for index in absent:
            json_integer(index, "absent_frames", 0, _INT64_MAX)
    for key in ("tiles_source", "frames_source", "georeference", "attribution"):
        if key in meta and not isinstance(meta[key], str):
            raise InvalidInputError(key, f"expected a string, got {meta[key]!r}")
    if "gt_fit_max_residual_px" in meta:
        json_number(meta["gt_fit_max_residual_px"], "gt_fit_max_residual_px", low=0.0)
    for key in ("spec", "import", "attitude_noise"):
        if key in meta:
            json_object(meta[key], key)


def _why(exc: Exception) -> str:
    """What a read or check error says, in one line."""
    if isinstance(exc, KeyError):
        return f"missing key {exc}"
    if isinstance(exc, InvalidInputError):
        return str(exc)
    return describe(exc)


def _frames(path: Path, root: Path) -> tuple[FrameRecord, ...]:
    """``frames.jsonl`` read and checked, naming the line of the first bad record (a frame id
    or index a line before already holds among them: results, records and reports are keyed by
    them; an image outside the dataset folder ``root``, by name or by a symbolic link:
    :mod:`~c3_matcher_tools.dataset.inside`); at least one frame. A FIFO or a device there is
    refused unread."""
    kind = special_kind(path)
    if kind is not None:
        raise InvalidInputError("dataset", f"{path}: is {kind}, not a file of frame records")
    try:
        lines = path.read_bytes().splitlines()
    except OSError as exc:
        raise InvalidInputError("dataset", f"{path}: unreadable: {exc}") from exc
    frames, real = [], real_root(root)
    first_line: dict[object, int] = {}  # frame id and index -> the line that holds it
    for n, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            frame = FrameRecord.from_json(loads_json(line.decode("utf-8")))
            if outside := leads_outside(real, root, frame.image):
                raise InvalidInputError("image", outside)
            for key, value in (("frame_id", frame.frame_id), ("index", frame.index)):
                if (key, value) in first_line:
                    raise InvalidInputError(key, f"{value} is line {first_line[key, value]}'s too")
                first_line[key, value] = n
        except (KeyError, TypeError, ValueError, OverflowError) as exc:  # JSON, UTF-8 among them
            raise InvalidInputError(
                "dataset", f"{path}:{n}: bad frame record: {_why(exc)}"
            ) from exc
        frames.append(frame)
    if not frames:
        raise InvalidInputError("dataset", f"{path}: no frames")
    return tuple(frames)


def load_dataset(
    root: str | Path, max_image_pixels: int = DEFAULT_MAX_IMAGE_PIXELS
) -> FlightDataset:
    """Read a dataset directory, naming what is missing or malformed (the file, and the line of
    ``frames.jsonl``) before any frame is used, and every file it names inside the directory
    (:mod:`~c3_matcher_tools.dataset.inside`); its frames are decoded up to
    ``max_image_pixels`` (width x height). A dataset whose importer had a fault fixed since is
    loaded with its notes (``import_faults``), not refused."""
    base = Path(root)
    meta_path = base / META_FILE
    if base.name == META_FILE and base.is_file():  # the file, given for its directory
        raise InvalidInputError(
            "dataset", f"{base} is the dataset's file: give its directory {base.parent}"
        )
    if not meta_path.is_file():
        raise InvalidInputError("dataset", f"{base}: no {META_FILE} (not a {FORMAT} dataset)")
    meta = _meta(meta_path)
    check_meta_paths(base, meta_path, meta)
    calibration = load_calibration(base / meta["calibration"], field="dataset")
    frames = _frames(base / meta["frames"], base)
    if not (base / meta["store"]).is_file():
        raise InvalidInputError("dataset", f"{base / meta['store']}: tile store missing")
    faults = import_faults(base, meta, [f.telemetry for f in frames])
    return FlightDataset(base, meta, calibration, frames, max_image_pixels, faults)
