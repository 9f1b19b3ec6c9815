"""The matcher contract test kit: AZ-345's AC-1 to AC-10 and AC-12, for any strategy.

A plugin's test module subclasses ``MatcherContract`` and implements ``make_matcher`` to build
its strategy over the doubles it is handed (the seeds' allowed test doubles)::

    from c3_matcher.testing.contract import MatcherContract

    class TestMyMatcherContract(MatcherContract):
        extract_phase = "my_forward"
        match_phase = "my_match"

        def make_matcher(self, doubles):
            return MyMatcher(doubles.inference, doubles.lightglue, doubles.ransac,
                             doubles.fdr, doubles.health, my_config, doubles.clock)

Every strategy built on ``c3_matcher.strategy`` or ``c3_matcher.pipeline`` passes it.
"""

from __future__ import annotations

import io
import json
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from c3_matcher.dto import MatchResult
from c3_matcher.errors import InsufficientInliersError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.health import RollingHealthWindow
from c3_matcher.logs import configure_logging
from c3_matcher.protocols import CrossDomainMatcher
from c3_matcher.testing.fakes import (
    FakeClock,
    FakeInferenceRuntime,
    FakeLightGlueRuntime,
    FakeRansacFilter,
    ScriptedCandidate,
    make_frame,
    make_rerank,
)

__all__ = ["Doubles", "MatcherContract"]

S = ScriptedCandidate
MIN_INLIERS = 60


@dataclass
class Doubles:
    """The doubles a contract test hands to ``make_matcher``, and what it inspects after."""

    script: list[ScriptedCandidate]
    inference: FakeInferenceRuntime
    lightglue: FakeLightGlueRuntime
    ransac: FakeRansacFilter
    fdr: InMemoryFdr
    health: RollingHealthWindow
    clock: FakeClock
    log_stream: io.StringIO

    def logs(self, kind: str) -> list[dict[str, Any]]:
        lines = [json.loads(x) for x in self.log_stream.getvalue().splitlines() if x]
        return [r for r in lines if r["kind"] == kind]


