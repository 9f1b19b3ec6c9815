"""Step 7's ambiguity check with the allowed test doubles: a rival with at least half the best
candidate's inliers that places the frame elsewhere gives no fix (``AmbiguousMatchError``, an
``InsufficientInliersError``: one health update without a fix, the ERROR line and the
``matcher.insufficient_inliers`` record naming both); a rival of the same place, a weaker one
elsewhere, or one whose id is no place leaves the fix as it was. The real path:
``tests/test_ambiguous_match.py``."""

from __future__ import annotations

import dataclasses

import pytest

from c3_matcher.dto import TileId
from c3_matcher.errors import AmbiguousMatchError, InsufficientInliersError
from c3_matcher.stages.ambiguity import AGREE_PX
from c3_matcher.testing import InMemoryFdr, ScriptedCandidate, ScriptedRig

S = ScriptedCandidate


def _placed(rig: ScriptedRig, *ids: TileId) -> ScriptedRig:
    """``rig`` with its candidates' tile ids replaced by ``ids`` (the doubles' rows are alike
    for every candidate, so a candidate's id is where it puts the frame)."""
    candidates = tuple(
        dataclasses.replace(c, tile_id=t) for c, t in zip(rig.rerank.candidates, ids, strict=True)
    )
    rig.rerank = dataclasses.replace(rig.rerank, candidates=candidates)
    return rig


def _km_north(km: float) -> TileId:
    return TileId(18, 47.0 + km / 111.195, 8.5)


@pytest.mark.parametrize(
    "rival",
    [
        pytest.param(50, id="exactly-half"),
        pytest.param(54, id="0.54-as-the-wrong-ALIKED-fixes-rivals"),
    ],
)
def test_a_rival_elsewhere_from_exactly_half_the_inliers_gives_no_fix(fdr, logs, rival):
    """Half the best's inliers is enough to refuse (49 is not: the weaker rival below), and
    so is 0.54 of them, the least share a rival of a wrong fix reached on repetitive texture
    (ALIKED; the module's evidence)."""
    rig = _placed(ScriptedRig([S(100), S(rival)], fdr), _km_north(0), _km_north(1.0))
    with pytest.raises(AmbiguousMatchError, match=f"candidate 1 .{rival} inliers, 0.{rival} of"):
        rig.match()


def test_the_agree_distance_is_where_placements_stop_agreeing(fdr, logs):
    """A rival placing the frame just over :data:`AGREE_PX` px of the best tile's ground sample
    distance away is refused; moved 0.4 m nearer, just under it, it agrees. (Each double's
    inliers lie one px further down its tile than the one before: a rival 5.3 m north of the
    best places the frame 5.0 m from it.)"""
    rig = ScriptedRig([S(100), S(100)], fdr)
    agree_m = AGREE_PX * rig.rerank.candidates[0].gsd_m_per_px
    far = _placed(rig, _km_north(0), _km_north(0.0053))
    with pytest.raises(AmbiguousMatchError):
        far.match()
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    distance_m = record["ambiguous"]["distance_m"]
    assert agree_m < distance_m < agree_m + 0.3 and distance_m - 0.4 < agree_m
    near = _placed(ScriptedRig([S(100), S(100)], InMemoryFdr()), _km_north(0), _km_north(0.0049))
    assert [c.inlier_count for c in near.match().per_candidate] == [100, 100]


def test_a_rival_elsewhere_with_half_the_inliers_or_more_gives_no_fix(fdr, logs):
    rig = _placed(ScriptedRig([S(100), S(90)], fdr), _km_north(0), _km_north(1.0))
    with pytest.raises(AmbiguousMatchError) as caught:
        rig.match()
    error = caught.value
    assert isinstance(error, InsufficientInliersError)
    assert error.best_inlier_count == 100 and error.threshold == 60
    assert "candidate 1 (90 inliers, 0.90 of the best's) places the frame 1000 m from " in str(
        error
    )
    (line,) = logs.of_kind("c3.matcher.insufficient_inliers")
    assert line["level"] == "ERROR" and "ambiguous match, no fix" in line["message"]
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    assert record["ambiguous"]["rival_index"] == 1 and record["ambiguous"]["best_index"] == 0
    assert record["ambiguous"]["distance_m"] == pytest.approx(1000.0, rel=1e-3)
    assert rig.health.last_update is not None and rig.health.last_update.best_inlier_count == 0


def test_the_rival_named_is_the_one_placing_the_frame_elsewhere(fdr, logs):
    ids = (_km_north(0), _km_north(0.001), _km_north(-2.0))  # 1 m: the same place; 2 km south
    rig = _placed(ScriptedRig([S(100), S(95), S(60)], fdr), *ids)
    with pytest.raises(AmbiguousMatchError, match="candidate 2 .60 inliers, 0.60"):
        rig.match()


@pytest.mark.parametrize(
    ("rival", "ids"),
    [
        pytest.param(49, (_km_north(0), _km_north(1.0)), id="weaker-elsewhere"),
        pytest.param(100, (_km_north(0), _km_north(0.002)), id="same-place-2m"),
        pytest.param(100, (TileId(0, 0.0, 0.0), TileId(0, 0.0, 1.0)), id="no-place"),
        pytest.param(100, (TileId(18, 86.0, 8.5), TileId(18, 86.0, 9.5)), id="beyond-mercator"),
    ],
)
def test_a_rival_of_the_same_place_weaker_or_unplaced_leaves_the_fix(fdr, logs, rival, ids):
    rig = _placed(ScriptedRig([S(100), S(rival)], fdr), *ids)
    result = rig.match()
    assert [c.inlier_count for c in result.per_candidate] == [100, rival]
    assert not fdr.of_kind("matcher.insufficient_inliers")
