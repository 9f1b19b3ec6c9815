"""A replayed flight as GeoJSON (RFC 7946: WGS84 lon/lat, what QGIS opens as it is).

Features, each with ``properties.kind``:

- ``truth_track`` / ``estimate_track``: LineStrings through the frames' true and estimated
  centres, in frame order (frames without one are skipped);
- ``truth`` / ``estimate``: one Point per frame with ``frame``, ``status``, ``inliers``,
  ``correct``, ``verdict`` (what the frame came to, in the flight report's words:
  :class:`~c3_matcher_tools.run.acceptance.Verdict`, e.g. "wrong tile", "another tile, right
  fix", "rightly raised"), ``ambiguous`` (the rival candidate of a frame refused as ambiguous,
  in the error's words; null otherwise), ``position_error_m``;
- ``footprint``: the estimated footprint Polygon of each matched frame, its ring the result's
  as it is (already counterclockwise, :func:`c3_matcher.georef.footprint_lonlat`);
- ``error``: a LineString from each frame's true to its estimated centre.

A line that crosses 180 deg is cut there into a MultiLineString (RFC 7946, 3.1.9), each part
ending on the line: joined whole, it would run round the world between points metres apart.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from c3_matcher.atomic import write_text_atomically
from c3_matcher_tools.run.acceptance import verdict
from c3_matcher_tools.run.records import FrameOutcome

__all__ = ["flight_geojson", "write_geojson"]


def _props(o: FrameOutcome, kind: str, strategy: str) -> dict[str, Any]:
    return {
        "kind": kind,
        "strategy": strategy,
        "frame": o.index,
        "frame_id": o.frame_id,
        "status": o.status,
        "inliers": o.candidate_inliers,
        "correct": o.correct if o.has_truth else None,
        "true_tile_present": o.true_present if o.has_truth else None,
        "verdict": str(verdict(o)),
        "ambiguous": o.ambiguous,
        "position_error_m": (
            round(o.position_error_m, 3) if math.isfinite(o.position_error_m) else None
        ),
    }


def _point(lat: float, lon: float) -> dict[str, Any]:
    return {"type": "Point", "coordinates": [lon, lat]}


def _line(points: Sequence[tuple[float, float]]) -> dict[str, Any]:
    """The LineString through ``points`` (lon, lat), or the MultiLineString of its parts cut at
    180 deg where one step crosses it (the shorter way round: a step of over 180 deg of
    longitude), each cut at the latitude where the step meets the line."""
    parts = [[list(points[0])]]
    for (x0, y0), (x1, y1) in itertools.pairwise(points):
        if abs(x1 - x0) > 180.0:
            side = 180.0 if x0 > 0 else -180.0
            span = (x1 + 2 * side) - x0  # the step's longitude the shorter way round
            y = y0 + (y1 - y0) * ((side - x0) / span if span else 0.0)
            parts[-1].append([side, y])
            parts.append([[-side, y]])
        parts[-1].append([x1, y1])
    if len(parts) == 1:
        return {"type": "LineString", "coordinates": parts[0]}
    return {"type": "MultiLineString", "coordinates": parts}


def flight_geojson(outcomes: Sequence[FrameOutcome], strategy: str) -> dict[str, Any]:
    """The FeatureCollection of one run (see the module docstring)."""
    feats: list[dict[str, Any]] = []
    truth = [
        (o.truth_lon, o.truth_lat)
        for o in outcomes
        if o.truth_lat is not None and o.truth_lon is not None
    ]
    est = [
        (o.est_lon, o.est_lat) for o in outcomes if o.est_lat is not None and o.est_lon is not None
    ]
    for kind, pts in (("truth_track", truth), ("estimate_track", est)):
        if len(pts) >= 2:
            feats.append(
                {
                    "type": "Feature",
                    "geometry": _line(pts),
                    "properties": {"kind": kind, "strategy": strategy, "frames": len(pts)},
                }
            )
    for o in outcomes:
        if o.truth_lat is not None and o.truth_lon is not None:
            feats.append(
                {
                    "type": "Feature",
                    "geometry": _point(o.truth_lat, o.truth_lon),
                    "properties": _props(o, "truth", strategy),
                }
            )
        if o.est_lat is not None and o.est_lon is not None:
            feats.append(
                {
                    "type": "Feature",
                    "geometry": _point(o.est_lat, o.est_lon),
                    "properties": _props(o, "estimate", strategy),
                }
            )
            ring = (o.result or {}).get("footprint")
            if ring:
                feats.append(
                    {
                        "type": "Feature",
                        "geometry": {"type": "Polygon", "coordinates": [ring]},
                        "properties": _props(o, "footprint", strategy),
                    }
                )
            if o.truth_lat is not None and o.truth_lon is not None:
                feats.append(
                    {
                        "type": "Feature",
                        "geometry": _line([(o.truth_lon, o.truth_lat), (o.est_lon, o.est_lat)]),
                        "properties": _props(o, "error", strategy),
                    }
                )
    return {"type": "FeatureCollection", "name": f"c3-flight {strategy}", "features": feats}


def write_geojson(path: Path, outcomes: Sequence[FrameOutcome], strategy: str) -> Path:
    """``path`` holding :func:`flight_geojson` of the run, written atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_text_atomically(path, json.dumps(flight_geojson(outcomes, strategy)) + "\n")