class MatcherContract:
    """Subclass and implement ``make_matcher``; set the phase names of your strategy."""

    extract_phase = "disk_forward"
    match_phase = "lightglue_match"

    def make_matcher(self, doubles: Doubles) -> CrossDomainMatcher:
        raise NotImplementedError("implement make_matcher(doubles) in your test class")

    # -- harness --------------------------------------------------------------------------------
    @pytest.fixture
    def rig(self) -> Iterator[Any]:
        stream = io.StringIO()
        fdr = InMemoryFdr()
        handle = configure_logging(fdr, level="DEBUG", stream=stream)

        def build(script: list[ScriptedCandidate]) -> tuple[Doubles, Any]:
            clock = FakeClock()
            doubles = Doubles(
                script,
                FakeInferenceRuntime(script),
                FakeLightGlueRuntime(script),
                FakeRansacFilter(script),
                fdr,
                RollingHealthWindow(clock, MIN_INLIERS),
                clock,
                stream,
            )
            matcher = self.make_matcher(doubles)
            frame, calibration = make_frame(uuid.UUID(int=11))
            rerank = make_rerank(frame.frame_id, script)

            def match() -> MatchResult:
                return matcher.match(frame, rerank, calibration)

            return doubles, match

        yield build
        handle.close()

    # -- AC-1 -----------------------------------------------------------------------------------
    def test_ac1_protocol_conformance(self, rig: Any) -> None:
        doubles, _ = rig([S()])
        assert isinstance(self.make_matcher(doubles), CrossDomainMatcher)

    # -- AC-2 -----------------------------------------------------------------------------------
    def test_ac2_best_candidate_and_tie_break(self, rig: Any) -> None:
        _, match = rig([S(120, 1.4), S(80, 1.0), S(120, 1.1)])
        result = match()
        assert result.best_candidate_idx == 0
        assert [(c.inlier_count, c.per_candidate_residual_px) for c in result.per_candidate] == [
            (120, 1.1),
            (120, 1.4),
            (80, 1.0),
        ]

    # -- AC-3 / AC-4 ----------------------------------------------------------------------------
    def test_ac3_extractor_failure_dropped(self, rig: Any) -> None:
        doubles, match = rig([S(100), S(100, fail_extract=True), S(90)])
        result = match()
        assert len(result.per_candidate) == 2 and result.candidates_dropped == 1
        (log,) = doubles.logs("c3.matcher.backbone_error")
        assert log["level"] == "ERROR" and log["phase"] == self.extract_phase
        assert log["tile_id"] is not None
        assert [r["phase"] for r in doubles.fdr.of_kind("matcher.backbone_error")] == [
            self.extract_phase
        ]

    def test_ac4_matcher_failure_dropped(self, rig: Any) -> None:
        doubles, match = rig([S(100, fail_match=True), S(100), S(90)])
        result = match()
        assert len(result.per_candidate) == 2
        assert [r["phase"] for r in doubles.logs("c3.matcher.backbone_error")] == [self.match_phase]
        assert len(doubles.fdr.of_kind("matcher.backbone_error")) == 1

    # -- AC-5 / AC-6 ----------------------------------------------------------------------------
    def test_ac5_below_threshold(self, rig: Any) -> None:
        doubles, match = rig([S(59), S(20), S(1)])
        with pytest.raises(InsufficientInliersError):
            match()
        assert len(doubles.logs("c3.matcher.insufficient_inliers")) == 1
        assert len(doubles.fdr.of_kind("matcher.insufficient_inliers")) == 1
        last = doubles.health.last_update
        assert doubles.health.update_count == 1 and last is not None
        assert (last.best_inlier_count, last.had_backbone_error) == (0, False)

    def test_ac6_all_failed(self, rig: Any) -> None:
        doubles, match = rig([S(fail_extract=True)] * 3)
        with pytest.raises(InsufficientInliersError):
            match()
        assert len(doubles.logs("c3.matcher.backbone_error")) == 3
        assert len(doubles.logs("c3.matcher.insufficient_inliers")) == 1
        last = doubles.health.last_update
        assert doubles.health.update_count == 1 and last is not None
        assert (last.best_inlier_count, last.had_backbone_error) == (0, True)

    # -- AC-7 -----------------------------------------------------------------------------------
    def test_ac7_residual_warn(self, rig: Any) -> None:
        doubles, match = rig([S(100, 4.2)])
        match()
        (warn,) = doubles.logs("c3.matcher.residual_above_threshold")
        assert (warn["level"], warn["residual_px"], warn["threshold_px"]) == ("WARNING", 4.2, 2.5)

    # -- AC-8 -----------------------------------------------------------------------------------
    def test_ac8_health_once_per_call(self, rig: Any) -> None:
        doubles, match = rig([S(100), S(50, fail_match=True), S(70)])
        match()
        match()
        assert doubles.health.update_count == 2
        last = doubles.health.last_update
        assert last is not None and (last.best_inlier_count, last.had_backbone_error) == (100, True)

    # -- AC-9 / AC-10 ---------------------------------------------------------------------------
    def test_ac9_correspondence_shape(self, rig: Any) -> None:
        _, match = rig([S(120), S(64)])
        for c in match().per_candidate:
            assert c.inlier_correspondences.shape == (c.inlier_count, 4)
            assert c.inlier_correspondences.dtype.name == "float32"

    def test_ac10_deterministic(self, rig: Any) -> None:
        _, match = rig([S(120, 1.4), S(80, 1.0), S(120, 1.1)])
        first, *others = [match() for _ in range(3)]
        for other in others:
            assert other.best_candidate_idx == first.best_candidate_idx
            assert all(
                a.same_content(b)
                for a, b in zip(first.per_candidate, other.per_candidate, strict=True)
            )

    # -- AC-12 ----------------------------------------------------------------------------------
    def test_ac12_frame_done(self, rig: Any) -> None:
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
