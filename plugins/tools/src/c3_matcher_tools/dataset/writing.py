"""Writing a ``c3-flight/1`` dataset, the files :mod:`c3_matcher_tools.dataset.format` reads,
under the names it gives them: every writer (``dataset render``, ``dataset import`` from a CSV
or from a log) ends here."""

from __future__ import annotations

import json
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher import dto
from c3_matcher_tools.dataset.format import (
    CALIBRATION_FILE,
    FORMAT,
    FRAMES_FILE,
    META_FILE,
    STORE_FILE,
    FrameRecord,
)

__all__ = ["calibration_to_json", "write_dataset"]


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
    *,
    store: Path,
) -> Path:
    """Write a dataset under ``root``, its frame images already there: the tile store ``store``
    copied in, the calibration, the frames and the description (the format and the files, then
    ``meta``: its ``name`` first, then how the dataset was made)."""
    root.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(store, root / STORE_FILE)
    described = {
        "format": FORMAT,
        "calibration": CALIBRATION_FILE,
        "frames": FRAMES_FILE,
        "name": meta["name"],
        "store": STORE_FILE,
        **meta,
    }
    (root / CALIBRATION_FILE).write_text(json.dumps(calibration_to_json(calibration), indent=1))
    with (root / FRAMES_FILE).open("w", encoding="utf-8") as fh:
        for f in frames:
            fh.write(json.dumps(f.to_json()) + "\n")
    (root / META_FILE).write_text(json.dumps(described, indent=2) + "\n")
    return root
