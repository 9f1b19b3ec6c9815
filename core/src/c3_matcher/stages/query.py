"""Steps 1-2: the query frame, prepared once and extracted.

Rotation search (``rotation_search``; off by default): a frame WITHOUT attitude is not
rectified, so its heading is unknown. With the option on, such a query is extracted turned by
0/90/180/270 deg (:meth:`~c3_matcher.prepared.PreparedImage.turned`: the turn is composed into
the engine -> working map, so correspondences still come back in WORKING px of the unturned
query); every candidate is then matched against each turn (:mod:`~c3_matcher.stages.verify`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from c3_matcher.dto import CameraCalibration, NavCameraFrame, RerankCandidate
from c3_matcher.features import Features
from c3_matcher.prepared import PreparedImage
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.protocols import FeatureBackend
from c3_matcher.query_geometry import QueryGeometry
from c3_matcher.stages.extract import extract_checked
from c3_matcher.stages.failure import timed

__all__ = ["QUERY_ROTATIONS_DEG", "Query", "QueryView", "prepare_query", "tile_gsd"]

QUERY_ROTATIONS_DEG = (0, 90, 180, 270)  # rotation search: counter-clockwise turns of the query


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


def tile_gsd(candidates: Sequence[RerankCandidate]) -> float | None:
    """The GSD the query is scaled to (m/px): the median of the candidates' (they share a
    zoom); None without a candidate."""
    values = [c.ground_sample_distance_m() for c in candidates]
    return float(np.median(values)) if values else None


def prepare_query(
    pre: FramePreprocessor,
    backend: FeatureBackend,
    frame: NavCameraFrame,
    calibration: CameraCalibration,
    candidates: Sequence[RerankCandidate],
    *,
    rotation_search: bool,
    timings: dict[str, float],
) -> Query:
    """Undistort, rectify and scale the frame to the candidates' GSD (``query_preprocess``),
    then extract it (``query_extract``); with ``rotation_search`` a frame without attitude is
    extracted at every turn of ``QUERY_ROTATIONS_DEG``. Any exception is a query failure."""
    with timed(timings, "query_preprocess"):
        geometry = pre.query_geometry(frame, calibration, tile_gsd(candidates))
        image = pre.render_query(frame, calibration, geometry)
        search = rotation_search and frame.attitude is None  # only an unknown heading
        turns = QUERY_ROTATIONS_DEG if search else (0,)
        images = [(deg, image.turned(deg)) for deg in turns]
    with timed(timings, "query_extract"):
        views = tuple(
            QueryView(deg, turned, extract_checked(backend, turned)) for deg, turned in images
        )
    return Query(geometry, image, views, search)
