"""One plugin's hooks, called apart from the others': a plugin that fails is left out alone.

``call_one`` calls one registered plugin's implementations of a hook (pluggy's subset hook
caller: wrappers, argument selection and result order as in a full call); ``CommandRecorder``
hands a plugin the command registry while noting the commands it adds, so that those of a plugin
whose ``c3_matcher_register_commands`` failed half-way refuse with the reason instead of running
half-registered code. ``is_failure`` says which exceptions count as a plugin's failure: any,
``SystemExit`` included (a module calling ``sys.exit`` as it is imported), but not Ctrl-C or
SIGTERM (``KeyboardInterrupt``) nor a closing generator.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import pluggy

    from c3_matcher.commands import CommandRegistry
    from c3_matcher.errors import PluginLoadError

__all__ = ["CommandRecorder", "call_one", "checked_list", "is_failure"]


def is_failure(exc: BaseException) -> bool:
    """Whether ``exc``, raised by a plugin, leaves that plugin out (False: it must propagate,
    as Ctrl-C, SIGTERM and a closing generator do)."""
    return not isinstance(exc, KeyboardInterrupt | GeneratorExit)


def call_one(pm: pluggy.PluginManager, plugin: str, hook: str, **kwargs: Any) -> list[Any]:
    """What the plugin registered as ``plugin`` returns from ``hook`` (one result per
    implementation), none of the other plugins being called."""
    others = [obj for name, obj in pm.list_name_plugin() if name != plugin and obj is not None]
    results: list[Any] = pm.subset_hook_caller(hook, others)(**kwargs)
    return results


def checked_list(returned: object, hook: str, kind: type) -> list[Any]:
    """``returned`` (a hook's result) as a list of ``kind``; ``TypeError`` saying what it is
    instead."""
    if not isinstance(returned, list | tuple):
        raise TypeError(
            f"{hook} returned {type(returned).__name__}, expected a list of {kind.__name__} "
            f"(return [{kind.__name__}(...)])"
        )
    for item in returned:
        if not isinstance(item, kind):
            raise TypeError(f"{hook} returned {type(item).__name__}, expected {kind.__name__}")
    return list(returned)


class CommandRecorder:
    """``registry`` as a plugin's command hook sees it, noting the parser of each command the
    plugin adds (into subcommand groups too)."""

    def __init__(
        self, registry: CommandRegistry, added: list[argparse.ArgumentParser] | None = None
    ) -> None:
        self._registry = registry
        self.added: list[argparse.ArgumentParser] = [] if added is None else added

    def add(self, name: str, *, help: str, **kwargs: Any) -> argparse.ArgumentParser:
        parser = self._registry.add(name, help=help, **kwargs)
        self.added.append(parser)
        return parser

    def group(self, name: str, *, help: str = "") -> CommandRecorder:
        return CommandRecorder(self._registry.group(name, help=help), self.added)

    def refuse(self, error: PluginLoadError) -> None:
        """Make every command added so far refuse with ``error`` when run."""

        def refused(args: argparse.Namespace, context: object) -> int:
            raise error

        for parser in self.added:
            parser.set_defaults(handler=refused)
