"""The product's file and wire formats, written once: calibration JSON files and the
``MatchResult`` JSON that ``c3-matcher match`` prints and replay writes to ``results.jsonl``."""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher._validate import whole_number
from c3_matcher.dto import CameraCalibration, MatchResult
from c3_matcher.dto.camera import FISHEYE_LENS_MODELS, OTHER_LENS_MODEL_FIX
from c3_matcher.errors import InvalidInputError
from c3_matcher.file_kinds import special_kind
from c3_matcher.json_text import loads_json

__all__ = ["load_calibration", "result_to_json"]


MAX_CALIBRATION_BYTES = 1 << 20
"""A calibration file larger than this is refused unread (``--calibration`` naming an image),
not read into memory whole; a device (``/dev/zero``, a disk) or a FIFO is refused unopened."""


CALIBRATION_SIZE_FIX = (
    "a calibration is for one image size: scale K and image_size by the ratio of the sizes, "
    "or calibrate at this size"
)
"""What to do about a calibration whose ``image_size`` is not the images' size."""
_REQUIRED_CALIBRATION_KEYS = {
    "K": "the 3x3 intrinsic matrix, px",
    "image_size": "[width, height] px of the images K was calibrated for",
}
_CALIBRATION_KEYS = {
    *_REQUIRED_CALIBRATION_KEYS,
    "distortion",
    "distortion_model",
    "camera_to_body",
}
_DISTORTION_FORM = "a list of 0, 4, 5, 8, 12 or 14 numbers (k1, k2, p1, p2[, k3...]; [] for none)"
DISTORTION_MODELS: dict[str, tuple[int, ...]] = {
    "opencv": (0, 4, 5, 8, 12, 14),
    "plumb_bob": (0, 5),
    "rational_polynomial": (0, 8, 12, 14),
    "radtan": (0, 4),
    "none": (0,),
}
"""The ``"distortion_model"`` names a calibration may give, each with the coefficient counts it
takes; all are OpenCV's model, in its order (k1, k2, p1, p2[, k3[, k4, k5, k6[, ...]]]): ROS's
``plumb_bob`` (5) and ``rational_polynomial`` (8, or 12 and 14 with OpenCV's thin-prism and
tilt terms), Kalibr's ``radtan`` (4) and ``none`` (0); none at all (``[]``) is no distortion for
each, as ROS drivers publish a rectified or simulated camera. ``opencv``, any count OpenCV
takes, is the default."""
_NOT_JSON_HINTS = (
    (
        re.compile(r"^\s*camera_matrix\s*:", re.MULTILINE),
        "it looks like a ROS camera_info YAML: write it as JSON, K the rows of "
        "camera_matrix.data, distortion its distortion_coefficients.data, distortion_model its "
        "distortion_model, image_size [image_width, image_height]",
    ),
    (
        re.compile(r"^\s*cam\d+\s*:", re.MULTILINE),
        "it looks like a Kalibr camchain YAML: write the camera as JSON, K [[fu, 0, pu], "
        "[0, fv, pv], [0, 0, 1]] from intrinsics [fu, fv, pu, pv], distortion its "
        "distortion_coeffs, distortion_model its distortion_model, image_size its resolution, "
        "camera_to_body the rotation of T_cam_imu transposed (when the IMU axes are the body's: "
        "x forward, y right, z down)",
    ),
)
"""How the fields of a calibration file in another tool's format map to the JSON, for the
formats told by a line of theirs."""


def load_calibration(path: Path, *, field: str | None = None) -> CameraCalibration:
    """Read a calibration JSON: ``{"K": 3x3, "distortion": [k1, k2, p1, p2, k3...],
    "image_size": [width, height], "distortion_model": name (optional, one of
    :data:`DISTORTION_MODELS`), "camera_to_body": 3x3 (optional)}``, every value checked
    (InvalidInputError naming the key and the form it takes; a fisheye model named refused).

    ``field`` says what the file is to the user: by default ``match``'s option,
    ``--calibration PATH: why``; given (``"dataset"`` for a dataset's own calibration.json),
    ``FIELD: PATH: why``."""

    def refused(why: str) -> InvalidInputError:
        if field is None:
            return InvalidInputError(f"--calibration {path}", why)
        return InvalidInputError(field, f"{path}: {why}")

    data = _calibration_json(Path(path), refused)
    if not isinstance(data, dict):
        raise refused(
            f"expected a JSON object with K, distortion, image_size; got {type(data).__name__}"
        )
    for key, what in _REQUIRED_CALIBRATION_KEYS.items():
        if key not in data:
            raise refused(f'missing key "{key}" ({what})')
    unknown = sorted(set(data) - _CALIBRATION_KEYS)
    if unknown:  # a misspelt "distortion" would otherwise be no distortion, silently
        known = ", ".join(f'"{key}"' for key in sorted(_CALIBRATION_KEYS))
        raise refused(f'unknown key "{unknown[0]}" (a calibration holds {known})')
    try:
        c2b = data.get("camera_to_body")
        return CameraCalibration(
            K=_matrix(data["K"], "K"),
            distortion=_distortion(data),
            image_size=_image_size(data["image_size"]),
            camera_to_body=None if c2b is None else _matrix(c2b, "camera_to_body"),
        )
    except InvalidInputError as exc:
        raise refused(str(exc)) from None


