"""The flight report's trajectory: frame centres on the map mosaic of the flight's tile store.

Truth (blue) and estimate (orange) with a red segment from each frame's reference to its estimate,
failed frames (x), frames that rightly raised with their true tile absent (cyan rings), wrong
fixes (diamonds) and picks of another tile that place the frame right (squares) marked; for a
recorded flight the vehicle's GNSS track and where the telemetry says each frame looks (green),
frames whose GNSS was absent or degraded ringed, frames whose attitude the import assumed level
marked grey (where a level camera would look: their segment to the estimate is dashed grey, no
error). Drawn onto a matplotlib ``Axes`` the caller owns; positions are WGS84
degrees, drawn in mosaic px (degrees when the store has no imagery there). A flight across
180 deg is drawn in one piece: its longitudes are taken within 180 deg of its first point's.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher.dto import TileId
from c3_matcher.georef import lonlat_to_tile_px, wrap_longitude
from c3_matcher.tilestore.geo import MERCATOR_MAX_LAT
from c3_matcher_tools.dataset.format import FlightDataset
from c3_matcher_tools.run.acceptance import Verdict, verdict
from c3_matcher_tools.run.records import FrameOutcome, FrameStatus

__all__ = ["ASSUMED_LABEL", "MAX_MOSAIC_PX", "RIGHT_REFUSAL", "draw_trajectory"]

MAX_MOSAIC_PX = 2048
RED = "#d62728"
GREY = "#7f7f7f"
RIGHT_REFUSAL = "#17becf"
"""The colour of a frame that rightly raised, its true tile absent: no failure's red, apart
from the truth's blue (here and in the per-frame chart)."""
ASSUMED_LABEL = "attitude assumed level: a level camera's look point"

Mosaic = tuple[NDArray[np.uint8], TileId, int]
"""The mosaic image, the tile id at its centre and its side (px)."""
Point = tuple["FrameOutcome", float, float]
"""A frame and where it is drawn (x, y)."""
ToXY = Callable[[float, float], tuple[float, float]]


def _points(outcomes: Sequence[FrameOutcome]) -> list[tuple[float, float]]:
    pts: list[tuple[float, float]] = []
    for o in outcomes:
        if o.truth_lat is not None and o.truth_lon is not None:
            pts.append((o.truth_lon, o.truth_lat))
        if o.est_lat is not None and o.est_lon is not None:
            pts.append((o.est_lon, o.est_lat))
        if o.telemetry_lat is not None and o.telemetry_lon is not None:
            pts.append((o.telemetry_lon, o.telemetry_lat))
    return pts


def _unwrapped(lon: NDArray[np.float64], about: float) -> NDArray[np.float64]:
    """Longitudes ``lon`` each taken within 180 deg of ``about`` (a flight across 180 deg stays
    in one piece: 179.99 and -179.99 are metres apart, not 360 deg)."""
    return np.asarray(about + wrap_longitude(lon - about), np.float64)


def _window(pts: Sequence[tuple[float, float]], zoom: int, margin_px: int) -> tuple[TileId, int]:
    """(the tile id at the middle of the positions (lon, lat), the side (px) of the square
    window at ``zoom`` that holds them all with ``margin_px`` to spare, 256 to
    :data:`MAX_MOSAIC_PX`); longitudes taken about the first position's (:func:`_unwrapped`)."""
    lon = _unwrapped(np.array([p[0] for p in pts]), pts[0][0])
    lat = np.array([p[1] for p in pts])
    middle = float(wrap_longitude((lon.min() + lon.max()) / 2))
    centre = TileId(zoom, float((lat.min() + lat.max()) / 2), middle)
    probe = lonlat_to_tile_px(centre, (0, 0), np.stack([lon, lat], axis=1))
    span = float(np.max(np.abs(probe))) * 2 + margin_px
    return centre, int(min(MAX_MOSAIC_PX, max(256, math.ceil(span))))


