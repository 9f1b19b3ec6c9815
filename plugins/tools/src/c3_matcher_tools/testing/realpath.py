"""Real-path acceptance scenarios shared by every strategy's tests (and the benchmarks).

Frames rendered over three real orthophotos shipped in ``data/imagery/`` with yaw from 0 to 180
deg and 15-20 deg of tilt given as attitude, lens distortion, a frame GSD half the tiles', a
photometric domain shift, and two distractor tiles that do not overlap the frame's footprint.
The bar: the true tile is best, >= 80 inliers, and
the mean inlier error against ground truth in ORIGINAL frame pixels < 2.5 px.
"""

from __future__ import annotations

import math
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np
import pytest

from c3_matcher.compose import build_default_helpers, compose_root
from c3_matcher.config import C3Settings
from c3_matcher.dto import RerankCandidate, RerankResult
from c3_matcher.errors import InsufficientInliersError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.protocols import CrossDomainMatcher
from c3_matcher.tiles import BytesTileHandle
from c3_matcher_tools.sim.scenario import Scenario, ScenarioSpec, build_scenario, inlier_errors_px

__all__ = [
    "MAX_MEAN_ERROR_PX",
    "MIN_INLIERS",
    "SCENARIOS",
    "Outcome",
    "RealPathSuite",
    "imagery_dir",
    "rerank_for",
    "run_scenario",
    "scenario_specs",
]

MIN_INLIERS = 80
MAX_MEAN_ERROR_PX = 2.5
REPO = Path(__file__).resolve().parents[5]


def imagery_dir() -> Path:
    """``data/imagery`` of the repository checkout."""
    return REPO / "data" / "imagery"


# (orthophoto, yaw, pitch, roll, tile px, image size, focal px, candidate order)
SCENARIOS: tuple[
    tuple[str, float, float, float, int, tuple[int, int], float, tuple[int, int, int]], ...
] = (
    ("open_orthophotos/test_tiled.tif", 30, 15, 0, 512, (640, 480), 560, (1, 0, 2)),
    ("open_orthophotos/test_tiled.tif", 90, -10, 14, 512, (640, 480), 560, (2, 1, 0)),
    (
        "open_orthophotos/5b90f92da0d7280005fab355_4310.tif",
        120,
        0,
        18,
        512,
        (640, 480),
        560,
        (0, 2, 1),
    ),
    (
        "open_orthophotos/swissimage_zurich_1091-322_00_0p5m.tif",
        180,
        -12,
        12,
        384,
        (480, 360),
        420,
        (1, 2, 0),
    ),
)


def scenario_specs() -> list[tuple[ScenarioSpec, tuple[int, int, int]]]:
    out = []
    for i, (path, yaw, pitch, roll, tile, size, focal, order) in enumerate(SCENARIOS):
        spec = ScenarioSpec(
            imagery_dir() / path,
            yaw,
            pitch,
            roll,
            frame_gsd_ratio=0.5,
            tile_size=tile,
            image_size=size,
            focal_px=focal,
            seed=i,
        )
        out.append((spec, order))
    return out


def tilt_deg(spec: ScenarioSpec) -> float:
    """Angle between the camera axis and the vertical (default mount)."""
    c = math.cos(math.radians(spec.pitch_deg)) * math.cos(math.radians(spec.roll_deg))
    return math.degrees(math.acos(c))


@dataclass(frozen=True)
class Outcome:
    """One match of a scenario: whether it passed the bar and its figures."""

    name: str
    with_attitude: bool
    insufficient: bool
    true_tile_best: bool
    inliers: int
    mean_error_px: float
    residual_px: float

    @property
    def passed(self) -> bool:
        return (
            not self.insufficient
            and self.true_tile_best
            and self.inliers >= MIN_INLIERS
            and self.mean_error_px < MAX_MEAN_ERROR_PX
        )


def rerank_for(scenario: Scenario, order: tuple[int, ...], frame_id: uuid.UUID) -> RerankResult:
    """The candidates in ``order`` (indices into ``scenario.tiles``; 0 is the true tile), PNG-
    encoded like a tile store's."""
    candidates: list[RerankCandidate] = []
    for i in order:
        ok, buf = cv2.imencode(".png", np.ascontiguousarray(scenario.tiles[i].image[:, :, ::-1]))
        assert ok
        candidates.append(
            RerankCandidate(
                scenario.tile_ids[i],
                1.0 - 0.1 * len(candidates),
                BytesTileHandle(buf.tobytes(), f"tile{i}"),
                scenario.tile_gsd_m,
            )
        )
    return RerankResult(frame_id, tuple(candidates))


