"""``c3-matcher features build STORE [--strategy NAME ...] [--workers N | --scheduler ADDRESS]``
and ``c3-matcher features info STORE``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from c3_matcher.commands import EXIT_OK, EXIT_USAGE, CommandRegistry
from c3_matcher.config import C3Settings

__all__ = ["register_features_command"]


def register_features_command(commands: CommandRegistry) -> None:
    group = commands.group("features", help="map features computed once on the ground")
    b = group.add(
        "build",
        help="precompute every tile's features for each strategy's extractor (Dask), "
        "stored beside the store in <STORE>.features.sqlite; resumable",
    )
    b.add_argument("store", type=Path, help="an MBTiles tile store")
    b.add_argument(
        "--strategy",
        action="append",
        default=None,
        help="strategy whose extractor to run (repeatable; default: the configured one)",
    )
    where = b.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=int,
        default=2,
        help="local Dask cluster of N worker processes (0: in this process, no Dask)",
    )
    where.add_argument("--scheduler", default=None, help="an existing Dask scheduler ADDRESS")
    b.add_argument("--margin", type=int, default=64, help="context margin px around each tile")
    b.add_argument(
        "--descriptor-dtype",
        choices=("float32", "float16"),
        default="float32",
        help="stored descriptor precision",
    )
    b.add_argument("--batch", type=int, default=8, help="tiles per Dask task")
    b.add_argument("--json", action="store_true", help="print the report as JSON")
    b.set_defaults(handler=_build)
    i = group.add("info", help="the feature sets stored beside a tile store")
    i.add_argument("store", type=Path)
    i.set_defaults(handler=_info)


def _build(args: argparse.Namespace, settings: C3Settings) -> int:
    from c3_matcher_tools.features.build import build_features

    if not args.store.is_file():
        print(f"features build: no such store: {args.store}", file=sys.stderr)
        return EXIT_USAGE
    report = build_features(
        args.store,
        args.strategy or [settings.matcher.strategy],
        settings,
        workers=args.workers,
        scheduler=args.scheduler,
        margin_px=args.margin,
        descriptor_dtype=args.descriptor_dtype,
        batch_size=args.batch,
    )
    if args.json:
        print(json.dumps(report.__dict__, indent=2))
        return EXIT_OK
    for name, r in report.strategies.items():
        print(
            f"{name}: {r['extracted']} extracted, {r['skipped']} already done of {r['tiles']} "
            f"tiles in {r['seconds']:.1f} s on {r['cores']} cores: "
            f"{r['tiles_per_s_per_core']:.2f} tiles/s/core -> {report.sidecar}"
        )
    return EXIT_OK


def _info(args: argparse.Namespace, settings: C3Settings) -> int:
    from c3_matcher.tilestore.features import TileFeatureStore, sidecar_path, stored_sets

    path = sidecar_path(args.store)
    if not path.is_file():
        print(f"{args.store}: no precomputed features ({path} absent)")
        return EXIT_OK
    with TileFeatureStore(path) as store:
        for s in stored_sets(store):
            print(json.dumps(s))
    return EXIT_OK
