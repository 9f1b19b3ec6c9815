"""The matcher contract test kit, for any strategy: protocol conformance, best candidate and
tie-break, drop-and-continue on a failing extractor or matcher, the inlier threshold, the
residual warning, one health update per call, correspondence shapes, determinism and the
per-frame flight-data record.

Any ``FeatureBackend`` (ORB + brute force, SIFT, a PyTorch model, an ONNX extractor): subclass
``BackendContract`` and implement ``make_backend``; the kit runs your real ``extract`` and
``match`` on a textured stand-in image (the query) and on views of the same texture moved a
known offset (the tiles) while the script decides which calls fail and what RANSAC finds,
checks that every match of the query with a tile follows that offset in (query, tile) order,
and checks your backend itself (every ``FeatureBackend`` member, features well formed, no
keypoint where ``image.valid`` is False, a blank image gives no keypoint rather than an
exception, self-matching finds the same points, matching the query with a tile pairs each query
point once with the tile point that shows it, confidences in [0, 1], determinism, start-up
probe). Every image follows your ``input_rule``::

    from c3_matcher.testing.contract import BackendContract

    class TestOrbContract(BackendContract):
        def make_backend(self):
            return OrbBackend()

A strategy built on the extractor kit over the runtimes (``ExtractorMatcher``) may instead
subclass ``MatcherContract`` and implement ``make_matcher`` to build its strategy over the
doubles it is handed (the allowed test doubles)::

    from c3_matcher.testing.contract import MatcherContract

    class TestMyMatcherContract(MatcherContract):
        extract_phase = "my_forward"
        match_phase = "my_match"

        def make_matcher(self, doubles):
            return MyMatcher(doubles.inference, doubles.lightglue, doubles.ransac,
                             doubles.fdr, doubles.health, my_config, doubles.clock)

For an ``ExtractorMatcher`` subclass, ``c3_matcher.testing.strategy_kit.ExtractorMatcherContract``
writes that ``make_matcher`` from the matcher class and its config.

Every strategy built on ``c3_matcher.strategy`` or ``c3_matcher.pipeline`` passes it.
"""

from __future__ import annotations

import dataclasses
import io
import json
import uuid
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from c3_matcher.dto import MatchResult
from c3_matcher.errors import InsufficientInliersError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.features import DESCRIPTOR_DTYPES, Features, RawMatches
from c3_matcher.health import RollingHealthWindow
from c3_matcher.logs import configure_logging
from c3_matcher.pipeline import FeatureBackend, PipelineSettings
from c3_matcher.prepared import PreparedImage
from c3_matcher.probe import (
    check_shifted_matches,
    engine_startup_probe,
    missing_members,
    probe_image,
    probe_pair,
    probe_shift,
    probe_side,
)
from c3_matcher.protocols import CrossDomainMatcher
from c3_matcher.stages.extract import checked_features
from c3_matcher.testing.backend_checks import assert_empty_fits, assert_within_budget
from c3_matcher.testing.doubles import Doubles
from c3_matcher.testing.fakes import (
    FakeClock,
    FakeInferenceRuntime,
    FakeLightGlueRuntime,
    FakeRansacFilter,
    ScriptedCandidate,
    make_frame,
    make_rerank,
    scripted_pipeline,
)
from c3_matcher.testing.scripted import MarkedRansac, ScriptedBackend

__all__ = ["BackendContract", "Doubles", "MatcherContract", "ScriptedBackend"]

S = ScriptedCandidate
MIN_INLIERS = 60