def run_scenario(
    matcher: CrossDomainMatcher,
    scenario: Scenario,
    order: tuple[int, ...],
    with_attitude: bool = True,
) -> Outcome:
    frame = scenario.frame.nav_frame(uuid.UUID(int=len(order) + 1), with_attitude=with_attitude)
    rerank = rerank_for(scenario, order, frame.frame_id)
    name = scenario.spec.name
    try:
        result = matcher.match(frame, rerank, scenario.calibration)
    except InsufficientInliersError as exc:
        return Outcome(name, with_attitude, True, False, exc.best_inlier_count, math.inf, math.inf)
    best_input = result.diagnostics["input_index"][0]
    best = result.per_candidate[0]
    errors = inlier_errors_px(scenario, order[best_input], best.inlier_correspondences)
    return Outcome(
        name,
        with_attitude,
        False,
        order[best_input] == 0,
        best.inlier_count,
        float(np.mean(errors)),
        result.reprojection_residual_px,
    )


_SPECS = scenario_specs()
_LARGE_YAW = [(s, o) for s, o in _SPECS if s.yaw_deg >= 90]


class RealPathSuite:
    """The real-path acceptance tests for any strategy: subclass, set ``strategy`` (and
    ``options`` for ``[matcher.options.<strategy>]``). Needs an ``engine_dir`` fixture that
    yields a directory holding the strategy's built engines (this repository's conftest.py
    builds them with the real engine compiler)::

        class TestMyRealPath(RealPathSuite):
            strategy = "my_matcher"
    """

    strategy: str = "disk_lightglue"
    options: ClassVar[dict[str, object]] = {}

    @pytest.fixture(scope="class")
    @classmethod
    def matcher(cls, engine_dir: Path, tmp_path_factory: Any) -> Iterator[CrossDomainMatcher]:
        settings = C3Settings(
            matcher={"strategy": cls.strategy, "options": {cls.strategy: cls.options}},
            engines={"directory": engine_dir},
            fdr={"path": tmp_path_factory.mktemp("fdr") / "fdr.jsonl"},
        )
        helpers = {**build_default_helpers(settings), "c13_fdr": InMemoryFdr()}
        root = compose_root(settings, helpers, configure_logs=False)
        yield root.matcher
        root.close()

    def test_scenarios_cover_the_required_conditions(self) -> None:
        specs = [s for s, _ in _SPECS]
        assert len({s.orthophoto for s in specs}) >= 3
        assert min(s.yaw_deg for s in specs) <= 30 and max(s.yaw_deg for s in specs) >= 180
        assert all(15 - 1e-6 <= tilt_deg(s) <= 20 + 1e-6 for s in specs)
        assert all(s.distortion[0] != 0 and s.frame_gsd_ratio != 1 for s in specs)
        assert {order.index(0) for _, order in _SPECS} == {0, 1, 2}  # true tile everywhere

    @pytest.mark.slow
    @pytest.mark.parametrize(("spec", "order"), _SPECS, ids=[s.name for s, _ in _SPECS])
    def test_true_tile_best_with_enough_accurate_inliers(
        self, matcher: CrossDomainMatcher, spec: ScenarioSpec, order: tuple[int, int, int]
    ) -> None:
        outcome = run_scenario(matcher, build_scenario(spec), order, with_attitude=True)
        print(self.strategy, self.options, outcome)
        assert not outcome.insufficient, outcome
        assert outcome.true_tile_best, outcome
        assert outcome.inliers >= MIN_INLIERS, outcome
        assert outcome.mean_error_px < MAX_MEAN_ERROR_PX, outcome

    @pytest.mark.slow
    @pytest.mark.parametrize(("spec", "order"), _LARGE_YAW, ids=[s.name for s, _ in _LARGE_YAW])
    def test_large_yaw_fails_without_attitude(
        self, matcher: CrossDomainMatcher, spec: ScenarioSpec, order: tuple[int, int, int]
    ) -> None:
        """Withholding the attitude (height kept) breaks the match: rectification does the work."""
        outcome = run_scenario(matcher, build_scenario(spec), order, with_attitude=False)
        print(self.strategy, self.options, outcome)
        assert not outcome.passed, outcome
