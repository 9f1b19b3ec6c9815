"""The refine pass on the real path: xfeat on the first frames of the shipped demo flight,
replayed with 3 deg (1 sigma) of attitude error, refine on: every frame refines its best
candidate, the picks stay right and within the IT-03 bar, and two runs agree bit for bit."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from c3_matcher.config import C3Settings
from c3_matcher_tools.dataset.format import load_dataset, with_attitude_noise
from c3_matcher_tools.run import open_matcher, run_flight

DEMO = Path(__file__).resolve().parents[3] / "data" / "flights" / "naip_demo"


def test_refine_on_real_frames_with_attitude_error(engine_dir: Path, tmp_path: Path) -> None:
    flight = with_attitude_noise(load_dataset(DEMO), 3.0)
    flight = dataclasses.replace(flight, frames=flight.frames[:4])
    settings = C3Settings(
        matcher={"strategy": "xfeat", "refine": True}, engines={"directory": engine_dir}
    )
    runs = []
    for n in range(2):
        with open_matcher(settings, "xfeat", tmp_path / f"run{n}", log_level="WARNING") as m:
            runs.append(run_flight(m, flight))
    first, second = runs
    assert [o.fingerprint for o in first] == [o.fingerprint for o in second]
    done = [
        r["payload"]
        for r in map(json.loads, (tmp_path / "run0" / "fdr.jsonl").read_text().splitlines())
        if r["kind"] == "matcher.frame_done"
    ]
    assert len(done) == len(flight.frames)
    for outcome, frame, record in zip(first, flight.frames, done, strict=True):
        assert outcome.status == "ok" and outcome.correct, outcome
        assert outcome.mean_error_px < 2.5
        refine = record["refine"]
        assert refine["candidate_index"] == frame.true_index
        assert refine["inliers_after"] > 0
        kept = refine["inliers_after"] if refine["kept"] else refine["inliers_before"]
        assert record["best_inlier_count"] == kept == outcome.best_inliers
