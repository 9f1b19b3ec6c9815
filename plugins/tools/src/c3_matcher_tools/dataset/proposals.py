"""Candidate tiles proposed from a tile store for each telemetry row (a stand-in for the upstream
re-ranker C2.5), and the imported frame's record that carries them (:func:`imported_frame`).

At zoom ``zoom`` of the store (default its finest), the ground point the camera's optical axis
hits (from the telemetry position, attitude, height and the calibration's camera mount; the
nadir when the axis points above the horizon) is located in a 256-px slippy tile; the candidates
are the ``candidate_size_px`` windows centred on (:func:`c3_matcher.tilestore.base.tile_centre_id`)
that tile, the other tiles whose square comes within ``uncertainty_m`` of the point, nearest
first, then the nearest further tiles (distractors) until there are ``candidates``; only tiles
the store holds. Their order is shuffled by a generator seeded by (``seed``, frame index), scores
0.9, 0.8, ... in that order. The options are a
:class:`~c3_matcher_tools.dataset.sources.options.ProposalOptions`.

The tiles of the search square are found in the store's index, one query a frame; only the
tiles proposed are read, so a damaged one among them (its sha256 does not match) is refused,
named, never proposed. Longitudes are wrapped into [-180, 180) and tile columns around the
globe: near 180 deg the tiles across the line are searched, at their true distance.
"""

from __future__ import annotations

import math
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from c3_matcher.dto import CameraCalibration, TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.georef import wrap_longitude
from c3_matcher.tilestore.base import tile_centre_id
from c3_matcher.tilestore.geo import TILE_PX, lonlat_to_world_px
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher_tools.dataset.format import CandidateTruth, FrameRecord
from c3_matcher_tools.dataset.sources.options import (
    MAX_SEARCH_TILES,
    ProposalOptions,
    max_uncertainty_m,
)
from c3_matcher_tools.dataset.telemetry import TelemetryRow
from c3_matcher_tools.geodesy import axis_ground_point

__all__ = [
    "SKIP_OUTSIDE",
    "StoreProposals",
    "imported_frame",
    "look_point",
    "propose_from_store",
    "shuffled_candidates",
    "store_zoom",
]


def look_point(row: TelemetryRow, calibration: CameraCalibration) -> tuple[float, float]:
    """(lon, lat) where the optical axis meets flat ground ``altitude_m`` below the vehicle
    (``axis_ground_point``; the telemetry position itself when the axis does not point down),
    the longitude in [-180, 180) (a look across 180 deg)."""
    hit = axis_ground_point(row.lat, row.lon, row.altitude_m, row.attitude, calibration)
    lon, lat = (row.lon, row.lat) if hit is None else (hit[1], hit[0])
    return float(wrap_longitude(lon)), lat


def store_zoom(store: MBTilesStore, path: object, zoom: int | None) -> int:
    """The zoom candidates are proposed at: ``zoom`` if the store holds it, else its finest;
    ``InvalidInputError`` for an empty store or a zoom it does not hold."""
    zooms = store.zooms()
    if not zooms:
        raise InvalidInputError("STORE", f"{path}: holds no tiles")
    chosen = zooms[-1] if zoom is None else zoom
    if chosen not in zooms:
        raise InvalidInputError("--zoom", f"{chosen} not in the store's zooms {zooms}")
    return chosen


