"""Map features a flight is not served are said, not silently ignored: on a copy of the demo
flight with a real XFeat set built at the default upscale (1), a matcher whose settings ask for
another set (``upscale = 2``) logs one WARNING over several frames naming the sidecar, the set it
asks for and the sets held, and extracts; one of the settings the set was built for says
nothing and is served. ``replay`` counts the candidates by where their features came from and,
when none was served stored features, says on stderr what builds the set the run asks for; a
store without a sidecar says nothing."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[3]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
FRAMES = 4
UNSERVED = "c3.matcher.stored_features_unserved"
UPSCALED = {"C3_MATCHER_MATCHER__OPTIONS__XFEAT": json.dumps({"upscale": 2})}
AS_IS: dict[str, str] = {}
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory, engine_dir: Path) -> Path:
    """A copy of the demo flight whose store holds XFeat's set of its candidates' windows,
    built at the default upscale by ``features build``."""
    flight = tmp_path_factory.mktemp("flight") / "naip_demo"
    shutil.copytree(FLIGHT, flight)
    proc = run_cli(
        "features", "build", flight, "--strategy", "xfeat", "--workers", "0",
        "--flight-candidates", cwd=flight.parent, engine_dir=engine_dir,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    return flight


def _matcher(engine_dir: Path, upscale: int, fdr: Any) -> Any:
    from c3_matcher.compose import build_default_helpers, compose_root
    from c3_matcher.config import load_settings

    s = load_settings(None, env={"C3_MATCHER_ENGINES__DIRECTORY": str(engine_dir)})
    update = {
        "strategy": "xfeat",
        "tile_cache_size": 0,
        "stored_features": True,
        "options": {"xfeat": {"upscale": upscale}},
    }
    s = s.model_copy(update={"matcher": s.matcher.model_copy(update=update)})
    root = compose_root(s, {**build_default_helpers(s), "c13_fdr": fdr}, configure_logs=False)
    return root.matcher


def _flown(built: Path, engine_dir: Path, upscale: int) -> tuple[list[dict[str, Any]], Any]:
    """The WARNING records (JSON) of FRAMES frames flown at ``upscale``, and its FDR."""
    from c3_matcher.errors import InsufficientInliersError
    from c3_matcher.fdr import InMemoryFdr
    from c3_matcher.logs import configure_logging
    from c3_matcher_tools.dataset.format import load_dataset

    dataset = load_dataset(built)
    fdr, stream = InMemoryFdr(), io.StringIO()
    handle = configure_logging(fdr, level="WARNING", stream=stream)
    try:
        matcher = _matcher(engine_dir, upscale, fdr)
        with dataset.open_store() as store:
            for f in dataset.frames[:FRAMES]:
                frame, rerank = dataset.nav_frame(f), dataset.rerank(f, store)
                with contextlib.suppress(InsufficientInliersError):
                    matcher.match(frame, rerank, dataset.calibration)
    finally:
        handle.close()
    return [json.loads(line) for line in stream.getvalue().splitlines() if line], fdr


def _sources(fdr: Any) -> list[list[str]]:
    done = fdr.of_kind("matcher.frame_done") + fdr.of_kind("matcher.insufficient_inliers")
    return [d["candidate_features"] for d in done]


def _held(built: Path) -> list[str]:
    from c3_matcher.tilestore.features import MapFeatureStore, sidecar_path

    with MapFeatureStore(sidecar_path(built / "tiles.mbtiles")) as side:
        return [s.set_id for s in side.feature_sets()]


def test_a_matcher_asking_for_a_set_the_sidecar_lacks_says_so_once(built: Path, engine_dir: Path):
    from c3_matcher.tilestore.features import sidecar_path

    records, fdr = _flown(built, engine_dir, upscale=2)
    (warning,) = [r for r in records if r["kind"] == UNSERVED]  # once, not per frame
    held = _held(built)
    sidecar = str(sidecar_path(built / "tiles.mbtiles"))
    assert warning["level"] == "WARNING"
    assert warning["sidecar"] == sidecar and warning["held_set_ids"] == held
    assert warning["asked_set_id"] == held[0] + ":x2"  # the same set, enlarged
    for said in (sidecar, warning["asked_set_id"], held[0], "extract"):
        assert said in warning["message"], said
    assert _sources(fdr) == [["extracted"] * 3] * FRAMES
    forwarded = [r for r in fdr.of_kind("log.warning") if r.get("kind") == UNSERVED]
    assert len(forwarded) == 1  # the FDR keeps the one warning too


def test_a_matcher_served_its_set_says_nothing(built: Path, engine_dir: Path):
    records, fdr = _flown(built, engine_dir, upscale=1)
    assert [r for r in records if r["kind"] == UNSERVED] == []
    assert _sources(fdr) == [["stored"] * 3] * FRAMES


def _replay(flight: Path, out: Path, engine_dir: Path, settings: dict[str, str]) -> Any:
    proc = run_cli(
        "replay", flight, "--strategy", "xfeat", "--limit", str(FRAMES), "--out", out,
        cwd=out.parent, engine_dir=engine_dir, settings=settings,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    return proc


def _logged(out: Path, kind: str) -> list[dict[str, Any]]:
    lines = (out / "matcher.log").read_text().splitlines()
    return [r for r in map(json.loads, lines) if r.get("kind") == kind]


def test_replay_counts_candidates_by_features_source(
    built: Path, engine_dir: Path, tmp_path: Path
) -> None:
    proc = _replay(built, tmp_path / "served", engine_dir, AS_IS)
    report = json.loads((tmp_path / "served" / "report.json").read_text())
    assert report["feature_sources"] == {"stored": 3 * FRAMES, "cached": 0, "extracted": 0}
    assert f"candidate features: {3 * FRAMES} stored, 0 cached, 0 extracted" in proc.stdout
    assert "features build" not in proc.stderr
    assert _logged(tmp_path / "served", UNSERVED) == []

    proc = _replay(built, tmp_path / "upscaled", engine_dir, UPSCALED)
    counts = json.loads((tmp_path / "upscaled" / "report.json").read_text())["feature_sources"]
    assert counts["stored"] == 0 and counts["cached"] + counts["extracted"] == 3 * FRAMES
    cached, extracted = counts["cached"], counts["extracted"]
    assert f"candidate features: 0 stored, {cached} cached, {extracted} extracted" in proc.stdout
    (said,) = [line for line in proc.stderr.splitlines() if "features build" in line]
    assert "no candidate" in said and "tiles.mbtiles.features.sqlite" in said
    command = f"c3-matcher features build {built} --strategy xfeat --window 448 --stride 32"
    assert command in said, said
    assert len(_logged(tmp_path / "upscaled", UNSERVED)) == 1


def test_a_store_without_a_sidecar_says_nothing(engine_dir: Path, tmp_path: Path) -> None:
    flight = tmp_path / "naip_demo"
    shutil.copytree(FLIGHT, flight)
    out = tmp_path / "out"
    proc = _replay(flight, out, engine_dir, UPSCALED)
    report = json.loads((out / "report.json").read_text())
    assert report["feature_sources"]["stored"] == 0 and report["feature_sources"]["extracted"] > 0
    assert "features build" not in proc.stderr
    assert _logged(out, UNSERVED) == []


def test_eval_counts_candidates_by_features_source(
    built: Path, engine_dir: Path, tmp_path: Path
) -> None:
    out = tmp_path / "eval"
    proc = run_cli(
        "eval", built, "--strategy", "xfeat", "--no-baseline", "--determinism-frames", "1",
        "--samples", "0", "--out", out, cwd=tmp_path, engine_dir=engine_dir, settings=UPSCALED,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    (entry,) = json.loads((out / "eval.json").read_text())["strategies"]
    counts = entry["feature_sources"]
    frames = json.loads((built / "dataset.json").read_text())["spec"]["n_frames"]
    assert counts["stored"] == 0 and counts["cached"] + counts["extracted"] == 3 * frames
    line = f"xfeat: candidate features: 0 stored, {counts['cached']} cached, "
    assert line + f"{counts['extracted']} extracted" in proc.stdout
    (said,) = [line for line in proc.stderr.splitlines() if "features build" in line]
    assert f"features build {built} --strategy xfeat --window 448 --stride 32" in said
    assert len(_logged(out / "xfeat", UNSERVED)) == 1
