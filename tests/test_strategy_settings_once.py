"""A strategy's settings are composed once: ``compose_root`` applies the strategy's own defaults
to the configuration and hands the result to the strategy's factory, which applies none again,
and every per-frame loop is built from one object (``PipelineSettings``: its thresholds and its
tile cache together). Each shipped strategy, composed over its real engines with settings a user
overrides beside the ones it leaves to the strategy, runs with exactly what the configuration
and the strategy's defaults say."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import Any

import pytest

from c3_matcher.compose import build_default_helpers, compose_root
from c3_matcher.config import C3Settings, with_strategy_defaults
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.pipeline import PipelineMatcher, PipelineSettings
from c3_matcher.plugins.types import StrategyDefaults
from c3_matcher.protocols import KeypointBudgetBackend
from c3_matcher.tile_cache import TileFeatureCache

STRATEGIES = {
    "disk_lightglue": "c3_matcher_disk_lightglue",
    "aliked_lightglue": "c3_matcher_aliked_lightglue",
    "xfeat": "c3_matcher_xfeat",
}
OVERRIDES = {  # set by the user; photometric and the refit are left to the strategy
    "max_keypoints": 1024,
    "max_long_side": 800,
    "tile_cache_size": 5,
    "min_inliers_threshold": 70,
    "stored_features": False,
    "rotation_search": True,
}


def declared(strategy: str) -> StrategyDefaults:
    defaults = importlib.import_module(f"{STRATEGIES[strategy]}.defaults").DEFAULTS
    assert isinstance(defaults, StrategyDefaults)
    return defaults


def overridden(strategy: str, engine_dir: Path, tmp_path: Path) -> C3Settings:
    return C3Settings(
        matcher={"strategy": strategy, **OVERRIDES},
        engines={"directory": engine_dir},
        fdr={"path": tmp_path / "fdr.jsonl"},
    )


@contextmanager
def counting_calls(function: Any) -> Iterator[list[str]]:
    """The callers' file names of each call of ``function`` while the block runs, however the
    caller imported it."""
    code, calls = function.__code__, []

    def profile(frame: FrameType, event: str, _arg: object) -> None:
        if event == "call" and frame.f_code is code and frame.f_back is not None:
            calls.append(frame.f_back.f_code.co_filename)

    previous = sys.getprofile()
    sys.setprofile(profile)
    try:
        yield calls
    finally:
        sys.setprofile(previous)


@contextmanager
def tile_cache_capacities(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[int]]:
    """The capacity of each tile-feature cache made while the block runs."""
    made: list[int] = []
    init = TileFeatureCache.__init__

    def recording(self: TileFeatureCache, capacity: int) -> None:
        made.append(capacity)
        init(self, capacity)

    with monkeypatch.context() as patched:
        patched.setattr(TileFeatureCache, "__init__", recording)
        yield made


@pytest.mark.parametrize("strategy", sorted(STRATEGIES))
def test_a_composition_applies_the_strategys_defaults_once(
    strategy: str, engine_dir: Path, tmp_path: Path
) -> None:
    """It applied them in ``compose_root`` and again in the plugin's config builder."""
    settings = overridden(strategy, engine_dir, tmp_path)
    helpers = {**build_default_helpers(settings), "c13_fdr": InMemoryFdr()}
    with counting_calls(with_strategy_defaults) as calls:
        root = compose_root(settings, helpers, configure_logs=False)
    root.close()
    assert [Path(c).name for c in calls] == ["compose.py"]


@pytest.mark.parametrize("strategy", sorted(STRATEGIES))
def test_the_composed_matcher_runs_with_the_users_settings_and_the_strategys_defaults(
    strategy: str, engine_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    settings = overridden(strategy, engine_dir, tmp_path)
    helpers = {**build_default_helpers(settings), "c13_fdr": InMemoryFdr()}
    with tile_cache_capacities(monkeypatch) as capacities:
        root = compose_root(settings, helpers, configure_logs=False)
    try:
        matcher = root.matcher
        assert isinstance(matcher, PipelineMatcher)
        resolved = with_strategy_defaults(settings, declared(strategy), strategy).matcher
        assert matcher.settings == PipelineSettings.from_settings(resolved)
        assert matcher.settings.photometric == declared(strategy).photometric
        assert matcher.settings.min_inliers_threshold == OVERRIDES["min_inliers_threshold"]
        assert matcher.settings.rotation_search and not matcher.settings.stored_features
        assert capacities == [OVERRIDES["tile_cache_size"]]
        backend = matcher.backend
        assert isinstance(backend, KeypointBudgetBackend)
        assert backend.max_keypoints == OVERRIDES["max_keypoints"]
        assert backend.input_rule.max_long_side == OVERRIDES["max_long_side"]
    finally:
        root.close()