def _propose(
    store: MBTilesStore, zoom: int, lonlat: tuple[float, float], options: ProposalOptions
) -> list[tuple[TileId, float]] | None:
    """(tile id, distance m from the point to the tile square) of the candidates, the tile
    holding the point first; None when the store lacks that tile. Refuses an uncertainty
    beyond :func:`max_uncertainty_m` there."""
    reach_m = max_uncertainty_m(zoom, lonlat[1])
    if options.uncertainty_m > reach_m:
        raise InvalidInputError(
            "--uncertainty-m",
            f"{options.uncertainty_m:g} m reaches beyond {MAX_SEARCH_TILES} tiles of the store's "
            f"zoom {zoom} ({reach_m:.0f} m at latitude {lonlat[1]:.2f}): give at most that",
        )
    p = lonlat_to_world_px([lonlat], zoom)[0]
    m_per_px = TileId(zoom, lonlat[1], lonlat[0]).web_mercator_gsd_m()
    n = 1 << zoom
    tx, ty = int(p[0] // TILE_PX), int(p[1] // TILE_PX)
    if store.tile_bytes(zoom, tx % n, ty) is None:
        return None
    ring = max(2, math.ceil(options.uncertainty_m / (m_per_px * TILE_PX)) + 1)
    ring = max(ring, math.ceil(math.sqrt(options.candidates)) + 1)
    px, py, reach, hypot = float(p[0]), float(p[1]), options.uncertainty_m, math.hypot
    near: list[tuple[float, float, int, int, float]] = []
    for x, y in _stored_around(store, zoom, (tx, ty), ring):
        if x == tx and y == ty:
            continue
        dx = max(x * TILE_PX - px, 0.0, px - (x + 1) * TILE_PX)
        dy = max(y * TILE_PX - py, 0.0, py - (y + 1) * TILE_PX)
        edge_m = hypot(dx, dy) * m_per_px
        centre_px = hypot((x + 0.5) * TILE_PX - px, (y + 0.5) * TILE_PX - py)
        # within the uncertainty first (nearest centre first), then the nearest others
        near.append((0.0 if edge_m <= reach else 1.0, centre_px, x, y, edge_m))
    near.sort()
    picked = [(tile_centre_id(zoom, tx % n, ty), 0.0)]
    for *_, x, y, edge_m in near:
        if len(picked) == options.candidates:
            break
        if store.tile_bytes(zoom, x % n, y) is not None:  # read: a damaged tile is refused
            picked.append((tile_centre_id(zoom, x % n, y), edge_m))
    return picked


def _stored_around(
    store: MBTilesStore, zoom: int, tile: tuple[int, int], ring: int
) -> list[tuple[int, int]]:
    """The stored tiles (x, y) within ``ring`` tiles of ``tile`` (x, y): their columns taken
    around the globe, each where it lies nearest ``tile`` (x beyond 0 .. 2**zoom - 1 across
    180 deg), from the store's index (no tile read)."""
    n = 1 << zoom
    (tx, ty), half = tile, n // 2
    rows = (max(ty - ring, 0), min(ty + ring, n - 1))
    if 2 * ring + 1 >= n:
        spans = [(0, n - 1)]
    else:
        first, last = (tx - ring) % n, (tx + ring) % n
        spans = [(first, last)] if first <= last else [(first, n - 1), (0, last)]
    found = [t for span in spans for t in store.stored_in(zoom, span, rows)]
    return [(tx + (x - tx + half) % n - half, y) for x, y in found]


@dataclass(frozen=True)
class StoreProposals:
    """The candidates proposed from a store for each telemetry row, in row order.

    ``looks``: (look point (lon, lat) deg, candidates as (tile id, distance m) or None where
    the store lacks the tile under the look point); ``outside``: the rows whose look point the
    store does not cover; ``attribution`` and ``tiles_source``: the store's metadata.
    """

    zoom: int
    looks: list[tuple[tuple[float, float], list[tuple[TileId, float]] | None]]
    outside: list[TelemetryRow]
    attribution: str
    tiles_source: str

    def refuse_outside(
        self,
        where: str,
        label: Callable[[TelemetryRow], str],
        *,
        hint: str = "",
        shown: int = 10,
        option: str | None = None,
    ) -> None:
        """``InvalidInputError`` naming ``where`` when any row looks outside the store: how many
        (of how many), then the first ``shown`` as ``label(row)`` and the (lat, lon) each looks
        at (as :meth:`within` lists them skipped, not the vehicle's position). When no
        row is inside, ``hint`` follows the zoom; else how many are inside, and ``option``
        (when given) as the way to import those."""
        if not self.outside:
            return
        looks = [look for look, cands in self.looks if cands is None]  # the outside rows'
        names = [
            f"{label(r)} (looks at {lat:.6f}, {lon:.6f})"
            for r, (lon, lat) in zip(self.outside, looks, strict=True)
        ]
        more = f" and {len(names) - shown} more" if len(names) > shown else ""
        inside = len(self.looks) - len(self.outside)
        head, way = f"{len(names)} frame(s)", ""
        if inside > 0:  # not the wrong place: the hint does not apply
            head, hint, way = (
                f"{len(names)} of {len(self.looks)} frame(s)",
                "",
                f"; {inside} inside",
            )
        if inside > 0 and option:
            way = f"; give {option} to import the {inside} inside and list the others as skipped"
        raise InvalidInputError(
            where,
            f"{head} look outside the store's coverage at zoom {self.zoom}{hint}: "
            + ", ".join(names[:shown])
            + more
            + way,
        )

    def within(
        self,
        rows: Sequence[TelemetryRow],
        where: str,
        label: Callable[[TelemetryRow], str],
        *,
        skip: bool,
        hint: str = "",
        shown: int = 10,
    ) -> tuple[list[int], StoreProposals, list[tuple[str, str]]]:
        """(the indices of the ``rows`` whose look point the store covers, these proposals of
        those rows alone, (image, why) of each other row); without ``skip`` refused when any
        row is outside (:meth:`refuse_outside`, naming :data:`SKIP_OUTSIDE`), with it when
        every row is."""
        if not skip or len(self.outside) >= len(self.looks):
            self.refuse_outside(where, label, hint=hint, shown=shown, option=SKIP_OUTSIDE)
        inside = [i for i, (_, cands) in enumerate(self.looks) if cands is not None]
        skipped = [
            (
                rows[i].image,
                f"its look point ({look[1]:.6f}, {look[0]:.6f}) lies outside the store's "
                f"coverage at zoom {self.zoom}",
            )
            for i, (look, cands) in enumerate(self.looks)
            if cands is None
        ]
        kept = replace(self, looks=[self.looks[i] for i in inside], outside=[])
        return inside, kept, skipped


SKIP_OUTSIDE = "--skip-outside"
"""The option of ``dataset import`` that skips the frames whose look point lies outside the
store (:meth:`StoreProposals.within`); without it such a flight is refused."""


def propose_from_store(
    rows: Sequence[TelemetryRow], calibration: CameraCalibration, options: ProposalOptions
) -> StoreProposals:
    """Propose ``options.candidates`` tiles of ``options.store`` around each row's look point."""
    with MBTilesStore(options.store) as store:
        zoom = store_zoom(store, options.store, options.zoom)
        looks: list[tuple[tuple[float, float], list[tuple[TileId, float]] | None]] = []
        outside: list[TelemetryRow] = []
        for r in rows:
            lonlat = look_point(r, calibration)
            cands = _propose(store, zoom, lonlat, options)
            if cands is None:
                outside.append(r)
            looks.append((lonlat, cands))
        return StoreProposals(
            zoom,
            looks,
            outside,
            store.metadata.get("attribution", ""),
            store.metadata.get("c3_source", ""),
        )


def shuffled_candidates(
    cands: list[tuple[TileId, float]] | None, seed: int, index: int
) -> tuple[CandidateTruth, ...]:
    """Frame ``index``'s candidates in a seeded order, priors 0.9, 0.8, ... (the truth tile is
    not always first); ``cands`` is never None once the coverage check passed."""
    assert cands is not None
    order = np.random.default_rng([seed, index]).permutation(len(cands))
    return tuple(CandidateTruth(cands[j][0], round(0.9 - 0.1 * k, 3)) for k, j in enumerate(order))


def imported_frame(
    index: int,
    row: TelemetryRow,
    t0_s: float,
    base: uuid.UUID,
    suffix: str,
    proposal: tuple[tuple[float, float], list[tuple[TileId, float]] | None],
    options: ProposalOptions,
    *,
    heights: dict[str, Any],
    extra: dict[str, Any] | None = None,
) -> FrameRecord:
    """The dataset record of imported frame ``index`` (image ``frames/<index><suffix>``, id from
    ``base`` and the source image name, time from ``t0_s``, the first row's time in s) with its
    ``proposal`` (look point (lon, lat) deg, candidates) in the order ``options.seed`` gives.
    Telemetry: position, ``heights`` (the height keys a source knows), time, source image, look
    point, ``options.uncertainty_m``, then ``extra``."""
    look, cands = proposal
    return FrameRecord(
        index=index,
        frame_id=uuid.uuid5(base, row.image),
        image=f"frames/{index:06d}{suffix}",
        captured_at_ns=round((row.time_s - t0_s) * 1e9),
        attitude_deg=(row.roll_deg, row.pitch_deg, row.yaw_deg),
        height_m=row.altitude_m,
        candidates=shuffled_candidates(cands, options.seed, index),
        telemetry={
            "lat": row.lat,
            "lon": row.lon,
            "altitude_m": row.altitude_m,
            **heights,
            "time_s": row.time_s,
            "source_image": row.image,
            "look_lat": look[1],
            "look_lon": look[0],
            "uncertainty_m": options.uncertainty_m,
            **(extra or {}),
        },
    )
