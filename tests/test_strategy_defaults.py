"""Per-strategy defaults: each strategy's ``[matcher] photometric``, ``[matcher]
refit_threshold_px``, ``[lightglue] filter_threshold`` and ``exit_matches`` come from its own
plugin's ``defaults.DEFAULTS`` when the configuration leaves them unset, reach the composed
matcher, the LightGlue runtime and the RANSAC filter, and a configured value applies to every
strategy instead (docs/precision.md chose the values)."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

from c3_matcher.compose import (
    build_default_helpers,
    build_plugin_host,
    compose_root,
    strategy_settings,
)
from c3_matcher.config import C3Settings, load_settings
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.plugins.types import StrategyDefaults

STRATEGIES = {
    "disk_lightglue": "c3_matcher_disk_lightglue",
    "aliked_lightglue": "c3_matcher_aliked_lightglue",
    "xfeat": "c3_matcher_xfeat",
}


def declared(strategy: str) -> StrategyDefaults:
    defaults = importlib.import_module(f"{STRATEGIES[strategy]}.defaults").DEFAULTS
    assert isinstance(defaults, StrategyDefaults)
    return defaults


@pytest.mark.parametrize("strategy", sorted(STRATEGIES))
def test_the_plugin_declares_its_defaults_in_one_place(strategy: str) -> None:
    assert build_plugin_host().resolve(strategy).defaults is declared(strategy)


@pytest.mark.parametrize("strategy", sorted(STRATEGIES))
def test_unset_settings_resolve_to_the_strategys_own_defaults(strategy: str) -> None:
    unset = load_settings(env={})
    assert unset.matcher.photometric is None and unset.lightglue.filter_threshold is None
    assert unset.matcher.refit_threshold_px is None
    resolved = strategy_settings(unset, strategy)
    assert resolved.matcher.strategy == strategy
    assert resolved.matcher.photometric == declared(strategy).photometric
    assert resolved.lightglue.filter_threshold == declared(strategy).filter_threshold
    assert resolved.matcher.refit_threshold_px == declared(strategy).refit_threshold_px
    assert resolved.lightglue.exit_matches == declared(strategy).exit_matches


@pytest.mark.parametrize("strategy", sorted(STRATEGIES))
def test_a_configured_value_applies_to_every_strategy(strategy: str) -> None:
    env = {
        "C3_MATCHER_MATCHER__PHOTOMETRIC": "grey",
        "C3_MATCHER_LIGHTGLUE__FILTER_THRESHOLD": "0.05",
        "C3_MATCHER_MATCHER__REFIT_THRESHOLD_PX": "0",
        "C3_MATCHER_LIGHTGLUE__EXIT_MATCHES": "12",
    }
    resolved = strategy_settings(load_settings(env=env), strategy)
    assert (resolved.matcher.photometric, resolved.lightglue.filter_threshold) == ("grey", 0.05)
    assert resolved.matcher.refit_threshold_px == 0.0
    assert resolved.lightglue.exit_matches == 12


@pytest.mark.parametrize("strategy", sorted(STRATEGIES))
def test_each_strategy_declares_what_its_measurements_chose(strategy: str) -> None:
    """A strategy that declares nothing gets upstream's values (no final refit); each shipped
    strategy measured a final refit that lowers IT-03 on every flight, so it declares one."""
    assert declared(strategy) != StrategyDefaults()
    assert 0.0 < declared(strategy).refit_threshold_px < C3Settings().matcher.ransac_threshold_px


@pytest.mark.parametrize("strategy", sorted(STRATEGIES))
def test_the_composed_matcher_and_runtime_use_the_strategys_defaults(
    strategy: str, engine_dir: Path, tmp_path: Path
) -> None:
    settings = C3Settings(
        matcher={"strategy": strategy},
        engines={"directory": engine_dir},
        fdr={"path": tmp_path / "fdr.jsonl"},
    )
    helpers = build_default_helpers(settings)
    assert helpers["c3_lightglue_runtime"].filter_threshold == declared(strategy).filter_threshold
    assert helpers["c3_lightglue_runtime"].exit_matches == declared(strategy).exit_matches
    ransac = helpers["c282_ransac_filter"]
    assert (ransac.refit_px, ransac.refit_floor) == (declared(strategy).refit_threshold_px, 60)
    root = compose_root(settings, {**helpers, "c13_fdr": InMemoryFdr()}, configure_logs=False)
    try:
        pipeline = root.matcher.settings  # type: ignore[attr-defined]
        assert pipeline.photometric == declared(strategy).photometric
    finally:
        root.close()
