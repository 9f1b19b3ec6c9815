"""The plugin author's path for any backend: the contract kit runs on OpenCV backends that never
touch an inference runtime (binary AKAZE descriptors with Hamming distance, float SIFT with L2),
it fails a backend that breaks the contract, ``Features`` keeps binary descriptors binary,
``backend_strategy_factory`` builds the pipeline, and ``dir(c3_matcher.plugins)`` lists its
lazily loaded names."""

from __future__ import annotations

import dataclasses
from typing import Any

import cv2
import numpy as np
import pytest

from c3_matcher import plugins as c3
from c3_matcher.config import C3Settings
from c3_matcher.errors import InvalidInputError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.features import Features, RawMatches
from c3_matcher.health import RollingHealthWindow
from c3_matcher.pipeline import FeatureBackend, PipelineMatcher
from c3_matcher.prepared import InputRule, PreparedImage
from c3_matcher.testing import FakeClock, FakeRansacFilter
from c3_matcher.testing.contract import BackendContract


class OpenCvBackend:
    """A FeatureBackend over an OpenCV detector and a brute-force matcher."""

    extract_phase, match_phase = "cv_detect", "cv_match"
    input_rule = InputRule(max_long_side=1024, multiple=1)

    def __init__(self, detector: Any, norm: int, label: str, *, cross_check: bool = True) -> None:
        self.label = label
        self._detector = detector
        self._bf = cv2.BFMatcher(norm, crossCheck=cross_check)
        self._width = detector.descriptorSize()  # its empty answer as wide as the others
        self._dtype = np.uint8 if norm == cv2.NORM_HAMMING else np.float32

    def extract(self, image: PreparedImage) -> Features:
        grey = cv2.cvtColor(image.image, cv2.COLOR_RGB2GRAY)
        kps, desc = self._detector.detectAndCompute(grey, image.valid.astype(np.uint8) * 255)
        if desc is None:
            desc = np.zeros((0, self._width), self._dtype)
        xy = np.array([k.pt for k in kps], np.float32).reshape(-1, 2)
        scores = np.array([k.response for k in kps], np.float32)
        return Features(xy, desc, scores, (grey.shape[1], grey.shape[0]))

    def match(self, query: Features, tile: Features) -> RawMatches:
        found = (
            self._bf.match(query.descriptors, tile.descriptors) if len(query) * len(tile) else []
        )
        pairs = np.array([(m.queryIdx, m.trainIdx) for m in found], np.int64).reshape(-1, 2)
        return RawMatches(pairs, np.ones(len(found), np.float32))

    def provenance(self) -> dict[str, Any]:
        return {"provider": "opencv", "engines": {}}


class TestAkazeBinaryContract(BackendContract):
    def make_backend(self) -> FeatureBackend:
        return OpenCvBackend(cv2.AKAZE_create(), cv2.NORM_HAMMING, "akaze_bf")


class TestSiftFloatContract(BackendContract):
    def make_backend(self) -> FeatureBackend:
        return OpenCvBackend(cv2.SIFT_create(500), cv2.NORM_L2, "sift_bf")


class TestOrbContract(BackendContract):
    def make_backend(self) -> FeatureBackend:
        return OpenCvBackend(cv2.ORB_create(2000), cv2.NORM_HAMMING, "orb_bf")


class RaisesOnBlank(OpenCvBackend):
    """The classic mistake: OpenCV returns None descriptors on a blank image."""

    def extract(self, image: PreparedImage) -> Features:
        grey = cv2.cvtColor(image.image, cv2.COLOR_RGB2GRAY)
        kps, desc = self._detector.detectAndCompute(grey, None)
        return Features(
            np.array([k.pt for k in kps], np.float32), desc, np.ones(len(kps), np.float32), (1, 1)
        )


class ShuffledMatches(OpenCvBackend):
    """Matches that pair the wrong points."""

    def match(self, query: Features, tile: Features) -> RawMatches:
        raw = super().match(query, tile)
        pairs = raw.matches.copy()
        pairs[:, 1] = np.roll(pairs[:, 1], 1)
        return RawMatches(pairs, raw.scores)


class ScaleForgotten(OpenCvBackend):
    """Detects images over 300 px upsampled twice and never scales the keypoints back."""

    def extract(self, image: PreparedImage) -> Features:
        features = super().extract(image)
        if max(features.image_size) <= 300:
            return features
        return dataclasses.replace(features, keypoints=features.keypoints * 2)


