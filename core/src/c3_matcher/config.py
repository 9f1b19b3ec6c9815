"""Configuration with pydantic-settings: defaults < TOML file < environment variables.

Environment variables use the prefix ``C3_MATCHER_`` and ``__`` between levels, e.g.
``C3_MATCHER_MATCHER__MIN_INLIERS_THRESHOLD=80``. Unknown keys are refused (a typo in a flight
configuration must not pass silently), and so are bad values, naming the field and why.
Defaults follow upstream LightGlue's conventions unless a measurement chose otherwise
(docs/decisions.md); every record derived from ``[matcher]`` takes them from here."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar

from pydantic import BaseModel, Field, PrivateAttr, ValidationError, ValidationInfo, field_validator
from pydantic_settings import (
    BaseSettings,
    InitSettingsSource,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    SettingsError,
)

from c3_matcher.config_problems import unparsed_env, validation_problems
from c3_matcher.config_sources import (
    ENV_PREFIX,
    REPLACED_KIND,
    GivenSectionsSource,
    MappingEnvSource,
    ReplacedByEnvironment,
    SettingsSection,
    read_toml,
    without_env_values,
)
from c3_matcher.engines.providers import canonical_provider_options, configured_providers
from c3_matcher.engines.store import default_engine_dir, usable_directory
from c3_matcher.errors import ConfigurationError
from c3_matcher.fdr.jsonl import MIN_BYTES, PENDING_BYTES, SEGMENT_BYTES
from c3_matcher.logs import log_event
from c3_matcher.plugins.types import StrategyDefaults
from c3_matcher.user_dirs import user_cache_dir, user_data_dir

__all__ = [
    "ENV_PREFIX",
    "KEYPOINT_BUDGET_RANGE",
    "C3Settings",
    "EngineSettings",
    "FdrSettings",
    "LightGlueSettings",
    "LoggingSettings",
    "MatcherSettings",
    "load_settings",
    "matcher_default",
    "with_strategy_defaults",
]

KEYPOINT_BUDGET_RANGE = (16, 8192)
"""The keypoints per image ``[matcher] max_keypoints`` and ``--max-keypoints`` accept."""


class MatcherSettings(SettingsSection):
    """The ``[matcher]`` table."""

    strategy: str = Field(
        "disk_lightglue",
        min_length=1,
        description="strategy name (a linked plugin's), default disk_lightglue",
    )
    min_inliers_threshold: int = Field(
        60,
        ge=4,
        le=KEYPOINT_BUDGET_RANGE[1],  # inliers <= keypoints: above the budget, refused at start-up
        description="RANSAC inliers a candidate needs; below it on every candidate: "
        "InsufficientInliersError",
    )
    residual_warn_threshold_px: float = Field(
        2.5,
        gt=0,
        allow_inf_nan=False,
        description="median residual (tile px) above which the result is logged as a WARNING "
        "(c3.matcher.residual_above_threshold)",
    )
    ransac_threshold_px: float = Field(
        3.0, gt=0, le=1000, allow_inf_nan=False, description="RANSAC inlier threshold, tile px"
    )
    max_image_pixels: int = Field(
        50_000_000,
        ge=256,
        le=2**31 - 1,
        description="images (frames, tiles) above width x height px are refused from their "
        "header before decoding (decompression bombs)",
    )
    max_long_side: int = Field(
        1024, ge=64, le=8192, description="images are downscaled so their long side <= this"
    )
    max_keypoints: int | None = Field(
        None,
        ge=KEYPOINT_BUDGET_RANGE[0],
        le=KEYPOINT_BUDGET_RANGE[1],
        description="keypoints per image; None: the strategy's default (2048 for DISK or ALIKED "
        "+ LightGlue, 4096 for XFeat with mutual nearest neighbours)",
    )
    ransac_seed: int = Field(
        0, ge=0, le=2**31 - 1, description="RANSAC generator seed (determinism; OpenCV's C int)"
    )
    tile_cache_size: int = Field(
        16,
        ge=0,
        le=1024,
        description="tiles whose features are kept between frames "
        "(0: re-extract every tile every frame)",
    )
    stored_features: bool = Field(
        True,
        description="serve a candidate's features from the tile store's precomputed map "
        "features (c3-matcher features build) when it has the window for this extractor "
        "engine, provider and preprocessing (the same bits extraction gives); otherwise, or "
        "False, the candidate's window is extracted in flight",
    )
    refit_threshold_px: float | None = Field(
        None,
        ge=0,
        le=1000,
        allow_inf_nan=False,
        description="final refit after RANSAC, tile px: keep only the inliers within this "
        "distance of the homography and re-fit it to them, unless fewer than "
        "min_inliers_threshold would remain (never drops a candidate); 0: off; unset: the "
        "strategy's own default (docs/precision.md); set: every strategy uses it",
    )
    photometric: Literal["none", "grey", "clahe"] | None = Field(
        None,
        description="photometric normalisation of query and tiles before extraction: none; "
        "grey (luminance only); clahe (grey + local contrast equalisation in 64 px cells); "
        "unset: the strategy's own default, chosen by measurement per strategy "
        "(docs/precision.md); set: every strategy uses it",
    )
    geometric_prior: bool = Field(
        True,
        description="with attitude AND height (rectified query at the tile GSD): keep only "
        "matches voting for the dominant translation before RANSAC and refuse a candidate "
        "whose homography is not near a translation (docs/decisions.md, the geometric prior)",
    )
    rotation_search: bool = Field(
        False,
        description="when a frame comes WITHOUT attitude (missing, or the caller does not trust "
        "it after an IMU fault and passes attitude=None): extract the query turned by 0/90/180/"
        "270 deg and keep, per candidate, the turn whose RANSAC result ranks best (inliers, then "
        "residual); about 4x the query extraction and matching (docs/accuracy.md, rotation "
        "search); off: such a frame is matched as it comes; never applied with attitude",
    )
    refine: bool = Field(
        False,
        description="a second pass for the best-ranked candidate: re-render the query through "
        "its first homography into the tile's pixel grid, extract and match again, and keep "
        "that pass when it passes the same checks and ranks better (inliers, then residual); "
        "one more query extraction and match per frame; no gain measured on the shipped "
        "flights (docs/accuracy.md, the seasonal gap)",
    )
    prior_rotation_tol_deg: float = Field(
        10.0, gt=0, le=90, description="heading error tolerated by the prior, deg"
    )
    prior_scale_tol: float = Field(
        0.15, gt=0, le=1, description="relative scale error tolerated (height, terrain relief)"
    )
    prior_shear_tol: float = Field(
        0.15, gt=0, le=1, description="anisotropy (singular-value ratio - 1) tolerated (tilt)"
    )
    prior_base_tol_px: float = Field(
        12.0, gt=0, le=1000, description="translation-vote tolerance at the nadir point, tile px"
    )
    options: dict[str, dict[str, Any]] = Field(
        default_factory=dict,
        description="per-strategy options, [matcher.options.<strategy>], validated by the plugin",
    )


def matcher_default(name: str) -> Any:
    """``[matcher]``'s default for ``name``: every record derived from it defaults to this."""
    return MatcherSettings.model_fields[name].default


