"""Settings each valid alone that no frame can meet with the strategy composed: refused at start-up
as configuration errors naming them (exit 2), not accepted to fail every frame, nor called an
engine fault with build advice. A count setting the start-up probe's small pair cannot meet but
real frames do is not refused. The real DISK + LightGlue strategy on its built engines."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from c3_matcher.compose import build_default_helpers
from c3_matcher.config import C3Settings
from c3_matcher.errors import ConfigurationError
from c3_matcher.testing.strategy_kit import compose_ready


def _settings(engine_dir: Path, tmp_path: Path, **sections: dict[str, Any]) -> C3Settings:
    return C3Settings(
        engines={"directory": engine_dir, "intra_op_threads": 1},
        fdr={"path": tmp_path / "fdr.jsonl"},
        **sections,
    )


def _composed(settings: C3Settings) -> dict[str, Any]:
    root, ready = compose_ready(settings, build_default_helpers(settings))
    root.close()
    return ready


@pytest.mark.parametrize(
    ("matcher", "said"),
    [
        ({"max_keypoints": 32}, "60 exceeds the 32 keypoints per image"),
        ({"min_inliers_threshold": 3000}, "3000 exceeds the 2048 keypoints per image"),
        (
            {"min_inliers_threshold": 3000, "max_keypoints": 4096},  # cut to the top-K
            "3000 exceeds the 2048 keypoints per image",
        ),
    ],
)
def test_an_inlier_threshold_above_the_keypoint_budget_is_refused_at_start_up(
    engine_dir: Path, tmp_path: Path, matcher: dict[str, Any], said: str
) -> None:
    """Accepted before, then every frame failed as insufficient inliers (exit 3)."""
    settings = _settings(engine_dir, tmp_path, matcher=matcher)
    with pytest.raises(ConfigurationError) as refused:
        _composed(settings)
    ((field, reason),) = refused.value.problems
    assert field == "matcher.min_inliers_threshold" and said in reason
    asked = matcher.get("max_keypoints", "unset")
    assert f"[matcher] max_keypoints = {asked}" in reason


def test_a_threshold_within_the_budget_still_composes(engine_dir: Path, tmp_path: Path) -> None:
    settings = _settings(engine_dir, tmp_path, matcher={"max_keypoints": 512})
    assert _composed(settings)["min_inliers_threshold"] == 60


def test_an_exit_count_the_probe_pair_cannot_reach_but_frames_do_composes(
    engine_dir: Path, tmp_path: Path
) -> None:
    """``exit_matches = 200`` (documented 0..8192): the 128 px probe pair has fewer confident
    matches than that after two layers, so start-up failed as an engine fault advising a
    rebuild, although the demo frame matches with it as with the default."""
    lightglue = {"mode": "adaptive", "exit_matches": 200}
    settings = _settings(engine_dir, tmp_path, lightglue=lightglue)
    assert _composed(settings)["strategy"] == "disk_lightglue"


def test_an_exit_count_above_the_keypoint_budget_is_a_configuration_error(
    engine_dir: Path, tmp_path: Path
) -> None:
    lightglue = {"mode": "adaptive", "exit_matches": 4000}
    with pytest.raises(ConfigurationError) as refused:
        _composed(_settings(engine_dir, tmp_path, lightglue=lightglue))
    ((field, reason),) = refused.value.problems
    assert field == "lightglue.exit_matches" and "4000 exceeds the 2048 keypoints" in reason
    assert "engines build" not in str(refused.value)
