"""What ``c3-matcher config`` shows beyond the settings as given: the values that apply where the
configuration leaves a setting to the strategy, and the warnings on what a run would not do as
written.

Shown (:func:`shown_settings`): for the configured strategy, where its plugin is installed, each
setting left unset that it resolves itself (``[matcher] photometric``, ``refit_threshold_px``,
``max_keypoints``; ``[lightglue] filter_threshold``, ``exit_matches`` unless it is declared not
to match with LightGlue) with the value it runs with, and its options model's defaults under
``[matcher.options.<strategy>]`` that the options as given accept (XFeat's ``min_cossim`` is
refused beside ``matcher = "lighterglue"``, so it is not shown there); each as a comment
(:class:`~c3_matcher.toml_text.Unset`), so that the document read back is the same
configuration, which another strategy resolves its own way. A strategy not installed here is
said in a comment on ``[matcher]``.

Warned (:func:`config_warnings`, on stderr; the exit status stays 0, a file may be written for
another machine): ``[lightglue]`` values the strategy does not read (start-up's
``unread_settings``), and configured execution providers this machine's onnxruntime lacks,
resolved as start-up resolves them (``engines.providers``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from c3_matcher.config import C3Settings, EngineSettings, with_strategy_defaults
from c3_matcher.engines.providers import (
    PROVIDERS_SETTING,
    providers_not_installed,
    resolve_providers,
)
from c3_matcher.errors import ConfigurationError, StrategyNotLinkedError
from c3_matcher.keypoint_budget import declared_budget, reads_lightglue
from c3_matcher.strategy.config import DEFAULT_MAX_KEYPOINTS
from c3_matcher.toml_text import Unset
from c3_matcher.unread_settings import ignored_line, unread_lightglue

if TYPE_CHECKING:
    from pydantic import BaseModel

    from c3_matcher.plugins.manager import PluginHost
    from c3_matcher.plugins.types import StrategySpec

__all__ = ["config_warnings", "provider_warning", "shown_settings"]

_MATCHER_OWN = ("photometric", "refit_threshold_px")
_LIGHTGLUE_OWN = ("filter_threshold", "exit_matches")
_NOT_SHOWN = "the values it gives the settings left unset are not shown"
_NOT_READ = "it reads none of these settings"
_NOT_DECLARED = (
    "declares neither its pair matcher nor engines of its own: these apply where it matches "
    "with LightGlue"
)


def shown_settings(settings: C3Settings, host: PluginHost) -> tuple[dict[str, Any], dict[str, str]]:
    """``settings`` as ``to_toml``'s data, each setting the configured strategy resolves itself
    and its options' defaults given as :class:`Unset` where the configuration leaves them, and
    the notes of the tables that say more (by table name). A strategy not installed here: the
    settings as given, and a note saying so on ``[matcher]``."""
    data = settings.model_dump(mode="json")
    name = settings.matcher.strategy
    try:
        spec = host.resolve(name)
    except StrategyNotLinkedError:
        return data, {"matcher": f"strategy {name} is not installed here: {_NOT_SHOWN}"}
    options = _options(settings, spec)
    resolved = with_strategy_defaults(settings, spec.defaults, name)
    engines = host.strategy_engine_specs(name)
    by, matcher, notes = f"{name}'s default", data["matcher"], {}
    _fill(matcher, resolved.matcher.model_dump(mode="json"), _MATCHER_OWN, by)
    budget = declared_budget(resolved, options, engines, DEFAULT_MAX_KEYPOINTS)
    if budget is not None:
        kept = {"max_keypoints": budget}
        _fill(matcher, kept, ("max_keypoints",), f"the keypoints per image {name} keeps")
    reads = reads_lightglue(options, engines)
    if reads is not False:  # it does, or it may
        _fill(data["lightglue"], resolved.lightglue.model_dump(mode="json"), _LIGHTGLUE_OWN, by)
    if reads is None:
        notes["lightglue"] = f"strategy {name} {_NOT_DECLARED}"
    elif not reads:
        notes["lightglue"] = f"strategy {name} does not match with LightGlue: {_NOT_READ}"
    shown = {} if options is None else _options_shown(matcher["options"].get(name, {}), options, by)
    if shown:  # no table for a strategy of no options: read back, an empty one is not the same
        matcher["options"][name] = shown
    return data, notes


def _fill(table: dict[str, Any], applied: dict[str, Any], keys: Sequence[str], by: str) -> None:
    """Each of ``keys`` that ``table`` leaves unset (None) set to its ``applied`` value as
    :class:`Unset` by ``by``."""
    for key in keys:
        if table[key] is None:
            table[key] = Unset(applied[key], by)


def _options(settings: C3Settings, spec: StrategySpec) -> BaseModel | None:
    """The strategy's options as its model reads the configuration's table (None: it takes
    none); the table was checked already (``strategy_options.check_options_tables``)."""
    if spec.options_model is None:
        return None
    return spec.options_model.model_validate(settings.matcher.options.get(spec.name, {}))


def _options_shown(table: dict[str, Any], options: BaseModel, by: str) -> dict[str, Any]:
    """``table`` (the options given), then each option it leaves out as :class:`Unset` holding
    the model's default (what the strategy runs with), in the model's order; only an option
    the model accepts set to that default beside ``table`` (:func:`_accepted`): a line the
    reader may uncomment, so one that would be refused (an option of a matcher not chosen)
    is left out."""
    try:
        defaults = options.model_dump(mode="json", by_alias=True)
    except ValueError:  # a value without a JSON form (a third party's model): as given
        return table
    model = type(options)
    unset = {k: v for k, v in defaults.items() if k not in table and _accepted(model, table, k, v)}
    return {**table, **{k: Unset(v, by) for k, v in unset.items()}}


def _accepted(model: type[BaseModel], table: dict[str, Any], key: str, value: Any) -> bool:
    """Whether ``model`` validates ``table`` with ``key`` set to ``value`` as well."""
    try:
        model.model_validate({**table, key: value})
    except ValidationError:
        return False
    return True


def config_warnings(settings: C3Settings, host: PluginHost) -> list[str]:
    """What a run of ``settings`` would not do as written, one line each: the ``[lightglue]``
    values the configured strategy (installed here) does not read, and configured execution
    providers not installed here."""
    lines: list[str] = []
    name = settings.matcher.strategy
    try:
        spec = host.resolve(name)
    except StrategyNotLinkedError:
        spec = None
    if spec is not None:
        engines = host.strategy_engine_specs(name)
        keys = unread_lightglue(settings, _options(settings, spec), engines, spec.defaults)
        if keys:
            lines.append(ignored_line(name, keys))
    provider = provider_warning(settings.engines)
    if provider is not None:
        lines.append(provider)
    return lines


def provider_warning(engines: EngineSettings) -> str | None:
    """The configured execution providers that this machine's onnxruntime (asked as start-up
    asks it) lacks, and what start-up does then: leaves them out (``resolve_providers``), or
    refuses when none is left; None when every one is installed or none is configured (the
    default chain takes what is installed)."""
    if engines.providers is None:
        return None
    import onnxruntime as ort

    installed = [str(p) for p in ort.get_available_providers()]
    missing = providers_not_installed(engines.providers, installed)
    if not missing:
        return None
    try:
        chain = resolve_providers(engines.providers, installed)
    except ConfigurationError:
        then = "start-up on this machine refuses it: none of the providers is installed"
    else:
        them = "it" if len(missing) == 1 else "them"
        then = f"a run here leaves {them} out and runs on {', '.join(chain)}"
    return (
        f"{PROVIDERS_SETTING}: {', '.join(missing)} not installed on this machine (installed: "
        f"{', '.join(installed)}); {then}"
    )
