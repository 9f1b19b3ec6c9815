"""Which backends a tile store serves precomputed features: those that declare the extractor
engine their features come from (``StoredFeaturesBackend.extractor_sha256``), the flight and a
build reading the same declaration; and a build in this process runs on its command's plugin
host, the plugins discovered once."""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.config import C3Settings
from c3_matcher.prepared import InputRule
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.protocols import KeypointBudgetBackend, StoredFeaturesBackend
from c3_matcher.stages.candidate_features import feature_request


def test_the_sift_baseline_is_no_stored_features_backend() -> None:
    """OpenCV SIFT declares a keypoint budget but no extractor engine: its tiles are extracted,
    and a build refuses it."""
    from c3_matcher_tools.baselines import SiftBackend

    sift = SiftBackend(InputRule(max_long_side=512, multiple=8))
    assert isinstance(sift, KeypointBudgetBackend)
    assert not isinstance(sift, StoredFeaturesBackend)
    assert feature_request(sift, FramePreprocessor(sift.input_rule)) is None


@pytest.mark.slow
def test_disk_declares_the_extractor_engine_its_provenance_names(engine_dir: Path) -> None:
    """DISK's declared sha is its extractor engine file's, the one its provenance names, and
    the one both the flight's request and a build's set are keyed by."""
    from c3_matcher.compose import build_plugin_host, strategy_settings
    from c3_matcher_tools.features.worker import ProcessBackends, set_facts
    from c3_matcher_tools.run.matcher import open_backend

    host = build_plugin_host()
    settings = C3Settings(engines={"directory": engine_dir})
    backend = open_backend(settings, "disk_lightglue", plugin_host=host)
    assert isinstance(backend, StoredFeaturesBackend)
    named = backend.provenance()["engines"]["extractor"]
    engine = engine_dir / Path(named["file"]).name
    assert backend.extractor_sha256 == named["file_sha256"]
    assert backend.extractor_sha256 == hashlib.sha256(engine.read_bytes()).hexdigest()
    request = feature_request(backend, FramePreprocessor(backend.input_rule))
    assert request is not None and request.extractor_sha256 == backend.extractor_sha256
    resolved = strategy_settings(settings, "disk_lightglue", host).model_dump_json()
    facts = set_facts("disk_lightglue", resolved, ProcessBackends(host))
    assert facts.extractor_sha256 == backend.extractor_sha256


@pytest.mark.slow
def test_a_build_in_this_process_discovers_the_plugins_once(
    small_flight: Callable[..., Path], engine_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``features build --workers 0`` and ``features info`` each run on the plugin host their
    command line was built from: no backend discovers the plugins again."""
    from c3_matcher.cli import main
    from c3_matcher.plugins.manager import PluginHost

    hosts: list[PluginHost] = []
    discover = PluginHost.__init__

    def counted(self: PluginHost, *args: Any, **kwargs: Any) -> None:
        hosts.append(self)
        discover(self, *args, **kwargs)

    flight = small_flight("one_host")
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    monkeypatch.setattr(PluginHost, "__init__", counted)
    argv = ["features", "build", str(flight), "--strategy", "xfeat", "--workers", "0"]
    assert main([*argv, "--flight-candidates"]) == 0
    assert len(hosts) == 1
    assert main(["features", "info", str(flight / "tiles.mbtiles")]) == 0
    assert len(hosts) == 2
