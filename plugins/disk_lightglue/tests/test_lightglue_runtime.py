"""LightGlue on ONNX Runtime vs kornia's LightGlue (pruning off) on real DISK features."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from kornia.feature.lightglue import normalize_keypoints as kornia_normalize
from numpy.typing import NDArray

from c3_matcher.engines.extract import run_extractor
from c3_matcher.engines.lightglue import OnnxLightGlueRuntime, normalize_keypoints
from c3_matcher.engines.runtime import OnnxInferenceRuntime
from c3_matcher.errors import EngineError
from c3_matcher.features import Features, PairSide
from c3_matcher.strategy import LightGluePairMatcher


@pytest.fixture(scope="module")
def naip_pair(
    runtime: OnnxInferenceRuntime,
    disk_engine: Path,
    read_image: Callable[[str], NDArray[np.uint8]],
) -> tuple[Features, Features]:
    """Real cross-date features: NAIP 2010 (640x480 crop) and 2020 (512x512 crop, overlapping)."""
    engine_id = runtime.load_engine(disk_engine)
    a = np.ascontiguousarray(
        read_image("naip_timeseries/m_4709963_se_14_1_20100629.tif")[:480, :640]
    )
    b = np.ascontiguousarray(
        read_image("naip_timeseries/m_4709963_se_14_1_20200831.tif")[100:612, 200:712]
    )
    fa = run_extractor(runtime, engine_id, a, np.ones(a.shape[:2], bool), 1024)
    fb = run_extractor(runtime, engine_id, b, np.ones(b.shape[:2], bool), 1024)
    return fa, fb


def test_normalisation_is_bit_identical_to_kornia(naip_pair: tuple[Features, Features]) -> None:
    for feats in naip_pair:
        size = feats.image_size
        ours = normalize_keypoints(feats.keypoints, size)
        theirs = kornia_normalize(
            torch.from_numpy(feats.keypoints)[None], torch.tensor([size], dtype=torch.float32)
        )[0].numpy()
        assert ours.dtype == np.float32
        assert ours.tobytes() == theirs.tobytes()
    # non-square: the long side spans [-1, 1], the short side keeps the aspect ratio
    corners = np.array([[0, 0], [640, 480]], np.float32)
    np.testing.assert_allclose(normalize_keypoints(corners, (640, 480)), [[-1, -0.75], [1, 0.75]])


def _reference_matches(
    reference: Any, fa: Features, fb: Features
) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    with torch.no_grad():
        out = reference(
            {
                "image0": {
                    "keypoints": torch.from_numpy(fa.keypoints)[None],
                    "descriptors": torch.from_numpy(fa.descriptors)[None],
                    "image_size": torch.tensor([fa.image_size], dtype=torch.float32),
                },
                "image1": {
                    "keypoints": torch.from_numpy(fb.keypoints)[None],
                    "descriptors": torch.from_numpy(fb.descriptors)[None],
                    "image_size": torch.tensor([fb.image_size], dtype=torch.float32),
                },
            }
        )
    return out["matches"][0].numpy().astype(np.int64), out["scores"][0].numpy()


def test_matches_identical_to_reference_on_real_features(
    runtime: OnnxInferenceRuntime,
    lightglue_engine: Path,
    lightglue_reference: Any,
    naip_pair: tuple[Features, Features],
) -> None:
    fa, fb = naip_pair
    pairs = LightGluePairMatcher(OnnxLightGlueRuntime(runtime), lightglue_engine, "disk")
    got = pairs.match(fa, fb)
    ref_matches, ref_scores = _reference_matches(lightglue_reference, fa, fb)
    assert len(ref_matches) > 20
    np.testing.assert_array_equal(got.matches, ref_matches)
    np.testing.assert_allclose(got.scores, ref_scores, atol=1e-4, rtol=0)
    again = pairs.match(fa, fb)
    assert again.matches.tobytes() == got.matches.tobytes()
    assert again.scores.tobytes() == got.scores.tobytes()


def test_threshold_is_configurable(
    runtime: OnnxInferenceRuntime, lightglue_engine: Path, naip_pair: tuple[Features, Features]
) -> None:
    fa, fb = naip_pair
    args = (fa.pair_side, fb.pair_side)
    loose = OnnxLightGlueRuntime(runtime, filter_threshold=0.0)
    strict = OnnxLightGlueRuntime(runtime, filter_threshold=0.9)
    loose.load("disk", lightglue_engine)
    strict.load("disk", lightglue_engine)
    n_loose = len(loose.match_pair(*args, feature_type="disk"))
    high = strict.match_pair(*args, feature_type="disk")
    assert n_loose > len(high)
    assert (high.scores > 0.9).all()


def test_load_rules_and_errors(
    runtime: OnnxInferenceRuntime, lightglue_engine: Path, disk_engine: Path
) -> None:
    matcher = OnnxLightGlueRuntime(runtime)
    kp = np.zeros((3, 2), np.float32)
    desc = np.zeros((3, 128), np.float32)
    side = PairSide(kp, desc, (64, 64))
    with pytest.raises(KeyError, match="no LightGlue engine loaded for feature type 'disk'"):
        matcher.match_pair(side, side, feature_type="disk")
    matcher.load("disk", lightglue_engine)
    matcher.load("disk", lightglue_engine)  # idempotent
    assert matcher.feature_types == ("disk",)
    with pytest.raises(EngineError, match="already loaded"):
        matcher.load("disk", disk_engine)  # another engine for the same feature type
    with pytest.raises(EngineError, match="matches 'disk' features"):
        matcher.load("aliked", lightglue_engine)
    empty = matcher.match_pair(PairSide(kp[:0], desc[:0], (64, 64)), side, feature_type="disk")
    assert empty.matches.shape == (0, 2) and empty.scores.shape == (0,)
    with pytest.raises(ValueError, match="desc1"):
        matcher.match_pair(side, PairSide(kp, desc[:2], (64, 64)), feature_type="disk")