def _calibration_json(path: Path, refused: Callable[[str], InvalidInputError]) -> Any:
    """The JSON value the calibration file at ``path`` holds; ``refused(why)`` raised when it is
    no regular file (a FIFO would be waited on, a device read without end: judged by ``stat``,
    never opened), is missing, larger than ``MAX_CALIBRATION_BYTES``, not UTF-8, not JSON (a
    ROS or Kalibr YAML told how its fields map), JSON Python cannot read (nested deeper than
    the parser recurses, a number too long to convert) or gives a key twice (the later would
    replace the earlier silently)."""
    special = special_kind(path)
    if special is not None:
        raise refused(f"is {special}, not a calibration JSON file")
    try:
        with path.open("rb") as file:
            raw = file.read(MAX_CALIBRATION_BYTES + 1)
    except FileNotFoundError:
        raise refused("no such file") from None
    except OSError as exc:
        raise refused(f"unreadable: {exc}") from None
    if len(raw) > MAX_CALIBRATION_BYTES:
        raise refused(
            f"larger than {MAX_CALIBRATION_BYTES} bytes: not a calibration (refused unread)"
        )
    try:
        return loads_json(raw.decode("utf-8"), object_pairs_hook=_unique_keys)
    except _DuplicateKeyError as exc:
        raise refused(str(exc)) from None
    except UnicodeDecodeError as exc:
        raise refused(f"not UTF-8 text: {exc}") from None
    except json.JSONDecodeError as exc:
        raise refused(_not_json(raw.decode("utf-8"), exc)) from None
    except ValueError as exc:  # JSON past what Python reads (nesting, digits)
        raise refused(f"unreadable: {exc}") from None


def _not_json(text: str, exc: json.JSONDecodeError) -> str:
    """Why ``text`` is refused as a calibration: not JSON, and how the fields of another
    tool's calibration file map to the JSON when it looks like one (see ``_NOT_JSON_HINTS``)."""
    why = f"not JSON ({exc})"
    for pattern, hint in _NOT_JSON_HINTS:
        if pattern.search(text):
            return f"{why}: {hint}"
    return why


class _DuplicateKeyError(ValueError):
    """A JSON object gives one key twice."""


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object's pairs as a dict (``object_pairs_hook``); ``_DuplicateKeyError`` naming a
    key given twice, which ``json`` would otherwise let the later value win silently."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise _DuplicateKeyError(f'key "{key}" given twice (which one is meant? give it once)')
        out[key] = value
    return out


def _shown(value: object) -> str:
    """``value`` as a refusal quotes it: its repr, cut short."""
    text = repr(value)
    return text if len(text) <= 60 else f"{text[:57]}..."


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _numbers(value: object, key: str, form: str) -> NDArray[np.float64]:
    """``value`` when it is a JSON list of numbers, as float64, else InvalidInputError naming
    ``key`` and the ``form`` it takes."""
    if not isinstance(value, list) or not all(_is_number(v) for v in value):
        raise InvalidInputError(key, f"expected {form}, got {_shown(value)}")
    try:
        return np.asarray(value, dtype=np.float64)
    except OverflowError:  # an integer beyond a float's range
        raise InvalidInputError(key, f"a number beyond float range in {_shown(value)}") from None


