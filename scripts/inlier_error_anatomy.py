"""Where a flight's IT-03 error comes from: scatter of the inliers, or a bias of the whole fit.

    .venv/bin/python scripts/inlier_error_anatomy.py FLIGHT_DIR RESULTS_JSONL

RESULTS_JSONL is ``<eval out>/<flight>/<strategy>/results.jsonl`` of ``c3-matcher eval`` (with
correspondences, the default). For every frame that picked the true tile it refits the
homography to the reported inliers and prints, per inlier threshold against that fit (3.0 px is
the pipeline's RANSAC threshold; tighter keeps fewer inliers), IT-03 p95 and median (ORIGINAL
frame px against ground truth) and the inlier counts. If tightening lowers the median but not
the p95, the worst frames are off as a whole: their inliers agree with each other and not with
the ground truth. It then prints each frame's median signed residual in tile px (east, south):
the offset between the fit and the ground truth, which no inlier selection can remove.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np

from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.truth import inlier_errors_px

THRESHOLDS_PX = (3.0, 2.5, 2.0, 1.5)


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    flight = load_dataset(argv[0])
    frames = {f.index: f for f in flight.frames}
    picks = []
    for line in Path(argv[1]).read_text().splitlines():
        row = json.loads(line)
        if row["status"] != "ok" or not row["correct"] or row["result"] is None:
            continue
        corr = np.asarray(row["result"]["per_candidate"][0]["inlier_correspondences"], np.float64)
        truth = frames[row["index"]].candidates[row["best_input_index"]].h_tile_to_undistorted
        if truth is None or len(corr) < 4:
            continue
        picks.append((row["index"], corr, truth))
    if not picks:
        print("no frame picked the true tile with correspondences recorded")
        return 1
    print(f"{flight.name}: {len(picks)} frames on the true tile")
    print(f"{'threshold px':>12} {'IT-03 p95':>10} {'median':>7} {'inliers min':>12} {'median':>7}")
    for threshold in THRESHOLDS_PX:
        means, counts = [], []
        for _, corr, truth in picks:
            fit, _ = cv2.findHomography(corr[:, 0:2], corr[:, 2:4], 0)
            projected = cv2.perspectiveTransform(corr[:, None, 0:2], fit)[:, 0]
            keep = np.linalg.norm(projected - corr[:, 2:4], axis=1) <= threshold
            errors = inlier_errors_px(truth, flight.calibration, corr[keep].astype(np.float32))
            if errors.size:
                means.append(float(errors.mean()))
            counts.append(int(keep.sum()))
        print(
            f"{threshold:>12.1f} {np.percentile(means, 95):>10.2f} {np.median(means):>7.2f} "
            f"{min(counts):>12d} {np.median(counts):>7.0f}"
        )
    print("median signed residual, tile px (east, south), per frame:")
    k, dist = flight.calibration.K, np.asarray(flight.calibration.distortion)
    for index, corr, truth in picks:
        und = cv2.undistortPoints(corr[:, None, 0:2], k, dist, P=k)[:, 0]
        predicted = cv2.perspectiveTransform(und[:, None], np.linalg.inv(truth))[:, 0]
        dx, dy = np.median(corr[:, 2:4] - predicted, axis=0)
        print(f"  frame {index:>3}: ({dx:+.2f}, {dy:+.2f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
