"""The ALIKED engines (built by the ``engine_dir`` fixture) on real imagery the build did not
verify on: agreement with kornia's ALIKED (same weights), fewer maxima than K, masking,
determinism, the size rule and the recorded verification."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

from c3_matcher.engines.extract import run_extractor
from c3_matcher.engines.manifest import read_manifest
from c3_matcher.engines.runtime import OnnxInferenceRuntime
from c3_matcher.engines.store import EngineStore
from c3_matcher.testing.strategy_kit import assert_features_identical
from c3_matcher_aliked_lightglue.engines import ALIKED_SPECS, ALIKED_TOLERANCES
from c3_matcher_aliked_lightglue.export import (
    aliked_reference_features,
    compare_features,
    load_aliked_reference,
)
from c3_matcher_tools.testing.realpath import imagery_dir


def read_rgb(relative: str) -> NDArray[np.uint8]:
    bgr = cv2.imread(str(imagery_dir() / relative), cv2.IMREAD_COLOR)
    assert bgr is not None, relative
    return np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))


@pytest.fixture(scope="module")
def runtime() -> OnnxInferenceRuntime:
    return OnnxInferenceRuntime()


@pytest.fixture(scope="module")
def zurich() -> NDArray[np.uint8]:
    return read_rgb("open_orthophotos/swissimage_zurich_1091-322_00_0p5m.tif")


def _engine(engine_dir: Path, variant: str) -> Path:
    return EngineStore(engine_dir).require("aliked", variant)


def _reference(variant: str, top_k: int = 2048) -> Any:
    spec = ALIKED_SPECS[variant]
    return load_aliked_reference(spec.weights.resolve(), f"aliked-{variant}", top_k)


def _assert_agree(figures: dict[str, Any]) -> None:
    assert figures["keypoints_mismatch"] == 0, figures
    for key in ("keypoints_max_abs_px", "scores_max_abs", "descriptors_max_abs"):
        assert figures[key] <= ALIKED_TOLERANCES[key], figures


@pytest.mark.parametrize("variant", ["n16", "n16rot"])
@pytest.mark.parametrize(
    ("image", "box"),
    [
        ("open_orthophotos/swissimage_zurich_1091-322_00_0p5m.tif", (0, 0, 320, 256)),
        ("naip_timeseries/m_4709963_se_14_1_20100629.tif", (100, 50, 768, 512)),
    ],
)
def test_engine_agrees_with_kornia_on_unseen_imagery(engine_dir, runtime, variant, image, box):
    x, y, w, h = box
    rgb = np.ascontiguousarray(read_rgb(image)[y : y + h, x : x + w])
    engine_id = runtime.load_engine(_engine(engine_dir, variant))
    got = run_extractor(runtime, engine_id, rgb, np.ones((h, w), dtype=bool), 2048)
    ref = aliked_reference_features(_reference(variant), rgb)
    figures = compare_features((got.keypoints, got.keypoint_scores, got.descriptors), ref)
    _assert_agree(figures)
    assert len(got) > 500
    assert got.image_size == (w, h)
    assert np.all(np.diff(got.keypoint_scores) <= 0)
    np.testing.assert_allclose(np.linalg.norm(got.descriptors, axis=1), 1.0, atol=1e-5)


def test_fewer_maxima_than_k_pads_with_zero_scores(engine_dir, runtime, zurich):
    """A mostly masked image has far fewer than K maxima: the padding rows are dropped and the
    rest still agrees with kornia's forward_laf (mask multiplied into the score map)."""
    rgb = np.ascontiguousarray(zurich[:256, :256])
    mask = np.zeros((256, 256), dtype=bool)
    mask[64:160, 96:192] = True
    engine_id = runtime.load_engine(_engine(engine_dir, "n16"))
    raw = runtime.run(
        engine_id,
        {
            "image": rgb.transpose(2, 0, 1)[None].astype(np.float32) / 255,
            "mask": mask[None, None].astype(np.float32),
        },
    )
    padding = raw["keypoint_scores"] <= 0
    assert 0 < int((~padding).sum()) < 600 and int(padding.sum()) > 1400
    got = run_extractor(runtime, engine_id, rgb, mask, 2048)
    ref = aliked_reference_features(_reference("n16"), rgb, mask)
    _assert_agree(compare_features((got.keypoints, got.keypoint_scores, got.descriptors), ref))


