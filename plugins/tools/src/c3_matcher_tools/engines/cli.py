"""``c3-matcher engines build|bench`` (ground tooling; build needs the ``engine-build`` extra).

stdout carries only the result; progress goes to stderr, and every line that says why the
command stopped starts ``c3-matcher:`` (a refusal is raised: the command line says it).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import NamedTuple

from c3_matcher.commands import EXIT_FAILURE, EXIT_OK, CommandRegistry, bounded_int
from c3_matcher.context import CommandContext
from c3_matcher.engines.cli import EnginesCliContext, engines_context, figures
from c3_matcher.engines.spec import EngineSpec
from c3_matcher.engines.store import BUILD_COMMAND, EngineStore
from c3_matcher.errors import C3Error, EngineError, InvalidInputError

__all__ = ["register_engines_build_commands"]


def _build(args: argparse.Namespace, command: CommandContext) -> int:
    ctx = engines_context(command.settings, command.plugin_host)
    from c3_matcher_tools.engines.compiler import build_engines

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
        raise  # a bad --only, or what a build needs not installed: exit 2, said by the command line
    except ValueError as exc:  # specs declared twice: the plugins' fault (a failed build: exit 1)
        raise C3Error(str(exc)) from exc
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


class _BenchGroup(NamedTuple):
    """One extractor engine and the matcher engines timed on its features."""

    extractor: EngineSpec
    matchers: tuple[EngineSpec, ...]


def _bench_groups(specs: Sequence[EngineSpec]) -> tuple[list[_BenchGroup], list[EngineSpec]]:
    """What ``engines bench`` times: every extractor spec once (each variant: ``aliked/n16``
    and ``aliked/n16rot``), in declared order, each with the matcher specs timed on its
    features; every matcher spec once (full and steps engines alike), on the features of the
    first extractor declared for its feature type (the plugin's default variant). Second: the
    matcher specs no declared extractor serves (not timed)."""
    extractors = [s for s in specs if s.kind == "extractor"]
    first: dict[str, EngineSpec] = {}
    for extractor in extractors:
        first.setdefault(extractor.model, extractor)
    matchers = [m for m in specs if m.kind == "matcher"]
    groups = [
        _BenchGroup(e, tuple(m for m in matchers if first.get(str(m.feature_type)) is e))
        for e in extractors
    ]
    return groups, [m for m in matchers if str(m.feature_type) not in first]


def _bench_image(args: argparse.Namespace, ctx: EnginesCliContext) -> Path:
    """``--image``, else the configured verification imagery's first, else the packaged one."""
    if args.image:
        return Path(args.image)
    if ctx.imagery:
        return Path(ctx.imagery[0])
    from c3_matcher_tools.engines.export import default_verification_imagery

    return default_verification_imagery()[0]


class _Missing(NamedTuple):
    """An engine ``engines bench`` would time that is not in the directory, and why (the error
    names the file looked for and the command that builds it)."""

    spec: EngineSpec
    error: EngineError


def _bench_engines(
    groups: Sequence[_BenchGroup], store: EngineStore
) -> tuple[list[tuple[Path, list[Path]]], list[_Missing]]:
    """Every group's engine files (extractor, matchers), found before anything is timed; second:
    each engine that is missing (or refused), for one message naming them all."""
    found: list[tuple[Path, list[Path]]] = []
    missing: list[_Missing] = []

    def require(spec: EngineSpec) -> Path:
        try:
            return store.require_spec(spec)
        except EngineError as exc:
            missing.append(_Missing(spec, exc))
            return Path()

    for group in groups:
        found.append((require(group.extractor), [require(m) for m in group.matchers]))
    return found, missing


def _refuse_missing(
    missing: Sequence[_Missing], directory: Path, command: CommandContext, *, as_json: bool
) -> C3Error:
    """Say which engines are missing, each with its reason, and with ``as_json`` the same in a
    document on stdout (each engine with the command that builds it, the one ``engines
    verify`` names, and the one command building them all); the error that ends the command
    (exit 1) names that command: nothing was timed."""
    for item in missing:
        command.err(f"c3-matcher: {item.error}")
    only = " ".join(f"--only {item.spec.key}" for item in missing)
    build = f"{BUILD_COMMAND} {only}"
    if as_json:
        rows = [
            {
                "engine": item.spec.key,
                "path": str(item.error.path),
                "problem": item.error.reason,
                "command": item.error.command,
            }
            for item in missing
        ]
        document = {"directory": str(directory), "missing": rows, "command": build}
        command.out(json.dumps(document, indent=2))
    return C3Error(
        f"{len(missing)} engine(s) to bench are missing or unusable, nothing was timed; "
        f"build them: {build}"
    )


def _bench(args: argparse.Namespace, command: CommandContext) -> int:
    if args.image and not args.image.is_file():
        raise InvalidInputError("--image", f"no such file: {args.image}")
    ctx: EnginesCliContext = engines_context(command.settings, command.plugin_host)
    from c3_matcher_tools.engines.bench import (
        FailedCase,
        bench_runtime,
        format_table,
        run_bench,
    )

    groups, unserved = _bench_groups(ctx.specs)
    if not groups:
        raise C3Error("no installed plugin declares an extractor engine to bench")
    for matcher in unserved:
        command.err(
            f"c3-matcher: note: {matcher.key} not benched: no extractor of {matcher.feature_type!r}"
        )
    engines = command.settings.engines
    bench_runtime(engines)  # no requested provider installed: refused here, before any case
    found, missing = _bench_engines(groups, EngineStore(ctx.engine_dir))
    if missing:
        raise _refuse_missing(missing, ctx.engine_dir, command, as_json=args.json)
    image = _bench_image(args, ctx)
    session_options: tuple[tuple[bool, bool], ...] | None = None  # arena as [engines] says
    if args.sweep_session_options:
        session_options = ((True, True), (False, True), (False, False))
    results = []
    for group, (extractor_path, matcher_paths) in zip(groups, found, strict=True):
        results += run_bench(
            extractor_path,
            matcher_paths,
            image,
            runs=args.runs,
            feature_type=group.extractor.model,
            engines=engines,
            settings=session_options,
            log=command.err,
        )
    if args.json:
        command.out(json.dumps([asdict(r) for r in results], indent=2))
    else:
        command.out(format_table(results))
    failed = [f"{r.case} ({r.settings})" for r in results if isinstance(r, FailedCase)]
    if failed:
        said = ", ".join(failed)
        command.err(f"c3-matcher: {len(failed)} case(s) failed, the others are timed: {said}")
        return EXIT_FAILURE
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
