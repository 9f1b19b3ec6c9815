"""``XFeatMatcher`` and ``create``: the light XFeat strategy (CPU-only and low-power builds).

XFeat keypoints and descriptors come from the XFeat engine run by the C7 ``InferenceRuntime``;
they are matched by the numpy mutual nearest neighbour (``matcher = "mnn"``, the default, match
phase ``xfeat_match``) or by LighterGlue in the shared ``LightGlueRuntime`` (``"lighterglue"``,
match phase ``lighterglue_match``); RANSAC runs in the shared ``RansacFilter``. Engines load in
the constructor, called by ``create`` at start-up; the start-up probe asserts their outputs.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from c3_matcher.config import C3Settings, matcher_default
from c3_matcher.engines.store import EngineStore
from c3_matcher.pipeline import PipelineSettings
from c3_matcher.prepared import InputRule
from c3_matcher.protocols import (
    LightGlueRuntime,
)
from c3_matcher.strategy import (
    ExtractorMatcher,
    LightGluePairMatcher,
    PairMatcher,
    strategy_factory,
)
from c3_matcher_xfeat.engines import (
    LIGHTERGLUE_SPEC,
    XFEAT_SIZE_MULTIPLE,
    XFEAT_SPEC,
)
from c3_matcher_xfeat.mnn import MutualNearestNeighbourMatcher
from c3_matcher_xfeat.options import (
    DEFAULT_MAX_KEYPOINTS,
    DEFAULT_MIN_COSSIM,
    DEFAULT_UPSCALE,
    XFeatMatcherKind,
    XFeatOptions,
)

__all__ = [
    "EXTRACT_PHASE",
    "MATCH_PHASES",
    "STRATEGY",
    "XFeatConfig",
    "XFeatMatcher",
    "create",
]

STRATEGY = "xfeat"
EXTRACT_PHASE = "xfeat_forward"
MATCH_PHASES: dict[str, str] = {"mnn": "xfeat_match", "lighterglue": "lighterglue_match"}


@dataclass(frozen=True, slots=True)
class XFeatConfig:
    """What the XFeat strategy needs (built from ``C3Settings`` and ``XFeatOptions``).

    Engine paths are files in the engine directory (``lighterglue_engine_path`` only for
    ``matcher == "lighterglue"``); image and keypoint rules are in px; ``max_keypoints`` is the
    per-image budget: above the graph's top-K (``XFEAT_TOP_K``) the extractor backend keeps the
    top-K and warns once (``c3.matcher.keypoints_capped``), as for every strategy; ``pipeline``
    is what the per-frame loop takes from ``[matcher]``.
    """

    extractor_engine_path: Path
    matcher: XFeatMatcherKind = "mnn"
    lighterglue_engine_path: Path | None = None
    min_cossim: float = DEFAULT_MIN_COSSIM
    max_long_side: int = matcher_default("max_long_side")
    max_keypoints: int = DEFAULT_MAX_KEYPOINTS["mnn"]
    pipeline: PipelineSettings = field(default_factory=PipelineSettings)  # from [matcher]
    similarity_threads: int = 0  # [engines] intra_op_threads, for the mutual-NN similarity
    upscale: int = DEFAULT_UPSCALE  # the extractor runs on each image enlarged this many times

    def __post_init__(self) -> None:
        if self.matcher not in MATCH_PHASES:
            raise ValueError(f"matcher must be one of {sorted(MATCH_PHASES)}, got {self.matcher!r}")
        if self.max_keypoints < 1:
            raise ValueError(f"max_keypoints must be >= 1, got {self.max_keypoints}")
        if self.matcher == "lighterglue" and self.lighterglue_engine_path is None:
            raise ValueError("matcher 'lighterglue' needs lighterglue_engine_path")

    @property
    def label(self) -> str:
        return STRATEGY

    @property
    def extract_phase(self) -> str:
        return EXTRACT_PHASE

    @property
    def match_phase(self) -> str:
        return MATCH_PHASES[self.matcher]

    @property
    def input_rule(self) -> InputRule:
        return InputRule(
            max_long_side=self.max_long_side, multiple=XFEAT_SIZE_MULTIPLE, upscale=self.upscale
        )

    def matcher_engines(self) -> Mapping[str, Path]:
        path = self.lighterglue_engine_path
        return {} if path is None else {"lighterglue": path}

    def pair_matcher(self, lightglue_runtime: LightGlueRuntime) -> PairMatcher:
        if self.matcher == "lighterglue":
            assert self.lighterglue_engine_path is not None  # __post_init__
            return LightGluePairMatcher(
                lightglue_runtime, self.lighterglue_engine_path, "xfeat", role="lighterglue"
            )
        return MutualNearestNeighbourMatcher(self.min_cossim, self.similarity_threads)

    @classmethod
    def from_c3_settings(
        cls, settings: C3Settings, options: XFeatOptions | None, engines: EngineStore
    ) -> XFeatConfig:
        """Engine paths from ``engines`` (``EngineError`` naming the build command if one is
        missing), the image rule and the loop's settings from ``[matcher]`` as composed for the
        strategy, the matcher choice and the keypoint budget from ``[matcher.options.xfeat]``
        (None: its defaults; ``XFeatOptions.keypoint_budget``: ``[matcher] max_keypoints``
        counts only when set explicitly)."""
        opts = options or XFeatOptions()
        m = settings.matcher
        return cls(
            extractor_engine_path=engines.require_spec(XFEAT_SPEC),
            matcher=opts.matcher,
            lighterglue_engine_path=(
                engines.require_spec(LIGHTERGLUE_SPEC) if opts.matcher == "lighterglue" else None
            ),
            min_cossim=opts.min_cossim,
            max_long_side=m.max_long_side,
            max_keypoints=opts.keypoint_budget(m.max_keypoints),
            pipeline=PipelineSettings.from_settings(m),
            similarity_threads=int(settings.engines.intra_op_threads),
            upscale=opts.upscale,
        )


class XFeatMatcher(ExtractorMatcher):
    """The XFeat ``CrossDomainMatcher`` (the core's ``ExtractorMatcher``). Single-threaded.
    ``pair_matcher=`` replaces the configured one (tests)."""


create = strategy_factory(XFeatMatcher, XFeatConfig.from_c3_settings, XFeatOptions)
"""Strategy factory (``compose_root``): resolve the engines the chosen matcher needs, load them
now (start-up) and return the wired ``XFeatMatcher``. ``options`` is the validated
``XFeatOptions`` (None: defaults)."""
