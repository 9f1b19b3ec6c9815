"""``c3-matcher dataset render``: a simulated flight over a real orthophoto (see
:mod:`c3_matcher_tools.dataset.flight`); ``c3-matcher dataset info``: a dataset's summary (JSON),
with the faults known of the importer that made it (:mod:`c3_matcher_tools.dataset.provenance`)."""

from __future__ import annotations

import argparse
import json
from dataclasses import MISSING, fields
from pathlib import Path
from typing import Any

from c3_matcher.commands import EXIT_OK, CommandRegistry, bounded_float, bounded_int
from c3_matcher.context import CommandContext
from c3_matcher.errors import describe
from c3_matcher_tools.args import add_seed_option, non_negative_float
from c3_matcher_tools.dataset.flight_spec import FlightSpec
from c3_matcher_tools.dataset.progress import ProgressBar

__all__ = ["register_dataset_command"]


IMAGE_SIDE_PX = (16, 8192)
"""The side (px) of a rendered frame, each of width and height (``dataset render --image-size``)."""
MAX_RENDER_FRAMES = 10_000
"""The most frames one ``dataset render`` plans (``--frames``): every frame is rendered and
held in memory before anything is written."""
MAX_RENDER_PIXELS = 2**31
"""The most frame pixels (frames x width x height) one ``dataset render`` holds: about 2.1 Gpx,
some 1-2 GB of JPEG, e.g. 27,000 frames of 320x240 or 32 of 8192x8192."""
_RENDER = {f.name: f.default for f in fields(FlightSpec) if f.default is not MISSING}
"""``dataset render``'s defaults: the flight spec's own."""


def _size(text: str) -> tuple[int, int]:
    """An argparse type: ``WIDTHxHEIGHT``, each side in :data:`IMAGE_SIDE_PX`."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    low, high = IMAGE_SIDE_PX
    if not (low <= w <= high and low <= h <= high):
        raise argparse.ArgumentTypeError(f"each side must be in [{low}, {high}] px, got {w}x{h}")
    return w, h


def _frame_count(text: str) -> int:
    """An argparse type: ``--frames``, an int in [1, :data:`MAX_RENDER_FRAMES`]."""
    frames = bounded_int()(text)
    if frames > MAX_RENDER_FRAMES:
        raise argparse.ArgumentTypeError(
            f"must be <= {MAX_RENDER_FRAMES} (a render holds every frame in memory), got {frames}"
        )
    return frames


IMPORT_HELP = """\
Build a c3-flight/1 dataset (no ground truth) from a recorded flight.

TELEMETRY CSV: a header row, then one row per image; columns (case-insensitive, any
order, extra columns ignored; aliases in brackets):
  time_s [time]              capture time, seconds (any origin; rows are sorted by it)
  image [file, filename, image_file]  image file name, relative to IMAGES_DIR
  lat [latitude]             vehicle latitude, degrees, WGS84
  lon [longitude]            vehicle longitude, degrees, WGS84
  altitude_m [altitude, height_m, agl_m, height_agl_m]  height ABOVE GROUND, metres
  or altitude_msl_m [alt_msl_m, altitude_amsl_m, amsl_m, msl_m]  altitude above mean
                             sea level, metres: height above ground = this minus
                             --ground-elevation M or the --dem GeoTIFF at (lat, lon)
  roll_deg [roll]            attitude, degrees: aerospace Z-Y-X (yaw, pitch, roll),
  pitch_deg [pitch]          NED body frame (x forward, y right, z down),
  yaw_deg [yaw]              yaw from TRUE north, clockwise positive
Example:
  time_s,image,lat,lon,altitude_m,roll_deg,pitch_deg,yaw_deg
  0.0,IMG_0001.jpg,47.02441,-99.15483,780.0,11.73,14.96,90.35

