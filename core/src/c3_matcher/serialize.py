"""The product's file and wire formats, written once: calibration JSON files and the
``MatchResult`` JSON that ``c3-matcher match`` prints and replay writes to ``results.jsonl``."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.dto import CameraCalibration, MatchResult
from c3_matcher.errors import InvalidInputError

__all__ = ["load_calibration", "result_to_json"]


MAX_CALIBRATION_BYTES = 1 << 20
"""A calibration file larger than this is refused unread (``--calibration`` naming an image, a
disk, ``/dev/zero``), not read into memory whole."""


CALIBRATION_SIZE_FIX = (
    "a calibration is for one image size: scale K and image_size by the ratio of the sizes, "
    "or calibrate at this size"
)
"""What to do about a calibration whose ``image_size`` is not the images' size."""
_REQUIRED_CALIBRATION_KEYS = {
    "K": "the 3x3 intrinsic matrix, px",
    "image_size": "[width, height] px of the images K was calibrated for",
}


def load_calibration(path: Path) -> CameraCalibration:
    """Read a calibration JSON: ``{"K": 3x3, "distortion": [k1, k2, p1, p2, k3...],
    "image_size": [width, height], "camera_to_body": 3x3 (optional)}``."""
    try:
        with Path(path).open("rb") as file:
            raw = file.read(MAX_CALIBRATION_BYTES + 1)
        if len(raw) > MAX_CALIBRATION_BYTES:
            raise InvalidInputError(
                f"--calibration {path}",
                f"larger than {MAX_CALIBRATION_BYTES} bytes: not a calibration (refused unread)",
            )
        data = json.loads(raw.decode("utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise InvalidInputError(f"--calibration {path}", f"unreadable: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise InvalidInputError(f"--calibration {path}", f"not UTF-8 text: {exc}") from None
    if not isinstance(data, dict):
        raise InvalidInputError(
            f"--calibration {path}",
            f"expected a JSON object with K, distortion, image_size; got {type(data).__name__}",
        )
    for key, what in _REQUIRED_CALIBRATION_KEYS.items():
        if key not in data:
            raise InvalidInputError(f"--calibration {path}", f'missing key "{key}" ({what})')
    try:
        c2b = data.get("camera_to_body")
        return CameraCalibration(
            K=np.asarray(data["K"], dtype=np.float64),
            distortion=np.asarray(data.get("distortion", []), dtype=np.float64),
            image_size=(int(data["image_size"][0]), int(data["image_size"][1])),
            camera_to_body=None if c2b is None else np.asarray(c2b, dtype=np.float64),
        )
    except InvalidInputError as exc:
        raise InvalidInputError(f"--calibration {path}", str(exc)) from None
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, OverflowError) as exc:
        raise InvalidInputError(f"--calibration {path}", f"malformed: {exc!r}") from None


def result_to_json(
    result: MatchResult,
    with_correspondences: bool = True,
    *,
    calibration: CameraCalibration | None = None,
    tile_sizes: Sequence[tuple[int, int]] | None = None,
    tile_gsd_m: float | None = None,
) -> dict[str, Any]:
    """The MatchResult as the CLI prints it; ``tile_index`` is the candidate's input position.
    With ``calibration`` it carries ``best_homography`` (UNDISTORTED query px -> best tile px)
    and, when the best tile id is georeferenced and ``tile_sizes`` (width, height per input
    position) are given, ``centre_lat``, ``centre_lon`` and ``footprint`` (closed [lon, lat]
    ring), see :func:`c3_matcher.georef.georeference_result`."""
    indices = result.diagnostics.get("input_index", list(range(len(result.per_candidate))))
    geo: dict[str, Any] = {}
    if calibration is not None:
        from c3_matcher.georef import georeference_result

        geo = georeference_result(result, calibration, tile_sizes, tile_gsd_m)
    return {
        "frame_id": str(result.frame_id),
        "best_candidate_idx": result.best_candidate_idx,
        "reprojection_residual_px": result.reprojection_residual_px,
        "matcher_label": result.matcher_label,
        "candidates_input": result.candidates_input,
        "candidates_dropped": result.candidates_dropped,
        "matched_at": result.matched_at,
        "per_candidate": [
            {
                "tile_id": c.tile_id.as_list(),
                "tile_index": int(index),
                "inlier_count": c.inlier_count,
                "ransac_outlier_count": c.ransac_outlier_count,
                "per_candidate_residual_px": c.per_candidate_residual_px,
                **(
                    {"inlier_correspondences": c.inlier_correspondences.tolist()}
                    if with_correspondences
                    else {}
                ),
            }
            for c, index in zip(result.per_candidate, indices, strict=True)
        ],
        **geo,
    }
