"""``c3-matcher eval`` writes, per strategy, the same flight.geojson and report.html as
``replay`` (one shared writer), on a 4-frame cut of the shipped demo flight through xfeat."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"


def test_eval_writes_flight_report_and_geojson_per_strategy(
    engine_dir: Path, tmp_path: Path
) -> None:
    flight = tmp_path / "demo4"
    shutil.copytree(DEMO, flight)
    lines = (flight / "frames.jsonl").read_text().splitlines()[:4]
    (flight / "frames.jsonl").write_text("\n".join(lines) + "\n")
    out = tmp_path / "eval"
    quick = ("--no-baseline", "--determinism-frames", "1", "--samples", "0")
    argv = ("eval", flight, "--strategy", "xfeat", *quick, "--out", out, "--json")
    proc = run_cli(*argv, cwd=REPO, engine_dir=engine_dir)
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(proc.stdout)
    (row,) = report["strategies"]
    assert row["html"] == str(out / "xfeat" / "report.html")
    assert row["geojson"] == str(out / "xfeat" / "flight.geojson")
    geo = json.loads((out / "xfeat" / "flight.geojson").read_text())
    kinds = {f["properties"].get("kind") for f in geo["features"]}
    assert {"truth_track", "estimate_track"} <= kinds, kinds
    page = (out / "xfeat" / "report.html").read_text()
    assert "data:image/png;base64," in page and "xfeat" in page
    assert "<script src=" not in page  # self-contained
