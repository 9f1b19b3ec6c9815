"""``c3-matcher engines build|list|verify|bench`` through ``add_engines_commands``."""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import pytest

from c3_matcher.engines.bench import run_bench
from c3_matcher.engines.cli import EnginesCliContext, add_engines_commands, dispatch


def _run(argv: list[str], ctx: EnginesCliContext) -> int:
    parser = argparse.ArgumentParser(prog="c3-matcher")
    add_engines_commands(parser.add_subparsers(dest="command", required=True))
    return dispatch(parser.parse_args(argv), ctx)


@pytest.fixture()
def ctx(engine_dir: Path, built_engines: dict[tuple[str, str], Path]) -> EnginesCliContext:
    from c3_matcher_disk_lightglue.engines import ENGINE_SPECS

    return EnginesCliContext(engine_dir, ENGINE_SPECS)


def test_build_reuses_and_prints_result_on_stdout(
    ctx: EnginesCliContext, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _run(["engines", "build"], ctx) == 0
    out, err = capsys.readouterr()
    assert "disk/depth" in out and "lightglue/disk" in out and "0 built, 2 reused" in out
    assert "reused" in err  # progress on stderr


def test_build_unknown_only(ctx: EnginesCliContext, capsys: pytest.CaptureFixture[str]) -> None:
    assert _run(["engines", "build", "--only", "sift/x"], ctx) == 1
    assert "choose one of disk/depth, lightglue/disk" in capsys.readouterr().err


def test_list_shows_manifests_and_figures(
    ctx: EnginesCliContext, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _run(["engines", "list"], ctx) == 0
    out = capsys.readouterr().out
    assert "keypoints_mismatch=0" in out and "matches_identical=True" in out
    assert _run(["engines", "list", "--json"], ctx) == 0
    records = json.loads(capsys.readouterr().out)
    models = {r["manifest"]["model"] for r in records if r["manifest"]}
    assert {"disk", "lightglue"} <= models


def test_verify_ok_then_tampered(
    ctx: EnginesCliContext, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _run(["engines", "verify"], ctx) == 0
    assert capsys.readouterr().out.count("OK") >= 2
    copy = tmp_path / "engines"
    shutil.copytree(ctx.engine_dir, copy, ignore=shutil.ignore_patterns(".build-*"))
    victim = next(copy.glob("disk_depth_*.onnx"))
    data = bytearray(victim.read_bytes())
    data[len(data) // 2] ^= 0x01
    victim.write_bytes(bytes(data))
    assert _run(["engines", "verify"], EnginesCliContext(copy, ctx.specs)) == 1
    assert f"FAIL {victim.name}: sha256" in capsys.readouterr().out


def test_verify_empty_directory(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _run(["engines", "verify"], EnginesCliContext(tmp_path, ())) == 1
    assert "c3-matcher engines build" in capsys.readouterr().err


def test_bench_machinery_smoke(
    disk_engine: Path, lightglue_engine: Path, read_image: object
) -> None:
    """The bench runs end to end on real imagery (a smoke test: one run, small cases, no timing
    assertions; the real measurement is ``c3-matcher engines bench``)."""
    from c3_matcher.engines.export import default_verification_imagery

    results = run_bench(
        disk_engine,
        lightglue_engine,
        default_verification_imagery()[0],
        runs=1,
        disk_sizes=((256, 256),),
        lightglue_counts=(128,),
    )
    assert [r.case for r in results] == ["disk 256x256", "disk lightglue 128x128 kpts"]
    for r in results:
        assert r.median_ms > 0 and r.peak_rss_mib > r.baseline_rss_mib > 0