def test_masked_pixels_yield_no_keypoints(engine_dir, runtime, zurich):
    rgb = np.ascontiguousarray(zurich[:512, :512])
    mask = np.ones((512, 512), dtype=bool)
    mask[:, :200] = False  # a left strip (a warp border)
    mask[300:400, 300:400] = False  # a nodata hole
    engine_id = runtime.load_engine(_engine(engine_dir, "n16"))
    got = run_extractor(runtime, engine_id, rgb, mask, 2048)
    assert len(got) > 500
    # Refinement moves a keypoint < 2 px from its (unmasked) maximum.
    assert got.keypoints[:, 0].min() > 198
    inside_hole = (
        (got.keypoints[:, 0] > 302)
        & (got.keypoints[:, 0] < 397)
        & (got.keypoints[:, 1] > 302)
        & (got.keypoints[:, 1] < 397)
    )
    assert not inside_hole.any()


def test_same_input_twice_is_bit_identical(engine_dir, runtime, zurich):
    engine_id = runtime.load_engine(_engine(engine_dir, "n16"))
    rgb = np.ascontiguousarray(zurich[:480, :640])
    mask = np.ones((480, 640), dtype=bool)
    a = run_extractor(runtime, engine_id, rgb, mask, 2048)
    b = run_extractor(runtime, engine_id, rgb, mask, 2048)
    assert_features_identical(a, b)


def test_size_rule_is_multiples_of_32(engine_dir, runtime, zurich):
    engine_id = runtime.load_engine(_engine(engine_dir, "n16"))
    assert runtime.manifest(engine_id).size_multiple == 32
    rgb = np.ascontiguousarray(zurich[:240, :320])  # 240 = 7.5 * 32
    with pytest.raises(ValueError, match="multiples of 32"):
        run_extractor(runtime, engine_id, rgb, np.ones((240, 320), dtype=bool), 2048)


@pytest.mark.parametrize("variant", ["n16", "n16rot"])
def test_manifest_records_a_passed_verification_at_three_sizes(engine_dir, variant):
    manifest = read_manifest(_engine(engine_dir, variant))
    report = manifest.verification
    assert report["passed"] and not report["failures"]
    assert len(report["checks"]) >= 3
    assert all(c["keypoints_mismatch"] == 0 for c in report["checks"])
    assert manifest.weights_sha256 == ALIKED_SPECS[variant].weights.sha256()


def test_pytorch_reference_backend_agrees_with_the_engine(engine_dir, runtime, zurich):
    """The bench's PyTorch reference (``c3_matcher_reference_backend``) extracts what the engine
    extracts on a masked real image."""
    from c3_matcher.compose import build_plugin_host
    from c3_matcher.config import C3Settings
    from c3_matcher.prepared import PreparedImage

    settings = C3Settings(matcher={"strategy": "aliked_lightglue"})
    backend = build_plugin_host().reference_backend("aliked_lightglue", settings)
    assert backend is not None and backend.extract_phase == "aliked_forward"
    assert backend.input_rule.multiple == 32
    rgb = np.ascontiguousarray(zurich[:320, :448])
    valid = np.ones((320, 448), dtype=bool)
    valid[:, :64] = False
    prepared = PreparedImage(
        image=rgb, valid=valid, working_from_engine=np.eye(3), working_size=(448, 320)
    )
    ref = backend.extract(prepared)
    engine_id = runtime.load_engine(_engine(engine_dir, "n16"))
    got = run_extractor(runtime, engine_id, rgb, valid, 2048)
    _assert_agree(
        compare_features(
            (got.keypoints, got.keypoint_scores, got.descriptors),
            (ref.keypoints, ref.keypoint_scores, ref.descriptors),
        )
    )
    assert len(backend.match(ref, ref)) > 0.9 * len(ref)