class EngineSettings(SettingsSection):
    """The ``[engines]`` table."""

    directory: Path = Field(
        default_factory=default_engine_dir,
        description="where engines and manifests live (default: <checkout>/.engines when run "
        "from a source checkout, else ~/.cache/c3-matcher/engines)",
    )
    tensorrt_cache_dir: Path = Field(
        default_factory=lambda: user_cache_dir() / "tensorrt",
        description="ONNX Runtime TensorRT engine cache (filled on the ground, reused in flight)",
    )
    providers: tuple[str, ...] | None = Field(
        None,
        description="ONNX Runtime execution providers in order of preference, full names or "
        "TensorRT, CUDA, ROCm, MIGraphX, OpenVINO, DirectML, CoreML, CPU; intersected with the "
        "installed ones; default: TensorRT -> CUDA -> ... -> CPU, whichever is installed",
    )
    device_id: int = Field(0, ge=0, le=64, description="GPU device id (GPU providers)")
    gpu_mem_limit_bytes: int | None = Field(
        None, ge=1 << 20, description="GPU memory arena limit (CUDA, ROCm); None: no limit"
    )
    tensorrt_fp16: bool = Field(
        False,
        description="TensorRT FP16 engines (opt-in: FP16 is not yet verified against FP32 "
        "for keypoints and matches)",
    )
    intra_op_threads: int = Field(
        0, ge=0, le=1024, description="ONNX Runtime intra-op threads (0: one per core)"
    )
    cpu_mem_arena: bool = Field(
        True,
        description="ONNX Runtime CPU memory arena: on is ~20 % faster for disk_lightglue on a "
        "CPU for ~65 MB more peak memory on the demo frame (559 vs 494 MB); off for the "
        "tightest memory (docs/decisions.md)",
    )
    provider_options: dict[str, dict[str, Any]] = Field(
        default_factory=dict,
        description="raw onnxruntime options per provider (any name providers accepts), merged "
        "last; none for CPU (its settings: intra_op_threads, cpu_mem_arena)",
    )

    @field_validator("directory", "tensorrt_cache_dir")
    @classmethod
    def _a_directory(cls, value: Path) -> Path:
        return usable_directory(value)  # ValueError: a file there, or above it

    @field_validator("providers", "provider_options")
    @classmethod
    def _known_providers(cls, value: Any, info: ValidationInfo) -> Any:
        """Provider names made canonical; unknown ones, options never applied are refused."""
        try:
            if info.field_name == "providers":
                return configured_providers(value)
            return canonical_provider_options(value, info.data.get("providers"))
        except ConfigurationError as exc:
            raise ValueError("; ".join(reason for _, reason in exc.problems)) from None


