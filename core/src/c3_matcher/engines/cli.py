"""``c3-matcher engines ...``: build, list, verify and bench the engines.

``add_engines_commands(subparsers)`` registers ``engines build [--force] [--only MODEL/VARIANT]``,
``engines list [--json]``, ``engines verify`` and ``engines bench [--runs N] [--json]``; each
parser's ``handler`` default is ``handler(args, ctx: EnginesCliContext) -> int`` (exit code).
stdout carries only the result; progress goes to stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from c3_matcher.engines.spec import EngineSpec
from c3_matcher.engines.store import BUILD_COMMAND, EngineStore
from c3_matcher.errors import C3Error

__all__ = ["EnginesCliContext", "add_engines_commands", "dispatch"]

Handler = Callable[[argparse.Namespace, "EnginesCliContext"], int]


@dataclass(frozen=True, slots=True)
class EnginesCliContext:
    """What the engines commands need: the engine directory and the installed plugins' specs
    (``imagery``: verification/bench images, default the packaged real orthophoto)."""

    engine_dir: Path
    specs: Sequence[EngineSpec]
    imagery: tuple[Path, ...] = ()


def _err(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def _figures(verification: dict[str, Any] | Any) -> list[str]:
    lines = []
    for check in verification.get("checks", []):
        label = check.get("input") or check.get("pair")
        figures = ", ".join(
            f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
            for k, v in check.items()
            if k not in ("input", "pair")
        )
        lines.append(f"    {label}: {figures}")
    return lines


def _build(args: argparse.Namespace, ctx: EnginesCliContext) -> int:
    from c3_matcher.engines.compiler import EngineBuildError, build_engines

    start = time.perf_counter()
    try:
        outcomes = build_engines(
            ctx.specs,
            ctx.engine_dir,
            force=args.force,
            only=args.only or None,
            imagery=ctx.imagery or None,
            log=_err,
        )
    except (EngineBuildError, ValueError) as exc:
        _err(f"error: {exc}")
        return 1
    total = time.perf_counter() - start
    for o in outcomes:
        state = "reused" if o.reused else f"built in {o.seconds:.1f} s"
        print(f"{o.spec.key:<18} {state:<16} {o.path}")
        if not o.reused:
            print("\n".join(_figures(dict(o.manifest.verification))))
    built = [o for o in outcomes if not o.reused]
    print(
        f"{len(built)} built, {len(outcomes) - len(built)} reused in {total:.1f} s "
        f"({ctx.engine_dir})"
    )
    return 0


def _list(args: argparse.Namespace, ctx: EnginesCliContext) -> int:
    records = EngineStore(ctx.engine_dir).list()
    if args.json:
        print(
            json.dumps(
                [
                    {
                        "path": str(r.path),
                        "problem": r.problem,
                        "manifest": None if r.manifest is None else r.manifest.to_json(),
                    }
                    for r in records
                ],
                indent=2,
            )
        )
        return 0
    if not records:
        print(f"no engines in {ctx.engine_dir} (build them with `{BUILD_COMMAND}`)")
        return 0
    for r in records:
        m = r.manifest
        status = "ok" if r.ok else f"PROBLEM: {r.problem}"
        print(f"{r.path.name}  [{status}]")
        if m is not None:
            print(
                f"    {m.model}/{m.variant} {m.kind} {m.precision} opset {m.opset}; "
                f"weights {m.weights.get('distribution')} {m.weights.get('version')} "
                f"sha256 {m.weights_sha256[:12]}...; built {m.built_at} in {m.build_seconds} s"
            )
            io = "; ".join(f"{t.name} {t.dtype} {list(t.shape)}" for t in (*m.inputs, *m.outputs))
            print(f"    I/O: {io}")
            print(
                f"    verification: {'passed' if m.verification_passed else 'FAILED'} "
                f"vs {m.verification.get('reference', '?')}"
            )
            print("\n".join(_figures(dict(m.verification))))
    return 0


def _verify(args: argparse.Namespace, ctx: EnginesCliContext) -> int:
    outcomes = EngineStore(ctx.engine_dir).verify()
    if not outcomes:
        _err(f"no engines in {ctx.engine_dir}; build them with `{BUILD_COMMAND}`")
        return 1
    for o in outcomes:
        print(f"{'OK  ' if o.ok else 'FAIL'} {o.path.name}: {o.detail}")
    return 0 if all(o.ok for o in outcomes) else 1


def _bench_pairs(specs: Sequence[EngineSpec]) -> list[tuple[EngineSpec, EngineSpec]]:
    """(extractor, matcher) pairs: each matcher spec with the extractor whose model is its
    feature type (DISK with LightGlue-for-DISK)."""
    extractors = {s.model: s for s in specs if s.kind == "extractor"}
    return [
        (extractors[m.feature_type], m)
        for m in specs
        if m.kind == "matcher" and m.feature_type in extractors
    ]


def _bench(args: argparse.Namespace, ctx: EnginesCliContext) -> int:
    from c3_matcher.engines.bench import format_table, run_bench

    pairs = _bench_pairs(ctx.specs)
    if not pairs:
        _err("error: no installed plugin declares an extractor + matcher pair to bench")
        return 1
    store = EngineStore(ctx.engine_dir)
    if args.image:
        image = Path(args.image)
    elif ctx.imagery:
        image = ctx.imagery[0]
    else:
        from c3_matcher.engines.export import default_verification_imagery

        image = default_verification_imagery()[0]
    settings: tuple[tuple[bool, bool], ...] = ((False, True),)
    if args.sweep_session_options:
        settings = ((True, True), (False, True), (False, False))
    results = []
    for extractor, matcher in pairs:
        try:
            extractor_path = store.require(extractor.model, extractor.variant)
            matcher_path = store.require(matcher.model, matcher.variant)
        except C3Error as exc:
            _err(f"error: {exc}")
            return 1
        results += run_bench(
            extractor_path,
            matcher_path,
            image,
            runs=args.runs,
            feature_type=str(matcher.feature_type),
            settings=settings,
            log=_err,
        )
    if args.json:
        print(json.dumps([asdict(r) for r in results], indent=2))
    else:
        print(format_table(results))
    return 0


def add_engines_commands(subparsers: Any) -> None:
    """Register ``engines {build,list,verify,bench}`` on an argparse subparsers object."""
    engines = subparsers.add_parser("engines", help="build, list, verify and bench the engines")
    sub = engines.add_subparsers(dest="engines_command", required=True)

    build = sub.add_parser("build", help="export + verify the engines the plugins declare")
    build.add_argument("--force", action="store_true", help="rebuild even valid engines")
    build.add_argument(
        "--only",
        action="append",
        metavar="MODEL/VARIANT",
        help="build only this engine (repeatable), e.g. disk/depth",
    )
    build.set_defaults(handler=_build)

    listing = sub.add_parser("list", help="engines, manifests and verification figures")
    listing.add_argument("--json", action="store_true")
    listing.set_defaults(handler=_list)

    verify = sub.add_parser("verify", help="re-check file hashes against the manifests")
    verify.set_defaults(handler=_verify)

    bench = sub.add_parser("bench", help="latency (median, p95) and peak memory per engine")
    bench.add_argument("--runs", type=int, default=20, help="timed runs per case (default 20)")
    bench.add_argument("--image", help="real image to use (default: packaged orthophoto)")
    bench.add_argument("--json", action="store_true")
    bench.add_argument(
        "--sweep-session-options",
        action="store_true",
        help="also compare memory pattern / arena settings",
    )
    bench.set_defaults(handler=_bench)


def dispatch(args: argparse.Namespace, ctx: EnginesCliContext) -> int:
    """Run the handler that ``add_engines_commands`` attached to ``args``."""
    handler: Handler = args.handler
    return handler(args, ctx)