def test_kit_fails_keypoints_off_a_frame_sized_image_that_small_images_miss() -> None:
    """The stand-in and the start-up probe are under 300 px: they pass this backend; the
    frame-sized image names its keypoints off the image, as the core refuses them in flight."""

    class Scaled(BackendContract):
        def make_backend(self) -> FeatureBackend:
            return ScaleForgotten(cv2.AKAZE_create(), cv2.NORM_HAMMING, "x")

    Scaled().test_backend_features_well_formed()
    Scaled().test_backend_startup_probe_and_provenance()
    with pytest.raises(InvalidInputError, match="outside the 640x480 px image"):
        Scaled().test_backend_keeps_keypoints_on_a_frame_sized_image()
    TestAkazeBinaryContract().test_backend_keeps_keypoints_on_a_frame_sized_image()


@pytest.mark.parametrize(
    ("backend_class", "check"),
    [
        (RaisesOnBlank, "test_backend_blank_image_gives_no_error"),
        (ShuffledMatches, "test_backend_self_match_finds_the_same_points"),
    ],
)
def test_kit_fails_a_backend_that_breaks_the_contract(backend_class: type, check: str) -> None:
    class Broken(BackendContract):
        def make_backend(self) -> FeatureBackend:
            backend: FeatureBackend = backend_class(cv2.AKAZE_create(), cv2.NORM_HAMMING, "x")
            return backend

    with pytest.raises((AssertionError, InvalidInputError, TypeError)):
        getattr(Broken(), check)()
    getattr(TestAkazeBinaryContract(), check)()  # the same check passes a correct backend


class SiftOverBudget(OpenCvBackend):
    """SIFT asked for 500 keypoints, declaring 500 its budget: OpenCV keeps the keypoints tied
    with the 500th, so a textured image gives 501."""

    max_keypoints = 500

    def __init__(self) -> None:
        super().__init__(cv2.SIFT_create(500), cv2.NORM_L2, "sift")


class OrbEmptyUnsized(OpenCvBackend):
    """ORB whose answer for an image without keypoints has descriptors (0, 0), not (0, 32)."""

    def __init__(self) -> None:
        super().__init__(cv2.ORB_create(2000), cv2.NORM_HAMMING, "orb")
        self._width = 0


def test_kit_names_what_flight_would_put_right_quietly() -> None:
    """Flight cuts an extraction to its budget and matches an empty one with nothing; the kit
    is stricter: a backend one keypoint over its ``max_keypoints``, or whose empty answer has
    descriptors of another width, fails it, naming what to change."""

    class Over(BackendContract):
        def make_backend(self) -> FeatureBackend:
            return SiftOverBudget()

    class Unsized(BackendContract):
        def make_backend(self) -> FeatureBackend:
            return OrbEmptyUnsized()

    with pytest.raises(AssertionError, match=r"501 keypoints on the kit's \d+x\d+ px image, more"):
        Over().test_backend_keeps_to_its_keypoint_budget()
    Over().test_backend_startup_probe_and_provenance()  # start-up passes it, as flight does
    with pytest.raises(AssertionError, match=r"descriptors are \(0, 0\) uint8, a textured"):
        Unsized().test_backend_blank_image_gives_no_error()
    TestOrbContract().test_backend_blank_image_gives_no_error()  # (0, 32): it fits
    TestOrbContract().test_backend_keeps_to_its_keypoint_budget()


def test_features_keep_binary_descriptors_and_refuse_other_dtypes() -> None:
    kp = np.zeros((2, 2), np.float32)
    scores = np.ones(2, np.float32)
    binary = Features(kp, np.zeros((2, 32), np.uint8), scores, (8, 8))
    assert binary.descriptors.dtype == np.uint8
    with pytest.raises(InvalidInputError, match="float32 or uint8"):
        Features(kp, np.zeros((2, 32), np.int32), scores, (8, 8))


def test_backend_strategy_factory_builds_the_pipeline_over_any_backend() -> None:
    made: list[Any] = []

    def make_backend(settings: C3Settings, options: Any) -> FeatureBackend:
        made.append(options)
        return OpenCvBackend(cv2.AKAZE_create(), cv2.NORM_HAMMING, "akaze_bf")

    create = c3.backend_strategy_factory(make_backend)
    clock = FakeClock()
    matcher = create(
        C3Settings(matcher={"tile_cache_size": 4, "photometric": "none"}),
        ransac_filter=FakeRansacFilter([]),
        health_window=RollingHealthWindow(clock, 60),
        fdr_client=InMemoryFdr(),
        clock=clock,
        inference_runtime=None,
        lightglue_runtime=None,
    )
    assert isinstance(matcher, PipelineMatcher) and matcher.backend.label == "akaze_bf"
    assert made == [None]


def test_dir_lists_the_lazily_loaded_names() -> None:
    names = dir(c3)
    for name in ("backend_strategy_factory", "Features", "StrategySpec", "hookimpl"):
        assert name in names
    assert set(c3.__all__) <= set(names)
