"""ALIKED+LightGlue on real imagery, through the real engines (built by the engine_dir fixture):
rendered frames over three real orthophotos, the same acceptance bar as DISK (issue 4)."""

from __future__ import annotations

import pytest

from c3_matcher.compose import build_default_helpers, compose_root
from c3_matcher.config import C3Settings
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.sim.scenario import build_scenario
from c3_matcher.testing.realpath import (
    MAX_MEAN_ERROR_PX,
    MIN_INLIERS,
    run_scenario,
    scenario_specs,
    tilt_deg,
)
from c3_matcher_aliked_lightglue import AlikedLightGlueMatcher

SPECS = scenario_specs()


@pytest.fixture(scope="module")
def matcher(engine_dir, tmp_path_factory):  # type: ignore[no-untyped-def]
    settings = C3Settings(
        engines={"directory": engine_dir},
        fdr={"path": tmp_path_factory.mktemp("fdr") / "fdr.jsonl"},
        matcher={"strategy": "aliked_lightglue"},
    )
    root = compose_root(
        settings,
        {**build_default_helpers(settings), "c13_fdr": InMemoryFdr()},
        configure_logs=False,
    )
    assert isinstance(root.matcher, AlikedLightGlueMatcher)
    yield root.matcher
    root.close()


def test_scenarios_cover_the_required_conditions():
    specs = [s for s, _ in SPECS]
    assert len({s.orthophoto for s in specs}) >= 3
    assert min(s.yaw_deg for s in specs) <= 30 and max(s.yaw_deg for s in specs) >= 180
    assert all(15 - 1e-6 <= tilt_deg(s) <= 20 + 1e-6 for s in specs)
    assert all(s.distortion[0] != 0 for s in specs)
    assert all(s.frame_gsd_ratio != 1 for s in specs)
    assert {order.index(0) for _, order in SPECS} == {0, 1, 2}  # true tile in every position


@pytest.mark.slow
@pytest.mark.parametrize(("spec", "order"), SPECS, ids=[s.name for s, _ in SPECS])
def test_true_tile_best_with_enough_accurate_inliers(matcher, spec, order):
    outcome = run_scenario(matcher, build_scenario(spec), order, with_attitude=True)
    print(outcome)
    assert not outcome.insufficient, outcome
    assert outcome.true_tile_best, outcome
    assert outcome.inliers >= MIN_INLIERS, outcome
    assert outcome.mean_error_px < MAX_MEAN_ERROR_PX, outcome


@pytest.mark.slow
@pytest.mark.parametrize(
    ("spec", "order"),
    [(s, o) for s, o in SPECS if s.yaw_deg >= 90],
    ids=[s.name for s, _ in SPECS if s.yaw_deg >= 90],
)
def test_large_yaw_fails_without_attitude(matcher, spec, order):
    """Withholding the attitude (height kept) breaks the match: the rectification does the work."""
    outcome = run_scenario(matcher, build_scenario(spec), order, with_attitude=False)
    print(outcome)
    assert not outcome.passed, outcome
