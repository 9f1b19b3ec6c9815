"""Steps 1-2: the query frame, prepared once per GSD of the candidates (one, when they share
a zoom) and extracted.

Each candidate is matched against the query scaled to its own GSD: candidates of different
zooms (a store built at two zooms, say) get a query each, since one scaled to the wrong zoom
is refused by the geometric prior whatever its inliers. Candidates whose GSDs lie within
``GSD_GROUP_RATIO`` of a group's smallest share that group's query (tiles of one zoom a few km
apart differ by ~1e-4 in GSD), scaled to the median of their GSDs (:func:`gsd_groups`).

Rotation search (``rotation_search``; off by default): a frame WITHOUT attitude is not
rectified, so its heading is unknown. With the option on, such a query is extracted turned by
0/90/180/270 deg (:meth:`~c3_matcher.prepared.PreparedImage.turned`: the turn is composed into
the engine -> working map, so correspondences still come back in WORKING px of the unturned
query); every candidate is then matched against each turn (:mod:`~c3_matcher.stages.verify`).
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from c3_matcher.dto import CameraCalibration, NavCameraFrame, RerankCandidate
from c3_matcher.features import Features
from c3_matcher.prepared import PreparedImage
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.query_geometry import QueryGeometry
from c3_matcher.stages.extract import Extraction
from c3_matcher.stages.failure import timed

__all__ = [
    "GSD_GROUP_RATIO",
    "QUERY_ROTATIONS_DEG",
    "GsdGroup",
    "Query",
    "QueryView",
    "gsd_groups",
    "prepare_query",
]

QUERY_ROTATIONS_DEG = (0, 90, 180, 270)  # rotation search: counter-clockwise turns of the query
# GSDs within this ratio of a group's smallest share its query: far under the geometric
# prior's scale tolerance, far over the spread of one zoom's GSD over a flight's tiles
GSD_GROUP_RATIO = 1.02


@dataclass(frozen=True)
class QueryView:
    """One extracted view of the query: its turn (deg, counter-clockwise), image, features."""

    rotation_deg: int
    image: PreparedImage
    features: Features


@dataclass(frozen=True)
class Query:
    """The prepared query: its ``geometry``, its ``image`` (unturned; its maps take WORKING px
    to ORIGINAL frame px), its ``views`` (one, or one per turn) and whether this frame ran the
    rotation search."""

    geometry: QueryGeometry
    image: PreparedImage
    views: tuple[QueryView, ...]
    rotation_search: bool


@dataclass(frozen=True)
class GsdGroup:
    """Candidates matched against one query: their input indices (ascending) and the GSD the
    query is scaled to (m/px), the median of theirs."""

    members: tuple[int, ...]
    gsd_m: float


def gsd_groups(candidates: Sequence[RerankCandidate]) -> tuple[GsdGroup, ...]:
    """The candidates grouped by GSD (``ground_sample_distance_m``: their own when given, else
    their zoom's): a GSD within ``GSD_GROUP_RATIO`` of a group's smallest joins it. Groups come
    in the order of their first candidate; candidates of one zoom make one group."""
    gsds = [c.ground_sample_distance_m() for c in candidates]
    smallest: list[float] = []  # each group's smallest GSD, ascending
    for gsd in sorted(set(gsds)):
        if not smallest or gsd > smallest[-1] * GSD_GROUP_RATIO:
            smallest.append(gsd)
    members: dict[int, list[int]] = {}  # in the order of each group's first candidate
    for index, gsd in enumerate(gsds):
        members.setdefault(bisect_right(smallest, gsd) - 1, []).append(index)
    return tuple(
        GsdGroup(tuple(group), float(np.median([gsds[i] for i in group])))
        for group in members.values()
    )


def prepare_query(
    pre: FramePreprocessor,
    extraction: Extraction,
    frame: NavCameraFrame,
    calibration: CameraCalibration,
    gsd_m: float,
    *,
    rotation_search: bool,
    timings: dict[str, float],
) -> Query:
    """Undistort, rectify and scale the frame to ``gsd_m`` m/px, a :class:`GsdGroup`'s
    (``query_preprocess``), then extract it (``query_extract``); with ``rotation_search`` a
    frame without attitude is extracted at every turn of ``QUERY_ROTATIONS_DEG``; an extraction
    over the keypoint budget is cut (``extraction``, the matcher's). Any exception is a query
    failure."""
    with timed(timings, "query_preprocess"):
        geometry = pre.query_geometry(frame, calibration, gsd_m)
        image = pre.render_query(frame, calibration, geometry)
        search = rotation_search and frame.attitude is None  # only an unknown heading
        turns = QUERY_ROTATIONS_DEG if search else (0,)
        images = [(deg, image.turned(deg)) for deg in turns]
    with timed(timings, "query_extract"):
        views = tuple(QueryView(deg, turned, extraction(turned)) for deg, turned in images)
    return Query(geometry, image, views, search)
