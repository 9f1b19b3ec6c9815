"""The flight dataset format (``c3-flight/1``): simulated or recorded frames, their attitude and
calibration, per frame a RerankResult of candidate tile ids in a tile store, and ground truth.

Layout of a dataset directory::

    dataset.json       {"format": "c3-flight/1", "name", "store": "tiles.mbtiles",
                        "candidate_size_px", "calibration": "calibration.json",
                        "frames": "frames.jsonl", "spec": {how it was made}, "attribution"}
    calibration.json   {"K", "distortion", "image_size"} (the ``c3-matcher match`` format)
    frames.jsonl       one JSON object per frame, see :class:`FrameRecord`
    frames/*.jpg       the nav-camera frames as captured (distorted), RGB JPEG
    tiles.mbtiles      the tile store the candidates' ids refer to (MBTiles, web mercator)

A frame record: ``index``, ``frame_id`` (UUID), ``image`` (path relative to the dataset),
``captured_at_ns``, ``attitude_deg`` [roll, pitch, yaw] (Z-Y-X, NED, yaw from north),
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
import json
import math
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher import dto
from c3_matcher.errors import InvalidInputError
from c3_matcher.serialize import load_calibration
from c3_matcher.tiles import DEFAULT_MAX_IMAGE_PIXELS, read_image
from c3_matcher.tilestore.mbtiles import MBTilesStore

__all__ = [
    "FORMAT",
    "CandidateTruth",
    "FlightDataset",
    "FrameRecord",
    "load_dataset",
    "with_attitude_noise",
    "write_dataset",
]

FORMAT = "c3-flight/1"


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
    def from_json(cls, data: dict[str, Any]) -> CandidateTruth:
        z, lat, lon = data["tile_id"]
        h = data.get("h_tile_to_undistorted")
        is_true = data.get("is_true")
        distance = data.get("distance_m")
        return cls(
            dto.TileId(int(z), float(lat), float(lon)),
            float(data.get("score", 1.0)),
            None if is_true is None else bool(is_true),
            None if distance is None else float(distance),
            None if h is None else np.asarray(h, dtype=np.float64).reshape(3, 3),
        )


@dataclass(frozen=True)
class FrameRecord:
    """One frame of a flight (see the module docstring); angles in degrees."""

    index: int
    frame_id: uuid.UUID
    image: str
    captured_at_ns: int
    attitude_deg: tuple[float, float, float]
    height_m: float
    candidates: tuple[CandidateTruth, ...]
    pose: dict[str, Any] = field(default_factory=dict)
    telemetry: dict[str, Any] = field(default_factory=dict)

    @property
    def has_truth(self) -> bool:
        """The record says which candidate is the true tile (a simulated flight)."""
        return bool(self.candidates) and all(c.has_truth for c in self.candidates)

    @property
    def true_tile_present(self) -> bool:
        """The true tile is among the candidates (False as well when there is no truth)."""
        return any(bool(c.is_true) for c in self.candidates)

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
    def from_json(cls, data: dict[str, Any]) -> FrameRecord:
        r, p, y = (float(a) for a in data["attitude_deg"])
        return cls(
            int(data["index"]),
            uuid.UUID(str(data["frame_id"])),
            str(data["image"]),
            int(data["captured_at_ns"]),
            (r, p, y),
            float(data["height_m"]),
            tuple(CandidateTruth.from_json(c) for c in data["candidates"]),
            dict(data.get("pose", {})),
            dict(data.get("telemetry", {})),
        )


@dataclass(frozen=True)
class FlightDataset:
    """A loaded dataset: its directory, metadata, calibration and frame records;
    ``max_image_pixels``: the largest frame (width x height) ``nav_frame`` decodes
    (``[matcher] max_image_pixels``)."""

    root: Path
    meta: dict[str, Any]
    calibration: dto.CameraCalibration
    frames: tuple[FrameRecord, ...]
    max_image_pixels: int = DEFAULT_MAX_IMAGE_PIXELS

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
        frames.append(dataclasses.replace(frame, attitude_deg=(roll, pitch, yaw)))
    meta = {**dataset.meta, "attitude_noise": {"sigma_deg": sigma_deg, "seed": seed}}
    return dataclasses.replace(dataset, meta=meta, frames=tuple(frames))


def calibration_to_json(calibration: dto.CameraCalibration) -> dict[str, Any]:
    out: dict[str, Any] = {
        "K": calibration.K.tolist(),
        "distortion": calibration.distortion.tolist(),
        "image_size": list(calibration.image_size),
    }
    if calibration.camera_to_body is not None:
        out["camera_to_body"] = np.asarray(calibration.camera_to_body).tolist()
    return out


def write_dataset(
    root: Path,
    meta: dict[str, Any],
    calibration: dto.CameraCalibration,
    frames: Sequence[FrameRecord],
) -> Path:
    """Write ``dataset.json``, ``calibration.json`` and ``frames.jsonl`` under ``root`` (the
    frame images and the store must already be there)."""
    root.mkdir(parents=True, exist_ok=True)
    full = {
        "format": FORMAT,
        "calibration": "calibration.json",
        "frames": "frames.jsonl",
        **meta,
    }
    (root / "calibration.json").write_text(json.dumps(calibration_to_json(calibration), indent=1))
    with (root / "frames.jsonl").open("w", encoding="utf-8") as fh:
        for f in frames:
            fh.write(json.dumps(f.to_json()) + "\n")
    (root / "dataset.json").write_text(json.dumps(full, indent=2) + "\n")
    return root


def load_dataset(
    root: str | Path, max_image_pixels: int = DEFAULT_MAX_IMAGE_PIXELS
) -> FlightDataset:
    """Read a dataset directory, naming what is missing or malformed; its frames are decoded
    up to ``max_image_pixels`` (width x height)."""
    base = Path(root)
    meta_path = base / "dataset.json"
    if not meta_path.is_file():
        raise InvalidInputError("dataset", f"{base}: no dataset.json (not a {FORMAT} dataset)")
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise InvalidInputError("dataset", f"{meta_path}: unreadable: {exc}") from exc
    if meta.get("format") != FORMAT:
        raise InvalidInputError(
            "dataset", f"{meta_path}: format {meta.get('format')!r}, expected {FORMAT!r}"
        )
    for key in ("store", "candidate_size_px", "frames", "calibration"):
        if key not in meta:
            raise InvalidInputError("dataset", f"{meta_path}: missing key {key!r}")
    calibration = load_calibration(base / str(meta["calibration"]))
    frames = []
    frames_path = base / str(meta["frames"])
    try:
        lines = frames_path.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise InvalidInputError("dataset", f"{frames_path}: unreadable: {exc}") from exc
    for n, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            frames.append(FrameRecord.from_json(json.loads(line)))
        except (KeyError, TypeError, ValueError, json.JSONDecodeError) as exc:
            raise InvalidInputError(
                "dataset", f"{frames_path}:{n}: bad frame record: {exc!r}"
            ) from exc
    if not (base / str(meta["store"])).is_file():
        raise InvalidInputError("dataset", f"{base / str(meta['store'])}: tile store missing")
    return FlightDataset(base, meta, calibration, tuple(frames), max_image_pixels)