def _distortion(data: dict[str, Any]) -> NDArray[np.float64]:
    """The ``"distortion"`` coefficients, of as many as the ``"distortion_model"`` named takes
    (:data:`DISTORTION_MODELS`; OpenCV's by default); a fisheye model is refused by name: its
    4 numbers read as k1, k2, p1, p2 would misplace every pixel off the centre."""
    coefficients = _numbers(data.get("distortion", []), "distortion", _DISTORTION_FORM)
    model = data.get("distortion_model", "opencv")
    names = ", ".join(f'"{name}"' for name in DISTORTION_MODELS)
    if not isinstance(model, str):
        raise InvalidInputError("distortion_model", f"expected one of {names}, got {_shown(model)}")
    name = model.strip().lower().replace("-", "_")
    if name in FISHEYE_LENS_MODELS:
        raise InvalidInputError(
            "distortion_model",
            f"{model!r} is a fisheye or omnidirectional lens model, not supported: "
            f"{OTHER_LENS_MODEL_FIX}",
        )
    counts = DISTORTION_MODELS.get(name)
    if counts is None:
        raise InvalidInputError(
            "distortion_model", f"unknown model {_shown(model)} (OpenCV's model is named {names})"
        )
    if name != "opencv" and coefficients.shape[0] not in counts:
        said = " or ".join(str(count) for count in counts)
        raise InvalidInputError(
            "distortion",
            f"distortion_model {model!r} takes {said} coefficients, got {coefficients.shape[0]}",
        )
    return coefficients


def _matrix(value: object, key: str) -> NDArray[np.float64]:
    """A 3x3 matrix given as a JSON list of 3 rows of 3 numbers."""
    form = "a 3x3 list of numbers ([[a, b, c], [d, e, f], [g, h, i]])"
    rows = value if isinstance(value, list) and len(value) == 3 else None
    if rows is None or not all(isinstance(r, list) and len(r) == 3 for r in rows):
        raise InvalidInputError(key, f"expected {form}, got {_shown(value)}")
    return np.stack([_numbers(r, key, form) for r in rows])


def _image_size(value: object) -> tuple[int, int]:
    """``[width, height]``: two whole numbers of pixels (``640.0`` is taken as 640)."""
    sizes = value if isinstance(value, list) and len(value) == 2 else [None, None]
    width, height = (whole_number(v) for v in sizes)
    if width is None or height is None:
        raise InvalidInputError(
            "image_size", f"expected [width, height] as whole numbers of px, got {_shown(value)}"
        )
    return width, height


def result_to_json(
    result: MatchResult,
    with_correspondences: bool = True,
    *,
    calibration: CameraCalibration | None = None,
    tile_sizes: Sequence[tuple[int, int]] | None = None,
    tile_gsds: Sequence[float | None] | None = None,
) -> dict[str, Any]:
    """The MatchResult as the CLI prints it; ``tile_index`` is the candidate's input position.
    ``tile_sizes`` (width, height) and ``tile_gsds`` (m/px; None or a None entry: a store
    window) are per input position. With ``tile_sizes`` each kept candidate carries its place on
    the map (:func:`c3_matcher.georef.candidate_placement`). With ``calibration`` the result
    carries ``best_homography`` (UNDISTORTED query px -> best tile px) and, when the best tile id
    is georeferenced and ``tile_sizes`` are given, ``centre_lat``, ``centre_lon`` and
    ``footprint`` (closed [lon, lat] ring), see :func:`c3_matcher.georef.georeference_result`."""
    from c3_matcher.georef import candidate_placement, georeference_result

    indices = [
        int(i) for i in result.diagnostics.get("input_index", range(len(result.per_candidate)))
    ]
    gsds = tile_gsds or [None] * (max(indices, default=0) + 1)
    geo: dict[str, Any] = {}
    if calibration is not None:
        geo = georeference_result(
            result, calibration, tile_sizes, gsds[indices[0]] if indices else None
        )
    entries = []
    for c, index in zip(result.per_candidate, indices, strict=True):
        entry: dict[str, Any] = {
            "tile_id": c.tile_id.as_list(),
            "tile_index": index,
            "inlier_count": c.inlier_count,
            "ransac_outlier_count": c.ransac_outlier_count,
            "per_candidate_residual_px": c.per_candidate_residual_px,
        }
        if with_correspondences:
            entry["inlier_correspondences"] = c.inlier_correspondences.tolist()
        if tile_sizes is not None:
            entry.update(candidate_placement(c.tile_id, tile_sizes[index], gsds[index]))
        entries.append(entry)
    return {
        "frame_id": str(result.frame_id),
        "best_candidate_idx": result.best_candidate_idx,
        "reprojection_residual_px": result.reprojection_residual_px,
        "matcher_label": result.matcher_label,
        "candidates_input": result.candidates_input,
        "candidates_dropped": result.candidates_dropped,
        "matched_at": result.matched_at,
        "per_candidate": entries,
        **geo,
    }
