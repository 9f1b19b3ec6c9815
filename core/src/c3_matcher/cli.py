"""The ``c3-matcher`` command line. stdout carries only a command's result; logs go to stderr.

Exit statuses: 0 success; 2 bad argument, bad configuration, unknown or unlinked strategy,
unreadable input or unwritable output (a one-line reason on stderr, never a traceback);
3 InsufficientInliersError (``match``); 1 any other failure (one line too). ``--config FILE``
may come before or after the subcommand; ``--version`` prints the version.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from c3_matcher.commands import EXIT_FAILURE, EXIT_OK, EXIT_USAGE, CommandRegistry, UsageParser
from c3_matcher.config import C3Settings, load_settings
from c3_matcher.config_argument import CONFIG_FLAG, split_config
from c3_matcher.context import CommandContext, Handler, result_stream
from c3_matcher.errors import (
    C3Error,
    ConfigurationError,
    InvalidInputError,
    StrategyNotLinkedError,
    UnknownStrategyError,
    describe,
)
from c3_matcher.ground_commands import ground_refusal
from c3_matcher.terminal_text import without_controls
from c3_matcher.toml_text import to_toml

if TYPE_CHECKING:
    from c3_matcher.plugins.manager import PluginHost

__all__ = ["main"]


def _cmd_plugins(args: argparse.Namespace, ctx: CommandContext) -> int:
    host, settings, out = ctx.plugin_host, ctx.settings, ctx.out
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
        out(json.dumps(report, indent=2))
        return EXIT_OK
    out(
        f"profile: {report['profile']} ({report['profile_distribution'] or 'no profile installed'}"
        f"{', strict' if report['strict'] else ''})"
    )
    for flag, state in report["flags"].items():
        out(f"  {flag} = {state}")
    out("strategies:" if report["strategies"] else "strategies: none linked")
    for s in report["strategies"]:
        mark = " (selected)" if s["name"] == settings.matcher.strategy else ""
        out(
            f"  {s['name']}{mark}: {s['distribution']} {s['version']} "
            f"[{s['build_flag'] or 'no flag'}] {s['description']}"
        )
    for p in report["ignored"]:
        out(f"ignored: {p['plugin']} ({p['distribution']}): {p['reason']}")
    for e in report["errors"]:
        out(f"error: {e}")
    return EXIT_OK


def _cmd_config(args: argparse.Namespace, ctx: CommandContext) -> int:
    # A name no plugin and no build flag knows (a misspelling) is refused; a real strategy
    # this build does not link (operator tooling) leaves the configuration itself good.
    # Every options table, and the settings the strategy's keypoint budget cannot meet, are
    # checked as start-up checks them; what a run would not do as written is warned on stderr
    # (exit 0); the TOML shows, as comments, the values the strategy gives unset settings.
    from c3_matcher.compose import check_strategy_budget
    from c3_matcher.config_shown import config_warnings, shown_settings
    from c3_matcher.strategy_options import check_options_tables

    settings, host = ctx.settings, ctx.plugin_host
    with contextlib.suppress(StrategyNotLinkedError):
        host.resolve(settings.matcher.strategy)
    check_options_tables(settings, host)
    check_strategy_budget(settings, host)
    for line in config_warnings(settings, host):
        _fail(f"warning: {line}")
    if args.json:
        ctx.out(json.dumps(settings.model_dump(mode="json"), indent=2))
        return EXIT_OK
    data, notes = shown_settings(settings, host)
    said = settings.replaced_by_environment.comments()  # the file's values left out, first
    ctx.out(said + to_toml(data, {**_notes(), **notes}))
    return EXIT_OK


def _noted(settings: C3Settings) -> C3Settings:
    """``settings``; the file's values a table set in the environment left out, said on stderr."""
    if settings.replaced_by_environment.values:
        _fail(f"note: {settings.replaced_by_environment.line()}")
    return settings


def _options_as_read(settings: C3Settings, host: PluginHost) -> C3Settings:
    """``settings`` with each strategy's options table as its plugin's options model reads it,
    the keys given: ``"0.5"`` from the environment is the number 0.5 the strategy runs with, as
    ``config`` prints it and a run records it. A table no linked strategy takes, or one its
    model refuses (or fails on: a plugin's own fault), stays as given: it is refused where it
    is checked, naming the table."""
    if not settings.matcher.options:
        return settings
    tables = dict(settings.matcher.options)
    for name, table in settings.matcher.options.items():
        with contextlib.suppress(Exception):
            model = host.resolve(name).options_model
            if model is not None:
                read = model.model_validate(table)
                tables[name] = read.model_dump(by_alias=True, exclude_unset=True)
    matcher = settings.matcher.model_copy(update={"options": tables})
    return settings.model_copy(update={"matcher": matcher})


def _notes() -> dict[str, str]:
    """Each setting's description, by dotted key (``matcher.min_inliers_threshold``)."""
    notes: dict[str, str] = {}
    for section, field in C3Settings.model_fields.items():
        model = field.annotation
        for key, sub in getattr(model, "model_fields", {}).items():
            if sub.description:
                notes[f"{section}.{key}"] = sub.description
    return notes


def _register_builtin(commands: CommandRegistry) -> None:
    """The flight commands: plugins, config, engines list|verify, match, fdr."""
    from c3_matcher.engines.cli import register_engines_commands
    from c3_matcher.fdr.cli import register_fdr_command
    from c3_matcher.match_cli import register_match_command

    p = commands.add("plugins", help="list strategies, distributions, profile and flags")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(handler=_cmd_plugins)
    c = commands.add(
        "config", help="print the effective configuration as TOML (or refuse a bad one)"
    )
    c.add_argument("--json", action="store_true", help="machine-readable output")
    c.set_defaults(handler=_cmd_config)
    register_engines_commands(commands)
    register_match_command(commands)
    register_fdr_command(commands)