def _mosaic(
    dataset: FlightDataset, outcomes: Sequence[FrameOutcome]
) -> tuple[NDArray[np.uint8], TileId, int] | None:
    """The store's imagery around every position (:func:`_window` at the flight's zoom); None
    without positions, candidates, tiles there, or with positions beyond web mercator's
    latitudes (no tile holds them)."""
    pts = _points(outcomes)
    zooms = [c.tile_id.zoom for f in dataset.frames for c in f.candidates]
    if not pts or not zooms or max(abs(p[1]) for p in pts) > MERCATOR_MAX_LAT:
        return None
    zoom = max(set(zooms), key=zooms.count)
    centre, size = _window(pts, zoom, dataset.candidate_size_px)
    try:
        with dataset.open_store() as store:
            image = store.handle(centre, size).decode()
    except Exception:
        return None
    return image, centre, size


def _projection(mosaic: Mosaic | None, about: float) -> ToXY:
    """(lon, lat) degrees -> drawn (x, y): mosaic px, or without a mosaic the degrees, the
    longitude taken within 180 deg of ``about`` (:func:`_unwrapped`)."""

    def to_xy(lon: float, lat: float) -> tuple[float, float]:
        if mosaic is None:
            return float(_unwrapped(np.array([lon]), about)[0]), lat
        x, y = lonlat_to_tile_px(mosaic[1], (mosaic[2], mosaic[2]), [[lon, lat]])[0]
        return float(x), float(y)

    return to_xy


def _located(
    outcomes: Sequence[FrameOutcome],
    where: Callable[[FrameOutcome], tuple[float | None, float | None]],
    to_xy: ToXY,
) -> list[Point]:
    """The frames whose ``where`` (lon, lat) is known, with their drawn position."""
    out: list[Point] = []
    for o in outcomes:
        lon, lat = where(o)
        if lat is not None and lon is not None:
            out.append((o, *to_xy(lon, lat)))
    return out


def _line(ax: Any, points: Sequence[Point], fmt: str, **style: Any) -> None:
    ax.plot([p[1] for p in points], [p[2] for p in points], fmt, **style)


def _mark(ax: Any, points: Sequence[Point], **style: Any) -> None:
    """Scatter ``points`` (nothing, and no legend entry, when there are none)."""
    if points:
        ax.scatter([p[1] for p in points], [p[2] for p in points], **style)


def _vehicle_track(
    ax: Any, dataset: FlightDataset, outcomes: Sequence[FrameOutcome], to_xy: ToXY
) -> None:
    """The vehicle's own GNSS positions over the frames replayed (a recorded flight)."""
    done = {o.index for o in outcomes}
    vehicle = [
        to_xy(float(f.telemetry["lon"]), float(f.telemetry["lat"]))
        for f in dataset.frames
        if f.index in done and "lat" in f.telemetry and "lon" in f.telemetry
    ]
    if vehicle:
        ax.plot(
            [v[0] for v in vehicle],
            [v[1] for v in vehicle],
            ":",
            color="#98df8a",
            lw=1.5,
            label="vehicle GNSS track",
        )


