"""XFeat on real imagery, through the real engines (built by the engine_dir fixture): the SAME
rendered frames over three real orthophotos and the SAME acceptance bar as DISK+LightGlue
(issue 4), for both matcher options."""

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
)

SPECS = scenario_specs()
MATCHERS = ("mnn", "lighterglue")


@pytest.fixture(scope="module", params=MATCHERS)
def matcher(request, engine_dir, tmp_path_factory):  # type: ignore[no-untyped-def]
    settings = C3Settings(
        matcher={"strategy": "xfeat", "options": {"xfeat": {"matcher": request.param}}},
        engines={"directory": engine_dir},
        fdr={"path": tmp_path_factory.mktemp("fdr") / "fdr.jsonl"},
    )
    root = compose_root(
        settings,
        {**build_default_helpers(settings), "c13_fdr": InMemoryFdr()},
        configure_logs=False,
    )
    yield root.matcher
    root.close()


@pytest.mark.slow
@pytest.mark.parametrize(("spec", "order"), SPECS, ids=[s.name for s, _ in SPECS])
def test_true_tile_best_with_enough_accurate_inliers(matcher, spec, order):
    outcome = run_scenario(matcher, build_scenario(spec), order, with_attitude=True)
    print(matcher.config.matcher, outcome)
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
    print(matcher.config.matcher, outcome)
    assert not outcome.passed, outcome