def _build_parser(host: PluginHost) -> argparse.ArgumentParser:
    # No abbreviation here: ``--conf FILE`` would name a file behind split_config's back (it
    # reads the abbreviations argparse took as --config, and refuses a second one)
    parser = UsageParser(
        prog="c3-matcher", description="C3 cross-domain matcher", allow_abbrev=False
    )
    parser.add_argument(
        CONFIG_FLAG,
        type=Path,
        default=None,
        help="TOML configuration file (environment variables C3_MATCHER_* override it)",
    )
    parser.add_argument("--version", action="version", version=f"c3-matcher {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=UsageParser)
    commands = CommandRegistry(sub)
    _register_builtin(commands)
    host.register_commands(commands)
    return parser


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("c3-matcher")
    except PackageNotFoundError:
        return "unknown"


def _fail(exc: BaseException | str) -> None:
    """The command's one line saying why it stopped (or a ``note:`` it goes on after), on stderr;
    lost, not raised, where stderr cannot be written (a full log disk): the exit status says it."""
    text = without_controls(" ".join(str(exc).split())) or type(exc).__name__
    with contextlib.suppress(OSError, ValueError):
        print(f"c3-matcher: {text}", file=sys.stderr, flush=True)


EXIT_BROKEN_PIPE = 128 + 13  # as a shell reports a command SIGPIPE ended
EXIT_INTERRUPTED, EXIT_TERMINATED = 128 + 2, 128 + 15  # SIGINT, SIGTERM: as a shell reports them


class _Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the command is, so that it cleans up as on Ctrl-C."""


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM raises :class:`_Terminated` in here (a command's temporary files and store
    journals are given back as on Ctrl-C); the previous handler afterwards."""

    def terminate(signum: int, frame: object) -> None:
        raise _Terminated

    try:
        previous = signal.signal(signal.SIGTERM, terminate)
    except ValueError:  # not the main thread (main called from a thread): leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _drop_stdout() -> None:
    """Point stdout at /dev/null: the interpreter's last flush then finds no broken pipe."""
    with contextlib.suppress(AttributeError, OSError, ValueError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())


def main(argv: Sequence[str] | None = None) -> int:
    """``c3-matcher ARGV``: the exit status. Ctrl-C or SIGTERM at any point, start-up included,
    is one line and 130 or 143."""
    with _terminate_as_interrupt():
        try:
            return _command(argv)
        except _Terminated:
            _fail("terminated")
            return EXIT_TERMINATED
        except KeyboardInterrupt:
            _fail("interrupted")
            return EXIT_INTERRUPTED


def _command(argv: Sequence[str] | None) -> int:
    """One command: the plugin host and its parser, the arguments, the settings, the handler."""
    from c3_matcher.logs import claim_stderr

    claim_stderr()  # a command owns its process: JSON log lines on stderr from the first one
    started = _host_and_parser()
    if started is None:
        return EXIT_FAILURE
    host, parser = started
    try:
        rest, config = split_config(sys.argv[1:] if argv is None else argv)
    except ConfigurationError as exc:  # --config given twice
        _fail(exc)
        return EXIT_USAGE
    if refusal := ground_refusal(parser, host.profile.name, rest):
        _fail(refusal)
        return EXIT_USAGE
    args = parser.parse_args(rest)
    if config is not None:
        args.config = config
    try:
        settings = _noted(_options_as_read(load_settings(args.config), host))
    except ConfigurationError as exc:
        _fail(exc)
        return EXIT_USAGE
    try:
        handler: Handler = args.handler
        with result_stream() as stdout:  # a plugin's prints, native ones too: the result alone
            context = CommandContext(settings, host, stdout, sys.stderr)  # is on stdout
            status = handler(args, context)
            context.flush()  # a full disk under stdout said here, not lost at exit
        return status
    except Exception as exc:
        return _exit_status(exc)


def _host_and_parser() -> tuple[PluginHost, argparse.ArgumentParser] | None:
    """The plugin host and the parser of every command; None, said in one line, where the
    installation is broken (e.g. two profiles installed) or a bug stops it. A plugin that
    fails is listed by ``plugins`` and left out: the host goes on without it."""
    from c3_matcher.compose import build_plugin_host

    try:
        with result_stream():  # a plugin printing as it is imported, natively too
            host = build_plugin_host()
            return host, _build_parser(host)  # or as it adds its commands
    except C3Error as exc:
        _fail(exc)
    except Exception as exc:
        _bug(exc)
    return None


def _exit_status(exc: Exception) -> int:
    """A command's error as its exit status, said in one line: the user's input, a matcher
    error, a reader of stdout gone (``c3-matcher config | head``: nothing said), a file the
    user named, else a bug."""
    usage = (InvalidInputError, ConfigurationError, UnknownStrategyError, StrategyNotLinkedError)
    if isinstance(exc, C3Error):
        _fail(exc)
        return EXIT_USAGE if isinstance(exc, usage) else EXIT_FAILURE
    if isinstance(exc, BrokenPipeError):
        _drop_stdout()
        return EXIT_BROKEN_PIPE
    if isinstance(exc, OSError):
        where = f"{exc.filename}: " if exc.filename else ""
        _fail(f"{where}{exc.strerror or exc}")
        return EXIT_USAGE
    return _bug(exc)


def _bug(exc: Exception) -> int:
    """A bug: one line, not a traceback (``C3_MATCHER_TRACEBACK=1`` raises it again)."""
    if os.environ.get("C3_MATCHER_TRACEBACK"):
        raise exc
    _fail(f"internal error: {describe(exc)}")
    return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
