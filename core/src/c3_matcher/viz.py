"""Pictures of matches (``c3-matcher match --viz`` and the flight report), OpenCV only.

:func:`render_match` lays out, top: the query RECTIFIED onto the best tile's grid (undistorted,
then warped by the query -> tile homography, so it reads north-up at the tile's scale) beside
that tile with the query's footprint drawn on it, and at most ``max_lines`` (100) evenly chosen
correspondence lines between the two: green where the point agrees with the fitted homography
(within ``good_px`` tile px, or with the ground truth when ``errors_px`` is given), red where it
does not; bottom: a strip of the candidates (in input order) with their inlier counts,
``BEST``, ``TRUE``/``dropped`` marks: as many as fit at ``MIN_CELL`` px each, the best and true
ones always, the rest counted ("+M more"). A failed frame (no homography) shows the original
query beside the candidates with the reason in the title.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.atomic import write_bytes_atomically
from c3_matcher.dto import CameraCalibration
from c3_matcher.fdr.files import make_dirs_durably

__all__ = ["CandidateView", "draw_matches", "render_match", "write_png"]

GOOD = (60, 200, 60)  # RGB
BAD = (230, 40, 40)
FOOT = (255, 210, 0)
MIN_CELL = 96
"""The least width of a candidate's cell in the strip, px: past as many as fit, the rest are
counted ("+M more"), never drawn smaller (a frame may have up to 1024 candidates)."""


@dataclass(frozen=True)
class CandidateView:
    """One candidate in the strip: its image (RGB), a short label, its inlier count (None:
    dropped / not matched) and marks."""

    image: NDArray[np.uint8]
    label: str
    inliers: int | None = None
    best: bool = False
    is_true: bool | None = None


def _text(img: NDArray[np.uint8], text: str, org: tuple[int, int], scale: float = 0.5) -> None:
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1, cv2.LINE_AA)


def _fit(img: NDArray[np.uint8], size: int) -> tuple[NDArray[np.uint8], float]:
    s = size / max(img.shape[:2])
    dsize = (max(1, round(img.shape[1] * s)), max(1, round(img.shape[0] * s)))
    out = np.asarray(cv2.resize(img, dsize, interpolation=cv2.INTER_AREA), np.uint8)
    pad = np.full((size, size, 3), 40, np.uint8)
    pad[: out.shape[0], : out.shape[1]] = out
    return pad, s


def _rectify(
    query: NDArray[np.uint8],
    calibration: CameraCalibration | None,
    h_query_to_tile: NDArray[np.float64],
    tile_shape: tuple[int, int],
) -> NDArray[np.uint8]:
    src = query
    if calibration is not None and calibration.distortion.size:
        src = np.asarray(cv2.undistort(query, calibration.K, calibration.distortion), np.uint8)
    th, tw = tile_shape
    return np.asarray(
        cv2.warpPerspective(src, h_query_to_tile, (tw, th), borderValue=(40, 40, 40)), np.uint8
    )


def _footprint(
    calibration: CameraCalibration | None, query_shape: tuple[int, int], h: NDArray[np.float64]
) -> NDArray[np.float64]:
    from c3_matcher import camera as cam

    qh, qw = query_shape
    ring = cam.image_boundary(qw, qh, 16)
    if calibration is not None and calibration.distortion.size:
        ring = cam.undistort_points(ring, calibration)
    return cam.apply_homography(h, ring)


def _shown(candidates: Sequence[CandidateView], slots: int) -> list[int]:
    """The indices of the candidates the strip draws, in input order: all of them when they
    fit in ``slots`` cells, else ``slots - 1`` (one cell says how many more there are): the
    best and true ones first, the rest by input order."""
    if len(candidates) <= slots:
        return list(range(len(candidates)))
    marked = [i for i, c in enumerate(candidates) if c.best or c.is_true]
    chosen = frozenset(marked)
    rest = [i for i in range(len(candidates)) if i not in chosen]
    return sorted((marked + rest)[: max(0, slots - 1)])


def _strip(candidates: Sequence[CandidateView], width: int, cell: int) -> NDArray[np.uint8]:
    """The candidates' strip, ``width`` px wide: a cell of at most ``cell`` px each, never
    under ``MIN_CELL`` (nor over ``width``); the candidates that do not fit are counted in the
    last cell ("+M more"), the best and true ones always drawn (:func:`_shown`)."""
    cell = min(max(min(cell, width // max(1, len(candidates))), MIN_CELL), width)
    shown = _shown(candidates, max(1, width // cell))
    strip = np.full((cell + 8, width, 3), 255, np.uint8)
    for slot, i in enumerate(shown):
        c = candidates[i]
        thumb, _ = _fit(c.image, max(1, cell - 8))
        x = slot * cell + 4
        strip[4 : 4 + thumb.shape[0], x : x + thumb.shape[1]] = thumb
        colour = GOOD if c.best else (150, 150, 150)
        if c.best and c.is_true is False:
            colour = BAD
        cv2.rectangle(strip, (x, 4), (x + thumb.shape[1] - 1, 4 + thumb.shape[0] - 1), colour, 3)
        count = "dropped" if c.inliers is None else f"{c.inliers} inl"
        marks = (" BEST" if c.best else "") + (" TRUE" if c.is_true else "")
        _text(strip, f"#{i} {count}{marks}", (x + 6, 22))
        _text(strip, c.label, (x + 6, thumb.shape[0] - 4), 0.4)
    if len(shown) < len(candidates):
        _text(strip, f"+{len(candidates) - len(shown)} more", (len(shown) * cell + 10, cell // 2))
    return strip


def _draw_correspondences(
    top: NDArray[np.uint8],
    corr: NDArray[np.float64],
    h_query_to_tile: NDArray[np.float64],
    calibration: CameraCalibration | None,
    query_shape: tuple[int, int],
    placement: tuple[float, float, int],
    errors_px: NDArray[np.floating] | None,
    good_px: float,
    max_lines: int,
) -> tuple[int, int]:
    """Draw the best tile's footprint and at most ``max_lines`` correspondences onto ``top``
    (``placement``: the left and right panels' scales and the right panel's x offset, px);
    returns (agreeing, off) counts: within ``good_px`` of the rectified query point, or of
    ``errors_px`` when given."""
    from c3_matcher import camera as cam

    sl, sr, offset = placement
    ring = _footprint(calibration, query_shape, h_query_to_tile)
    pts = np.round(ring * sr).astype(np.int32) + np.array([offset, 0], np.int32)
    cv2.polylines(top, [pts.reshape(-1, 1, 2)], True, FOOT, 2, cv2.LINE_AA)
    if not len(corr):
        return 0, 0
    q = corr[:, 0:2]
    if calibration is not None and calibration.distortion.size:
        q = cam.undistort_points(q, calibration)
    qt = cam.apply_homography(h_query_to_tile, q)  # the query point on the rectified grid
    if errors_px is not None:
        good = np.asarray(errors_px, np.float64).reshape(-1) <= good_px
    else:
        good = np.linalg.norm(qt - corr[:, 2:4], axis=1) <= good_px
    step = max(1, int(np.ceil(len(corr) / max_lines)))
    for i in range(0, len(corr), step):
        colour = GOOD if good[i] else BAD
        p0 = (round(qt[i, 0] * sl), round(qt[i, 1] * sl))
        p1 = (round(corr[i, 2] * sr) + offset, round(corr[i, 3] * sr))
        cv2.line(top, p0, p1, colour, 1, cv2.LINE_AA)
        cv2.circle(top, p0, 3, colour, -1, cv2.LINE_AA)
        cv2.circle(top, p1, 3, colour, -1, cv2.LINE_AA)
    return int(good.sum()), int((~good).sum())


def render_match(
    query: NDArray[np.uint8],
    candidates: Sequence[CandidateView],
    *,
    best_index: int | None = None,
    h_query_to_tile: NDArray[np.float64] | None = None,
    correspondences: NDArray[np.floating] | None = None,
    calibration: CameraCalibration | None = None,
    errors_px: NDArray[np.floating] | None = None,
    title: str = "",
    panel: int = 420,
    max_lines: int = 100,
    good_px: float = 3.0,
) -> NDArray[np.uint8]:
    """The picture as an RGB array (see the module docstring). ``correspondences`` (x_query,
    y_query, x_tile, y_tile) in ORIGINAL query px and best-tile px; ``h_query_to_tile`` maps
    UNDISTORTED query px to best-tile px; ``errors_px`` (one per correspondence, e.g. against
    ground truth) decides the colours when given."""
    matched = best_index is not None and h_query_to_tile is not None
    tile = candidates[best_index].image if matched and best_index is not None else None
    if matched and tile is not None and h_query_to_tile is not None:
        left_src = _rectify(query, calibration, h_query_to_tile, tile.shape[:2])
    else:
        left_src = query
    left, sl = _fit(left_src, panel)
    right_src = tile if tile is not None else (candidates[0].image if candidates else query)
    right, sr = _fit(right_src, panel)
    top = np.concatenate([left, np.full((panel, 8, 3), 255, np.uint8), right], axis=1)
    offset = panel + 8
    n_good = n_bad = 0
    if matched and h_query_to_tile is not None and correspondences is not None:
        n_good, n_bad = _draw_correspondences(
            top,
            np.asarray(correspondences, np.float64).reshape(-1, 4),
            h_query_to_tile,
            calibration,
            query.shape[:2],
            (sl, sr, offset),
            errors_px,
            good_px,
            max_lines,
        )
    _text(top, "query, rectified onto the tile" if matched else "query (as captured)", (8, 18))
    _text(top, "best tile + footprint" if matched else "no match", (offset + 8, 18))
    if matched:
        _text(
            top,
            f"lines: green {n_good} agree, red {n_bad} off by > {good_px:g} px"
            f" (<= {max_lines} drawn)",
            (8, panel - 10),
            0.45,
        )
    width = top.shape[1]
    strip = _strip(candidates, width, 200)
    head = np.full((34, width, 3), 255, np.uint8)
    cv2.putText(head, title[:110], (8, 23), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, 16)
    return np.concatenate([head, top, strip], axis=0)


def write_png(image_rgb: NDArray[np.uint8], out: Path) -> Path:
    """``out`` holding ``image_rgb`` as a PNG, replaced whole (:mod:`c3_matcher.atomic`): a
    picture that cannot be written leaves the previous one as it was."""
    out = Path(out)
    make_dirs_durably(out.parent)  # a file in the way: "<file> is not a directory"
    ok, png = cv2.imencode(".png", np.ascontiguousarray(image_rgb[:, :, ::-1]))
    if not ok:
        raise OSError(f"cannot encode {out} as PNG")
    return write_bytes_atomically(out, png.tobytes())


def draw_matches(
    query: NDArray[np.uint8],
    tile: NDArray[np.uint8],
    correspondences: NDArray[np.float32],
    out: Path,
    *,
    title: str = "",
    max_lines: int = 100,
    height: int = 420,
    calibration: CameraCalibration | None = None,
) -> Path:
    """Write the :func:`render_match` picture of one query and one tile (PNG)."""
    from c3_matcher.georef import fit_query_to_tile

    corr = np.asarray(correspondences, np.float64).reshape(-1, 4)
    hom = fit_query_to_tile(corr, calibration)
    view = CandidateView(tile, "tile", len(corr) if hom is not None else None, hom is not None)
    picture = render_match(
        query,
        [view],
        best_index=0 if hom is not None else None,
        h_query_to_tile=hom,
        correspondences=corr,
        calibration=calibration,
        title=title,
        panel=height,
        max_lines=max_lines,
    )
    return write_png(picture, out)
