"""``c3-matcher match``: one nav-camera image against candidate tile images, through the real
composition root. stdout carries exactly one JSON object; logs go to stderr."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
import time
import uuid
from pathlib import Path
from typing import Any

from c3_matcher.commands import EXIT_INSUFFICIENT, EXIT_USAGE, CommandContext, CommandRegistry
from c3_matcher.config import C3Settings
from c3_matcher.dto import (
    Attitude,
    CameraCalibration,
    NavCameraFrame,
    RerankCandidate,
    RerankResult,
    TileId,
)
from c3_matcher.errors import C3Error, InsufficientInliersError, InvalidInputError
from c3_matcher.protocols import TilePixelsHandle
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


def _keypoints(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not 16 <= value <= 8192:
        raise argparse.ArgumentTypeError(f"must be in 16..8192, got {value}")
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
        "--max-keypoints",
        type=_keypoints,
        default=None,
        help="override [matcher] max_keypoints (16..8192)",
    )
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


def run_match(args: argparse.Namespace, ctx: CommandContext) -> int:
    from c3_matcher.compose import build_default_helpers, compose_root, state_default_fdr_path

    settings, host = ctx.settings, ctx.plugin_host
    if args.tile_id and len(args.tile_id) != len(args.tile):
        raise InvalidInputError(
            "--tile-id",
            f"{len(args.tile_id)} given for {len(args.tile)} --tile; give one per tile or none",
        )
    update: dict[str, Any] = {}
    matcher_update: dict[str, Any] = {}
    if args.strategy:
        matcher_update["strategy"] = args.strategy
    if args.max_keypoints:
        matcher_update["max_keypoints"] = args.max_keypoints
    if matcher_update:
        update["matcher"] = settings.matcher.model_copy(update=matcher_update)
    if args.fdr:
        update["fdr"] = settings.fdr.model_copy(update={"path": args.fdr})
    settings = settings.model_copy(update=update)

    limit = settings.matcher.max_image_pixels
    image = read_image(args.query, limit)
    height, width = image.shape[:2]
    calibration = (
        load_calibration(args.calibration)
        if args.calibration
        else CameraCalibration.pinhole(width, height, focal_px=float(width))
    )
    if tuple(calibration.image_size) != (width, height):  # bad input (exit 2), not a backbone
        cw, ch = calibration.image_size
        raise InvalidInputError(
            f"--calibration {args.calibration}",
            f"image_size is {cw}x{ch} px but the --query image {args.query} is {width}x{height} px",
        )
    frame = NavCameraFrame(uuid.uuid4(), image, time.monotonic_ns(), args.attitude, args.height)
    _warn_missing(args)
    candidates = []
    for i, path in enumerate(args.tile):
        tile_id = args.tile_id[i] if args.tile_id else TileId(0, 0.0, float(i))
        candidates.append(RerankCandidate(tile_id, 1.0, _readable_tile(path, limit), args.tile_gsd))
    rerank = RerankResult(frame.frame_id, tuple(candidates))

    helpers: dict[str, Any] = dict(build_default_helpers(settings, plugin_host=host))
    problems: list[str] = []  # output that could not be written: reported after the result
    own_fdr = _open_fdr(settings, problems)
    helpers["c13_fdr"] = own_fdr
    root = compose_root(settings, helpers, plugin_host=host)
    state_default_fdr_path(settings)
    reasons: dict[str, str] = {}
    sink = _collect_drop_reasons(reasons)
    try:
        try:
            result = root.matcher.match(frame, rerank, calibration)
        except InsufficientInliersError as exc:
            if args.viz:
                _draw_or_report(problems, args, image, calibration, rerank, None, f"FAILED: {exc}")
            ctx.out(
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
                        **({"viz": str(args.viz)} if args.viz and not problems else {}),
                    }
                )
            )
            _report(problems)
            return EXIT_INSUFFICIENT
        sizes = [_image_size(c.tile_pixels_handle) for c in rerank.candidates]
        out = result_to_json(
            result,
            with_correspondences=not args.no_correspondences,
            calibration=calibration,
            tile_sizes=sizes,
            tile_gsd_m=args.tile_gsd,
        )
        kept = {int(c["tile_index"]) for c in out["per_candidate"]}
        out["dropped"] = [
            {
                "tile_index": i,
                "tile_id": c.tile_id.as_list(),
                "reason": reasons.get(str(c.tile_id), "no inliers after RANSAC"),
            }
            for i, c in enumerate(rerank.candidates)
            if i not in kept
        ]
        if args.viz and _draw_or_report(
            problems,
            args,
            image,
            calibration,
            rerank,
            result,
            f"{result.matcher_label}: {result.per_candidate[0].inlier_count} inliers, "
            f"median residual {result.reprojection_residual_px:.2f} px",
        ):
            out["viz"] = str(args.viz)
        ctx.out(json.dumps(out))
        ctx.stdout.flush()
        return EXIT_USAGE if _report(problems) else 0
    finally:
        _remove_sink(sink)
        root.close()
        close = getattr(own_fdr, "close", None)
        if callable(close):
            close()


def _readable_tile(path: Path, max_pixels: int) -> MmapTileHandle:
    """A handle on a ``--tile`` file that exists and decodes within ``max_pixels`` (exit 2
    otherwise, naming it)."""
    from c3_matcher.tiles import decode_image

    p = Path(path)
    if not p.is_file():
        raise InvalidInputError(f"--tile {p}", "no such image file")
    handle = MmapTileHandle(p, max_pixels=max_pixels)
    decode_image(handle.encoded(), f"--tile {p}", max_pixels)
    return handle


def _open_fdr(settings: C3Settings, problems: list[str]) -> Any:
    """The durable recorder at the configured path; if it cannot be opened, the frame is still
    matched and printed (its records kept in memory) and the failure is reported (exit 2)."""
    from c3_matcher.fdr import FdrOpenError, InMemoryFdr, JsonlFdrRecorder
    from c3_matcher.health import MonotonicClock

    try:
        return JsonlFdrRecorder(
            settings.fdr.path, MonotonicClock(), max_bytes=settings.fdr.max_bytes
        )
    except FdrOpenError as exc:
        problems.append(f"{exc}; the result was printed but NOT recorded in the FDR")
        return InMemoryFdr()


def _draw_or_report(problems: list[str], *args: Any) -> bool:
    try:
        _draw(*args)
    except (OSError, C3Error) as exc:
        problems.append(f"--viz {args[0].viz}: cannot write the picture: {exc}")
        return False
    return True


def _report(problems: list[str]) -> bool:
    for line in problems:
        print(f"c3-matcher: {' '.join(line.split())}", file=sys.stderr)
    return bool(problems)


def _warn_missing(args: argparse.Namespace) -> None:
    """Say on stderr what the matcher will have to do without (it fails silently otherwise)."""
    missing = []
    if args.attitude is None:
        missing.append("--attitude (the query is not rotated north-up: yaw >= ~60 deg fails)")
    if args.height is None:
        missing.append("--height (the query's scale is not matched to the tiles')")
    if args.tile_gsd is None and not args.tile_id:
        missing.append("--tile-gsd or --tile-id (the tiles' ground sample distance is unknown)")
    for what in missing:
        print(f"c3-matcher match: warning: no {what}", file=sys.stderr)


def _collect_drop_reasons(reasons: dict[str, str]) -> int:
    from loguru import logger

    def sink(message: Any) -> None:
        extra = message.record["extra"]
        kind = extra.get("kind")
        if kind == "c3.matcher.backbone_error":
            reasons[str(extra.get("tile_id"))] = (
                f"backbone error in {extra.get('phase')}: {extra.get('error')}"
            )
        elif kind == "c3.matcher.zero_inliers":
            reasons[str(extra.get("tile_id"))] = (
                f"no inliers after RANSAC ({extra.get('raw_matches')} raw matches)"
            )

    return int(logger.add(sink, level="DEBUG", format="{message}"))


def _remove_sink(sink: int) -> None:
    from loguru import logger

    with contextlib.suppress(ValueError):
        logger.remove(sink)


def _image_size(handle: TilePixelsHandle) -> tuple[int, int]:
    h, w = handle.decode().shape[:2]
    return w, h


def _draw(
    args: argparse.Namespace,
    image: Any,
    calibration: CameraCalibration,
    rerank: RerankResult,
    result: Any,
    title: str,
) -> None:
    """The --viz picture: rectified query beside the best tile, every candidate in a strip;
    the query beside the candidates for a failed frame."""
    from c3_matcher.georef import fit_query_to_tile
    from c3_matcher.viz import CandidateView, render_match, write_png

    counts: dict[int, int] = {}
    best_index = hom = corr = None
    if result is not None:
        indices = result.diagnostics.get("input_index", range(len(result.per_candidate)))
        counts = {int(i): c.inlier_count for i, c in zip(indices, result.per_candidate)}
        best_index = int(next(iter(indices)))
        corr = result.per_candidate[0].inlier_correspondences
        hom = fit_query_to_tile(corr, calibration)
    views = [
        CandidateView(
            c.tile_pixels_handle.decode(),
            str(c.tile_id) if c.tile_id.zoom else path.name,
            counts.get(i),
            best=i == best_index,
        )
        for i, (path, c) in enumerate(zip(args.tile, rerank.candidates, strict=True))
    ]
    picture = render_match(
        image,
        views,
        best_index=best_index if hom is not None else None,
        h_query_to_tile=hom,
        correspondences=corr,
        calibration=calibration,
        title=title,
    )
    write_png(picture, args.viz)
