"""The hook specifications of c3-matcher (one marker pair named after the project).

Every hook is prefixed ``c3_matcher_`` and documented; a test fails when one is not.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:
    from c3_matcher.commands import CommandRegistry
    from c3_matcher.config import C3Settings
    from c3_matcher.engines.spec import EngineSpec
    from c3_matcher.pipeline import FeatureBackend
    from c3_matcher.plugins.types import StrategySpec

__all__ = ["PROJECT_NAME", "hookimpl", "hookspec"]

PROJECT_NAME = "c3_matcher"
hookspec = pluggy.HookspecMarker(PROJECT_NAME)
hookimpl = pluggy.HookimplMarker(PROJECT_NAME)


@hookspec
def c3_matcher_strategies() -> list[StrategySpec]:  # type: ignore[empty-body]
    """Return the matcher strategies this plugin offers.

    Each ``StrategySpec`` names the strategy (what ``[matcher] strategy`` selects), its
    BUILD_MATCHER_* flag, its factory and its options model. Two distributions offering one name
    are both rejected (DuplicateStrategyError naming both).
    """


@hookspec(firstresult=True)
def c3_matcher_reference_backend(strategy: str, settings: C3Settings) -> FeatureBackend | None:
    """Return the PyTorch reference implementation of ``strategy``'s model I/O, or None.

    Used only by ``c3-matcher bench`` in the engine-build environment (PyTorch installed) to time
    the upstream models doing the same work beside the engines; import torch inside the hook.
    Return None for strategies this plugin does not own.
    """


@hookspec
def c3_matcher_engine_specs() -> list[EngineSpec]:  # type: ignore[empty-body]
    """Return the networks this plugin needs as ONNX engines.

    Each ``EngineSpec`` names a model and variant, the pretrained weights file (inside an
    installed distribution) and the build-time exporter that ``c3-matcher engines build`` runs
    (PyTorch is needed then, never at run time). A strategy's factory loads the built engines
    from the engine directory at start-up.
    """


@hookspec
def c3_matcher_register_commands(commands: CommandRegistry) -> None:
    """Add commands to the ``c3-matcher`` command line.

    ``commands.add(name, help=...)`` returns a new command's argparse parser (add arguments and
    ``set_defaults(handler=run)``, ``run(args, context) -> exit status``, ``context`` a
    ``c3_matcher.context.CommandContext``: settings, plugin host, output streams);
    ``commands.group(name)`` returns the registry of a command group (``engines``) to add
    subcommands to. The core's flight commands come first; ground tooling adds its own here.
    """
