"""``c3-matcher match``: one nav-camera image against candidate tile images, through the real
composition root. stdout carries exactly one JSON object; logs go to stderr."""

from __future__ import annotations

import argparse
import json
import math
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.config import C3Settings
from c3_matcher.dto import (
    Attitude,
    CameraCalibration,
    MatchResult,
    NavCameraFrame,
    RerankCandidate,
    RerankResult,
    TileId,
)
from c3_matcher.errors import InsufficientInliersError, InvalidInputError
from c3_matcher.tiles import MmapTileHandle, read_image

__all__ = ["add_match_command", "load_calibration", "result_to_json"]

EXIT_INSUFFICIENT = 3


def _floats(text: str, n: int, what: str) -> tuple[float, ...]:
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{what}: expected {n} comma-separated numbers, got {text!r}"
        ) from None
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"{what}: expected {n} finite numbers, got {text!r}")
    return values


def _attitude(text: str) -> Attitude:
    roll, pitch, yaw = _floats(text, 3, "--attitude")
    try:
        return Attitude.from_degrees(roll, pitch, yaw)
    except InvalidInputError as exc:
        raise argparse.ArgumentTypeError(f"--attitude: {exc}") from None


def _tile_id(text: str) -> TileId:
    try:
        return TileId.parse(text)
    except InvalidInputError as exc:
        raise argparse.ArgumentTypeError(f"--tile-id: {exc}") from None


def _positive(text: str) -> float:
    (value,) = _floats(text, 1, "value")
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def load_calibration(path: Path) -> CameraCalibration:
    """Read a calibration JSON: ``{"K": 3x3, "distortion": [k1, k2, p1, p2, k3...],
    "image_size": [width, height], "camera_to_body": 3x3 (optional)}``."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise InvalidInputError(f"--calibration {path}", f"unreadable: {exc}") from exc
    try:
        c2b = data.get("camera_to_body")
        return CameraCalibration(
            K=np.asarray(data["K"], dtype=np.float64),
            distortion=np.asarray(data.get("distortion", []), dtype=np.float64),
            image_size=(int(data["image_size"][0]), int(data["image_size"][1])),
            camera_to_body=None if c2b is None else np.asarray(c2b, dtype=np.float64),
        )
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise InvalidInputError(f"--calibration {path}", f"malformed: {exc!r}") from exc


def result_to_json(result: MatchResult, with_correspondences: bool = True) -> dict[str, Any]:
    """The MatchResult as the CLI prints it; ``tile_index`` is the candidate's input position."""
    indices = result.diagnostics.get("input_index", list(range(len(result.per_candidate))))
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
    }


def add_match_command(sub: Any) -> Callable[[argparse.Namespace, C3Settings], int]:
    p = sub.add_parser(
        "match",
        help="match a nav-camera image against candidate tiles (JSON on stdout)",
        description="Match one nav-camera image against 1..N candidate tile images. Exit 0 with "
        "the MatchResult as JSON; 3 with a JSON error object on "
        "InsufficientInliersError; 2 on a bad argument or unreadable image.",
    )
    p.add_argument("--query", type=Path, required=True, help="nav-camera image (as captured)")
    p.add_argument(
        "--tile",
        type=Path,
        action="append",
        required=True,
        help="candidate tile image (north-up); repeat per candidate",
    )
    p.add_argument(
        "--tile-id",
        type=_tile_id,
        action="append",
        default=[],
        help="ZOOM,LAT,LON of the matching --tile, in order (default: 0,0,INDEX)",
    )
    p.add_argument(
        "--tile-gsd",
        type=_positive,
        default=None,
        help="tiles' ground sample distance, m/px (default: from the tile id's zoom)",
    )
    p.add_argument(
        "--calibration",
        type=Path,
        default=None,
        help="camera calibration JSON (K, distortion, image_size[, camera_to_body]);"
        " default: a distortion-free pinhole with focal = image width",
    )
    p.add_argument(
        "--attitude",
        type=_attitude,
        default=None,
        help="ROLL,PITCH,YAW of the vehicle in DEGREES (Z-Y-X, NED, yaw from north)",
    )
    p.add_argument("--height", type=_positive, default=None, help="height above ground, m")
    p.add_argument("--strategy", default=None, help="strategy to use (default: configuration)")
    p.add_argument(
        "--viz",
        type=Path,
        default=None,
        help="write a picture of query, best tile and inlier lines (PNG)",
    )
    p.add_argument(
        "--fdr",
        type=Path,
        default=None,
        help="flight-data record file (default: the configuration's [fdr] path)",
    )
    p.add_argument(
        "--no-correspondences",
        action="store_true",
        help="omit inlier_correspondences from the JSON",
    )
    return run_match


def run_match(args: argparse.Namespace, settings: C3Settings) -> int:
    from c3_matcher.compose import build_default_helpers, compose_root

    if args.tile_id and len(args.tile_id) != len(args.tile):
        raise InvalidInputError(
            "--tile-id",
            f"{len(args.tile_id)} given for {len(args.tile)} --tile; give one per tile or none",
        )
    update: dict[str, Any] = {}
    if args.strategy:
        update["matcher"] = settings.matcher.model_copy(update={"strategy": args.strategy})
    if args.fdr:
        update["fdr"] = settings.fdr.model_copy(update={"path": args.fdr})
    settings = settings.model_copy(update=update)

    image = read_image(args.query)
    height, width = image.shape[:2]
    calibration = (
        load_calibration(args.calibration)
        if args.calibration
        else CameraCalibration.pinhole(width, height, focal_px=float(width))
    )
    frame = NavCameraFrame(uuid.uuid4(), image, time.monotonic_ns(), args.attitude, args.height)
    candidates = []
    for i, path in enumerate(args.tile):
        if not Path(path).is_file():
            raise InvalidInputError(f"--tile {path}", "no such image file")
        tile_id = args.tile_id[i] if args.tile_id else TileId(0, 0.0, float(i))
        candidates.append(RerankCandidate(tile_id, 1.0, MmapTileHandle(path), args.tile_gsd))
    rerank = RerankResult(frame.frame_id, tuple(candidates))

    root = compose_root(settings, build_default_helpers(settings))
    try:
        try:
            result = root.matcher.match(frame, rerank, calibration)
        except InsufficientInliersError as exc:
            print(
                json.dumps(
                    {
                        "error": "InsufficientInliersError",
                        "message": str(exc),
                        "frame_id": str(exc.frame_id),
                        "best_inlier_count": exc.best_inlier_count,
                        "threshold": exc.threshold,
                        "candidates_input": exc.candidates_input,
                        "candidates_dropped": exc.candidates_dropped,
                        "matcher_label": exc.matcher_label,
                    }
                )
            )
            return EXIT_INSUFFICIENT
        out = result_to_json(result, with_correspondences=not args.no_correspondences)
        if args.viz:
            from c3_matcher.viz import draw_matches

            best_index = out["per_candidate"][0]["tile_index"]
            draw_matches(
                image,
                read_image(args.tile[best_index]),
                result.per_candidate[0].inlier_correspondences,
                args.viz,
                title=f"{result.matcher_label}: {result.per_candidate[0].inlier_count} "
                f"inliers, median residual "
                f"{result.reprojection_residual_px:.2f} px",
            )
            out["viz"] = str(args.viz)
        print(json.dumps(out))
        return 0
    finally:
        root.close()
