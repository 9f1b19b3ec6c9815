"""Pictures of matches: query and tile side by side with inlier lines."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["draw_matches"]


def draw_matches(
    query: NDArray[np.uint8],
    tile: NDArray[np.uint8],
    correspondences: NDArray[np.float32],
    out: Path,
    *,
    title: str = "",
    max_lines: int = 300,
    height: int = 600,
) -> Path:
    """Write a PNG: ``query`` (RGB) left, ``tile`` (RGB) right, one line per correspondence
    (x_query, y_query, x_tile, y_tile) in each image's own pixels; at most ``max_lines``, evenly
    subsampled (deterministic)."""
    sq, st = height / query.shape[0], height / tile.shape[0]
    left = cv2.resize(query, (round(query.shape[1] * sq), height), interpolation=cv2.INTER_AREA)
    right = cv2.resize(tile, (round(tile.shape[1] * st), height), interpolation=cv2.INTER_AREA)
    canvas = np.concatenate([left, right], axis=1)[:, :, ::-1].copy()  # BGR for OpenCV
    offset = left.shape[1]
    step = max(1, len(correspondences) // max_lines)
    for i, (xq, yq, xt, yt) in enumerate(correspondences[::step]):
        hue = int(179 * i / max(1, len(correspondences[::step])))
        hsv = np.array([[[hue, 255, 255]]], dtype=np.uint8)
        color = [int(c) for c in cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0]]
        p0 = (round(xq * sq), round(yq * sq))
        p1 = (round(xt * st) + offset, round(yt * st))
        cv2.line(canvas, p0, p1, color, 1, cv2.LINE_AA)
        cv2.circle(canvas, p0, 3, color, -1, cv2.LINE_AA)
        cv2.circle(canvas, p1, 3, color, -1, cv2.LINE_AA)
    if title:
        cv2.putText(
            canvas, title, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 0, 0), 4, cv2.LINE_AA
        )
        cv2.putText(
            canvas, title, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2, cv2.LINE_AA
        )
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), canvas):
        raise OSError(f"cannot write {out}")
    return out