def _references(ax: Any, truth: list[Point], tele: list[Point], est: list[Point]) -> None:
    """Red segments from each frame's reference (truth, else telemetry) to its estimate (dashed
    grey from a look point of an attitude assumed level: no error), and every tenth reference
    (or estimate) labelled with its frame index."""
    by_index = {t[0].index: t for t in (truth or tele)}
    for e in est:
        t = by_index.get(e[0].index)
        if t is not None:
            style = {"color": GREY, "ls": "--"} if t[0].attitude_assumed else {"color": RED}
            ax.plot([t[1], e[1]], [t[2], e[2]], lw=0.8, **style)
    labelled = truth or tele or est
    for o, x, y in labelled[:: max(1, len(labelled) // 10)]:
        ax.annotate(
            str(o.index),
            (x, y),
            textcoords="offset points",
            xytext=(4, 4),
            fontsize=8,
            color="white",
            bbox={"boxstyle": "round,pad=0.1", "fc": "black", "alpha": 0.5},
        )


def _axes_and_scale(ax: Any, title: str, mosaic: Mosaic | None) -> None:
    """The title; degree labels without a mosaic, else no ticks and a metric scale bar."""
    ax.set_title(title, parse_math=False)  # a dataset's name is text, never mathtext
    if mosaic is None:
        ax.set_xlabel("lon (deg)")
        ax.set_ylabel("lat (deg)")
        return
    ax.set_xticks([])
    ax.set_yticks([])
    m_per_px = mosaic[1].web_mercator_gsd_m()
    bar = 10 ** math.floor(math.log10(mosaic[2] * m_per_px / 4))
    x0, y0 = mosaic[2] * 0.05, mosaic[2] * 0.95
    ax.plot([x0, x0 + bar / m_per_px], [y0, y0], color="white", lw=4)
    ax.text(x0, y0 - mosaic[2] * 0.02, f"{bar:g} m", color="white", fontsize=9)


def _mark_unmatched(ax: Any, points: Sequence[Point], where: str) -> None:
    """Over the frames drawn at their ``where`` (truth, telemetry) that did not match: a red x
    over a failed frame, a cyan ring over one that rightly raised (:class:`Verdict`)."""
    judged = [(p, verdict(p[0])) for p in points if p[0].status != FrameStatus.OK]
    failed = [p for p, v in judged if v == Verdict.FAILED]
    _mark(ax, failed, marker="x", s=70, color=RED, zorder=5, label=f"failed frame ({where})")
    refused = [p for p, v in judged if v == Verdict.RIGHTLY_RAISED]
    ring = {"facecolors": "none", "edgecolors": RIGHT_REFUSAL, "linewidths": 2, "zorder": 5}
    label = f"{Verdict.RIGHTLY_RAISED} (true tile absent)"
    _mark(ax, refused, marker="o", s=110, **ring, label=label)


def _mark_picks(ax: Any, est: Sequence[Point]) -> None:
    """Over the estimates: a red diamond over a wrong fix, a green square over a pick of
    another tile that places the frame right (:class:`Verdict`)."""
    ring = {"facecolors": "none", "edgecolors": RED, "zorder": 6}
    wrong = [e for e in est if verdict(e[0]).wrong_fix]
    _mark(ax, wrong, marker="D", s=60, **ring, label="wrong fix")
    ring = {**ring, "edgecolors": "#2c9f2c"}
    elsewhere = [e for e in est if verdict(e[0]) == Verdict.OTHER_TILE]
    _mark(ax, elsewhere, marker="s", s=60, **ring, label=Verdict.OTHER_TILE)


def draw_trajectory(
    ax: Any, dataset: FlightDataset, outcomes: Sequence[FrameOutcome], title: str
) -> None:
    """Draw the flight's trajectory (module docstring) onto the matplotlib ``ax``."""
    mosaic = _mosaic(dataset, outcomes)
    pts = _points(outcomes)
    to_xy = _projection(mosaic, pts[0][0] if pts else 0.0)
    if mosaic is not None:
        ax.imshow(mosaic[0], interpolation="bilinear")
    truth = _located(outcomes, lambda o: (o.truth_lon, o.truth_lat), to_xy)
    est = _located(outcomes, lambda o: (o.est_lon, o.est_lat), to_xy)
    if truth:
        _line(ax, truth, "-o", color="#1f77b4", ms=4, lw=1.5, label="truth")
        _mark_unmatched(ax, truth, "truth")
    if est:
        _line(ax, est, "-s", color="#ff7f0e", ms=4, lw=1.2, label="estimate")
        _mark_picks(ax, est)
    tele = _located(outcomes, lambda o: (o.telemetry_lon, o.telemetry_lat), to_xy)
    _vehicle_track(ax, dataset, outcomes, to_xy)
    if tele:
        label = "telemetry: where the frame looks"
        _line(ax, tele, "-^", color="#2ca02c", ms=4, lw=1.2, label=label)
        degraded = [t for t in tele if t[0].gnss_degraded]
        ring = {"facecolors": "none", "edgecolors": "#ffbf00", "linewidths": 1.5, "zorder": 6}
        _mark(ax, degraded, marker="o", s=90, **ring, label="GNSS absent or degraded")
        assumed = [t for t in tele if t[0].attitude_assumed]
        ring = {**ring, "edgecolors": GREY}
        _mark(ax, assumed, marker="^", s=90, **ring, label=ASSUMED_LABEL)
        if not truth:
            _mark_unmatched(ax, tele, "telemetry")
    _references(ax, truth, tele, est)
    _axes_and_scale(ax, title, mosaic)
    if truth or est or tele:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
