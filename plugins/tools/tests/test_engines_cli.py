"""``c3-matcher engines list|verify`` (and the tools' ``engines build|bench``) through the real
command line, ``c3_matcher.cli.main``, with the engine directory set by environment."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from c3_matcher.cli import main
from c3_matcher.config import EngineSettings
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
    assertions; the real measurement is ``c3-matcher engines bench``), on the runtime of the
    ``[engines]`` settings it is given, and names the provider and threads of each case."""
    from c3_matcher_tools.engines.bench import format_table
    from c3_matcher_tools.engines.export import default_verification_imagery

    store = EngineStore(engine_dir)
    results = run_bench(
        store.require("disk", "depth"),
        [store.require("lightglue", "disk")],
        default_verification_imagery()[0],
        runs=1,
        disk_sizes=((256, 256),),
        lightglue_counts=(128,),
        engines=EngineSettings(providers=("CPU",), intra_op_threads=1, cpu_mem_arena=False),
    )
    assert [r.case for r in results] == ["disk/depth 256x256", "lightglue/disk 128x128 kpts"]
    assert results[1].detail["mode"] == "full"
    for r in results:
        assert r.median_ms > 0 and r.peak_rss_mib > r.baseline_rss_mib > 0
        assert (r.provider, r.threads) == ("CPUExecutionProvider", 1)
        assert r.settings == "CPU threads=1 mem_pattern=off arena=off"
    assert format_table(results).count("CPU threads=1 mem_pattern=off arena=off") == 2


def test_bench_runtime_hands_the_engines_settings_to_onnx_runtime(
    engine_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each case's session gets the ``[engines]`` threads, arena and providers (it always got
    the CPU provider and the default options); the sweep's memory pattern and arena win."""
    import onnxruntime as ort

    from c3_matcher_tools.engines.bench import bench_runtime

    sessions: list[ort.InferenceSession] = []
    real = ort.InferenceSession

    def spy(*args: object, **kwargs: object) -> ort.InferenceSession:
        sessions.append(real(*args, **kwargs))
        return sessions[-1]

    monkeypatch.setattr(ort, "InferenceSession", spy)
    engine = EngineStore(engine_dir).require("xfeat", "default")
    engines = EngineSettings(providers=("CPU",), intra_op_threads=1, cpu_mem_arena=False)
    bench_runtime(engines).load_engine(engine)
    bench_runtime(engines, mem_pattern=True, arena=True).load_engine(engine)
    configured, swept = (s.get_session_options() for s in sessions)
    assert (configured.intra_op_num_threads, swept.intra_op_num_threads) == (1, 1)
    assert (configured.enable_cpu_mem_arena, configured.enable_mem_pattern) == (False, False)
    assert (swept.enable_cpu_mem_arena, swept.enable_mem_pattern) == (True, True)
    assert all(s.get_providers() == ["CPUExecutionProvider"] for s in sessions)


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
        return bench.BenchResult(engine, f"{engine} {size}", *[1] * 8, "", {}, "CPU", 0)

    monkeypatch.setattr(bench, "_run_child", child)
    monkeypatch.setattr(bench, "_prepare_features", lambda *_args: None)
    assert main(["engines", "bench", "--runs", "1", "--json"]) == 0
    assert len(json.loads(capsys.readouterr().out)) == len(started)
    assert len(set(started)) == len(started)
    store = EngineStore(engines)
    for spec in build_plugin_host().engine_specs():
        runs = [s for s in started if s[:2] == (spec.kind, store.require_spec(spec).name)]
        assert len(runs) == 2, (spec.key, started)


@pytest.fixture()
def stubbed_children(monkeypatch: pytest.MonkeyPatch) -> list[list[str]]:
    """``engines bench``'s cases, recorded instead of run (no inference): each child's argv."""
    import c3_matcher_tools.engines.bench as bench

    started: list[list[str]] = []

    def child(argv: list[str]) -> bench.BenchResult:
        started.append(argv)
        return bench.BenchResult(argv[2], argv[2], *[1] * 8, "", {}, "CPU", 0)

    monkeypatch.setattr(bench, "_run_child", child)
    monkeypatch.setattr(bench, "_prepare_features", lambda *_args: None)
    return started