Candidates (a stand-in for the upstream re-ranker): at --zoom, the slippy tile holding
the point where the optical axis meets the ground (from position, attitude, height
and the calibration's camera mount), then the tiles within --uncertainty-m of that
point, then the nearest others, --candidates in all, shuffled deterministically
(--seed); each is a --candidate-size px window centred on its tile. Images without
a row and rows without an image are skipped and each is listed in the summary; a
refused value names its CSV line. Every input is checked before anything is written;
OUT is written atomically (temp dir + rename; a missing parent folder is created).
"""


FORCE_HELP = (
    "replace an existing dataset directory OUT (never a file, a directory that is not a dataset, "
    "or one holding an input)"
)


def _dataset_name(text: str) -> str:
    """An argparse type: a name ``replay`` and ``eval`` can name a directory after."""
    from c3_matcher_tools.dataset.format import name_problem

    why = name_problem(text)
    if why:
        raise argparse.ArgumentTypeError(f"{text!r} {why}")
    return text


def register_dataset_command(commands: CommandRegistry) -> None:
    p = commands.add(
        "dataset",
        help="flight datasets: render a simulated flight, import a recorded one, inspect one",
    )
    ds = p.add_subparsers(dest="dataset_command", required=True, parser_class=type(p))
    _add_render(ds)
    _add_import(ds)
    i = ds.add_parser("info", help="summary of a dataset")
    i.add_argument("dataset", type=Path, help="dataset directory (holds dataset.json)")
    i.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(handler=run_dataset)


def _add_render(ds: Any) -> None:
    """Declare ``dataset render``: its inputs, then its option groups in --help order."""
    r = ds.add_parser(
        "render",
        help="render a flight over a GeoTIFF against an MBTiles store (c3-matcher tiles build)",
        description="Render a simulated flight with ground truth. Every input is checked and "
        "every frame rendered before anything is written; OUT is written atomically (temp dir "
        "+ rename) and an existing OUT is refused without --force.",
    )
    r.add_argument("frames_geotiff", type=Path, help="orthophoto the frames are rendered from")
    r.add_argument("store", type=Path, help="MBTiles store of the candidate tiles")
    r.add_argument("out", type=Path, help="dataset directory to write")
    _add_flight_path_options(r)
    _add_camera_options(r)
    _add_candidate_options(r)
    _add_dataset_options(r)


def _add_flight_path_options(r: argparse.ArgumentParser) -> None:
    """Add ``dataset render``'s flight path and motion: frames, pattern, height, speed, tilt."""
    from c3_matcher.dto import MAX_HEIGHT_ABOVE_GROUND_M

    r.add_argument(
        "--frames",
        type=_frame_count,
        default=_RENDER["n_frames"],
        help=f"number of frames, 1..{MAX_RENDER_FRAMES} and at most "
        f"{MAX_RENDER_PIXELS / 1e9:.1f} Gpx in all (frames x width x height) "
        f"(default {_RENDER['n_frames']})",
    )
    r.add_argument(
        "--pattern",
        choices=("orbit", "line"),
        default=_RENDER["pattern"],
        help=f"flight path (default {_RENDER['pattern']})",
    )
    r.add_argument(
        "--height",
        type=bounded_float(0.0, MAX_HEIGHT_ABOVE_GROUND_M, above=True),
        default=_RENDER["height_m"],
        help="height above ground, m",
    )
    r.add_argument(
        "--speed", type=non_negative_float(), default=_RENDER["speed_mps"], help="ground speed, m/s"
    )
    r.add_argument(
        "--interval",
        type=bounded_float(0.0, above=True),
        default=_RENDER["frame_interval_s"],
        help="seconds between frames",
    )
    r.add_argument(
        "--heading",
        type=bounded_float(),
        default=_RENDER["heading_deg"],
        help="line heading / orbit start, deg",
    )
    r.add_argument(
        "--radius",
        type=bounded_float(0.0, above=True),
        default=_RENDER["orbit_radius_m"],
        help="orbit radius, m",
    )
    r.add_argument(
        "--max-tilt", type=float, default=_RENDER["max_tilt_deg"], help="max attitude tilt, deg"
    )


def _add_camera_options(r: argparse.ArgumentParser) -> None:
    """Add ``dataset render``'s camera: image size and focal length."""
    r.add_argument(
        "--image-size",
        type=_size,
        default=_RENDER["image_size"],
        help=f"WxH px, each side {IMAGE_SIDE_PX[0]}..{IMAGE_SIDE_PX[1]} "
        f"(default {'x'.join(map(str, _RENDER['image_size']))})",
    )
    r.add_argument(
        "--focal",
        type=bounded_float(0.0, above=True),
        default=_RENDER["focal_px"],
        help="focal length, px",
    )


def _add_candidate_options(r: argparse.ArgumentParser) -> None:
    """Add ``dataset render``'s candidates: their size, absent true tiles and the distractors."""
    r.add_argument(
        "--candidate-size",
        type=int,
        default=_RENDER["candidate_size_px"],
        help="candidate image side, px",
    )
    r.add_argument(
        "--absent-share",
        type=bounded_float(0.0, 1.0),
        default=_RENDER["absent_share"],
        help=f"share of frames without their true tile (default {_RENDER['absent_share']:g})",
    )
    r.add_argument(
        "--min-distractor-distance",
        type=non_negative_float(),
        default=_RENDER["min_distractor_distance_m"],
        help=f"m (default {_RENDER['min_distractor_distance_m']:g})",
    )
    r.add_argument(
        "--max-distractor-nodata",
        type=bounded_float(0.0, 1.0),
        default=_RENDER["max_distractor_nodata"],
        help="largest nodata share of a distractor window "
        f"(default {_RENDER['max_distractor_nodata']:g})",
    )


def _add_dataset_options(r: argparse.ArgumentParser) -> None:
    """Add ``dataset render``'s georeference, credit and seed, and how the dataset is written."""
    from c3_matcher_tools.tilestore.cli import parse_latlon

    r.add_argument(
        "--ref-latlon",
        type=parse_latlon,
        default=None,
        help="LAT,LON reference for local-tangent-plane grids",
    )
    r.add_argument("--attribution", default="", help="imagery credit stored in dataset.json")
    add_seed_option(r, "random seed of the flight")
    r.add_argument("--force", action="store_true", help=FORCE_HELP)
    r.add_argument("--json", action="store_true", help="print the summary as JSON")


def _add_proposal_options(m: argparse.ArgumentParser) -> None:
    """How ``dataset import`` proposes each frame's candidates from the store, and what becomes
    of a frame the store does not cover."""
    from c3_matcher_tools.dataset.sources.options import (
        MAX_CANDIDATES,
        MAX_SEARCH_TILES,
        max_uncertainty_m,
    )

    m.add_argument(
        "--uncertainty-m",
        type=non_negative_float(),
        default=50.0,
        help="position uncertainty, m: tiles within it are proposed first (default 50); at most "
        f"{MAX_SEARCH_TILES} tiles of the store's zoom from the look point, as the tiles searched "
        f"per frame grow with its square (about {max_uncertainty_m(15) / 1000:.0f} km at zoom "
        f"15, {max_uncertainty_m(18) / 1000:.1f} km at zoom 18 on the equator, less towards "
        "the poles)",
    )
    m.add_argument(
        "--candidates",
        type=bounded_int(1, MAX_CANDIDATES),
        default=3,
        help=f"candidates per frame (1..{MAX_CANDIDATES}; default 3)",
    )
    m.add_argument("--zoom", type=int, default=None, help="store zoom (default: its finest)")
    m.add_argument(
        "--candidate-size", type=int, default=512, help="candidate image side, px (default 512)"
    )
    add_seed_option(m, "candidate shuffle seed")
    m.add_argument(
        "--skip-outside",
        action="store_true",
        help="skip the frames whose look point lies outside the store, listing them with the "
        "reason (default: refuse such a flight, as a wrong --time-offset or another place's "
        "store must not drop frames unasked); refused still when no frame is inside",
    )


def _add_import(ds: Any) -> None:
    from c3_matcher_tools.dataset.sources.cli import add_log_import_options

    m = ds.add_parser(
        "import",
        help="build a dataset (no ground truth) from a recorded flight: images, telemetry CSV, "
        "calibration, candidates proposed from a tile store around the telemetry position",
        description=IMPORT_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    m.add_argument(
        "images_dir", type=Path, help="folder of the nav-camera images (or a video, see below)"
    )
    m.add_argument(
        "telemetry", type=Path, help="telemetry CSV (see above) or a recorded log (see below)"
    )
    m.add_argument(
        "calibration",
        type=Path,
        help="calibration JSON {K, distortion, image_size[, distortion_model, camera_to_body]}"
        " (as for match)",
    )
    m.add_argument("store", type=Path, help="MBTiles store the candidates are proposed from")
    m.add_argument(
        "out", type=Path, help="dataset directory to write (an existing one only with --force)"
    )
    _add_proposal_options(m)
    m.add_argument(
        "--name",
        type=_dataset_name,
        default=None,
        help="dataset name, one path component (default: OUT's name)",
    )
    m.add_argument("--force", action="store_true", help=FORCE_HELP)
    m.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_log_import_options(m)


def run_dataset(args: argparse.Namespace, ctx: CommandContext) -> int:
    from c3_matcher_tools.dataset.sources.cli import run_log_import

    if args.dataset_command == "info":
        return _info(args, ctx)
    if args.dataset_command == "import":  # every kind of log: a FIFO would be waited on
        from c3_matcher_tools.dataset.importer import refuse_special_inputs

        given = (("TELEMETRY", args.telemetry), ("CALIBRATION", args.calibration))
        refuse_special_inputs((*given, ("--dem", args.dem)))
    if args.dataset_command == "import" and (code := run_log_import(args, ctx)) is not None:
        return code  # a recorded log (PX4, ArduPilot, ROS bag, photo metadata)
    if args.dataset_command == "import":
        return _import_csv(args, ctx)
    return _render(args, ctx)


def _info(args: argparse.Namespace, ctx: CommandContext) -> int:
    from c3_matcher_tools.dataset.format import load_dataset

    d = load_dataset(args.dataset)
    info: dict[str, object] = {
        "path": str(d.root),
        "name": d.name,
        "frames": len(d.frames),
        "ground_truth_frames": sum(f.has_truth for f in d.frames),
        # frames whose true tile is not among the candidates: only known with ground truth
        "absent_frames": (
            sum(not f.true_tile_present for f in d.frames if f.has_truth)
            if any(f.has_truth for f in d.frames)
            else None
        ),
        "candidate_size_px": d.candidate_size_px,
        "calibration_image_size": list(d.calibration.image_size),
        **{k: d.meta[k] for k in ("tiles_source", "frames_source", "import") if k in d.meta},
    }
    if args.json:
        info["import_faults"] = [f.to_json() for f in d.import_faults]
        ctx.out(json.dumps(info, indent=2))
        return EXIT_OK
    record = info.pop("import", None)
    ctx.out("\n".join(f"{k}: {v}" for k, v in info.items()))
    if isinstance(record, dict):  # what the import said: marked frames, skipped images, notes
        ctx.out("\n".join(_import_lines(record, d.name)))
    for fault in d.import_faults:  # an importer's fault fixed since: what to do about it
        ctx.out(f"import fault: {fault.line()}")
    return EXIT_OK


def _import_lines(record: dict[str, object], name: str) -> list[str]:
    """The import's own summary, as ``dataset import`` printed it; one line when the record
    cannot be read (a dataset written by another version)."""
    from c3_matcher_tools.dataset.sources.options import ImportReport

    try:
        return ImportReport.from_record(record, name).lines()
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        return [f"import record unreadable ({describe(exc)})"]


def _import_csv(args: argparse.Namespace, ctx: CommandContext) -> int:
    from c3_matcher_tools.dataset.importer import ImportSpec, import_csv_flight
    from c3_matcher_tools.dataset.sources.cli import proposal_options

    report = import_csv_flight(
        ImportSpec(
            images_dir=args.images_dir,
            telemetry_csv=args.telemetry,
            calibration_json=args.calibration,
            proposal=proposal_options(args),
            ground_elevation_m=args.ground_elevation,
            dem=args.dem,
        ),
        args.out,
        name=args.name,
        force=args.force,
    )
    ctx.out(json.dumps(report.to_json()) if args.json else "\n".join(report.lines()))
    return EXIT_OK


def _render(args: argparse.Namespace, ctx: CommandContext) -> int:
    from c3_matcher_tools.dataset.flight import render_flight

    _check_render_budget(args.frames, args.image_size)
    spec = FlightSpec(
        frames_geotiff=args.frames_geotiff,
        store=args.store,
        n_frames=args.frames,
        pattern=args.pattern,
        height_m=args.height,
        speed_mps=args.speed,
        frame_interval_s=args.interval,
        heading_deg=args.heading,
        orbit_radius_m=args.radius,
        max_tilt_deg=args.max_tilt,
        image_size=args.image_size,
        focal_px=args.focal,
        candidate_size_px=args.candidate_size,
        absent_share=args.absent_share,
        min_distractor_distance_m=args.min_distractor_distance,
        max_distractor_nodata=args.max_distractor_nodata,
        reference_latlon=args.ref_latlon,
        seed=args.seed,
    )
    out = render_flight(
        spec,
        args.out,
        attribution=args.attribution,
        progress=ProgressBar("dataset render"),
        force=args.force,
    )
    if args.json:
        ctx.out(json.dumps({"dataset": str(out), "frames": spec.n_frames}))
    else:
        ctx.out(f"{out}: {spec.n_frames} frames rendered")
    return EXIT_OK


def _check_render_budget(frames: int, image_size: tuple[int, int]) -> None:
    """Refuse a render whose frames would not fit in memory (:data:`MAX_RENDER_PIXELS`) before
    any is rendered, naming both options."""
    from c3_matcher.errors import InvalidInputError

    width, height = image_size
    pixels = frames * width * height
    if pixels > MAX_RENDER_PIXELS:
        most = max(1, MAX_RENDER_PIXELS // (width * height))
        raise InvalidInputError(
            "--frames",
            f"{frames} frames of {width}x{height} px is {pixels / 1e9:.1f} Gpx, more than a "
            f"render holds in memory ({MAX_RENDER_PIXELS / 1e9:.1f} Gpx): at most {most} frames "
            "of this --image-size; lower --frames or --image-size",
        )
