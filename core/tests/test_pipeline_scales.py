"""The pipeline with candidates of two GSDs: the query is prepared and extracted once per GSD
(once when they share one), and each candidate is matched against its own."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import pytest

from c3_matcher.dto import RerankResult
from c3_matcher.errors import InvalidInputError, MatcherBackboneError
from c3_matcher.testing import ScriptedCandidate as S
from c3_matcher.testing import ScriptedRig

from .host_exit import ctrl_c, host_exit, host_handler


def _two_gsds(rig: ScriptedRig) -> None:
    """The rig's second candidate at twice the others' GSD (another zoom)."""
    first, second, *rest = rig.rerank.candidates
    coarse = dataclasses.replace(second, gsd_m_per_px=2 * second.ground_sample_distance_m())
    rig.rerank = RerankResult(rig.rerank.frame_id, (first, coarse, *rest))


def test_one_query_per_gsd_and_every_candidate_matched(fdr, logs):
    # the doubles' rows are alike at either GSD, so the coarse tile puts the frame elsewhere:
    # rivals under half its inliers, not to be ambiguous (stages.ambiguity)
    rig = ScriptedRig([S(70, 1.1), S(150, 1.0), S(65, 1.5)], fdr)
    _two_gsds(rig)
    result = rig.match()
    assert rig.query_extractions == 2
    assert result.diagnostics["input_index"] == [1, 0, 2]
    assert [m.inlier_count for m in result.per_candidate] == [150, 70, 65]
    assert len(result.diagnostics["query_to_tile"]) == 3
    (record,) = fdr.of_kind("matcher.frame_done")
    assert (
        record["timings_ms"]["query_extract"] == result.diagnostics["timings_ms"]["query_extract"]
    )


def test_candidates_sharing_a_gsd_share_one_query(fdr, logs):
    rig = ScriptedRig([S(120, 1.1), S(150, 1.0), S(80, 1.5)], fdr)
    rig.match()
    assert rig.query_extractions == 1


class Abort(BaseException):
    """A plugin's own ``BaseException``."""


@pytest.mark.parametrize(
    "raised",
    [
        InvalidInputError("tile_gsd_m", "would scale the frame too far"),
        Abort("gave up"),
        SystemExit("plugin quit"),
    ],
    ids=["bad-gsd", "a-plugins-own-BaseException", "a-plugins-own-sys.exit"],
)
def test_a_gsd_the_frame_cannot_be_prepared_at_drops_only_its_candidates(
    fdr, logs, monkeypatch: pytest.MonkeyPatch, raised: BaseException
):
    """Drop and continue: the candidate of a GSD the query fails at (a GSD mistyped in other
    units, say, or the backend's own ``BaseException`` or ``sys.exit()`` at that scale) is
    dropped with phase
    ``query_extract``; the others are matched."""
    rig = _failing_at_the_coarse_gsd(fdr, monkeypatch, raised)
    result = rig.match()
    assert result.diagnostics["input_index"] == [0, 2] and result.candidates_dropped == 1
    (record,) = fdr.of_kind("matcher.backbone_error")
    assert (record["phase"], record["candidate_index"]) == ("query_extract", 1)


@pytest.mark.parametrize(
    ("stop", "stopped"),
    [(ctrl_c, KeyboardInterrupt), (host_exit, SystemExit)],
    ids=["Ctrl-C", "the-hosts-handlers-sys.exit"],
)
def test_a_stop_at_one_gsd_goes_on_to_the_caller(
    fdr, logs, monkeypatch: pytest.MonkeyPatch, stop: Any, stopped: type[BaseException]
):
    """A stop (Ctrl-C, the host's ``sys.exit`` from its signal handler) while the query is
    prepared at one GSD fails no candidate: the frame's one health update and
    ``matcher.interrupted`` record, then the stop reaches the caller."""
    rig = _failing_at_the_coarse_gsd(fdr, monkeypatch, stop)
    with host_handler(), pytest.raises(stopped):
        rig.match()
    assert [kind for kind, _ in fdr.records] == ["matcher.interrupted"]
    assert rig.health.update_count == 1


def _failing_at_the_coarse_gsd(
    fdr: Any, monkeypatch: pytest.MonkeyPatch, raised: BaseException | Callable[[], object]
) -> ScriptedRig:
    """A rig of candidates at two GSDs whose query raises ``raised`` (or what calling it
    raises) at the coarse one."""
    from c3_matcher.stages import scales

    real = scales.prepare_query

    def fails_at_the_coarse_gsd(*args: Any, **kwargs: Any) -> Any:
        if args[4] > 1.5 * rig.rerank.candidates[0].ground_sample_distance_m():
            if isinstance(raised, BaseException):
                raise raised
            raised()
        return real(*args, **kwargs)

    monkeypatch.setattr(scales, "prepare_query", fails_at_the_coarse_gsd)
    rig = ScriptedRig([S(120, 1.1), S(150, 1.0), S(80, 1.5)], fdr)
    _two_gsds(rig)
    return rig


def test_every_gsd_failing_is_the_query_failing(fdr, logs, monkeypatch: pytest.MonkeyPatch):
    from c3_matcher.stages import scales

    def fails(*args: Any, **kwargs: Any) -> Any:
        raise InvalidInputError("tile_gsd_m", "would scale the frame too far")

    monkeypatch.setattr(scales, "prepare_query", fails)
    rig = ScriptedRig([S(120, 1.1), S(150, 1.0)], fdr)
    _two_gsds(rig)
    with pytest.raises(MatcherBackboneError) as err:
        rig.match()
    assert err.value.phase == "query_extract"