def test_bench_cases_run_on_the_engines_settings(
    engines: Path,
    stubbed_children: list[list[str]],
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Every case is handed the ``[engines]`` settings (threads, providers...) and runs with
    the arena they set (each ran on the CPU provider with the default session options)."""
    monkeypatch.setenv("C3_MATCHER_ENGINES__INTRA_OP_THREADS", "1")
    monkeypatch.setenv("C3_MATCHER_ENGINES__CPU_MEM_ARENA", "false")
    monkeypatch.setenv("C3_MATCHER_ENGINES__PROVIDERS", '["CPU"]')
    assert main(["engines", "bench", "--runs", "1", "--json"]) == 0
    assert stubbed_children and len(json.loads(capsys.readouterr().out)) == len(stubbed_children)
    for argv in stubbed_children:
        assert argv[argv.index("--arena") + 1] == "off", argv
        settings = json.loads(argv[argv.index("--engine-settings") + 1])
        assert settings["intra_op_threads"] == 1 and settings["providers"] == [
            "CPUExecutionProvider"
        ]


def test_bench_refuses_a_provider_not_installed_before_any_case(
    engines: Path,
    stubbed_children: list[list[str]],
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """As ``match`` does: the cases ran on the CPU whatever ``[engines] providers`` asked."""
    monkeypatch.setenv("C3_MATCHER_ENGINES__PROVIDERS", '["CUDA"]')
    assert main(["engines", "bench", "--runs", "1"]) != 0
    out, err = capsys.readouterr()
    assert stubbed_children == [] and out == ""
    assert "[engines] providers" in err and "CUDAExecutionProvider" in err


def test_bench_refuses_missing_engines_before_timing_any(
    engine_dir: Path,
    engines_at,  # type: ignore[no-untyped-def]
    stubbed_children: list[list[str]],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Two engines missing (a later group's): both are named with the one command that builds
    them, and nothing is timed. The bench timed every earlier group first, then threw all its
    cases away, printing nothing, at the first missing engine. The other engines are listed
    as the store lists them (manifest and a file of the recorded size: the children are
    stubbed, nothing loads them). ``--json`` names the two in a document on stdout."""
    copy = tmp_path / "engines"
    copy.mkdir()
    for engine in engine_dir.glob("*.onnx"):
        if engine.name.startswith(("disk_depth_", "lighterglue_xfeat_")):
            continue
        shutil.copy2(engine.with_suffix(".manifest.json"), copy)
        with (copy / engine.name).open("wb") as sparse:
            sparse.truncate(engine.stat().st_size)
    engines_at(copy)
    assert main(["engines", "bench", "--runs", "1", "--json"]) == 1
    out, err = capsys.readouterr()
    assert stubbed_children == []
    assert "no valid disk/depth engine" in err and "no valid lighterglue/xfeat engine" in err
    build = "c3-matcher engines build --only disk/depth --only lighterglue/xfeat"
    assert err.strip().splitlines()[-1] == (
        "c3-matcher: 2 engine(s) to bench are missing or unusable, nothing was timed; "
        f"build them: {build}"
    )
    document = json.loads(out)
    assert document["command"] == build and document["directory"] == str(copy)
    assert [row["engine"] for row in document["missing"]] == ["disk/depth", "lighterglue/xfeat"]
    assert all(line.startswith("c3-matcher: ") for line in err.strip().splitlines()), err


def test_a_bench_case_whose_process_fails_is_said_and_the_others_still_run(
    engines: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A case's process that fails (out of memory, killed) lost every case timed before it:
    the command stopped with a traceback and printed nothing. It is a failed row now, the
    others are timed, and the command exits 1 naming it."""
    import c3_matcher_tools.engines.bench as bench

    def child(argv: list[str]) -> bench.BenchResult | bench.FailedCase:
        if argv[0] == "matcher" and argv[argv.index("--keypoints") + 1] == "2048":
            killed = "killed by signal 9"
            return bench.FailedCase(argv[2], f"{argv[2]} 2048 kpts", "arena=on", killed)
        return bench.BenchResult(argv[2], argv[2], *[1] * 8, "", {}, "CPU", 0)

    monkeypatch.setattr(bench, "_run_child", child)
    monkeypatch.setattr(bench, "_prepare_features", lambda *_args: None)
    assert main(["engines", "bench", "--runs", "1"]) == 1
    out, err = capsys.readouterr()
    rows = out.splitlines()[2:]
    failed = [row for row in rows if "failed (arena=on): killed by signal 9" in row]
    assert failed and len(rows) > len(failed)
    assert f"c3-matcher: {len(failed)} case(s) failed, the others are timed" in err


def test_a_case_process_that_fails_becomes_a_failed_case_with_its_last_words(
    tmp_path: Path,
) -> None:
    """The real child process, on an engine file that is not a model: how it ended and the
    last line it wrote, under the case it was to time."""
    from c3_matcher_tools.engines.bench import FailedCase, _child_argv, _run_child, _setting_flags

    engine = tmp_path / "disk_depth_fp32_hw16-k2048_op18_0000000000.onnx"
    engine.write_bytes(b"not a model")
    options = ["--image", str(tmp_path / "none.png"), "--size", "256", "192"]
    flags = _setting_flags(False, False, 1, EngineSettings())
    result = _run_child(_child_argv("extractor", engine, options, flags))
    assert isinstance(result, FailedCase)
    assert result.case == f"{engine.name} 256x192"
    assert result.settings == "mem_pattern=off arena=off"  # a sweep's cases told apart
    assert result.failed.startswith("exit status ") and len(result.failed) > len("exit status 1")


@pytest.mark.parametrize(
    ("raised", "said"),
    [
        ("build", "c3-matcher: engine build xfeat/default failed: export failed: boom; no engine"),
        ("specs", "c3-matcher: engine specs declared more than once: disk/depth"),
    ],
)
def test_a_build_that_fails_is_one_line_starting_as_every_other_and_exit_1(
    raised: str,
    said: str,
    engines_at,  # type: ignore[no-untyped-def]
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    import c3_matcher_tools.engines.compiler as compiler

    def fails(*args: object, **kwargs: object) -> None:
        if raised == "build":
            raise compiler.EngineBuildError("xfeat/default", "export failed: boom")
        raise ValueError("engine specs declared more than once: disk/depth")

    engines_at(tmp_path)
    monkeypatch.setattr(compiler, "build_engines", fails)
    assert main(["engines", "build", "--json"]) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.startswith(said) and err.count("\n") == 1, err


def test_bench_without_an_extractor_to_time_is_one_line_starting_as_every_other(
    engines_at,  # type: ignore[no-untyped-def]
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    import c3_matcher_tools.engines.cli as cli
    from c3_matcher.engines.cli import EnginesCliContext

    monkeypatch.setattr(cli, "engines_context", lambda *_: EnginesCliContext(tmp_path, ()))
    assert main(["engines", "bench", "--runs", "1", "--json"]) == 1
    out, err = capsys.readouterr()
    assert out == "" and err == (
        "c3-matcher: no installed plugin declares an extractor engine to bench\n"
    ), err


def test_bench_notes_and_refusals_all_start_as_every_other_line(
    engines_at,  # type: ignore[no-untyped-def]
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A matcher no extractor serves is noted; the extractor's engine missing is refused."""
    import c3_matcher_tools.engines.cli as cli
    from c3_matcher.engines.cli import EnginesCliContext, engines_context

    def one_extractor(*args: object) -> EnginesCliContext:
        real = engines_context(*args)  # type: ignore[arg-type]
        disk = next(s for s in real.specs if s.kind == "extractor" and s.model == "disk")
        other = next(s for s in real.specs if s.kind == "matcher" and s.feature_type != "disk")
        return EnginesCliContext(tmp_path, (disk, other))

    engines_at(tmp_path)  # empty: the extractor's engine is missing
    monkeypatch.setattr(cli, "engines_context", one_extractor)
    assert main(["engines", "bench", "--runs", "1", "--json"]) == 1
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert len(lines) == 3, err
    assert [row["engine"] for row in json.loads(out)["missing"]] == ["disk/depth"]
    assert lines[0].startswith("c3-matcher: note: ") and "not benched" in lines[0], err
    assert lines[2].startswith("c3-matcher: 1 engine(s) to bench are missing"), err
    assert all(line.startswith("c3-matcher: ") for line in lines), err


def test_bench_json_without_engines_names_each_missing_one_with_its_build_command(
    engines_at,  # type: ignore[no-untyped-def]
    stubbed_children: list[list[str]],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """An empty engine directory: ``--json`` printed nothing on stdout, a script had nothing to
    parse. Now a document names every engine to bench with what is wrong and the command that
    builds it, the one ``engines verify --json`` gives it; exit 1 as before, nothing timed."""
    from c3_matcher.compose import build_plugin_host

    engines_at(tmp_path)
    assert main(["engines", "verify", "--json"]) == 1
    verified = {
        row["path"]: row["command"] for row in json.loads(capsys.readouterr().out)["engines"]
    }
    assert main(["engines", "bench", "--runs", "1", "--json"]) == 1
    out, err = capsys.readouterr()
    assert stubbed_children == [] and err.strip().splitlines()[-1].startswith(
        "c3-matcher: 9 engine(s) to bench are missing or unusable, nothing was timed; "
    )
    document = json.loads(out)
    assert set(document) == {"directory", "missing", "command"}
    assert document["directory"] == str(tmp_path)
    rows = document["missing"]
    keys = {spec.key for spec in build_plugin_host().engine_specs()}
    assert {row["engine"] for row in rows} == keys and len(rows) == len(keys)
    for row in rows:
        assert set(row) == {"engine", "path", "problem", "command"}
        assert (
            row["command"]
            == verified[row["path"]]
            == f"c3-matcher engines build --only {row['engine']}"
        )
        assert row["problem"].startswith(f"no valid {row['engine']} engine in {tmp_path}")
    assert document["command"] == "c3-matcher engines build " + " ".join(
        f"--only {row['engine']}" for row in rows
    )
    assert err.strip().endswith(f"build them: {document['command']}")
