"""``c3-matcher engines build|bench`` (ground tooling; build needs the ``engine-build`` extra).

stdout carries only the result; progress goes to stderr.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

from c3_matcher.commands import EXIT_FAILURE, EXIT_OK, CommandRegistry, bounded_int
from c3_matcher.context import CommandContext
from c3_matcher.engines.cli import EnginesCliContext, engines_context, figures
from c3_matcher.engines.spec import EngineSpec
from c3_matcher.engines.store import EngineStore
from c3_matcher.errors import C3Error, InvalidInputError

__all__ = ["register_engines_build_commands"]


def _build(args: argparse.Namespace, command: CommandContext) -> int:
    ctx = engines_context(command.settings, command.plugin_host)
    from c3_matcher_tools.engines.compiler import EngineBuildError, build_engines

    start = time.perf_counter()
    try:
        outcomes = build_engines(
            ctx.specs,
            ctx.engine_dir,
            force=args.force,
            only=args.only or None,
            imagery=ctx.imagery or None,
            log=command.err,
        )
    except InvalidInputError:
        raise  # a bad --only: a usage error (exit 2), said by the command line
    except (EngineBuildError, ValueError) as exc:
        command.err(f"error: {exc}")
        return EXIT_FAILURE
    total = time.perf_counter() - start
    if args.json:
        rows = [
            {"engine": o.spec.key, "reused": o.reused, "seconds": o.seconds, "path": str(o.path)}
            for o in outcomes
        ]
        command.out(json.dumps({"directory": str(ctx.engine_dir), "engines": rows}, indent=2))
        return EXIT_OK
    width = max((len(o.spec.key) for o in outcomes), default=0)
    for o in outcomes:
        state = "reused" if o.reused else f"built in {o.seconds:.1f} s"
        command.out(f"{o.spec.key:<{width}}  {state:<16} {o.path}")
        if not o.reused:
            command.out("\n".join(figures(dict(o.manifest.verification))))
    built = [o for o in outcomes if not o.reused]
    command.out(
        f"{len(built)} built, {len(outcomes) - len(built)} reused in {total:.1f} s "
        f"({ctx.engine_dir})"
    )
    return EXIT_OK


def _bench_pairs(specs: Sequence[EngineSpec]) -> list[tuple[EngineSpec, EngineSpec]]:
    """(extractor, matcher) pairs: each matcher spec with the extractor whose model is its
    feature type (DISK with LightGlue-for-DISK)."""
    extractors = {s.model: s for s in specs if s.kind == "extractor"}
    return [
        (extractors[m.feature_type], m)
        for m in specs
        if m.kind == "matcher" and m.feature_type in extractors
    ]


def _bench(args: argparse.Namespace, command: CommandContext) -> int:
    if args.image and not args.image.is_file():
        raise InvalidInputError("--image", f"no such file: {args.image}")
    ctx: EnginesCliContext = engines_context(command.settings, command.plugin_host)
    from c3_matcher_tools.engines.bench import format_table, run_bench

    pairs = _bench_pairs(ctx.specs)
    if not pairs:
        command.err("error: no installed plugin declares an extractor + matcher pair to bench")
        return EXIT_FAILURE
    store = EngineStore(ctx.engine_dir)
    if args.image:
        image = args.image
    elif ctx.imagery:
        image = ctx.imagery[0]
    else:
        from c3_matcher_tools.engines.export import default_verification_imagery

        image = default_verification_imagery()[0]
    session_options: tuple[tuple[bool, bool], ...] = ((False, True),)
    if args.sweep_session_options:
        session_options = ((True, True), (False, True), (False, False))
    results = []
    for extractor, matcher in pairs:
        try:
            extractor_path = store.require_spec(extractor)
            matcher_path = store.require_spec(matcher)
        except C3Error as exc:
            command.err(f"error: {exc}")
            return EXIT_FAILURE
        results += run_bench(
            extractor_path,
            matcher_path,
            image,
            runs=args.runs,
            feature_type=str(matcher.feature_type),
            settings=session_options,
            log=command.err,
        )
    if args.json:
        command.out(json.dumps([asdict(r) for r in results], indent=2))
    else:
        command.out(format_table(results))
    return EXIT_OK


def register_engines_build_commands(commands: CommandRegistry) -> None:
    """``engines build`` and ``engines bench`` in the core's ``engines`` group."""
    engines = commands.group("engines")
    build = engines.add("build", help="export + verify the engines the plugins declare")
    build.add_argument("--force", action="store_true", help="rebuild even valid engines")
    build.add_argument(
        "--only",
        action="append",
        metavar="MODEL/VARIANT",
        help="build only this engine (repeatable), e.g. disk/depth",
    )
    build.add_argument("--json", action="store_true", help="print the outcome as JSON")
    build.set_defaults(handler=_build)

    bench = engines.add("bench", help="latency (median, p95) and peak memory per engine")
    bench.add_argument("--runs", type=bounded_int(), default=20, help="timed runs per case (>= 1)")
    bench.add_argument(
        "--image", type=Path, help="real image to use (default: packaged orthophoto)"
    )
    bench.add_argument("--json", action="store_true", help="machine-readable output")
    bench.add_argument(
        "--sweep-session-options",
        action="store_true",
        help="also compare memory pattern / arena settings",
    )
    bench.set_defaults(handler=_bench)
