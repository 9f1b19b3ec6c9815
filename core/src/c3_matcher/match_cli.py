"""``c3-matcher match``: one nav-camera image against candidate tile images, through the real
composition root. stdout carries exactly one JSON object; logs go to stderr."""

from __future__ import annotations

import argparse
import contextlib
import functools
import json
import sys
import time
from pathlib import Path
from typing import Any

from c3_matcher.atomic import refuse_output_over_inputs
from c3_matcher.commands import (
    EXIT_FAILURE,
    EXIT_INSUFFICIENT,
    EXIT_OK,
    EXIT_USAGE,
    CommandRegistry,
    add_max_keypoints_option,
    bounded_float,
    bounded_int,
    with_keypoint_budget,
)
from c3_matcher.config import C3Settings
from c3_matcher.context import CommandContext
from c3_matcher.dto.camera import CameraCalibration, NavCameraFrame
from c3_matcher.dto.candidates import RerankResult, TilePixelsHandle
from c3_matcher.dto.geo import TileId
from c3_matcher.errors import (
    AmbiguousMatchError,
    InsufficientInliersError,
    InvalidInputError,
    MatcherBackboneError,
)
from c3_matcher.fdr import FdrOpenError, FdrWriteError, InMemoryFdr, JsonlFdrRecorder
from c3_matcher.match_inputs import (
    attitude_arg,
    file_candidates,
    frame_id_of,
    open_store,
    read_query,
    store_candidates,
    tile_id_arg,
    usable_height,
    warn_missing_inputs,
)
from c3_matcher.match_viz import draw_or_report
from c3_matcher.serialize import result_to_json
from c3_matcher.stages.drops import drops_heard
from c3_matcher.terminal_text import without_controls

__all__ = ["register_match_command"]

DEFAULT_WINDOW_PX = 512  # a --store candidate window's side without --window
_POSITIVE = bounded_float(0.0, above=True)


def register_match_command(commands: CommandRegistry) -> None:
    p = commands.add(
        "match",
        help="match a nav-camera image against candidate tiles (JSON on stdout)",
        description="Match one nav-camera image against 1..N candidate tile images (or windows "
        "of an MBTiles store). Exit 0 with "
        "the MatchResult as JSON; 3 with a JSON error object on "
        "InsufficientInliersError; 2 on a bad argument or unreadable image.",
    )
    p.add_argument("--query", type=Path, required=True, help="nav-camera image (as captured)")
    _add_candidate_options(p)
    p.add_argument(
        "--calibration",
        type=Path,
        default=None,
        help="camera calibration JSON (K, distortion, image_size[, distortion_model,"
        " camera_to_body]); default: a distortion-free pinhole with focal = image width",
    )
    p.add_argument(
        "--attitude",
        type=attitude_arg,
        default=None,
        help="ROLL,PITCH,YAW of the vehicle in DEGREES (Z-Y-X, NED, yaw from north)",
    )
    p.add_argument("--height", type=_POSITIVE, default=None, help="height above ground, m")
    _add_output_options(p)
    p.set_defaults(handler=run_match)


def _add_candidate_options(p: argparse.ArgumentParser) -> None:
    """The candidates: tile files or windows of a store, their ids and GSD."""
    tiles = p.add_mutually_exclusive_group(required=True)
    tiles.add_argument(
        "--tile",
        type=Path,
        action="append",
        help="candidate tile image (north-up); repeat per candidate",
    )
    tiles.add_argument(
        "--store",
        type=Path,
        default=None,
        help="an MBTiles store: each --tile-id is a candidate, the --window px square around it",
    )
    p.add_argument(
        "--tile-id",
        type=tile_id_arg,
        action="append",
        default=[],
        help="ZOOM,LAT,LON of the matching --tile, in order, or of a --store window's centre "
        "(default for --tile: none, null in the JSON, a zoom-0 placeholder in the FDR: 0,0,INDEX "
        "for the first 181)",
    )
    p.add_argument(
        "--window",
        type=bounded_int(64, 4096),
        default=None,
        help=f"side of a --store candidate window, px (default {DEFAULT_WINDOW_PX})",
    )
    p.add_argument(
        "--tile-gsd",
        type=_POSITIVE,
        default=None,
        help="--tile images' ground sample distance, m/px (default: from the tile id's zoom; "
        "a --store window's is always its zoom's)",
    )


