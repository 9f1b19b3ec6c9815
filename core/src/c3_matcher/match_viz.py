"""The ``--viz`` picture of ``c3-matcher match``: the rectified query beside the best tile,
every candidate in a strip (the query beside the candidates for a failed frame)."""

from __future__ import annotations

import argparse
from typing import Any

from c3_matcher.dto import CameraCalibration, RerankResult
from c3_matcher.errors import C3Error

__all__ = ["draw_or_report"]


def draw_or_report(problems: list[str], *args: Any) -> bool:
    """Draw the picture (``_draw``'s arguments after ``problems``); a picture that cannot be
    written is a problem (reported after the result, exit 2), not a lost result."""
    try:
        _draw(*args)
    except (OSError, C3Error) as exc:
        problems.append(f"--viz {args[0].viz}: cannot write the picture: {exc}")
        return False
    return True


def _draw(
    args: argparse.Namespace,
    image: Any,
    calibration: CameraCalibration,
    rerank: RerankResult,
    result: Any,
    title: str,
) -> None:
    """The --viz picture: rectified query beside the best tile, every candidate in a strip;
    the query beside the candidates for a failed frame."""
    from c3_matcher.georef import best_query_to_tile
    from c3_matcher.viz import CandidateView, render_match, write_png

    counts: dict[int, int] = {}
    best_index = hom = corr = None
    if result is not None:
        indices = result.diagnostics.get("input_index", range(len(result.per_candidate)))
        counts = {int(i): c.inlier_count for i, c in zip(indices, result.per_candidate)}
        best_index = int(next(iter(indices)))
        corr = result.per_candidate[0].inlier_correspondences
        hom = best_query_to_tile(result, calibration)
    names = [p.name for p in args.tile or ()] or [str(c.tile_id) for c in rerank.candidates]
    views = [
        CandidateView(
            *_pixels(c.tile_pixels_handle, str(c.tile_id) if c.tile_id.zoom else name),
            counts.get(i),
            best=i == best_index,
        )
        for i, (name, c) in enumerate(zip(names, rerank.candidates, strict=True))
    ]
    picture = render_match(
        image,
        views,
        best_index=best_index if hom is not None else None,
        h_query_to_tile=hom,
        correspondences=corr,
        calibration=calibration,
        title=title,
    )
    write_png(picture, args.viz)


def _pixels(handle: Any, label: str) -> tuple[Any, str]:
    """A candidate's pixels and label; a grey square labelled so when they cannot be decoded
    (a window over no stored tile, a damaged tile: dropped in the match, as in flight)."""
    import numpy as np

    try:
        return handle.decode(), label
    except C3Error:
        return np.full((64, 64, 3), 128, np.uint8), f"{label} (no pixels)"
