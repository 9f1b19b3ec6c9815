"""``c3-matcher engines list|verify``: the engines a flight computer has (building and
benchmarking them is ground tooling: ``c3-matcher-tools`` adds ``engines build|bench``).

stdout carries only the result; progress goes to stderr.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from c3_matcher.commands import EXIT_FAILURE, EXIT_OK
from c3_matcher.engines.spec import EngineSpec
from c3_matcher.engines.store import BUILD_COMMAND, EngineStore, VerifyOutcome
from c3_matcher.errors import EngineError

if TYPE_CHECKING:
    from c3_matcher.commands import CommandRegistry
    from c3_matcher.config import C3Settings
    from c3_matcher.context import CommandContext
    from c3_matcher.plugins.manager import PluginHost

__all__ = ["EnginesCliContext", "engines_context", "figures", "register_engines_commands"]


@dataclass(frozen=True, slots=True)
class EnginesCliContext:
    """What the engines commands need: the engine directory and the installed plugins' specs
    (``imagery``: verification/bench images, default the packaged real orthophoto)."""

    engine_dir: Path
    specs: Sequence[EngineSpec]
    imagery: tuple[Path, ...] = ()


def engines_context(
    settings: C3Settings, plugin_host: PluginHost | None = None
) -> EnginesCliContext:
    """The engine directory of ``settings`` and the engine specs of the installed plugins
    (``plugin_host``'s: the command line's; default: discovered now)."""
    from c3_matcher.compose import build_plugin_host

    host = plugin_host if plugin_host is not None else build_plugin_host()
    return EnginesCliContext(settings.engines.directory, host.engine_specs())


def figures(verification: dict[str, Any] | Any) -> list[str]:
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


def _list(args: argparse.Namespace, command: CommandContext) -> int:
    ctx = engines_context(command.settings, command.plugin_host)
    records = EngineStore(ctx.engine_dir).list()
    if args.json:
        command.out(
            json.dumps(
                [
                    {
                        "path": str(r.path),
                        "problem": r.problem,
                        "command": None if r.ok else r.command,
                        "manifest": None if r.manifest is None else r.manifest.to_json(),
                    }
                    for r in records
                ],
                indent=2,
            )
        )
        return EXIT_OK
    if not records:
        command.out(f"no engines in {ctx.engine_dir} (build them with `{BUILD_COMMAND}`)")
        return EXIT_OK
    for r in records:
        m = r.manifest
        status = "ok" if r.ok else f"PROBLEM: {r.problem}"
        command.out(f"{r.path.name}  [{status}]")
        _say_build(command, r.command if not r.ok else None)
        if m is not None:
            command.out(
                f"    {m.model}/{m.variant} {m.kind} {m.precision} opset {m.opset}; "
                f"weights {m.weights.get('distribution')} {m.weights.get('version')} "
                f"sha256 {m.weights_sha256[:12]}...; built {m.built_at} in {m.build_seconds} s"
            )
            io = "; ".join(f"{t.name} {t.dtype} {list(t.shape)}" for t in (*m.inputs, *m.outputs))
            command.out(f"    I/O: {io}")
            command.out(
                f"    verification: {'passed' if m.verification_passed else 'FAILED'} "
                f"vs {m.verification.get('reference', '?')}"
            )
            command.out("\n".join(figures(dict(m.verification))))
    return EXIT_OK


def _verify(args: argparse.Namespace, command: CommandContext) -> int:
    """A row per engine file (re-hashed against its manifest) and per engine an installed
    plugin needs that is not there; the same document (``--json``) or rows whatever the
    directory holds, a missing or empty one included (every needed engine missing)."""
    ctx = engines_context(command.settings, command.plugin_host)
    store = EngineStore(ctx.engine_dir)
    outcomes = store.verify()
    if not outcomes:
        command.err(
            f"c3-matcher: no engines in {ctx.engine_dir}; build them with `{BUILD_COMMAND}`"
        )
    outcomes += _missing(store, ctx.specs, {o.path for o in outcomes})
    if args.json:
        rows = [
            {"path": str(o.path), "ok": o.ok, "detail": o.detail, "command": o.command}
            for o in outcomes
        ]
        command.out(json.dumps({"directory": str(ctx.engine_dir), "engines": rows}, indent=2))
    else:
        for o in outcomes:
            command.out(f"{'OK  ' if o.ok else 'FAIL'} {o.path.name}: {o.detail}")
            _say_build(command, o.command if not o.ok else None)
    return EXIT_OK if outcomes and all(o.ok for o in outcomes) else EXIT_FAILURE


def _say_build(command: CommandContext, build: str | None) -> None:
    """Under an engine's row, the command that builds it anew (``build``; None: nothing)."""
    if build is not None:
        command.out(f"    build it with `{build}`")


def _missing(
    store: EngineStore, specs: Sequence[EngineSpec], seen: set[Path]
) -> list[VerifyOutcome]:
    """A failed row for each engine of ``specs`` (every one an installed plugin needs) that
    ``store`` cannot serve, unless a row names its file already."""
    rows = []
    for spec in specs:
        try:
            store.require_spec(spec)
        except EngineError as exc:
            path = Path(str(exc.path))
            if path not in seen:
                rows.append(VerifyOutcome(path, False, f"missing: {exc.reason}", exc.command))
    return rows


def register_engines_commands(commands: CommandRegistry) -> None:
    """``engines list [--json]`` and ``engines verify`` in the ``engines`` group."""
    engines = commands.group("engines", help="the ONNX engines: list, verify (build, bench: tools)")
    listing = engines.add("list", help="engines, manifests and verification figures")
    listing.add_argument("--json", action="store_true", help="machine-readable output")
    listing.set_defaults(handler=_list)
    verify = engines.add("verify", help="re-check file hashes against the manifests")
    verify.add_argument("--json", action="store_true", help="machine-readable output")
    verify.set_defaults(handler=_verify)
