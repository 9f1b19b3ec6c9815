"""The ``c3-matcher`` command line. stdout carries only a command's result; logs go to stderr.

Exit statuses: 0 success; 2 bad argument, bad configuration or unreadable input (a one-line
reason on stderr); 3 InsufficientInliersError (``match``); 1 any other failure.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from c3_matcher.config import C3Settings, load_settings
from c3_matcher.errors import C3Error, ConfigurationError, InvalidInputError

__all__ = ["main"]

EXIT_OK, EXIT_FAILURE, EXIT_USAGE, EXIT_INSUFFICIENT = 0, 1, 2, 3

Handler = Callable[[argparse.Namespace, C3Settings], int]


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(EXIT_USAGE)


def _cmd_plugins(args: argparse.Namespace, settings: C3Settings) -> int:
    from c3_matcher.compose import build_plugin_host

    host = build_plugin_host()
    report: dict[str, Any] = {
        "profile": host.profile.name,
        "profile_distribution": host.profile.distribution,
        "strict": host.profile.strict,
        "flags": host.profile.flag_report(),
        "strategies": [
            {
                "name": name,
                "build_flag": spec.build_flag,
                "distribution": host.strategy_plugin(name).distribution,
                "version": host.strategy_plugin(name).version,
                "description": spec.description,
            }
            for name, spec in host.strategies().items()
        ],
        "ignored": [
            {"plugin": p.name, "distribution": p.distribution, "reason": p.reason}
            for p in host.ignored
        ],
        "errors": [str(e) for e in host.errors],
        "selected": settings.matcher.strategy,
    }
    if args.json:
        print(json.dumps(report, indent=2))
        return EXIT_OK
    print(
        f"profile: {report['profile']} ({report['profile_distribution'] or 'no profile installed'}"
        f"{', strict' if report['strict'] else ''})"
    )
    for flag, state in report["flags"].items():
        print(f"  {flag} = {state}")
    print("strategies:" if report["strategies"] else "strategies: none linked")
    for s in report["strategies"]:
        mark = " (selected)" if s["name"] == settings.matcher.strategy else ""
        print(
            f"  {s['name']}{mark}: {s['distribution']} {s['version']} "
            f"[{s['build_flag'] or 'no flag'}] {s['description']}"
        )
    for p in report["ignored"]:
        print(f"ignored: {p['plugin']} ({p['distribution']}): {p['reason']}")
    for e in report["errors"]:
        print(f"error: {e}")
    return EXIT_OK


def _cmd_config(args: argparse.Namespace, settings: C3Settings) -> int:
    print(json.dumps(settings.model_dump(mode="json"), indent=2))
    return EXIT_OK


def _cmd_engines(args: argparse.Namespace, settings: C3Settings) -> int:
    from c3_matcher.compose import build_plugin_host
    from c3_matcher.engines.cli import EnginesCliContext, dispatch

    context = EnginesCliContext(settings.engines.directory, build_plugin_host().engine_specs())
    return dispatch(args, context)


def _build_parser() -> tuple[argparse.ArgumentParser, dict[str, Handler]]:
    parser = _Parser(prog="c3-matcher", description="C3 cross-domain matcher")
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="TOML configuration file (environment variables C3_MATCHER_* override it)",
    )
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    handlers: dict[str, Handler] = {}

    p = sub.add_parser("plugins", help="list strategies, distributions, profile and flags")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    handlers["plugins"] = _cmd_plugins

    sub.add_parser("config", help="print the effective configuration (or refuse a bad one)")
    handlers["config"] = _cmd_config

    from c3_matcher.engines.cli import add_engines_commands

    add_engines_commands(sub)
    handlers["engines"] = _cmd_engines
    from c3_matcher.match_cli import add_match_command

    handlers["match"] = add_match_command(sub)
    from c3_matcher.bench import add_bench_command

    handlers["bench"] = add_bench_command(sub)
    from c3_matcher.tilestore.cli import add_tiles_command

    handlers["tiles"] = add_tiles_command(sub)
    from c3_matcher.dataset.cli import add_dataset_command

    handlers["dataset"] = add_dataset_command(sub)
    from c3_matcher.replay import add_replay_command

    handlers["replay"] = add_replay_command(sub)
    from c3_matcher.evaluate import add_eval_command

    handlers["eval"] = add_eval_command(sub)
    return parser, handlers


def main(argv: Sequence[str] | None = None) -> int:
    parser, handlers = _build_parser()
    args = parser.parse_args(argv)
    try:
        settings = load_settings(args.config)
    except ConfigurationError as exc:
        print(f"c3-matcher: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        return handlers[args.command](args, settings)
    except (InvalidInputError, ConfigurationError) as exc:
        print(f"c3-matcher: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except C3Error as exc:
        print(f"c3-matcher: {exc}", file=sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