def _adaptive_share(description: str, *, upstream: str) -> Any:
    """A share in [-1, 1] of LightGlue's adaptive mode: -1 switches it off, None (the default)
    takes upstream's value for the feature type (``upstream`` states it)."""
    return Field(
        None,
        ge=-1,
        le=1,
        description=f"{description}; -1 off; None: upstream's default for the feature type "
        f"({upstream})",
    )


class LightGlueSettings(SettingsSection):
    """The ``[lightglue]`` table: how the LightGlue-family matchers run."""

    mode: Literal["auto", "adaptive", "full"] = Field(
        "auto",
        description="adaptive: the transformer in steps with upstream's early exit and point "
        "pruning (needs the <feature>-steps engine, else full); full: the single graph, every "
        "layer on every point; auto: adaptive where the sessions run on the CPU (a GPU provider "
        "that fell back too), full on a GPU (measured: docs/decisions.md)",
    )
    filter_threshold: float | None = Field(
        None,
        ge=0,
        lt=1,
        description="match confidence a LightGlue match must exceed (upstream: 0.1); unset: "
        "the strategy's own default, chosen by measurement per strategy (docs/precision.md); "
        "set: every strategy uses it",
    )
    depth_confidence: float | None = _adaptive_share(
        "early exit (adaptive mode): stop when this share of tokens is confident",
        upstream="0.95; -1 for LighterGlue",
    )
    width_confidence: float | None = _adaptive_share(
        "point pruning (adaptive mode): drop points whose matchability is below 1 - this",
        upstream="0.99; 0.95 for LighterGlue",
    )
    exit_matches: int | None = Field(
        None,
        ge=0,
        le=KEYPOINT_BUDGET_RANGE[1],  # matches <= keypoints: above the budget, refused at start-up
        description="unmatchable-pair exit (adaptive mode): after the second layer, stop a pair "
        "with no matches when fewer than this many mutual matches have confidence above 0.3; "
        "0 off; unset: the strategy's own default, chosen by measurement (docs/decisions.md)",
    )


class FdrSettings(SettingsSection):
    """The ``[fdr]`` table."""

    path: Path = Field(
        default_factory=lambda: user_data_dir() / "fdr" / "c3_fdr.jsonl",
        description="live FDR segment (JSON Lines); default in the user data directory "
        "($XDG_DATA_HOME/c3-matcher/fdr, else ~/.local/share/c3-matcher/fdr)",
    )
    max_bytes: int = Field(SEGMENT_BYTES, ge=MIN_BYTES, description="rotate above this size")
    max_pending_bytes: int = Field(
        PENDING_BYTES, ge=MIN_BYTES, description="held while the disk is full"
    )


