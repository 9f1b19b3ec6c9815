"""Test doubles for control-flow tests (the external helpers a unit test may replace).

The scripted doubles let a test say, per candidate, how many inliers and which median residual
RANSAC "finds", and which call raises: ``ScriptedCandidate(inliers=120, residual=1.1)``.
Candidate ``i``'s tile image is the constant value ``i + 1`` (0 would read as nodata) and the
fake extractor puts that mark in its keypoints' y coordinate, so each double knows which
candidate it is looking at without any shared counter. On a textured image (the start-up
probe's) the fake extractor finds the corners of the texture's blocks, each described by the
colours around it, and the fake LightGlue pairs equal descriptors, so the doubles match the
probe the way a real strategy does.
"""

from __future__ import annotations

import dataclasses
import math
import uuid
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.dto import (
    Attitude,
    CameraCalibration,
    MatchResult,
    NavCameraFrame,
    RansacResult,
    RerankCandidate,
    RerankResult,
    TileId,
)
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.features import Features, PairSide, RawMatches
from c3_matcher.health import RollingHealthWindow
from c3_matcher.pipeline import PipelineMatcher, PipelineSettings
from c3_matcher.prepared import InputRule, PreparedImage
from c3_matcher.strategy import PipelineHelpers, match_features, pipeline_matcher
from c3_matcher.testing.fake_texture import (
    FAKE_DESCRIPTOR_DIM,
    equal_descriptor_pairs,
    rgb_uint8,
    texture_features,
)
from c3_matcher.tiles import BytesTileHandle

__all__ = [
    "FakeBackend",
    "FakeClock",
    "FakeInferenceRuntime",
    "FakeLightGlueRuntime",
    "FakeRansacFilter",
    "ScriptedCandidate",
    "ScriptedPairMatcher",
    "ScriptedRig",
    "SequenceRansacFilter",
    "make_frame",
    "make_rerank",
    "scripted_pipeline",
]

QUERY_MARK = 255  # pixel value of the query frame; tile i has the value i + 1


@dataclass(frozen=True, slots=True)
class ScriptedCandidate:
    """What the doubles do for one candidate: RANSAC outcome, and which stage raises."""

    inliers: int = 100
    residual: float = 1.0
    outliers: int = 10
    fail_extract: bool = False
    fail_match: bool = False
    fail_decode: bool = False


class FakeClock:
    """A settable monotonic clock; ``advance`` moves it forward."""

    def __init__(self, start_ns: int = 1_000_000_000) -> None:
        self.now_ns = start_ns

    def monotonic_ns(self) -> int:
        return self.now_ns

    def advance(self, seconds: float) -> None:
        self.now_ns += int(seconds * 1e9)


class FakeInferenceRuntime:
    """An InferenceRuntime double: engines are names, ``run`` returns keypoints on the image
    that encode its mark in their y (a tile's; the query's 255 lies past a small image, so its
    keypoints lie on the last row: no double reads the query's mark from them), with distinct
    unit descriptors (keypoint ``i`` of every marked image has the ``i``-th unit vector); raises
    on the scripted candidates (``fail_extract``). A colour texture (marked images are grey)
    gives its block corners (``texture_features``)."""

    provider = "FakeExecutionProvider"

    def __init__(self, script: Sequence[ScriptedCandidate] = ()) -> None:
        self.script = list(script)
        self.loaded: list[str] = []
        self.calls: list[int] = []

    def load_engine(self, path: Any) -> str:
        self.loaded.append(str(path))
        return str(path)

    def run(self, engine_id: str, feeds: Mapping[str, NDArray[Any]]) -> dict[str, NDArray[Any]]:
        image = np.asarray(feeds["image"] if "image" in feeds else next(iter(feeds.values())))
        first = float(image.reshape(-1)[0])
        mark = round(first * 255) if image.dtype.kind == "f" else int(first)
        self.calls.append(mark - 1)
        if 0 <= mark - 1 < len(self.script) and self.script[mark - 1].fail_extract:
            raise RuntimeError(f"scripted extractor failure on candidate {mark - 1}")
        pixels = rgb_uint8(image)
        if np.mean(pixels[..., 0] != pixels[..., 1]) > 0.5:  # colour: a texture, not a mark
            return texture_features(pixels, feeds.get("mask"))
        n = 8
        row = min(mark, pixels.shape[0] - 1)  # on the image
        kpts = np.stack([np.arange(n, dtype=np.float32), np.full(n, row, np.float32)], axis=1)
        return {
            "keypoints": kpts,
            "keypoint_scores": np.ones(n, np.float32),
            "descriptors": np.eye(n, FAKE_DESCRIPTOR_DIM, dtype=np.float32),
        }


