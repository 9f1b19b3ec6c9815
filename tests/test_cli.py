"""The command line end to end, in subprocesses, with the real engines: stdout carries exactly
one JSON object, logs go to stderr, exit statuses 0 / 2 / 3 as documented."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "data" / "demo"
META = json.loads((DEMO / "demo.json").read_text())


def c3(args: list[str], settings: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=REPO, settings=settings, timeout=600)


@pytest.fixture
def env(engine_dir, tmp_path) -> dict[str, str]:  # type: ignore[no-untyped-def]
    return {
        "C3_MATCHER_ENGINES__DIRECTORY": str(engine_dir),
        "C3_MATCHER_FDR__PATH": str(tmp_path / "fdr.jsonl"),
    }


def demo_args(tiles: list[int]) -> list[str]:
    att = META["attitude_deg"]
    args = [
        "match",
        "--query",
        str(DEMO / "frame.jpg"),
        "--calibration",
        str(DEMO / "calibration.json"),
        "--attitude",
        f"{att['roll']},{att['pitch']},{att['yaw']}",
        "--height",
        str(META["height_m"]),
        "--tile-gsd",
        str(META["tile_gsd_m"]),
    ]
    for i in tiles:
        t = META["tiles"][i]
        args += ["--tile", str(DEMO / t["file"]), "--tile-id", ",".join(map(str, t["tile_id"]))]
    return args


def test_match_demo_prints_one_json_object_and_a_picture(env, tmp_path):
    viz = tmp_path / "matches.png"
    proc = c3([*demo_args([0, 1, 2]), "--viz", str(viz)], env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout)  # exactly one JSON document on stdout
    assert proc.stdout.count("\n") == 1
    best = out["per_candidate"][0]
    assert META["tiles"][best["tile_index"]]["true"]
    assert best["inlier_count"] >= 80 and out["best_candidate_idx"] == 0
    assert len(best["inlier_correspondences"]) == best["inlier_count"]
    assert out["matcher_label"] == "disk_lightglue" and out["candidates_input"] == 3
    assert viz.stat().st_size > 10_000
    kinds = {json.loads(line)["kind"] for line in proc.stderr.splitlines() if line.startswith("{")}
    assert "c3.matcher.ready" in kinds
    assert "c3.inference.provider_selected" in kinds  # made before the sinks: said once they are
    records = [json.loads(x) for x in Path(env["C3_MATCHER_FDR__PATH"]).read_text().splitlines()]
    assert [r["kind"] for r in records].count("matcher.frame_done") == 1


def test_match_twice_on_the_same_inputs_prints_the_same_result_matched_at_aside(env, tmp_path):
    """The frame id too: it is derived from the query image, not drawn at random."""
    runs = []
    for n in range(2):
        settings = {**env, "C3_MATCHER_FDR__PATH": str(tmp_path / f"fdr{n}.jsonl")}
        proc = c3([*demo_args([1]), "--no-correspondences"], settings)
        assert proc.returncode == 0, proc.stderr[-2000:]
        out = json.loads(proc.stdout)
        del out["matched_at"]
        (done,) = (
            r["payload"]
            for r in map(
                json.loads, Path(settings["C3_MATCHER_FDR__PATH"]).read_text().splitlines()
            )
            if r["kind"] == "matcher.frame_done"
        )
        del done["timings_ms"], done["per_candidate_timings_ms"]  # what the frame cost and
        del done["captured_at_ns"]  # when it was read: by nature not the same twice
        runs.append((out, done))
    assert runs[0] == runs[1]
    assert runs[0][1]["frame_id"] == runs[0][0]["frame_id"]


def test_match_without_the_true_tile_exits_3_with_a_json_error(env):
    distractors = [i for i, t in enumerate(META["tiles"]) if not t["true"]]
    proc = c3(demo_args(distractors), env)
    assert proc.returncode == 3, proc.stderr[-2000:]
    error = json.loads(proc.stdout)
    assert error["error"] == "InsufficientInliersError" and error["candidates_input"] == 2


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["match", "--query", "missing.jpg", "--tile", "x.png"], "missing.jpg"),
        (
            [
                "match",
                "--query",
                str(DEMO / "frame.jpg"),
                "--tile",
                str(DEMO / "tile_a.png"),
                "--attitude",
                "1,2",
            ],
            "--attitude",
        ),
        (
            [
                "match",
                "--query",
                str(DEMO / "frame.jpg"),
                "--tile",
                str(DEMO / "tile_a.png"),
                "--tile-id",
                "18,47",
            ],
            "--tile-id",
        ),
    ],
)
def test_bad_arguments_exit_2_with_one_line(args, needle, tmp_path):
    proc = c3(args, {"C3_MATCHER_ENGINES__DIRECTORY": str(tmp_path)})
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert needle in proc.stderr and len(proc.stderr.strip().splitlines()) <= 2


def test_config_refuses_a_bad_file_naming_the_field(tmp_path):
    bad = tmp_path / "c3.toml"
    bad.write_text("[matcher]\nmin_inliers_threshold = 1\n")
    proc = c3(["--config", str(bad), "config"], {})
    assert proc.returncode == 2 and "matcher.min_inliers_threshold" in proc.stderr
    good = c3(["config", "--json"], {"C3_MATCHER_MATCHER__MAX_KEYPOINTS": "1024"})
    assert good.returncode == 0
    assert json.loads(good.stdout)["matcher"]["max_keypoints"] == 1024


# -- every bad input exits 2 with one line, never a traceback ----------------------------------
def _one_line(proc: subprocess.CompletedProcess[str]) -> str:
    assert "Traceback" not in proc.stderr, proc.stderr[-2000:]
    lines = [line for line in proc.stderr.strip().splitlines() if not line.startswith("{")]
    assert len(lines) == 1, proc.stderr[-2000:]
    return lines[0]


def test_non_utf8_config_exits_2(tmp_path):
    bad = tmp_path / "c3.toml"
    bad.write_bytes(b'[matcher]\nstrategy = "\xff"\n')
    proc = c3(["--config", str(bad), "config"], {})
    assert proc.returncode == 2 and "UTF-8" in _one_line(proc)


def test_config_option_after_the_subcommand_and_version(tmp_path):
    good = tmp_path / "c3.toml"
    good.write_text("[matcher]\nmin_inliers_threshold = 77\n")
    proc = c3(["config", "--json", "--config", str(good)], {})
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["matcher"]["min_inliers_threshold"] == 77
    proc = c3(["config", "--json", f"--config={good}"], {})
    assert json.loads(proc.stdout)["matcher"]["min_inliers_threshold"] == 77
    version = c3(["--version"], {})
    assert version.returncode == 0 and version.stdout.startswith("c3-matcher ")


def test_bad_json_in_env_exits_2_naming_the_variable():
    proc = c3(["config"], {"C3_MATCHER_MATCHER__OPTIONS": "not json"})
    assert proc.returncode == 2 and "C3_MATCHER_MATCHER__OPTIONS" in _one_line(proc)


@pytest.mark.parametrize("content", ["[]", "null"])
def test_calibration_that_is_not_an_object_exits_2(tmp_path, content):
    cal = tmp_path / "cal.json"
    cal.write_text(content)
    args = [*demo_args([0]), "--calibration", str(cal)]
    proc = c3(args, {"C3_MATCHER_ENGINES__DIRECTORY": str(tmp_path)})
    assert proc.returncode == 2 and "--calibration" in _one_line(proc)


def test_unreadable_tile_exits_2_not_3(tmp_path):
    junk = tmp_path / "tile.png"
    junk.write_text("not an image")
    args = demo_args([0])
    args[args.index("--tile") + 1] = str(junk)
    proc = c3(args, {"C3_MATCHER_ENGINES__DIRECTORY": str(tmp_path)})
    assert proc.returncode == 2 and "--tile" in _one_line(proc)
    junk.write_bytes((DEMO / "tile_a.png").read_bytes()[:3000])  # cut short: OpenCV warns
    proc = c3(args, {"C3_MATCHER_ENGINES__DIRECTORY": str(tmp_path)})
    assert proc.returncode == 2 and "--tile" in _one_line(proc)  # in its words only
    args[args.index("--tile") + 1] = str(tmp_path)  # there, but a directory
    proc = c3(args, {"C3_MATCHER_ENGINES__DIRECTORY": str(tmp_path)})
    said = f"c3-matcher: --tile {tmp_path}: cannot read image file: it is a directory"
    assert proc.returncode == 2 and _one_line(proc) == said


def test_unknown_strategy_exits_2(env):
    proc = c3([*demo_args([0]), "--strategy", "no_such_strategy"], env)
    assert proc.returncode == 2 and "no_such_strategy" in _one_line(proc)


def test_a_setting_that_stops_every_pair_is_refused_as_configuration_naming_it(env):
    """An unmatchable-pair exit above what any pair reaches (more matches than the keypoints
    kept): a configuration error naming the setting, exit 2, no engine rebuild advised."""
    proc = c3(demo_args([0]), {**env, "C3_MATCHER_LIGHTGLUE__EXIT_MATCHES": "5000"})
    assert proc.returncode == 2 and proc.stdout == ""
    line = _one_line(proc)
    assert "lightglue.exit_matches" in line and "engines build" not in line, line


def test_replay_refuses_negative_limit_and_keypoints(tmp_path):
    flight = REPO / "data" / "flights" / "naip_demo"
    for flag, value in (("--limit", "-28"), ("--max-keypoints", "-5"), ("--limit", "0")):
        proc = c3(["replay", str(flight), flag, value, "--out", str(tmp_path / "o")], {})
        assert proc.returncode == 2 and flag in _one_line(proc)


@pytest.mark.parametrize(
    ("command", "flag", "value"),
    [
        ("eval", "--max-keypoints", "8193"),
        ("bench", "--max-keypoints", "15"),
        ("bench", "--keypoints", "0"),  # the option's former name, still accepted
    ],
)
def test_eval_and_bench_refuse_a_keypoint_budget_out_of_range(command, flag, value, tmp_path):
    flight = REPO / "data" / "flights" / "naip_demo"
    where = [str(flight)] if command == "eval" else ["--data", str(flight)]
    proc = c3([command, *where, flag, value], {})
    assert proc.returncode == 2 and flag in _one_line(proc) and "16, 8192" in _one_line(proc)


def test_unwritable_fdr_and_viz_print_the_result_and_exit_2(env, tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    proc = c3(
        [*demo_args([0, 1, 2]), "--viz", str(blocker / "viz.png"), "--fdr", str(blocker / "f")],
        env,
    )
    assert proc.returncode == 2, proc.stderr[-2000:]
    out = json.loads(proc.stdout)  # the computed result is not thrown away
    assert out["per_candidate"][0]["inlier_count"] > 0 and "viz" not in out
    assert "Traceback" not in proc.stderr
    assert "--viz" in proc.stderr and "fdr.path" in proc.stderr


def test_fdr_path_that_is_a_directory_exits_2_for_replay(env, tmp_path):
    flight = REPO / "data" / "flights" / "naip_demo"
    (tmp_path / "o" / "fdr.jsonl").mkdir(parents=True)
    proc = c3(["replay", str(flight), "--limit", "1", "--out", str(tmp_path / "o")], env)
    assert proc.returncode == 2 and "fdr" in _one_line(proc)


def test_engines_verify_fails_when_an_engine_file_is_missing(engine_dir, tmp_path):
    import shutil

    copy = tmp_path / "engines"
    shutil.copytree(engine_dir, copy)
    victim = sorted(copy.glob("disk_*.onnx"))[0]
    victim.unlink()
    proc = c3(["engines", "verify"], {"C3_MATCHER_ENGINES__DIRECTORY": str(copy)})
    assert proc.returncode != 0
    assert victim.name in proc.stdout or "disk" in proc.stdout


def test_a_reader_that_stops_reading_stdout_ends_the_command_quietly(monkeypatch, capsys):
    """``c3-matcher config | head``: exit 141 as for SIGPIPE, nothing on stderr."""
    import sys

    from c3_matcher.cli import main

    class GoneReader:
        def write(self, text: str) -> int:
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self) -> None:
            raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(sys, "stdout", GoneReader())
    assert main(["config"]) == 141
    assert capsys.readouterr().err == ""


def test_a_result_that_cannot_be_written_to_stdout_exits_1_naming_stdout(monkeypatch, capsys):
    """``c3-matcher config > /dev/full``: the disk's failure (1), not the user's input (2)."""
    import errno
    import sys

    from c3_matcher.cli import main

    class FullDisk:
        def write(self, text: str) -> int:
            raise OSError(errno.ENOSPC, "No space left on device")

        def flush(self) -> None:
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(sys, "stdout", FullDisk())
    assert main(["config"]) == 1
    err = capsys.readouterr().err.strip()
    assert err == "c3-matcher: cannot write the result to stdout: No space left on device"


def test_match_with_a_tile_gsd_in_other_units_than_the_height_exits_2_with_one_line(env):
    """A GSD that scales the frame a billion times is a number in the wrong units: bad input,
    said in one line on stderr with nothing on stdout, not a backbone failure."""
    calibration = str(DEMO / "calibration.json")
    argv = ["match", "--query", str(DEMO / "frame.jpg"), "--tile", str(DEMO / "tile_a.png")]
    proc = c3([*argv, "--tile-gsd", "1e9", "--calibration", calibration, "--height", "27"], env)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stdout == ""
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("c3-matcher: tile_gsd_m: 1e+09 m/px would scale the frame"), last


def test_match_with_a_height_but_tiles_of_unknown_gsd_matches_unscaled(env):
    """Tiles given without --tile-gsd or --tile-id have no known GSD: the frame cannot be
    scaled to it. With --height it was scaled to zoom 0's 156 543 m/px placeholder and refused
    (exit 2, nothing on stdout, a query failure in the FDR); it now matches as without one."""
    att = META["attitude_deg"]
    argv = ["match", "--query", str(DEMO / "frame.jpg"), "--tile", str(DEMO / "tile_b.png")]
    argv += ["--calibration", str(DEMO / "calibration.json")]
    argv += ["--attitude", f"{att['roll']},{att['pitch']},{att['yaw']}"]
    proc = c3([*argv, "--height", str(META["height_m"])], env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads(proc.stdout)["candidates_input"] == 1
    assert "the tiles' GSD is unknown; --height is not used" in proc.stderr


def test_match_a_query_frame_the_backbone_fails_on_prints_a_json_error_and_exits_1(
    env, monkeypatch, capsys
):
    """The query frame failing to extract (an engine run failing, say) is the matcher's own
    error: a JSON error object on stdout as for no match, one line on stderr, exit 1, and the
    frame's FDR record."""
    from c3_matcher.cli import main

    for key, value in env.items():
        monkeypatch.setenv(key, value)

    def engine_run_fails(*args: object, **kwargs: object) -> None:
        raise RuntimeError("engine run failed: out of device memory")

    monkeypatch.setattr("c3_matcher.stages.scales.prepare_query", engine_run_fails)
    assert main(demo_args([0, 1])) == 1
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert captured.out.count("\n") == 1
    assert (out["error"], out["phase"], out["strategy"]) == (
        "MatcherBackboneError",
        "query_extract",
        "disk_lightglue",
    )
    assert "out of device memory" in out["message"]
    last = captured.err.strip().splitlines()[-1]
    assert last.startswith("c3-matcher: backbone failure in phase 'query_extract' on query frame")
    fdr = Path(env["C3_MATCHER_FDR__PATH"]).read_text().splitlines()
    (record,) = [
        r["payload"] for r in map(json.loads, fdr) if r["kind"] == "matcher.backbone_error"
    ]
    assert record["phase"] == "query_extract" and record["frame_id"] == out["frame_id"]