class LoggingSettings(SettingsSection):
    """The ``[logging]`` table."""

    level: Literal["TRACE", "DEBUG", "INFO", "WARNING", "ERROR"] = Field(
        "INFO",
        description="the least severe of the matcher's JSON log records kept, of TRACE < DEBUG "
        "< INFO < WARNING < ERROR (any case): on stderr, and in a replay's matcher.log; the "
        "flight data recorder takes the WARNING and ERROR records whatever it is",
    )

    @field_validator("level", mode="before")
    @classmethod
    def _any_case(cls, value: Any) -> Any:
        return value.upper() if isinstance(value, str) else value


class C3Settings(BaseSettings):
    """The whole configuration."""

    model_config = SettingsConfigDict(
        env_prefix=ENV_PREFIX, env_nested_delimiter="__", extra="forbid", frozen=True
    )

    matcher: MatcherSettings = MatcherSettings()
    engines: EngineSettings = EngineSettings()
    lightglue: LightGlueSettings = LightGlueSettings()
    fdr: FdrSettings = FdrSettings()
    logging: LoggingSettings = LoggingSettings()
    _replaced: ReplacedByEnvironment = PrivateAttr(default_factory=ReplacedByEnvironment)

    @property
    def replaced_by_environment(self) -> ReplacedByEnvironment:
        """The file's values a table set in the environment left out (``load_settings``)."""
        return self._replaced

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        # init < environment (os.environ; load_settings passes its own: TOML < a given one)
        return (MappingEnvSource(settings_cls), GivenSectionsSource.replacing(init_settings))


def with_strategy_defaults(
    settings: C3Settings, defaults: StrategyDefaults, strategy: str = ""
) -> C3Settings:
    """``settings`` with each setting left unset (None) taken from a strategy's ``defaults``
    (``[matcher] photometric``, ``refit_threshold_px``, ``[lightglue] filter_threshold``,
    ``exit_matches``); a set value is kept. Idempotent. ``ConfigurationError`` names the
    strategy when its declared defaults are not valid settings."""
    try:
        matcher = _defaulted(settings.matcher, defaults, ("photometric", "refit_threshold_px"))
        lightglue = _defaulted(settings.lightglue, defaults, ("filter_threshold", "exit_matches"))
    except ValidationError as exc:
        where = f"strategy {strategy!r} defaults" if strategy else "strategy defaults"
        raise ConfigurationError(where, validation_problems(exc)) from None
    if matcher is settings.matcher and lightglue is settings.lightglue:
        return settings
    return settings.model_copy(update={"matcher": matcher, "lightglue": lightglue})


_S = TypeVar("_S", bound=BaseModel)


def _defaulted(section: _S, defaults: StrategyDefaults, keys: tuple[str, ...]) -> _S:
    """``section`` with its unset (None) ``keys`` from ``defaults``, validated (or itself)."""
    unset = {key: getattr(defaults, key) for key in keys if getattr(section, key) is None}
    return type(section).model_validate({**dict(section), **unset}) if unset else section


def load_settings(
    toml_path: Path | None = None, env: Mapping[str, str] | None = None
) -> C3Settings:
    """Load and validate the configuration: defaults < the TOML file < the environment (``env``,
    default ``os.environ``, only read), whose value replaces the file's whole, a table too (what
    it leaves out: ``replaced_by_environment``, logged); ``ConfigurationError`` names bad fields."""
    environ = dict(os.environ if env is None else env)
    source = f"{toml_path} + environment" if toml_path else "environment"
    data = read_toml(toml_path, source) if toml_path is not None else {}
    data, replaced = without_env_values(data, environ, toml_path)
    try:
        sources = (MappingEnvSource(C3Settings, environ), InitSettingsSource(C3Settings, data))
        settings = C3Settings(_build_sources=(sources, data))  # environment > TOML > defaults
    except ValidationError as exc:
        problems = validation_problems(exc, environ, toml_path, data)  # each value's origin
        raise ConfigurationError(source, problems) from None
    except (SettingsError, ValueError, TypeError, RecursionError) as exc:  # JSON not read
        raise ConfigurationError(source, unparsed_env(exc, environ)) from None
    settings._replaced = replaced
    if replaced.values:
        log_event("WARNING", REPLACED_KIND, replaced.line(), **replaced.fields())
    return settings