class MatcherContract:
    """Subclass and implement ``make_matcher``; set the phase names of your strategy."""

    extract_phase = "disk_forward"
    match_phase = "lightglue_match"
    frame_size = 64  # px, the square query frame

    def make_matcher(self, doubles: Doubles) -> CrossDomainMatcher:
        raise NotImplementedError("implement make_matcher(doubles) in your test class")

    def _scripted_backend(self, script: list[ScriptedCandidate]) -> ScriptedBackend | None:
        return None

    def _phases(self, doubles: Doubles) -> tuple[str, str]:
        """(extract, match) phase names the pipeline reports for this strategy."""
        if doubles.backend is not None:
            return doubles.backend.extract_phase, doubles.backend.match_phase
        return self.extract_phase, self.match_phase

    # -- harness --------------------------------------------------------------------------------
    @pytest.fixture
    def rig(self) -> Iterator[Any]:
        stream = io.StringIO()
        fdr = InMemoryFdr()
        handle = configure_logging(fdr, level="DEBUG", stream=stream)

        def build(script: list[ScriptedCandidate]) -> tuple[Doubles, Any]:
            clock = FakeClock()
            backend = self._scripted_backend(script)
            doubles = Doubles(
                script,
                FakeInferenceRuntime(script),
                FakeLightGlueRuntime(script),
                FakeRansacFilter(script) if backend is None else MarkedRansac(script, backend),
                fdr,
                RollingHealthWindow(clock, MIN_INLIERS),
                clock,
                stream,
                backend,
            )
            matcher = self.make_matcher(doubles)
            frame, calibration = make_frame(uuid.UUID(int=11), self.frame_size)
            rerank = make_rerank(frame.frame_id, script, self.frame_size)

            def match() -> MatchResult:
                try:
                    return matcher.match(frame, rerank, calibration)
                finally:  # a match that broke the (query, tile) contract fails the test
                    if backend is not None:
                        backend.assert_no_breach()

            return doubles, match

        yield build
        handle.close()

    def test_protocol_conformance(self, rig: Any) -> None:
        doubles, _ = rig([S()])
        assert isinstance(self.make_matcher(doubles), CrossDomainMatcher)

    def test_best_candidate_and_tie_break(self, rig: Any) -> None:
        _, match = rig([S(120, 1.4), S(80, 1.0), S(120, 1.1)])
        result = match()
        assert result.best_candidate_idx == 0
        assert [(c.inlier_count, c.per_candidate_residual_px) for c in result.per_candidate] == [
            (120, 1.1),
            (120, 1.4),
            (80, 1.0),
        ]

    def test_extractor_failure_dropped(self, rig: Any) -> None:
        doubles, match = rig([S(100), S(100, fail_extract=True), S(90)])
        result = match()
        assert len(result.per_candidate) == 2 and result.candidates_dropped == 1
        (log,) = doubles.logs("c3.matcher.backbone_error")
        extract_phase, _ = self._phases(doubles)
        assert log["level"] == "ERROR" and log["phase"] == extract_phase
        assert log["tile_id"] is not None
        assert [r["phase"] for r in doubles.fdr.of_kind("matcher.backbone_error")] == [
            extract_phase
        ]

    def test_matcher_failure_dropped(self, rig: Any) -> None:
        doubles, match = rig([S(100, fail_match=True), S(100), S(90)])
        result = match()
        assert len(result.per_candidate) == 2
        _, match_phase = self._phases(doubles)
        assert [r["phase"] for r in doubles.logs("c3.matcher.backbone_error")] == [match_phase]
        assert len(doubles.fdr.of_kind("matcher.backbone_error")) == 1

    def test_below_threshold(self, rig: Any) -> None:
        doubles, match = rig([S(59), S(20), S(1)])
        with pytest.raises(InsufficientInliersError):
            match()
        assert len(doubles.logs("c3.matcher.insufficient_inliers")) == 1
        assert len(doubles.fdr.of_kind("matcher.insufficient_inliers")) == 1
        last = doubles.health.last_update
        assert doubles.health.update_count == 1 and last is not None
        assert (last.best_inlier_count, last.had_backbone_error) == (0, False)

    def test_all_failed(self, rig: Any) -> None:
        doubles, match = rig([S(fail_extract=True)] * 3)
        with pytest.raises(InsufficientInliersError):
            match()
        assert len(doubles.logs("c3.matcher.backbone_error")) == 3
        assert len(doubles.logs("c3.matcher.insufficient_inliers")) == 1
        last = doubles.health.last_update
        assert doubles.health.update_count == 1 and last is not None
        assert (last.best_inlier_count, last.had_backbone_error) == (0, True)

    def test_residual_warn(self, rig: Any) -> None:
        doubles, match = rig([S(100, 4.2)])
        match()
        (warn,) = doubles.logs("c3.matcher.residual_above_threshold")
        assert (warn["level"], warn["residual_px"], warn["threshold_px"]) == ("WARNING", 4.2, 2.5)

    def test_health_once_per_call(self, rig: Any) -> None:
        doubles, match = rig([S(100), S(50, fail_match=True), S(70)])
        match()
        match()
        assert doubles.health.update_count == 2
        last = doubles.health.last_update
        assert last is not None and (last.best_inlier_count, last.had_backbone_error) == (100, True)

    def test_correspondence_shape(self, rig: Any) -> None:
        _, match = rig([S(120), S(64)])
        for c in match().per_candidate:
            assert c.inlier_correspondences.shape == (c.inlier_count, 4)
            assert c.inlier_correspondences.dtype.name == "float32"

    def test_deterministic(self, rig: Any) -> None:
        _, match = rig([S(120, 1.4), S(80, 1.0), S(120, 1.1)])
        first, *others = [match() for _ in range(3)]
        for other in others:
            assert other.best_candidate_idx == first.best_candidate_idx
            assert all(
                a.same_content(b)
                for a, b in zip(first.per_candidate, other.per_candidate, strict=True)
            )

    def test_frame_done(self, rig: Any) -> None:
        doubles, match = rig([S(120, 1.1), S(fail_extract=True), S(80, 1.5)])
        result = match()
        (done,) = doubles.fdr.of_kind("matcher.frame_done")
        assert (
            done["candidates_input"],
            done["candidates_dropped"],
            done["best_inlier_count"],
            done["best_residual_px"],
        ) == (3, 1, 120, 1.1)
        assert done["frame_id"] == str(result.frame_id)
        assert done["best_tile_id"] == result.per_candidate[0].tile_id.as_list()


