"""The settings a strategy does not read, said rather than refused.

``[lightglue]`` applies only to a strategy that matches its pairs with LightGlue (its plugin's
declaration: ``keypoint_budget.reads_lightglue``); XFeat with mutual nearest neighbours and the
SIFT baseline read none of it. A value the user set there (a file, the environment, a caller)
for such a strategy would change nothing, silently: start-up logs it as one WARNING
(``IGNORED_KIND``) and ``c3-matcher config`` says it on stderr. It is not refused: a site file
tuned for DISK must still run XFeat. A value that applies unset too is not said (a file
``c3-matcher config`` wrote holds ``mode = "auto"``), nor one the user left unset, nor one of a
strategy whose plugin declares neither its pair matcher nor engines of its own (one reusing
another plugin's DISK and LightGlue reads them): only what is known unread is said.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from c3_matcher.config import C3Settings, LightGlueSettings
from c3_matcher.keypoint_budget import reads_lightglue
from c3_matcher.logs import log_event

if TYPE_CHECKING:
    from c3_matcher.engines.spec import EngineSpec
    from c3_matcher.plugins.manager import PluginHost
    from c3_matcher.plugins.types import StrategyDefaults, StrategySpec

__all__ = [
    "IGNORED_KIND",
    "ignored_line",
    "say_unread",
    "strategy_reads_lightglue",
    "unread_lightglue",
]

IGNORED_KIND = "c3.config.ignored"
"""The WARNING of settings the user set that the composed strategy does not read."""


def unread_lightglue(
    config: C3Settings, options: object, engines: Sequence[EngineSpec], defaults: StrategyDefaults
) -> tuple[str, ...]:
    """The ``[lightglue]`` settings (dotted, in the table's order) the user set that a strategy
    of these validated ``options``, declared ``engines`` and own ``defaults`` leaves unread;
    none unless it is declared not to match with LightGlue. A value that would apply unset too
    (the setting's default, or the strategy's own: settings its defaults already filled, as a
    ground worker gets them) is not counted: leaving it out changes nothing either."""
    if reads_lightglue(options, engines) is not False:  # it does, or it may
        return ()
    given = config.lightglue.model_fields_set
    return tuple(
        f"lightglue.{key}"
        for key, field in LightGlueSettings.model_fields.items()
        if key in given
        and getattr(config.lightglue, key)
        not in (field.get_default(), getattr(defaults, key, None))
    )


def ignored_line(strategy: str, keys: Sequence[str]) -> str:
    """The sentence that says ``keys`` are set but not read by ``strategy``."""
    them = "it" if len(keys) == 1 else "them"
    return (
        f"{', '.join(keys)} set, but strategy {strategy} does not match with LightGlue and "
        f"reads no [lightglue] setting: its run is the same without {them} (remove {them}, or "
        "choose a strategy or pair matcher that uses LightGlue)"
    )


def say_unread(config: C3Settings, spec: StrategySpec, options: object, host: PluginHost) -> None:
    """Log the ``[lightglue]`` values the user set in ``config`` (before the strategy's own
    defaults fill it) that ``spec``'s strategy, of these validated ``options``, does not read:
    one WARNING ``IGNORED_KIND``, at start-up."""
    keys = unread_lightglue(config, options, host.strategy_engine_specs(spec.name), spec.defaults)
    if keys:
        line = ignored_line(spec.name, keys)
        log_event("WARNING", IGNORED_KIND, line, strategy=spec.name, settings=list(keys))


def strategy_reads_lightglue(config: C3Settings, host: PluginHost, strategy: str) -> bool | None:
    """Whether ``strategy`` (an installed one) reads ``[lightglue]`` under ``config``'s options
    table for it, None where its plugin does not say (``reads_lightglue``): a run's report
    leaves those settings out only where it is known not to."""
    model = host.resolve(strategy).options_model
    table = config.matcher.options.get(strategy, {})
    options = None if model is None else model.model_validate(table)
    return reads_lightglue(options, host.strategy_engine_specs(strategy))
