"""A strategy's ``create`` written from a few facts: ``strategy_factory`` for an
``ExtractorMatcher`` subclass and its config, ``backend_strategy_factory`` for any
``FeatureBackend``.

Either ``create`` takes its shared helpers by name (``StrategyHelpers``, as ``compose_root``
hands them) or by position in the specification's order, ``create(config, lightglue_runtime,
ransac_filter, inference_runtime, health_window)``, then the FDR client and the clock it also
takes (:data:`HELPER_ORDER`). A helper missing, given twice or unknown is a ``TypeError`` that
names it.

The ``config`` a ``create`` gets is the settings ``compose_root`` composed for its strategy (the
strategy's own defaults applied where the configuration leaves a setting unset:
``compose.strategy_settings``); neither factory applies them again."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any, cast

from pydantic import BaseModel

from c3_matcher.config import C3Settings
from c3_matcher.engines.store import EngineStore
from c3_matcher.pipeline import FeatureBackend, PipelineSettings
from c3_matcher.plugins.types import StrategyFactory
from c3_matcher.probe import check_members
from c3_matcher.protocols import CrossDomainMatcher
from c3_matcher.strategy.config import ExtractorStrategyConfig
from c3_matcher.strategy.matcher import ExtractorMatcher, PipelineHelpers, pipeline_matcher

HELPER_ORDER = (
    "lightglue_runtime",
    "ransac_filter",
    "inference_runtime",
    "health_window",
    "fdr_client",
    "clock",
)
"""The helpers ``create`` takes by position after ``config``, in this order."""

_EXTRACTOR_NEEDS = HELPER_ORDER
_BACKEND_NEEDS = ("ransac_filter", "health_window", "fdr_client", "clock")


def _helpers(given: tuple[Any, ...], named: dict[str, Any], needs: tuple[str, ...]) -> Any:
    """The helpers of a ``create`` call, by name: ``given`` by position in
    :data:`HELPER_ORDER`, ``named`` by keyword; ``TypeError`` naming each one too many,
    unknown, given twice or missing from ``needs``."""
    if len(given) > len(HELPER_ORDER):
        raise TypeError(
            f"create() takes config and at most {len(HELPER_ORDER)} helpers by position "
            f"({', '.join(HELPER_ORDER)}), got {len(given)}"
        )
    helpers = dict(zip(HELPER_ORDER, given, strict=False))
    problems = [f"unknown helper {n!r}" for n in sorted(set(named) - set(HELPER_ORDER))]
    problems += [f"{n!r} given twice" for n in sorted(set(named) & set(helpers))]
    helpers |= named
    problems += [f"{n!r} missing" for n in needs if helpers.get(n) is None]
    if problems:
        raise TypeError(f"create(): {'; '.join(problems)} (helpers: {', '.join(HELPER_ORDER)})")
    return helpers


def _validated(options_model: type[BaseModel] | None, options: Any) -> Any:
    """``options`` validated with ``options_model`` (a mapping, or None for its defaults);
    options already of that model, or of a strategy without one, as they are."""
    if options_model is not None and not isinstance(options, options_model):
        return options_model.model_validate(options or {})
    return options


ConfigMaker = Callable[[C3Settings, Any, EngineStore], ExtractorStrategyConfig]
"""``make_config(settings, options, engines)``: a strategy's config (``strategy_factory``)."""


def strategy_factory(
    matcher_class: type[ExtractorMatcher],
    make_config: ConfigMaker | Callable[[C3Settings, Any], ExtractorStrategyConfig],
    options_model: type[BaseModel] | None = None,
) -> StrategyFactory:
    """A strategy's ``create(config, *helpers, options, **helpers)`` from two facts: its
    matcher class and how its config is made, ``make_config(settings, options, engines)``:
    from the composed settings, its validated options (a mapping is validated with
    ``options_model`` here; None means its defaults) and the engine directory
    (``[engines] directory``, opened here once: ``engines.require_spec`` gives an engine's
    file). The per-frame loop's settings come from ``[matcher]`` (``PipelineSettings``). A
    ``make_config(settings, options)`` of two parameters, as plugins wrote it before the engine
    directory was handed over, is called so (it opens the directory itself)."""
    config_of = _three_parameters(make_config)

    def create(
        config: C3Settings, *given: Any, options: Any = None, **named: Any
    ) -> CrossDomainMatcher:
        """``create``: resolve the strategy's engines, load them now (start-up) and
        return its wired matcher."""
        helpers = _helpers(given, named, _EXTRACTOR_NEEDS)
        engines = EngineStore(config.engines.directory)
        return matcher_class(
            helpers["inference_runtime"],
            helpers["lightglue_runtime"],
            helpers["ransac_filter"],
            helpers["fdr_client"],
            helpers["health_window"],
            config_of(config, _validated(options_model, options), engines),
            helpers["clock"],
        )

    return create


def _three_parameters(
    make_config: ConfigMaker | Callable[[C3Settings, Any], ExtractorStrategyConfig],
) -> ConfigMaker:
    """``make_config`` as one of ``(settings, options, engines)``: as it is, or, taking two
    positional parameters, called without ``engines``."""
    try:
        parameters = inspect.signature(make_config).parameters.values()
    except (TypeError, ValueError):  # no signature to read (a builtin): as documented
        return cast(ConfigMaker, make_config)
    positional = [p for p in parameters if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    if len(positional) == 2 and not any(p.kind is p.VAR_POSITIONAL for p in parameters):
        two = cast(Callable[[C3Settings, Any], ExtractorStrategyConfig], make_config)
        return lambda settings, options, _engines: two(settings, options)
    return cast(ConfigMaker, make_config)


def backend_strategy_factory(
    make_backend: Callable[[C3Settings, Any], FeatureBackend],
    options_model: type[BaseModel] | None = None,
) -> StrategyFactory:
    """A strategy's ``create`` for ANY ``FeatureBackend`` (OpenCV ORB/SIFT/AKAZE, a PyTorch or
    hand-written matcher: no ONNX engine, no ``InferenceRuntime`` needed): ``make_backend(config,
    options)`` builds the backend at start-up (``options`` validated with ``options_model``; None
    means its defaults) and the result is the one ``PipelineMatcher`` over it with ``[matcher]``'s
    thresholds, stored-features and tile-cache settings and the shared RANSAC, FDR, health window
    and clock. The runtimes it is handed (``inference_runtime``, ``lightglue_runtime``) are not
    used. Descriptors may be float32 or packed binary uint8 (``c3_matcher.features``)."""

    def create(
        config: C3Settings, *given: Any, options: Any = None, **named: Any
    ) -> CrossDomainMatcher:
        helpers = _helpers(given, named, _BACKEND_NEEDS)
        backend = make_backend(config, _validated(options_model, options))
        check_members(backend)  # None or another object: said as such, before it is used
        loop = PipelineSettings.from_settings(config.matcher)
        return pipeline_matcher(backend, loop, PipelineHelpers.from_named(helpers))

    return create
