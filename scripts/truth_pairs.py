"""Draw frames of a flight beside their true tile as the ground truth sees it.

    .venv/bin/python scripts/truth_pairs.py FLIGHT_DIR FRAMES OUT.png

FRAMES is a comma-separated list of frame indices (each must have its true tile among its
candidates). Each row is the frame (undistorted) and the true candidate tile warped into it
through the recorded ground-truth homography: what the matcher had to find. Used to see why a
frame fails across seasons (docs/accuracy.md, "What limits the correct rate on naip_cross_date").
"""

from __future__ import annotations

import sys

import cv2
import numpy as np

from c3_matcher_tools.dataset.format import load_dataset


def main(argv: list[str]) -> int:
    if len(argv) != 3:
        print(__doc__, file=sys.stderr)
        return 2
    flight = load_dataset(argv[0])
    k = flight.calibration.K
    dist = np.asarray(flight.calibration.distortion)
    rows = []
    with flight.open_store() as store:
        for index in (int(i) for i in argv[1].split(",")):
            frame = flight.frames[index]
            true = frame.true_index
            truth = None if true is None else frame.candidates[true].h_tile_to_undistorted
            if true is None or truth is None:
                print(f"frame {index}: its true tile is not among its candidates", file=sys.stderr)
                return 1
            image = np.asarray(flight.nav_frame(frame).image)
            undistorted = cv2.undistort(image, k, dist)
            rerank = flight.rerank(frame, store)
            tile = np.asarray(rerank.candidates[true].tile_pixels_handle.decode())
            size = (undistorted.shape[1], undistorted.shape[0])
            warped = cv2.warpPerspective(tile, np.asarray(truth), size)
            rows.append(np.hstack([undistorted, warped]))
    picture = np.vstack(rows)
    cv2.imwrite(argv[2], cv2.cvtColor(picture, cv2.COLOR_RGB2BGR))
    print(f"{argv[2]}: {len(rows)} rows (frame | true tile through the ground truth)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