class FakeLightGlueRuntime:
    """A LightGlueRuntime double: pairs each keypoint of image 0 with the first keypoint of
    image 1 whose descriptor equals its own (a marked image's keypoint ``i`` with keypoint
    ``i``: ``FakeInferenceRuntime``); raises when scripted."""

    def __init__(self, script: Sequence[ScriptedCandidate] = ()) -> None:
        self.script = list(script)
        self.calls: list[int] = []

    def match_pair(self, side0: PairSide, side1: PairSide, *, feature_type: str) -> RawMatches:
        """``LightGlueRuntime.match_pair``."""
        kpts1 = side1.keypoints
        mark = int(kpts1[0, 1]) - 1 if len(kpts1) else -1
        self.calls.append(mark)
        if 0 <= mark < len(self.script) and self.script[mark].fail_match:
            raise RuntimeError(f"scripted LightGlue failure on candidate {mark}")
        return equal_descriptor_pairs(side0.descriptors, side1.descriptors)


class ScriptedPairMatcher:
    """A ``PairMatcher`` that raises for the candidates scripted ``fail_match`` (the tile's
    mark is its keypoints' y: ``FakeInferenceRuntime``) and otherwise runs ``inner``: the
    contract kit's wrapper of a strategy's own pair matcher, whatever it is."""

    def __init__(self, inner: Any, script: Sequence[ScriptedCandidate]) -> None:
        self.inner = inner
        self.script = list(script)

    def match(self, query: Features, tile: Features) -> RawMatches:
        mark = int(tile.keypoints[0, 1]) - 1 if len(tile) else -1
        if 0 <= mark < len(self.script) and self.script[mark].fail_match:
            raise RuntimeError(f"scripted matcher failure on candidate {mark}")
        raw: RawMatches = self.inner.match(query, tile)
        return raw


def _inlier_rows(n: int, first: tuple[float, float, float, float]) -> NDArray[np.float32]:
    """``n`` inlier rows: ``first``, then on an 8-px grid on both sides (spread as real inliers
    are, for ``stages.verify.SpreadCheck``)."""
    side = math.isqrt(max(n - 1, 0)) + 1
    grid = np.stack(np.divmod(np.arange(n), side), axis=1)[:, ::-1].astype(np.float32)
    rows = np.tile(np.array([first], np.float32), (n, 1))
    rows[:, 0:2] += 8.0 * grid
    rows[:, 2:4] += 8.0 * grid
    return rows


def _shift(rows: NDArray[np.float32]) -> NDArray[np.float64] | None:
    """The translation taking the query points of ``rows`` (all shifted alike) to their tile
    points; None without rows."""
    if not len(rows):
        return None
    homography = np.eye(3)
    homography[0:2, 2] = rows[0, 2:4] - rows[0, 0:2]
    return homography


class FakeRansacFilter:
    """A RansacFilter double: returns the scripted inlier count and residual for the candidate
    whose tile keypoints it sees (the tile mark is the y coordinate of the tile points), and
    the homography its inliers follow, a translation that differs per candidate (so a test
    can tell which candidate's homography a record carries)."""

    def __init__(self, script: Sequence[ScriptedCandidate]) -> None:
        self.script = list(script)
        self.calls: list[int] = []

    def filter(self, correspondences: NDArray[np.float32], threshold_px: float) -> RansacResult:
        mark = round(float(correspondences[0, 3])) - 1 if len(correspondences) else -1
        self.calls.append(mark)
        s = self.script[mark] if 0 <= mark < len(self.script) else ScriptedCandidate(inliers=0)
        rows = _inlier_rows(s.inliers, (1.0, 2.0, 3.0, float(mark + 1)))
        return RansacResult(
            rows,
            s.outliers,
            float(s.residual) if s.inliers else 0.0,
            _shift(rows),
            np.ones(s.inliers + s.outliers, bool),
        )


class SequenceRansacFilter:
    """A RansacFilter double that answers its n-th call with ``outcomes[n]`` (inliers,
    residual), cycling; identity homography when there are inliers."""

    def __init__(self, outcomes: Sequence[tuple[int, float]]) -> None:
        self.outcomes = list(outcomes)
        self.calls: list[int] = []

    def filter(self, correspondences: NDArray[np.float32], threshold_px: float) -> RansacResult:
        n, residual = self.outcomes[len(self.calls) % len(self.outcomes)]
        self.calls.append(n)
        rows = _inlier_rows(n, (1.0, 2.0, 3.0, 4.0))
        m = len(correspondences)
        return RansacResult(
            rows, 5, residual if n else 0.0, np.eye(3) if n else None, np.ones(m, bool)
        )


