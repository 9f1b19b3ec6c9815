"""Frozen records that plugins hand to the core through the hooks."""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypedDict

from pydantic import BaseModel

from c3_matcher.errors import InvalidInputError
from c3_matcher.protocols import CrossDomainMatcher

if TYPE_CHECKING:
    from c3_matcher.health import RollingHealthWindow
    from c3_matcher.protocols import (
        Clock,
        FdrClient,
        InferenceRuntime,
        LightGlueRuntime,
        RansacFilter,
    )

__all__ = ["StrategyDefaults", "StrategyFactory", "StrategyHelpers", "StrategySpec"]

_NAME = re.compile(r"^[a-z][a-z0-9_]{1,63}$")


StrategyFactory = Callable[..., CrossDomainMatcher]
"""``create(...)`` of a strategy: called once by ``compose_root`` with keyword arguments
``config`` (``C3Settings``), ``options`` and the ``StrategyHelpers``."""


class StrategyHelpers(TypedDict):
    """The shared helpers ``compose_root`` hands a strategy's ``create`` (keyword arguments):
    the runtimes, RANSAC, the FDR client and clock, and the matcher's health window."""

    inference_runtime: InferenceRuntime
    lightglue_runtime: LightGlueRuntime
    ransac_filter: RansacFilter
    health_window: RollingHealthWindow
    fdr_client: FdrClient
    clock: Clock


@dataclass(frozen=True, slots=True)
class StrategyDefaults:
    """A strategy's own defaults for the settings that are left unset (None) in the
    configuration: ``photometric`` (``[matcher] photometric``: ``none``, ``grey`` or ``clahe``),
    ``filter_threshold`` (``[lightglue] filter_threshold``, the match confidence a LightGlue
    match must exceed, in [0, 1)), ``refit_threshold_px`` (``[matcher] refit_threshold_px``,
    tile px, 0 = no final refit) and ``exit_matches`` (``[lightglue] exit_matches``, the
    unmatchable-pair exit of adaptive LightGlue, 0 = off). A value set in the configuration
    applies to every strategy instead. The record's own defaults are upstream's (no
    normalisation, 0.1, no refit, no unmatchable-pair exit): what a strategy that declares none
    gets. Checked when resolved (``c3_matcher.config``)."""

    photometric: str = "none"
    filter_threshold: float = 0.1
    refit_threshold_px: float = 0.0
    exit_matches: int = 0


@dataclass(frozen=True, slots=True)
class StrategySpec:
    """One strategy a plugin offers.

    ``name`` is what ``[matcher] strategy`` selects; ``build_flag`` its BUILD_MATCHER_* flag
    (None for a third-party strategy outside the matrix); ``options_model`` validates
    ``[matcher.options.<name>]`` (unknown keys refused) or is None when it has no options.
    ``baseline`` marks a classical reference (SIFT + MAGSAC) that replay, eval and bench run
    beside the learned strategies; it is never a flight strategy. ``defaults`` are the
    strategy's own values for the settings the configuration leaves unset (``StrategyDefaults``).
    """

    name: str
    factory: StrategyFactory
    build_flag: str | None = None
    options_model: type[BaseModel] | None = None
    description: str = ""
    baseline: bool = False
    defaults: StrategyDefaults = StrategyDefaults()

    def __post_init__(self) -> None:
        if not _NAME.match(self.name):
            raise InvalidInputError("strategy.name", f"{self.name!r} must match {_NAME.pattern}")
        if self.build_flag is not None and not self.build_flag.startswith("BUILD_MATCHER_"):
            raise InvalidInputError(
                "strategy.build_flag", f"{self.build_flag!r} must start with BUILD_MATCHER_"
            )
        if not callable(self.factory):
            raise InvalidInputError("strategy.factory", "must be callable")
        model = self.options_model
        if model is not None and not (isinstance(model, type) and issubclass(model, BaseModel)):
            raise InvalidInputError(
                "strategy.options_model",
                f"{model!r} is not a pydantic model (a BaseModel subclass), or None",
            )
