"""A strategy's ``[matcher.options.NAME]`` table, validated by its options model: each
refusal names the value refused and where it came from, as the core's own settings do; and
every table checked at start-up, not only the selected strategy's."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ValidationError

from c3_matcher.config import C3Settings
from c3_matcher.config_problems import validation_problems as said
from c3_matcher.errors import (
    ConfigurationError,
    StrategyNotLinkedError,
    UnknownStrategyError,
    describe,
)
from c3_matcher.plugins.manager import PluginHost

__all__ = ["check_options_tables", "strategy_options"]


def check_options_tables(config: C3Settings, host: PluginHost) -> None:
    """Every ``[matcher.options.NAME]`` table checked, not only the selected strategy's: one
    whose name no installed plugin and no build flag knows (a misspelling would otherwise leave
    the strategy on its defaults, silently), and the values of each installed strategy's own
    (``ConfigurationError`` naming the key). A strategy this build does not link is passed over:
    its table does no harm here."""
    for name in config.matcher.options:
        try:
            spec = host.resolve(name)
        except StrategyNotLinkedError:
            continue
        except UnknownStrategyError as exc:
            raise ConfigurationError(
                "matcher.options",
                [(f"matcher.options.{name}", f"options for no installed strategy: {exc}")],
            ) from None
        strategy_options(config, name, spec.options_model)


def strategy_options(config: C3Settings, name: str, model: type[BaseModel] | None) -> Any:
    """Strategy ``name``'s options table in ``config`` validated by its options ``model`` (None
    for a strategy that takes none: a table for it is refused); ``ConfigurationError`` naming
    each key refused, or the model's own failure."""
    raw = config.matcher.options.get(name, {})
    if model is None:
        if raw:
            why = f"strategy {name!r} takes no options, got {sorted(raw)}"
            raise ConfigurationError("matcher.options", [(f"matcher.options.{name}", why)])
        return None
    try:
        return model.model_validate(raw)
    except ValidationError as exc:  # each refusal naming the value refused, as the core's do
        where = f"matcher.options.{name}"
        problems = [(f"{where}.{k}" if k != "(root)" else where, why) for k, why in said(exc)]
        raise ConfigurationError("matcher.options", problems) from None
    except Exception as exc:  # the plugin's validator failed (a KeyError...): not a traceback
        why = f"strategy {name!r}'s options model failed on it: {describe(exc)}"
        raise ConfigurationError("matcher.options", [(f"matcher.options.{name}", why)]) from exc