class BackendContract(MatcherContract):
    """The contract for ANY ``FeatureBackend``: implement ``make_backend`` (no runtimes, no
    engines needed). Every matcher test above runs through ``PipelineMatcher`` over your backend
    (see ``ScriptedBackend``); the tests below check the backend itself."""

    frame_size = 256  # px, at least (then the input rule's): room for a border (ORB's: 31 px)
    min_self_matches = 8  # matches of the stand-in with itself or with a tile, at least

    def make_backend(self) -> FeatureBackend:
        raise NotImplementedError("implement make_backend() in your test class")

    def _scripted_backend(self, script: list[ScriptedCandidate]) -> ScriptedBackend | None:
        backend = self.make_backend()
        shift = probe_shift(backend.input_rule, self._side(backend))
        return ScriptedBackend(backend, script, shift)

    def make_matcher(self, doubles: Doubles) -> CrossDomainMatcher:
        backend = doubles.backend or ScriptedBackend(self.make_backend(), doubles.script)
        return scripted_pipeline(
            backend,
            doubles.ransac,
            doubles.fdr,
            PipelineSettings(),
            clock=doubles.clock,
            health=doubles.health,
        )

    def _image(self, pixels: NDArray[np.uint8]) -> PreparedImage:
        """``pixels`` as a prepared image, every pixel valid."""
        h, w = pixels.shape[:2]
        return PreparedImage(pixels, np.ones((h, w), bool), np.eye(3), (w, h))

    def _side(self, backend: FeatureBackend) -> int:
        """The stand-in's side: ``frame_size`` rounded by the backend's input rule."""
        return probe_side(backend.input_rule, self.frame_size)

    def _textured(self, backend: FeatureBackend | None = None) -> Features:
        backend = backend or self.make_backend()
        side = self._side(backend)
        return backend.extract(probe_image(side, side))

    def test_backend_has_every_member(self) -> None:
        backend = self.make_backend()
        missing = missing_members(backend)
        assert not missing, f"{type(backend).__name__} lacks {', '.join(missing)}"

    def test_backend_keeps_keypoints_on_valid_pixels(self) -> None:
        """``image.valid`` False (nodata, padding, warp borders) keeps no keypoint: here the
        left half, textured like the rest, is masked out."""
        backend = self.make_backend()
        side = self._side(backend)
        valid = np.ones((side, side), bool)
        valid[:, : side // 2] = False
        image = dataclasses.replace(probe_image(side, side), valid=valid)
        features = backend.extract(image)
        assert len(features) > 0, "no keypoint on the valid half (is the mask 0/255?)"
        outside = int((features.keypoints[:, 0] < side // 2 - 1.0).sum())
        assert outside == 0, f"{outside} keypoints where image.valid is False (pass it as a mask)"

    def test_backend_features_well_formed(self) -> None:
        backend = self.make_backend()
        features = self._textured(backend)
        assert isinstance(features, Features) and len(features) > 0
        assert features.descriptors.dtype in DESCRIPTOR_DTYPES
        side = self._side(backend)
        assert features.image_size == (side, side)
        checked_features(features, (side, side))  # refused as in flight, naming them

    def test_backend_keeps_keypoints_on_a_frame_sized_image(self) -> None:
        """A nav-frame-sized image (640 x 480 px, rounded by the input rule): its keypoints on
        it, as the core checks on every image in flight (a scale forgotten past some image size
        shows here, not on the small stand-in)."""
        backend = self.make_backend()
        w, h = probe_side(backend.input_rule, 640), probe_side(backend.input_rule, 480)
        features = backend.extract(probe_image(w, h))
        assert isinstance(features, Features) and len(features) > 0
        assert features.image_size == (w, h)
        checked_features(features, (w, h))  # refused as in flight, naming them

    def test_backend_blank_image_gives_no_error(self) -> None:
        """A blank image gives ``Features`` (none, or few), with descriptors of the textured
        image's width and dtype, that ``match`` takes."""
        backend = self.make_backend()
        side = self._side(backend)
        blank = backend.extract(self._image(np.full((side, side, 3), 128, np.uint8)))
        assert isinstance(blank, Features)
        textured = self._textured(backend)
        raw = backend.match(blank, textured)
        assert isinstance(raw, RawMatches) and len(raw) <= len(blank)
        assert_empty_fits(blank, textured)

    def test_backend_keeps_to_its_keypoint_budget(self) -> None:
        """At most ``max_keypoints`` keypoints (where declared, else the core's ceiling) on
        each of the kit's images: the stand-in, the probe pair and the frame-sized image."""
        backend = self.make_backend()
        side, rule = self._side(backend), backend.input_rule
        query, tile, _ = probe_pair(rule, self.frame_size)
        frame_sized = probe_image(probe_side(rule, 640), probe_side(rule, 480))
        assert_within_budget(backend, [probe_image(side, side), query, tile, frame_sized])

    def test_backend_self_match_finds_the_same_points(self) -> None:
        backend = self.make_backend()
        features = self._textured(backend)
        raw = backend.match(features, features)
        assert isinstance(raw, RawMatches) and len(raw) >= self.min_self_matches
        q, t = raw.matches[:, 0], raw.matches[:, 1]
        assert bool(((q >= 0) & (q < len(features)) & (t >= 0) & (t < len(features))).all())
        moved = np.linalg.norm(features.keypoints[q] - features.keypoints[t], axis=1)
        assert float(np.mean(moved < 1.0)) >= 0.8
        scores = raw.scores
        assert bool(((scores >= 0) & (scores <= 1)).all()), "match confidences outside [0, 1]"

    def _pair(self, backend: FeatureBackend) -> tuple[Features, Features, int]:
        """The query and tile features of the probe pair (``probe_pair``), and its shift."""
        query, tile, shift = probe_pair(backend.input_rule, self.frame_size)
        return backend.extract(query), backend.extract(tile), shift

    def test_backend_matches_a_view_that_holds_the_image_in_query_tile_order(self) -> None:
        """The tile shows the query's texture ``shift`` px further right, and texture the query
        lacks: each pair is (query index, tile index), joins a point to the same point of the
        tile, and uses a keypoint of either side once."""
        backend = self.make_backend()
        query, tile, shift = self._pair(backend)
        raw = backend.match(query, tile)
        assert isinstance(raw, RawMatches) and len(raw) >= self.min_self_matches
        try:
            check_shifted_matches(query, tile, raw, shift)
        except ValueError as exc:
            raise AssertionError(str(exc)) from None
        scores = raw.scores
        assert bool(((scores >= 0) & (scores <= 1)).all()), "match confidences outside [0, 1]"

    def test_backend_deterministic(self) -> None:
        backend = self.make_backend()
        a, tile, _ = self._pair(backend)
        b, _, _ = self._pair(backend)
        for name in ("keypoints", "descriptors", "keypoint_scores"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert np.array_equal(backend.match(a, tile).matches, backend.match(b, tile).matches)

    def test_backend_startup_probe_and_provenance(self) -> None:
        backend = self.make_backend()
        engine_startup_probe(backend)
        json.dumps(dict(backend.provenance()))