class FakeBackend:
    """A FeatureBackend double over the fake runtimes (the shape a real strategy has)."""

    label = "fake_backend"
    extract_phase = "disk_forward"
    match_phase = "lightglue_match"

    def __init__(
        self,
        inference: FakeInferenceRuntime,
        lightglue: FakeLightGlueRuntime,
        rule: InputRule | None = None,
    ) -> None:
        self.inference = inference
        self.lightglue = lightglue
        self.input_rule = rule or InputRule(max_long_side=64, multiple=16)
        self.engine_id = inference.load_engine("fake-engine")

    def extract(self, image: PreparedImage) -> Features:
        out = self.inference.run(self.engine_id, {"image": image.image})
        return Features(
            out["keypoints"],
            out["descriptors"],
            out["keypoint_scores"],
            (image.image.shape[1], image.image.shape[0]),
        )

    def match(self, query: Features, tile: Features) -> RawMatches:
        return match_features(self.lightglue, query, tile, "fake")

    def provenance(self) -> Mapping[str, Any]:
        return {"provider": self.inference.provider, "engines": {"fake": "0" * 64}}


class _FailingHandle:
    def encoded(self) -> memoryview:
        return memoryview(b"")

    def decode(self) -> NDArray[np.uint8]:
        raise ValueError("scripted tile decode failure")


def _marked_png(mark: int, size: int = 64) -> bytes:
    """A constant image whose every pixel equals ``mark``: survives resize and preprocessing."""
    image = np.full((size, size, 3), mark, np.uint8)
    ok, buf = cv2.imencode(".png", image)
    assert ok
    return buf.tobytes()


def make_frame(
    frame_id: uuid.UUID | None = None, size: int = 64
) -> tuple[NavCameraFrame, CameraCalibration]:
    """A marked query frame (no attitude) and a matching distortion-free calibration."""
    image = np.full((size, size, 3), QUERY_MARK, np.uint8)
    frame = NavCameraFrame(frame_id or uuid.uuid4(), image, captured_at_ns=1)
    return frame, CameraCalibration.pinhole(size, size, focal_px=float(size))


def make_rerank(
    frame_id: uuid.UUID, script: Sequence[ScriptedCandidate], size: int = 64
) -> RerankResult:
    """One candidate per script entry (``size`` px square tiles) of one place, as a re-rank's
    overlapping tiles are: tile ids (18, 47.0 + i/1e6, 8.5), a tenth of a metre apart."""
    candidates = []
    for i, s in enumerate(script):
        handle = (
            _FailingHandle()
            if s.fail_decode
            else BytesTileHandle(_marked_png(i + 1, size), f"tile{i}")
        )
        candidates.append(
            RerankCandidate(TileId(18, 47.0 + i / 1e6, 8.5), 1.0 - i / 10, handle, gsd_m_per_px=0.3)
        )
    return RerankResult(frame_id, tuple(candidates))


def scripted_pipeline(
    backend: Any,
    ransac: Any,
    fdr: InMemoryFdr,
    settings: PipelineSettings,
    *,
    clock: FakeClock | None = None,
    health: RollingHealthWindow | None = None,
) -> PipelineMatcher:
    """A :class:`PipelineMatcher` over ``backend`` and ``ransac`` with ``clock`` (a new fake
    clock by default) and ``health`` (a new window on that clock by default), no tile cache."""
    clock = clock or FakeClock()
    health = health or RollingHealthWindow(clock, settings.min_inliers_threshold)
    loop = dataclasses.replace(settings, tile_cache_size=0)
    return pipeline_matcher(backend, loop, PipelineHelpers(ransac, fdr, health, clock))


class ScriptedRig:
    """A pipeline over the scripted doubles for ``script`` (one candidate each), the marked
    query frame (``attitude`` or none) and everything a test inspects. ``ransac`` replaces the
    scripted RANSAC double; ``wrap_backend`` wraps the :class:`FakeBackend`."""

    def __init__(
        self,
        script: list[ScriptedCandidate],
        fdr: InMemoryFdr,
        settings: PipelineSettings | None = None,
        *,
        attitude: Attitude | None = None,
        ransac: Any = None,
        wrap_backend: Callable[[FakeBackend], Any] | None = None,
    ) -> None:
        self.script = script
        self.clock = FakeClock()
        self.fdr = fdr
        self.settings = settings or PipelineSettings()
        self.health = RollingHealthWindow(self.clock, self.settings.min_inliers_threshold)
        self.inference = FakeInferenceRuntime(script)
        self.lightglue = FakeLightGlueRuntime(script)
        self.ransac = ransac or FakeRansacFilter(script)
        backend = FakeBackend(self.inference, self.lightglue)
        self.backend = wrap_backend(backend) if wrap_backend is not None else backend
        self.pipeline = scripted_pipeline(
            self.backend, self.ransac, fdr, self.settings, clock=self.clock, health=self.health
        )
        frame, self.calibration = make_frame(uuid.UUID(int=7))
        self.frame = NavCameraFrame(frame.frame_id, frame.image, 1, attitude=attitude)
        self.rerank = make_rerank(self.frame.frame_id, script)

    def match(self) -> MatchResult:
        return self.pipeline.match(self.frame, self.rerank, self.calibration)

    @property
    def query_extractions(self) -> int:
        """Extractions of the query: every call but one per tile (no tile cache here)."""
        return len(self.inference.calls) - len(self.rerank.candidates)
