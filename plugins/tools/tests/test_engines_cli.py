"""``c3-matcher engines list|verify`` (and the tools' ``engines build|bench``) through the real
command line, ``c3_matcher.cli.main``, with the engine directory set by environment."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from c3_matcher.cli import main
from c3_matcher.engines.store import EngineStore
from c3_matcher_tools.engines.bench import run_bench


@pytest.fixture()
def engines_at(monkeypatch: pytest.MonkeyPatch) -> object:
    def point(directory: Path) -> Path:
        monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(directory))
        return directory

    return point


@pytest.fixture()
def engines(engine_dir: Path, engines_at) -> Path:  # type: ignore[no-untyped-def]
    return engines_at(engine_dir)


def test_build_reuses_and_prints_result_on_stdout(
    engines: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["engines", "build", "--only", "disk/depth", "--only", "lightglue/disk"]) == 0
    out, err = capsys.readouterr()
    assert "disk/depth" in out and "lightglue/disk" in out and "0 built, 2 reused" in out
    assert "reused" in err  # progress on stderr


def test_build_unknown_only(engines: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A name no plugin declares is the caller's bad input: exit 2, one line naming --only."""
    assert main(["engines", "build", "--only", "sift/x"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("c3-matcher: --only: unknown engine sift/x: choose one of") and (
        "disk/depth" in err and err.count("\n") == 1
    ), err


def test_list_shows_manifests_and_figures(
    engines: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["engines", "list"]) == 0
    out = capsys.readouterr().out
    assert "keypoints_mismatch=0" in out and "matches_identical=True" in out
    assert main(["engines", "list", "--json"]) == 0
    records = json.loads(capsys.readouterr().out)
    models = {r["manifest"]["model"] for r in records if r["manifest"]}
    assert {"disk", "lightglue"} <= models


def test_verify_ok_then_tampered(
    engines: Path,
    engines_at,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],  # type: ignore[no-untyped-def]
) -> None:
    assert main(["engines", "verify"]) == 0
    assert capsys.readouterr().out.count("OK") >= 2
    copy = tmp_path / "engines"
    shutil.copytree(engines, copy, ignore=shutil.ignore_patterns(".build-*"))
    victim = next(copy.glob("disk_depth_*.onnx"))
    data = bytearray(victim.read_bytes())
    data[len(data) // 2] ^= 0x01
    victim.write_bytes(bytes(data))
    engines_at(copy)
    assert main(["engines", "verify"]) == 1
    assert f"FAIL {victim.name}: sha256" in capsys.readouterr().out


def test_verify_empty_directory(
    engines_at,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],  # type: ignore[no-untyped-def]
) -> None:
    engines_at(tmp_path)
    assert main(["engines", "verify"]) == 1
    assert "c3-matcher engines build" in capsys.readouterr().err


def test_bench_machinery_smoke(engine_dir: Path) -> None:
    """The bench runs end to end on real imagery (a smoke test: one run, small cases, no timing
    assertions; the real measurement is ``c3-matcher engines bench``)."""
    from c3_matcher_tools.engines.export import default_verification_imagery

    store = EngineStore(engine_dir)
    results = run_bench(
        store.require("disk", "depth"),
        [store.require("lightglue", "disk")],
        default_verification_imagery()[0],
        runs=1,
        disk_sizes=((256, 256),),
        lightglue_counts=(128,),
    )
    assert [r.case for r in results] == ["disk/depth 256x256", "lightglue/disk 128x128 kpts"]
    assert results[1].detail["mode"] == "full"
    for r in results:
        assert r.median_ms > 0 and r.peak_rss_mib > r.baseline_rss_mib > 0


@pytest.mark.parametrize("runs", ["0", "-3"])
def test_bench_runs_below_one_is_a_usage_error(
    runs: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as stop:  # refused while parsing: no engine is loaded
        main(["engines", "bench", "--runs", runs])
    err = capsys.readouterr().err.strip()
    assert stop.value.code == 2 and len(err.splitlines()) == 1, err
    assert f"--runs: must be >= 1, got {runs}" in err


def test_bench_child_refuses_fewer_than_one_run() -> None:
    from c3_matcher_tools.engines.bench import _main

    with pytest.raises(SystemExit) as stop:
        _main(["child", "extractor", "--engine", "none.onnx", "--runs", "0"])
    assert stop.value.code == 2


def test_bench_missing_image_is_refused_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "none.png"
    assert main(["engines", "bench", "--image", str(missing), "--runs", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"c3-matcher: --image: no such file: {missing}"


def test_bench_times_every_engine_once_under_its_own_label() -> None:
    """Every extractor variant (ALIKED n16, the default, and n16rot) and every matcher engine
    (full and steps) is one case set, on the real plugins' specs; no two labels are equal and
    each names its engine's key (once ALIKED was timed only as n16rot, each extractor twice, and
    ``lightglue/disk`` and ``lightglue/disk-steps`` shared the label ``disk lightglue ...``)."""
    from c3_matcher.compose import build_plugin_host
    from c3_matcher.engines.lightglue_specs import STEPS_OPTION
    from c3_matcher_tools.engines.bench import (
        DISK_SIZES,
        LIGHTGLUE_COUNTS,
        extractor_label,
        matcher_label,
    )
    from c3_matcher_tools.engines.cli import _bench_groups

    specs = build_plugin_host().engine_specs()
    groups, unserved = _bench_groups(specs)
    assert unserved == []
    assert [g.extractor.key for g in groups] == [s.key for s in specs if s.kind == "extractor"]
    timed = sorted(m.key for g in groups for m in g.matchers)
    assert timed == sorted(s.key for s in specs if s.kind == "matcher")
    by_key = {g.extractor.key: [m.key for m in g.matchers] for g in groups}
    assert by_key["aliked/n16"] == ["lightglue/aliked", "lightglue/aliked-steps"]
    assert by_key["aliked/n16rot"] == [] and "disk/depth" in by_key
    labels = [
        (g.extractor.key, extractor_label(g.extractor.key, w, h))
        for g in groups
        for w, h in DISK_SIZES
    ]
    labels += [
        (m.key, matcher_label(m.key, STEPS_OPTION in m.options, n, n))
        for g in groups
        for m in g.matchers
        for n in LIGHTGLUE_COUNTS
    ]
    assert len({label for _, label in labels}) == len(labels)
    assert all(label.split(" ", 1)[0] == key for key, label in labels)
    assert "lightglue/disk-steps 512x512 kpts, every layer" in {label for _, label in labels}


def test_bench_command_runs_each_engine_once(
    engines: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``engines bench`` itself (children stubbed: no inference) starts one case per engine
    and size or keypoint count, ALIKED n16 included, none twice."""
    import c3_matcher_tools.engines.bench as bench
    from c3_matcher.compose import build_plugin_host

    started: list[tuple[str, str, str]] = []

    def child(argv: list[str]) -> bench.BenchResult:
        kind, engine = argv[0], Path(argv[2]).name
        size = " ".join(argv[6:8]) if kind == "extractor" else argv[6]
        started.append((kind, engine, size))
        return bench.BenchResult(engine, f"{engine} {size}", 1, 1, 1, 1, 1, 1, 1, 1, "", {})

    monkeypatch.setattr(bench, "_run_child", child)
    monkeypatch.setattr(bench, "_prepare_features", lambda *_args: None)
    assert main(["engines", "bench", "--runs", "1", "--json"]) == 0
    assert len(json.loads(capsys.readouterr().out)) == len(started)
    assert len(set(started)) == len(started)
    store = EngineStore(engines)
    for spec in build_plugin_host().engine_specs():
        runs = [s for s in started if s[:2] == (spec.kind, store.require_spec(spec).name)]
        assert len(runs) == 2, (spec.key, started)
