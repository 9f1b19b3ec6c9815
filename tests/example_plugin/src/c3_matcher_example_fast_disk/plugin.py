"""The whole plugin: an options model, a config and one hook implementation.

It reuses the engines the DISK plugin declares (``disk/depth`` and ``lightglue/disk``, a
dependency of this distribution), so it declares none of its own and takes each engine by its
spec: the build of exactly that graph, never another one found under the same name. A plugin with
its own networks would add ``c3_matcher_engine_specs``.
"""

from pydantic import BaseModel, ConfigDict, Field

from c3_matcher import plugins as c3
from c3_matcher_disk_lightglue.engines import DISK_SIZE_MULTIPLE, DISK_SPEC, LIGHTGLUE_DISK_SPEC

NAME = "example_fast_disk"


class Options(BaseModel):
    """``[matcher.options.example_fast_disk]``."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    max_keypoints: int | None = Field(None, ge=64, le=4096)  # None: [matcher]'s, else 512
    max_long_side: int = Field(640, ge=128, le=2048)


def make_config(
    settings: c3.C3Settings, options: Options, engines: c3.EngineStore
) -> c3.ExtractorLightGlueConfig:
    """DISK + LightGlue at the options' keypoint budget, else ``[matcher] max_keypoints`` (None
    when unset), else 512 (``--max-keypoints`` sets the latter and clears the former), and at
    the options' long side (px); the engines from ``engines``, the engine directory."""
    return c3.ExtractorLightGlueConfig.from_settings(
        settings,
        label=NAME,
        feature_type="disk",
        extract_phase="disk_forward",
        extractor_engine_path=engines.require_spec(DISK_SPEC),
        lightglue_engine_path=engines.require_spec(LIGHTGLUE_DISK_SPEC),
        size_multiple=DISK_SIZE_MULTIPLE,
        max_keypoints=options.max_keypoints or settings.matcher.max_keypoints or 512,
        max_long_side=options.max_long_side,
    )


create = c3.strategy_factory(c3.ExtractorMatcher, make_config, Options)


@c3.hookimpl
def c3_matcher_strategies() -> list[c3.StrategySpec]:
    description = "example third-party plugin: fast DISK + LightGlue"
    return [c3.StrategySpec(NAME, create, options_model=Options, description=description)]
