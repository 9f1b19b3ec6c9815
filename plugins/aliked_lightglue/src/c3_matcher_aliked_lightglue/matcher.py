"""``AlikedLightGlueMatcher`` and ``create`` (the strategy's create, with the FDR and clock).

ALIKED keypoints and descriptors come from the ALIKED engine (variant ``n16`` by default,
``n16rot`` by ``[matcher.options.aliked_lightglue] variant = "n16rot"``) run by the C7
``InferenceRuntime``; LightGlue (ALIKED weights, feature type ``"aliked"``) runs in the shared
``LightGlueRuntime``; RANSAC in the shared ``RansacFilter``. Engines load in the constructor,
called by ``create`` at start-up.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from pydantic import BaseModel, ConfigDict

from c3_matcher.config import C3Settings
from c3_matcher.engines.store import EngineStore
from c3_matcher.strategy import ExtractorLightGlueConfig, ExtractorMatcher, strategy_factory
from c3_matcher_aliked_lightglue.engines import (
    ALIKED_SIZE_MULTIPLE,
    ALIKED_SPECS,
    LIGHTGLUE_ALIKED_SPEC,
)

__all__ = [
    "ALIKED_SIZE_MULTIPLE",
    "EXTRACT_PHASE",
    "FEATURE_TYPE",
    "STRATEGY",
    "AlikedLightGlueConfig",
    "AlikedLightGlueMatcher",
    "AlikedLightGlueOptions",
    "create",
]

STRATEGY = "aliked_lightglue"
FEATURE_TYPE = str(LIGHTGLUE_ALIKED_SPEC.feature_type)
EXTRACT_PHASE = "aliked_forward"


class AlikedLightGlueOptions(BaseModel):
    """``[matcher.options.aliked_lightglue]``: ``variant`` selects the ALIKED weights, ``"n16"``
    (default) or ``"n16rot"`` (trained with in-plane rotation augmentation). Unknown keys are
    refused."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    variant: Literal["n16", "n16rot"] = "n16"


@dataclass(frozen=True, slots=True)
class AlikedLightGlueConfig(ExtractorLightGlueConfig):
    """``MatcherConfig`` for ALIKED + LightGlue."""

    @classmethod
    def from_c3_settings(
        cls, settings: C3Settings, options: AlikedLightGlueOptions | None, engines: EngineStore
    ) -> AlikedLightGlueConfig:
        """Engine paths from ``engines`` (``EngineError`` naming the build command if one is
        missing) for the options' variant (None: the default), image rules and the loop's
        settings from ``settings`` as composed for the strategy
        (``ExtractorLightGlueConfig.from_settings``)."""
        variant = (options or AlikedLightGlueOptions()).variant
        return cls.from_settings(
            settings,
            label=STRATEGY,
            feature_type=FEATURE_TYPE,
            extract_phase=EXTRACT_PHASE,
            extractor_engine_path=engines.require_spec(ALIKED_SPECS[variant]),
            lightglue_engine_path=engines.require_spec(LIGHTGLUE_ALIKED_SPEC),
            size_multiple=ALIKED_SIZE_MULTIPLE,
        )


class AlikedLightGlueMatcher(ExtractorMatcher):
    """ALIKED + LightGlue ``CrossDomainMatcher``. Single-threaded."""


create = strategy_factory(
    AlikedLightGlueMatcher, AlikedLightGlueConfig.from_c3_settings, AlikedLightGlueOptions
)
"""``create``: resolve the ALIKED (``options.variant``) and LightGlue engines, load them
now (start-up) and return the wired ``AlikedLightGlueMatcher``. ``options`` is the validated
``AlikedLightGlueOptions`` (a mapping is validated here; None = defaults)."""
