"""XFeat's ``upscale`` option (1 by default): the extractor runs on each prepared image enlarged a
whole number of times, its keypoints given back in the prepared image's px; on a store of small
tiles (Zurich, zoom 16: 160 px windows, a 20 x 20 descriptor map) that is what lets XFeat find the
true tile. Stored map features built with the factor carry it in their set's key: they serve a
flight of that factor only."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3_matcher.compose import build_default_helpers
from c3_matcher.config import C3Settings
from c3_matcher.engines.extract import run_extractor
from c3_matcher.engines.store import EngineStore
from c3_matcher_tools.testing.cli import run_cli

ZURICH = Path(__file__).resolve().parents[3] / "data" / "flights" / "zurich_z16"
UPSCALED = {"C3_MATCHER_MATCHER__OPTIONS__XFEAT": json.dumps({"upscale": 2})}
AS_IS: dict[str, str] = {}  # the default: the images as prepared


def test_an_upscaled_extraction_is_the_engine_on_the_enlarged_image_in_this_images_px(
    engine_dir: Path, tmp_path: Path
) -> None:
    settings = C3Settings(engines={"directory": engine_dir}, fdr={"path": tmp_path / "fdr.jsonl"})
    runtime = build_default_helpers(settings)["c7_inference"]
    engine = runtime.load_engine(EngineStore(engine_dir).require("xfeat", "default"))
    tile = cv2.cvtColor(cv2.imread(str(ZURICH / "frames" / "000000.jpg")), cv2.COLOR_BGR2RGB)
    image = np.ascontiguousarray(tile[:160, :224])
    valid = np.ones(image.shape[:2], bool)
    valid[:, :64] = False
    small = run_extractor(runtime, engine, image, valid, 4096, upscale=2)
    big = run_extractor(
        runtime,
        engine,
        cv2.resize(image, (448, 320), interpolation=cv2.INTER_LINEAR),
        cv2.resize(valid.astype(np.uint8), (448, 320), interpolation=cv2.INTER_NEAREST) > 0,
        4096,
    )
    assert small.image_size == (224, 160) and len(small) == len(big) > 100
    np.testing.assert_array_equal(small.keypoints, (big.keypoints + 0.5) / np.float32(2) - 0.5)
    np.testing.assert_array_equal(small.descriptors, big.descriptors)
    x, y = small.keypoints[:, 0], small.keypoints[:, 1]
    assert (x >= 63.5).all() and (x < 224).all() and (y > -0.5).all() and (y < 160).all()


def _correct(stdout: str) -> tuple[int, int]:
    found = re.search(r"correct candidate (\d+)/(\d+)", stdout)
    assert found is not None, stdout
    return int(found.group(1)), int(found.group(2))


def test_upscale_finds_the_true_tile_on_a_store_of_small_tiles(
    engine_dir: Path, tmp_path: Path
) -> None:
    def replay(out: str, settings: dict[str, str]) -> tuple[int, int]:
        args = ("replay", ZURICH, "--strategy", "xfeat", "--limit", "4", "--out", tmp_path / out)
        proc = run_cli(*args, cwd=tmp_path, engine_dir=engine_dir, settings=settings)
        assert proc.returncode == 0, proc.stderr
        return _correct(proc.stdout)

    assert replay("as_is", AS_IS) == (0, 4)
    assert replay("upscaled", UPSCALED) == (4, 4)
    for out, factor in (("as_is", 1), ("upscaled", 2)):  # the run says which it had
        report = json.loads((tmp_path / out / "report.json").read_text())
        assert report["provenance"]["input_rule"]["upscale"] == factor
    results = (tmp_path / "upscaled" / "results.jsonl").read_text().splitlines()
    assert all(json.loads(line)["status"] == "ok" for line in results)


def _best_inliers(out: Path) -> list[int]:
    lines = (out / "results.jsonl").read_text().splitlines()
    return [json.loads(line)["best_inliers"] for line in lines]


def _candidate_features(out: Path) -> list[list[str]]:
    records = [json.loads(line) for line in (out / "fdr.jsonl").read_text().splitlines()]
    kinds = ("matcher.frame_done", "matcher.insufficient_inliers")  # each frame's last record
    done = [r["payload"] for r in records if r["kind"] in kinds]
    return [d["candidate_features"] for d in done]


def test_map_features_built_upscaled_serve_the_flight_the_same_matches(
    engine_dir: Path, tmp_path: Path
) -> None:
    """A set built with the factor is its own (its key says so): the flight is served its
    windows and matches as when it extracts them."""
    flight = tmp_path / "flight"
    shutil.copytree(ZURICH, flight)

    def c3(*args: object, settings: dict[str, str] = UPSCALED) -> str:
        proc = run_cli(*args, cwd=tmp_path, engine_dir=engine_dir, settings=settings)
        assert proc.returncode == 0, proc.stderr
        return proc.stdout

    c3("features", "build", flight, "--strategy", "xfeat", "--workers", "0", "--flight-candidates")
    assert ":x2" in c3("features", "info", flight, "--json")
    replay = ("replay", flight, "--strategy", "xfeat", "--limit", "4", "--out")
    assert _correct(c3(*replay, tmp_path / "stored")) == (4, 4)
    assert _candidate_features(tmp_path / "stored") == [["stored"] * 3] * 4
    extracted = {**UPSCALED, "C3_MATCHER_MATCHER__STORED_FEATURES": "false"}
    c3(*replay, tmp_path / "extracted", settings=extracted)
    assert _best_inliers(tmp_path / "stored") == _best_inliers(tmp_path / "extracted")
    c3(*replay, tmp_path / "as_is", settings=AS_IS)  # a set of another factor is not served
    served = _candidate_features(tmp_path / "as_is")
    assert len(served) == 4 and not any("stored" in frame for frame in served), served


@pytest.mark.parametrize("upscale", [0, 5, 1.5, True])
def test_an_upscale_out_of_range_is_refused_naming_it(tmp_path: Path, upscale: float) -> None:
    proc = run_cli(
        "replay", ZURICH, "--strategy", "xfeat", "--out", tmp_path / "out",
        cwd=tmp_path, engine_dir=tmp_path / "none",
        settings={"C3_MATCHER_MATCHER__OPTIONS__XFEAT": json.dumps({"upscale": upscale})},
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert "matcher.options.xfeat.upscale" in proc.stderr
    assert not (tmp_path / "out").exists()


def test_a_set_built_with_another_factor_is_said_not_to_serve_the_flight(
    engine_dir: Path, tmp_path: Path
) -> None:
    """Map features built with ``upscale = 2``, a flight at the default 1: ``features info
    --verify`` says the set is never served, why, and the command that builds the one it is
    served; with the factor it was built for, it is served; once the other is built, it is
    replaced and the check passes."""
    flight = tmp_path / "flight"
    shutil.copytree(ZURICH, flight)

    def c3(*args: object, settings: dict[str, str] = AS_IS) -> subprocess.CompletedProcess[str]:
        return run_cli(*args, cwd=tmp_path, engine_dir=engine_dir, settings=settings)

    build = ("features", "build", flight, "--strategy", "xfeat", "--workers", "0")
    assert c3(*build, "--flight-candidates", settings=UPSCALED).returncode == 0
    verify = ("features", "info", flight, "--verify", "--json")
    proc = c3(*verify)
    assert proc.returncode == 1, proc.stderr
    (built,) = json.loads(proc.stdout)["sets"]
    assert (built["engine_installed"], built["served"]) == (True, False)
    assert built["set_id"] == built["asked_set_id"] + ":x2"
    said = proc.stderr
    assert "but other settings than a flight has here" in said and ":w160), so" in said
    command = re.search(r"build its set: c3-matcher (features build .*?)\. No command", said)
    assert command is not None, said
    words = command.group(1).split(" (run it where")[0]  # the environment it needs, said apart
    assert words.endswith("--window 160 --stride 16 --flight-candidates"), said
    assert c3(*verify, settings=UPSCALED).returncode == 0  # the flight it was built for
    assert c3(*build, "--flight-candidates").returncode == 0
    proc = c3(*verify)
    assert proc.returncode == 0, proc.stderr
    assert "which it is served, replaces it" in proc.stderr


def test_the_pytorch_reference_extracts_as_the_engine_does(
    engine_dir: Path, tmp_path: Path
) -> None:
    """``bench``'s PyTorch reference runs on the same enlarged image: the same keypoints."""
    from c3_matcher.prepared import PreparedImage
    from c3_matcher_xfeat.export import XFeatReference

    settings = C3Settings(
        matcher={"options": {"xfeat": {"upscale": 2}}},
        engines={"directory": engine_dir},
        fdr={"path": tmp_path / "fdr.jsonl"},
    )
    runtime = build_default_helpers(settings)["c7_inference"]
    engine = runtime.load_engine(EngineStore(engine_dir).require("xfeat", "default"))
    tile = cv2.cvtColor(cv2.imread(str(ZURICH / "frames" / "000000.jpg")), cv2.COLOR_BGR2RGB)
    image, valid = np.ascontiguousarray(tile[:160, :224]), np.ones((160, 224), bool)
    ours = run_extractor(runtime, engine, image, valid, 4096, upscale=2)
    reference = XFeatReference(settings).extract(PreparedImage(image, valid, np.eye(3), (224, 160)))
    assert reference.image_size == (224, 160) and len(reference) == len(ours) > 100
    gap = np.abs(reference.keypoints[:, None, :] - ours.keypoints[None, :, :]).max(axis=2)
    assert (gap.min(axis=1) < 0.01).mean() > 0.99