def _add_output_options(p: argparse.ArgumentParser) -> None:
    """The strategy, keypoint budget and where the picture and the records go."""
    p.add_argument("--strategy", default=None, help="strategy to use (default: configuration)")
    add_max_keypoints_option(p)
    p.add_argument(
        "--viz",
        type=Path,
        default=None,
        help="write a picture of query, best tile and inlier lines (a .png file)",
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


def run_match(args: argparse.Namespace, ctx: CommandContext) -> int:
    """``match``; records the FDR could not write when it closed are reported after the result
    (exit 2 for a result, as for an FDR that could not be opened)."""
    unrecorded: list[str] = []
    code = _run_match(args, ctx, unrecorded)
    return EXIT_USAGE if _report(unrecorded) and code == EXIT_OK else code


def _run_match(args: argparse.Namespace, ctx: CommandContext, unrecorded: list[str]) -> int:
    from c3_matcher.compose import build_default_helpers, compose_root, state_default_fdr_path

    settings, host = _match_settings(args, ctx.settings), ctx.plugin_host
    _refuse_output_over_input(args, settings.fdr.path)
    max_pixels = settings.matcher.max_image_pixels
    image, calibration = read_query(args.query, args.calibration, max_pixels)
    height = usable_height(args)
    frame = NavCameraFrame(frame_id_of(image), image, time.monotonic_ns(), args.attitude, height)
    problems: list[str] = []  # output that could not be written: reported after the result
    with contextlib.ExitStack() as opened:  # given back in reverse, also when composing fails
        if args.store:
            store = opened.enter_context(contextlib.closing(open_store(args.store)))
            window = DEFAULT_WINDOW_PX if args.window is None else args.window
            rerank = store_candidates(frame.frame_id, store, args.tile_id, window, args.tile_gsd)
        elif args.window is not None:
            raise InvalidInputError("--window", "sizes --store windows; a --tile is matched whole")
        else:
            rerank = file_candidates(
                frame.frame_id, args.tile or [], args.tile_id, args.tile_gsd, max_pixels
            )
        helpers: dict[str, Any] = dict(build_default_helpers(settings, plugin_host=host))
        own_fdr = _open_fdr(settings, problems)
        if own_fdr is not None:
            opened.callback(_close_fdr, own_fdr, unrecorded)
        helpers["c13_fdr"] = InMemoryFdr() if own_fdr is None else own_fdr
        root = compose_root(settings, helpers, plugin_host=host)
        opened.callback(root.close)
        state_default_fdr_path(settings)
        warn_missing_inputs(args)  # logged now: on stderr as JSON at the level, and in the FDR
        heard = opened.enter_context(drops_heard())  # why each dropped candidate was
        draw = functools.partial(draw_or_report, problems, args, image, calibration, rerank)
        try:
            result = root.matcher.match(frame, rerank, calibration)
        except InsufficientInliersError as exc:
            if args.viz:
                draw(None, f"FAILED: {exc}")
            reasons = {i: drop.reason for i, drop in heard.items()}
            dropped = _dropped_json(args, rerank, sorted(reasons), reasons)
            ctx.out(json.dumps(_insufficient_json(exc, args, problems, dropped)))
            _report(problems)
            return EXIT_INSUFFICIENT
        except MatcherBackboneError as exc:
            if isinstance(exc.cause, InvalidInputError):  # the frame's own numbers, such as a
                raise exc.cause from exc  # height and a GSD in different units: bad input
            return _backbone_failed(ctx, exc, frame, settings.matcher.strategy, problems)
        reasons = {i: drop.reason for i, drop in heard.items()}
        out = _result_json(args, result, rerank, calibration, reasons)
        if args.viz and draw(
            result,
            f"{result.matcher_label}: {result.per_candidate[0].inlier_count} inliers, "
            f"median residual {result.reprojection_residual_px:.2f} px",
        ):
            out["viz"] = str(args.viz)
        ctx.out(json.dumps(out))
        ctx.flush()
        return EXIT_USAGE if _report(problems) else EXIT_OK


def _match_settings(args: argparse.Namespace, settings: C3Settings) -> C3Settings:
    """The configuration with the command's ``--strategy``, ``--max-keypoints`` and ``--fdr``."""
    if args.max_keypoints:
        settings = with_keypoint_budget(settings, args.max_keypoints)
    update: dict[str, Any] = {}
    if args.strategy:
        update["matcher"] = settings.matcher.model_copy(update={"strategy": args.strategy})
    if args.fdr:
        update["fdr"] = settings.fdr.model_copy(update={"path": args.fdr})
    return settings.model_copy(update=update)


def _refuse_output_over_input(args: argparse.Namespace, fdr_path: Path) -> None:
    """Neither file the command writes (the flight-data record, ``--viz``) may be one of the
    files it reads, nor ``--viz`` the record: the recorder would cut an image's tail as a torn
    line and append its records to it, ``--viz`` would replace it; and ``--viz`` is a PNG, so
    named (bad input, exit 2, nothing written)."""
    inputs = [args.query, *(args.tile or ()), args.store, args.calibration]
    fdr_field = "--fdr" if args.fdr else "[fdr] path"
    for out, field in ((fdr_path, fdr_field), (args.viz, "--viz")):
        if out is not None and Path(out).is_dir():
            raise InvalidInputError(field, f"{out} is a directory: it names a file to write")
    refuse_output_over_inputs(fdr_path, inputs, field=fdr_field)
    if args.viz:
        refuse_output_over_inputs(args.viz, [*inputs, fdr_path], field="--viz")
        if Path(args.viz).suffix.lower() != ".png":  # a viewer trusts the name
            raise InvalidInputError("--viz", f"{args.viz}: the picture is a PNG; name it *.png")


def _backbone_failed(
    ctx: CommandContext,
    exc: MatcherBackboneError,
    frame: NavCameraFrame,
    strategy: str,
    problems: list[str],
) -> int:
    """The query frame failed in the backbone: its JSON error object on stdout, its one line on
    stderr (then any output that could not be written), exit 1."""
    ctx.out(json.dumps(_error_json(exc, frame.frame_id, phase=exc.phase, strategy=strategy)))
    _report([str(exc), *problems])
    return EXIT_FAILURE


def _error_json(exc: Exception, frame_id: object, **fields: Any) -> dict[str, Any]:
    """The JSON error object of a frame the matcher answered with its contract's error."""
    return {"error": type(exc).__name__, "message": str(exc), "frame_id": str(frame_id), **fields}


def _insufficient_json(
    exc: InsufficientInliersError,
    args: argparse.Namespace,
    problems: list[str],
    dropped: list[dict[str, Any]],
) -> dict[str, Any]:
    """The no-fix frame's JSON error object, with each dropped candidate and why."""
    return _error_json(
        exc,
        exc.frame_id,
        best_inlier_count=exc.best_inlier_count,
        threshold=exc.threshold,
        candidates_input=exc.candidates_input,
        candidates_dropped=exc.candidates_dropped,
        matcher_label=exc.matcher_label,
        dropped=dropped,
        **({"ambiguous": exc.ambiguity} if isinstance(exc, AmbiguousMatchError) else {}),
        **({"viz": str(args.viz)} if args.viz and not problems else {}),
    )


def _result_json(
    args: argparse.Namespace,
    result: Any,
    rerank: RerankResult,
    calibration: CameraCalibration,
    reasons: dict[int, str],
) -> dict[str, Any]:
    """The result as ``match`` prints it, each kept candidate placed on the map
    (:func:`~c3_matcher.serialize.result_to_json`), with the dropped candidates and why."""
    out = result_to_json(
        result,
        with_correspondences=not args.no_correspondences,
        calibration=calibration,
        tile_sizes=_kept_tile_sizes(result, rerank),
        tile_gsds=[_georef_gsd(args, c.tile_id) for c in rerank.candidates],
    )
    kept = {int(c["tile_index"]) for c in out["per_candidate"]}
    dropped = [i for i in range(len(rerank.candidates)) if i not in kept]
    out["dropped"] = _dropped_json(args, rerank, dropped, reasons)
    if not args.tile_id:  # zoom-0 placeholder ids are no place: the JSON says none
        for entry in out["per_candidate"]:
            entry["tile_id"] = None
    return out


def _georef_gsd(args: argparse.Namespace, tile_id: TileId) -> float | None:
    """The GSD the georeference reads a candidate's tile at: None for a ``--store`` window (its
    pixels are its zoom's grid), else the ``--tile`` image's (``--tile-gsd``, or its id's zoom
    GSD): a ``--tile`` image is centred exactly on its ``--tile-id``, never snapped onto the
    zoom's grid (see :mod:`c3_matcher.georef`)."""
    if args.store:
        return None
    if args.tile_gsd is not None:
        return float(args.tile_gsd)
    return float(tile_id.web_mercator_gsd_m())


def _dropped_json(
    args: argparse.Namespace, rerank: RerankResult, dropped: list[int], reasons: dict[int, str]
) -> list[dict[str, Any]]:
    """The candidates at input positions ``dropped``: each one's position, tile id (null for
    the placeholder ids of ``--tile`` files without ``--tile-id``) and why it was dropped."""
    return [
        {
            "tile_index": i,
            "tile_id": rerank.candidates[i].tile_id.as_list() if args.tile_id else None,
            "reason": reasons.get(i, "no inliers after RANSAC"),
        }
        for i in dropped
    ]


def _open_fdr(settings: C3Settings, problems: list[str]) -> JsonlFdrRecorder | None:
    """The durable recorder at the configured path; None if it cannot be opened: the frame is
    still matched and printed (its records kept in memory) and the failure is reported
    (exit 2)."""
    from c3_matcher.compose import open_recorder
    from c3_matcher.health import MonotonicClock

    try:
        return open_recorder(settings.fdr, MonotonicClock())
    except FdrOpenError as exc:
        problems.append(f"{exc}; the result was printed but NOT recorded in the FDR")
        return None


def _close_fdr(fdr: JsonlFdrRecorder, unrecorded: list[str]) -> None:
    try:
        fdr.close()
    except FdrWriteError as exc:  # the records pending are said lost: reported, not raised
        unrecorded.append(f"{exc}; the result was printed but NOT recorded in the FDR")


def _report(problems: list[str]) -> bool:
    for line in problems:
        print(f"c3-matcher: {without_controls(' '.join(line.split()))}", file=sys.stderr)
    return bool(problems)


def _kept_tile_sizes(result: Any, rerank: RerankResult) -> list[tuple[int, int]]:
    """(width, height) per input position, decoded for the kept candidates alone (the best
    one's georeferences the frame, each one's places its tile px); the others stand as (0, 0):
    a dropped one's pixels may be what dropped it (a window over no stored tile, a damaged
    tile)."""
    kept = {int(i) for i in result.diagnostics.get("input_index", [0])}
    return [
        _image_size(c.tile_pixels_handle) if i in kept else (0, 0)
        for i, c in enumerate(rerank.candidates)
    ]


def _image_size(handle: TilePixelsHandle) -> tuple[int, int]:
    h, w = handle.decode().shape[:2]
    return w, h
