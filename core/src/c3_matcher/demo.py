"""The inputs of one ``match`` call read from a demo-format directory (``demo.json``: one
frame, its candidate tiles, the camera's calibration; ``data/demo`` is one): what ``bench``
and the tools' run layer read from such a directory, and what the core's tests match the
shipped demo frame with (it needs the core alone, so they read the demo without the ground
tools installed)."""

from __future__ import annotations

import json
import uuid
from pathlib import Path

from c3_matcher.dto.camera import CameraCalibration, NavCameraFrame
from c3_matcher.dto.candidates import RerankCandidate, RerankResult
from c3_matcher.dto.geo import Attitude, TileId
from c3_matcher.serialize import load_calibration
from c3_matcher.tiles import DEFAULT_MAX_IMAGE_PIXELS, MmapTileHandle, read_image

__all__ = ["MatchInputs", "demo_inputs"]

MatchInputs = tuple[NavCameraFrame, RerankResult, CameraCalibration]
"""One ``match`` call's arguments."""


def demo_inputs(data_dir: Path, max_pixels: int = DEFAULT_MAX_IMAGE_PIXELS) -> MatchInputs:
    """The frame of a demo-format directory with its candidate tiles (``demo.json``'s order),
    each image within ``max_pixels`` (``[matcher] max_image_pixels``)."""
    meta = json.loads((data_dir / "demo.json").read_text())
    att = meta["attitude_deg"]
    frame = NavCameraFrame(
        uuid.UUID(int=1),
        read_image(data_dir / "frame.jpg", max_pixels),
        1,
        Attitude.from_degrees(att["roll"], att["pitch"], att["yaw"]),
        meta["height_m"],
    )
    candidates = tuple(
        RerankCandidate(
            TileId(*t["tile_id"]),
            1.0,
            MmapTileHandle(data_dir / t["file"], max_pixels=max_pixels),
            meta["tile_gsd_m"],
        )
        for t in meta["tiles"]
    )
    calibration = load_calibration(data_dir / "calibration.json", field="--data")
    return frame, RerankResult(frame.frame_id, candidates), calibration
