"""``c3-matcher tiles build GEOTIFF OUT.mbtiles``, ``tiles info STORE``, ``tiles digest STORE``."""

from __future__ import annotations

import argparse
import json
import math
import os
from dataclasses import asdict
from pathlib import Path
from typing import Any

from c3_matcher.commands import EXIT_OK, CommandRegistry
from c3_matcher.context import CommandContext
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.progress import ProgressBar

__all__ = ["parse_latlon", "parse_value_range", "register_tiles_command"]


def parse_latlon(text: str) -> tuple[float, float]:
    try:
        lat, lon = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LAT,LON in degrees, got {text!r}") from None
    if not (-90 <= lat <= 90 and -180 <= lon <= 180):
        raise argparse.ArgumentTypeError(f"LAT,LON out of range: {text!r}")
    return lat, lon


def parse_value_range(text: str) -> str | tuple[float, float]:
    """``auto``, ``bits`` or ``LO,HI`` (source values) for ``--value-range``."""
    if text in ("auto", "bits"):
        return text
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto, bits or LO,HI, got {text!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise argparse.ArgumentTypeError(f"expected finite LO < HI, got {text!r}")
    return lo, hi


def register_tiles_command(commands: CommandRegistry) -> None:
    p = commands.add(
        "tiles", help="tile stores: build an MBTiles store from a GeoTIFF, inspect, add digests"
    )
    tiles = p.add_subparsers(dest="tiles_command", required=True, parser_class=type(p))
    _add_build(tiles)
    i = tiles.add_parser(
        "info", help="print a tile store's metadata (MBTiles) and tile counts (MBTiles or XYZ)"
    )
    i.add_argument(
        "store", type=Path, help="a tile store: an MBTiles file or an XYZ folder (z/x/y.png|jpg)"
    )
    i.add_argument("--json", action="store_true", help="print the info as JSON")
    d = tiles.add_parser(
        "digest",
        help="record a sha256 for every tile that has none (a store made by another tool), so "
        "the flight read path detects a tile that changes later; tile bytes are not touched",
    )
    d.add_argument("store", type=Path, help="an MBTiles tile store (updated in place)")
    d.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(handler=run_tiles)


def _store_file(text: str) -> Path:
    """``tiles build``'s OUT: a file; a name ending in a separator means a folder (Path would
    drop the slash and write a file under the folder's name)."""
    if text.endswith(("/", os.sep)):
        raise argparse.ArgumentTypeError(
            f"{text} names a folder: OUT is the .mbtiles file to write, e.g. {text}map.mbtiles"
        )
    return Path(text)


def _add_build(tiles: Any) -> None:
    b = tiles.add_parser(
        "build",
        help="build an MBTiles store (256-px web-mercator tiles) from a north-up GeoTIFF",
    )
    b.add_argument("geotiff", type=Path, help="the georeferenced orthophoto (GeoTIFF) to tile")
    b.add_argument("out", type=_store_file, help="the .mbtiles file to write")
    b.add_argument(
        "--zoom",
        type=int,
        action="append",
        default=None,
        help="zoom; repeat for a multi-zoom store (default: the coarsest zoom not coarser than "
        "the orthophoto's GSD)",
    )
    b.add_argument(
        "--zooms", default=None, metavar="A-B", help="a range of zooms, e.g. 14-16 (with --zoom)"
    )
    b.add_argument(
        "--reader",
        choices=("auto", "rasterio", "tifffile"),
        default="auto",
        help="GeoTIFF reader: rasterio (windowed, nodata tag, overviews; the geo extra) or the "
        "tifffile fallback (whole raster); auto: rasterio when installed (default auto)",
    )
    b.add_argument("--format", choices=("png", "jpg"), default="png", help="tile encoding")
    b.add_argument("--quality", type=int, default=90, help="JPEG quality (default 90)")
    b.add_argument(
        "--ref-latlon",
        type=parse_latlon,
        default=None,
        help="LAT,LON of the image centre, for grids other than UTM / mercator / EPSG:4326 "
        "(local tangent plane)",
    )
    b.add_argument("--attribution", default="", help="metadata attribution text")
    b.add_argument(
        "--value-range",
        type=parse_value_range,
        default=None,
        metavar="auto|bits|LO,HI",
        help="how 16-bit / float values become 8 bits: auto (default: 0..the 99.9th percentile "
        "of the valid pixels), bits (the declared bit depth, e.g. 0..4095 for 12-bit data in "
        "16-bit words) or LO,HI; the build report states the mapping used",
    )
    b.add_argument(
        "--force",
        action="store_true",
        help="overwrite OUT (never the GEOTIFF itself, nor an OUT that is no regular file), and "
        "build a zoom more than 4x finer than the source",
    )
    b.add_argument("--json", action="store_true", help="print the report as JSON")


def run_tiles(args: argparse.Namespace, ctx: CommandContext) -> int:
    if args.tiles_command == "digest":
        return _digest(args, ctx)
    if args.tiles_command == "info":
        return _info(args, ctx)
    return _build(args, ctx)


def _digest(args: argparse.Namespace, ctx: CommandContext) -> int:
    from c3_matcher_tools.tilestore.writer import add_missing_digests

    done = add_missing_digests(args.store)
    if args.json:
        ctx.out(json.dumps({**asdict(done), "path": str(done.path)}, indent=2))
    else:
        blank = "with no data (NULL or 0 bytes: no tile to a flight)"
        empty = f", {done.empty} {blank}" if done.empty else ""
        ctx.out(
            f"{done.path}: {done.added} digests added, {done.kept} already there{empty} "
            f"({done.tiles} tiles)"
        )
    return EXIT_OK


def _info(args: argparse.Namespace, ctx: CommandContext) -> int:
    from c3_matcher.tilestore.mbtiles import MBTilesStore

    if Path(args.store).is_dir():
        info = _xyz_info(Path(args.store))
    else:
        with MBTilesStore(args.store) as store:  # refuses a store of tiles not 256 px
            size = store.tile_size
            info = {
                "path": str(store.path),
                "format": "mbtiles",
                "metadata": dict(store.metadata),
                "tiles": {str(z): len(list(store.tiles(z))) for z in store.zooms()},
                "tile_px": None if size is None else list(size),
            }
    if args.json:
        ctx.out(json.dumps(info, indent=2))
        return EXIT_OK
    kind = " (XYZ folder)" if info["format"] == "xyz" else ""
    ctx.out(
        f"{info['path']}{kind}: "
        + ", ".join(f"zoom {z}: {n} tiles" for z, n in info["tiles"].items())
    )
    if info["format"] == "mbtiles":
        size = info["tile_px"]  # from one tile's header at open; unknown when none told it
        ctx.out(f"  tile size: {'unknown' if size is None else f'{size[0]}x{size[1]} px'}")
    for key, value in info["metadata"].items():
        ctx.out(f"  {key}: {value if len(value) <= 120 else value[:117] + '...'}")
    return EXIT_OK


def _xyz_info(root: Path) -> dict[str, Any]:
    """``tiles info`` of the XYZ folder ``root``: its tile counts per zoom (an XYZ folder has
    no metadata); InvalidInputError when it holds no tile."""
    from c3_matcher.tilestore.files import cannot_open
    from c3_matcher.tilestore.xyz import XyzTileStore

    store = XyzTileStore(root)
    try:
        counts = {str(z): sum(1 for _ in store.tiles(z)) for z in store.zooms()}
    except OSError as exc:  # a folder it may not list
        raise InvalidInputError("store", f"{exc.filename or root}: {cannot_open(exc)}") from exc
    tiles = {z: n for z, n in counts.items() if n}
    if not tiles:
        raise InvalidInputError(
            "store",
            f"{root}: is a directory, not an MBTiles file, and holds no XYZ tiles (z/x/y.png|jpg)",
        )
    return {"path": str(root), "format": "xyz", "metadata": {}, "tiles": tiles}


def _build(args: argparse.Namespace, ctx: CommandContext) -> int:
    from c3_matcher.file_kinds import special_kind
    from c3_matcher_tools.tilestore.build import build_mbtiles, parse_zooms

    kind = special_kind(Path(args.geotiff))  # either reader would say "no such file"
    if kind is not None:  # or wait forever on a FIFO
        raise InvalidInputError("geotiff", f"{args.geotiff}: is {kind}, not a GeoTIFF")
    if not 1 <= args.quality <= 100:
        raise InvalidInputError("--quality", f"must be in [1, 100], got {args.quality}")
    zooms = parse_zooms([*(args.zoom or []), *([args.zooms] if args.zooms else [])])
    report = build_mbtiles(
        args.geotiff,
        args.out,
        zoom=zooms,
        tile_format=args.format,
        jpeg_quality=args.quality,
        reference=args.ref_latlon,
        attribution=args.attribution,
        overwrite=args.force,
        progress=ProgressBar(f"tiles build {Path(args.out).name}"),
        use_rasterio=None if args.reader == "auto" else args.reader == "rasterio",
        value_range=args.value_range,
        force=args.force,
    )
    data = {
        k: str(v) if isinstance(v, Path) else list(v) if isinstance(v, tuple) else v
        for k, v in vars(report).items()
    }
    if args.json:
        ctx.out(json.dumps(data, indent=2))
    else:
        ctx.out(
            f"{report.path}: {report.tiles} tiles at zoom "
            f"{'/'.join(str(z) for z in report.zooms)} (read with {report.reader}; finest "
            f"{report.tile_gsd_m:.2f} m/px; source {report.source_gsd_m:.2f} m/px), "
            f"{report.bytes / 1e6:.2f} MB; georeference {report.georeference}; "
            f"pixel values {report.value_mapping}"
        )
        if report.beyond_world_pct > 0:
            ctx.out(
                f"  {report.beyond_world_pct:.0f} % of the orthophoto lies beyond the web-mercator "
                "world (|lat| > 85.0511 deg, where there are no tiles) and is left out"
            )
    return EXIT_OK
