"""``c3-matcher match``: one nav-camera image against candidate tile images, through the real
composition root. stdout carries exactly one JSON object; logs go to stderr."""

from __future__ import annotations

import argparse
import json
import math
import time
import uuid
from pathlib import Path
from typing import Any

from c3_matcher.commands import EXIT_INSUFFICIENT, CommandRegistry
from c3_matcher.config import C3Settings
from c3_matcher.dto import (
    Attitude,
    CameraCalibration,
    NavCameraFrame,
    RerankCandidate,
    RerankResult,
    TileId,
)
from c3_matcher.errors import InsufficientInliersError, InvalidInputError
from c3_matcher.serialize import load_calibration, result_to_json
from c3_matcher.tiles import MmapTileHandle, read_image

__all__ = ["register_match_command"]


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


def register_match_command(commands: CommandRegistry) -> None:
    p = commands.add(
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
    p.set_defaults(handler=run_match)


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
