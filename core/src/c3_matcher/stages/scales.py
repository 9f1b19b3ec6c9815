"""Steps 1-2 for a frame's candidates: the query prepared and extracted once per GSD of the
candidates (:func:`~c3_matcher.stages.query.gsd_groups`; one, when they share a zoom), each
with its own verifier, whose geometric prior is that query's (built here from the frame's
:class:`~c3_matcher.stages.verify.VerifierSettings`).

A GSD the frame cannot be prepared at (one a tile's GSD mistyped in other units asks for)
fails only its own candidates, dropped with the others going on; every GSD failing is the
query's failure, as a frame that cannot be decoded is."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType

from c3_matcher.arrays import F64
from c3_matcher.dto import CameraCalibration, NavCameraFrame, RerankCandidate
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.stages.extract import Extraction
from c3_matcher.stages.interrupts import is_stop
from c3_matcher.stages.outcomes import Survivor
from c3_matcher.stages.query import Query, gsd_groups, prepare_query
from c3_matcher.stages.verify import Verifier, VerifierSettings

__all__ = ["FrameScales", "QueryScale", "prepare_scales"]


@dataclass(frozen=True)
class QueryScale:
    """What the candidates of one GSD are matched against: the ``query`` scaled to their GSD
    and its ``verifier``; ``members``: those candidates' input indices."""

    query: Query
    verifier: Verifier
    members: tuple[int, ...]


@dataclass(frozen=True)
class FrameScales:
    """A frame's queries (``scales``, at least one) and the candidates of a GSD it could not
    be prepared at (``failed``: input index -> the exception)."""

    scales: tuple[QueryScale, ...]
    failed: Mapping[int, BaseException] = field(default_factory=lambda: MappingProxyType({}))

    def of(self, index: int) -> QueryScale:
        """The query and verifier candidate ``index`` is matched against (not one failed)."""
        return next(scale for scale in self.scales if index in scale.members)

    @property
    def rotation_search(self) -> bool:
        """Whether this frame ran the rotation search (the same at every GSD)."""
        return self.scales[0].query.rotation_search

    @property
    def geometric_prior(self) -> bool:
        """Whether this frame ran with a geometric prior (the same at every GSD: attitude and
        height known)."""
        return self.scales[0].verifier.prior is not None

    def query_to_tile(self, survivor: Survivor) -> F64 | None:
        """``survivor``'s model from UNDISTORTED px of the query it was matched against
        (``PreparedImage.from_undistorted``; None without a model or a rectification)."""
        image = self.of(survivor.input_index).query.image
        return image.from_undistorted(survivor.homography)


def prepare_scales(
    pre: FramePreprocessor,
    extraction: Extraction,
    frame: NavCameraFrame,
    calibration: CameraCalibration,
    candidates: Sequence[RerankCandidate],
    *,
    rotation_search: bool,
    verification: VerifierSettings,
    timings: dict[str, float],
) -> FrameScales:
    """The frame prepared, extracted (``prepare_query``) and given its verifier (from
    ``verification``, with that query's prior) once per GSD of ``candidates``; raises the
    first GSD's exception when none could be prepared."""
    scales: list[QueryScale] = []
    failed: dict[int, BaseException] = {}
    for group in gsd_groups(candidates):
        try:
            query = prepare_query(
                pre,
                extraction,
                frame,
                calibration,
                group.gsd_m,
                rotation_search=rotation_search,
                timings=timings,
            )
        except BaseException as exc:  # that scale's candidates fail (a plugin's own too)
            if is_stop(exc):  # Ctrl-C, a signal handler's exit: they go on
                raise
            failed |= dict.fromkeys(group.members, exc)
            continue
        scales.append(QueryScale(query, verification.verifier(query.image), group.members))
    if not scales:
        raise failed[min(failed)]
    return FrameScales(tuple(scales), MappingProxyType(failed))
