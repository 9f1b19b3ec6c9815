"""``c3-matcher bench`` times its cases interleaved: one worker process a case, all of one
strategy loaded first, then round by round each times one match in turn, in an order that
changes every round, so that load from outside falls on every case alike. Driven here with a
stand-in worker (a small script speaking the workers' protocol, its times given by the test) for
the order, the paired ratio and what happens when a worker fails, refuses its input or bench is
stopped: reported as before, and no worker left behind. Last, the real path: the real worker
and a real engine for two rounds."""

from __future__ import annotations

import itertools
import json
import os
import sys
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import pytest

from c3_matcher_tools import bench, bench_worker
from c3_matcher_tools.bench_worker import SETTLE_LIMIT_S, BenchCase, round_order

REPO = Path(__file__).resolve().parents[3]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
DEMO = REPO / "data" / "demo"

STAND_IN = r"""
import json, os, signal, statistics, sys, threading
from c3_matcher_tools.bench_worker import BenchCase

case = BenchCase(**json.loads(sys.argv[1]))
runs, log, plans = int(sys.argv[2]), sys.argv[3], json.loads(sys.argv[4])
kind = case.kind + ("" if case.tile_cache_size == 0 else "+cache")
plan = plans.get(f"{case.strategy}:{kind}", plans.get(kind, {}))
times = plan.get("ms", [100.0] * runs)


def note(line):
    with open(log, "a") as f:
        f.write(line + "\n")


def answer(value):
    print(json.dumps(value), flush=True)


def end_at(n):  # n: 0 while loading, else the timed run
    if plan.get("refuse") == n:
        print(json.dumps({"field": "--data", "reason": "frame 2 cannot be read"}), file=sys.stderr)
        sys.exit(2)
    if plan.get("die") == n:
        print("Traceback (most recent call last):\nRuntimeError: worker died", file=sys.stderr)
        sys.exit(1)
    if plan.get("hang") == n:
        hold_on()


def hold_on():  # a worker that outlives its pipes and ignores SIGTERM: only SIGKILL ends it
    threading.Event().wait()


note(f"pid {os.getpid()} {case.label}")
if plan.get("stubborn"):
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
end_at(0)
answer({"ready": True})
for n in range(runs):
    if not sys.stdin.readline():
        hold_on() if plan.get("stubborn") else sys.exit(1)
    note(f"turn {case.label}")
    end_at(n + 1)
    answer({"ms": times[n]})
sys.stdin.readline()
note(f"result {case.label}")
answer({
    "case": json.loads(sys.argv[1]), "label": case.label, "provider": "CPUExecutionProvider",
    "runs": runs, "startup_s": 0.0, "best_inliers": 50, "frames_raised": 0,
    "frame_ms": {"p50": statistics.median(times), "p95": max(times)}, "frame_ms_runs": times,
    "per_candidate_ms": None, "stages_ms": {},
    "feature_sources": {"cached" if case.tile_cache_size else "extracted": 3 * runs},
    "peak_rss_mib": 100.0,
})
if plan.get("stubborn"):
    hold_on()
"""

Plans = dict[str, dict[str, Any]]


@pytest.fixture()
def stand_in(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Callable[[Plans], Path]:
    """``stand_in(plans)``: bench's workers replaced by the stand-in, each case's behaviour
    from ``plans`` by its kind (``engine``, ``engine+cache``, ``pytorch``, ``sift``, or one
    strategy's, ``xfeat:engine``: ``ms`` its
    times round by round, ``die`` / ``refuse`` / ``hang`` (never answer) at that run (0: while
    loading), ``stubborn``);
    the log it writes (``pid PID LABEL`` as each starts, ``turn LABEL`` at each timed run,
    ``result LABEL`` as it gives its result)."""
    script = tmp_path / "stand_in.py"
    script.write_text(STAND_IN)
    log = tmp_path / "turns.log"
    monkeypatch.setattr(bench, "_has_torch", lambda: True)
    monkeypatch.setattr(bench_worker, "GRACE_S", 0.2)

    def use(plans: Plans) -> Path:
        def command(case: BenchCase, runs: int, data: Path, config: Path | None) -> list[str]:
            case_json = json.dumps(asdict(case))
            return [sys.executable, str(script), case_json, str(runs), str(log), json.dumps(plans)]

        monkeypatch.setattr(bench_worker, "_worker_command", command)
        return log

    return use


def _turns(log: Path) -> list[str]:
    return [
        line[len("turn ") :] for line in log.read_text().splitlines() if line.startswith("turn ")
    ]


def _assert_all_reaped(log: Path) -> None:
    """Every worker started has ended and been waited for (a zombie still answers kill 0)."""
    pids = [
        int(line.split()[1]) for line in log.read_text().splitlines() if line.startswith("pid ")
    ]
    assert pids
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


def _bench(*argv: str, runs: int) -> list[str]:
    return ["bench", "--runs", str(runs), *argv, "--no-stored", "--data", str(FLIGHT)]


@pytest.mark.parametrize("cases", range(1, 8))
def test_the_round_order_gives_every_case_each_place_and_each_predecessor_alike(
    cases: int,
) -> None:
    cycle = cases if cases % 2 == 0 else 2 * cases
    rows = [round_order(cases, r) for r in range(cycle)]
    assert all(sorted(row) == list(range(cases)) for row in rows)
    assert rows == [round_order(cases, r + cycle) for r in range(cycle)]  # then it repeats
    places = Counter((place, case) for row in rows for place, case in enumerate(row))
    assert set(places.values()) == {cycle // cases}, places
    follows = Counter(pair for row in rows for pair in itertools.pairwise(row))
    assert len(follows) == cases * (cases - 1)  # every ordered pair, each as often
    assert set(follows.values()) <= {cycle // cases}, follows


def test_cases_are_timed_round_by_round_in_a_changing_order(
    stand_in: Callable[[Plans], Path], capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    log = stand_in({})
    argv = _bench("--strategy", "xfeat", "--no-reference", "--threads", "1", "--json", runs=8)
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    labels = [r["label"] for r in report["results"]]
    assert len(labels) == 4 and labels[-1].startswith("sift_magsac")  # in the plan's order
    assert report["interleaved"] == [labels]  # the baseline with the strategy's cases
    lines = log.read_text().splitlines()
    first_turn = next(n for n, line in enumerate(lines) if line.startswith("turn "))
    assert all(line.startswith("pid ") for line in lines[:first_turn]) and first_turn == 4
    turns = _turns(log)
    rounds = [turns[n : n + 4] for n in range(0, len(turns), 4)]
    assert rounds == [[labels[i] for i in round_order(4, n)] for n in range(8)]
    before = {label: {r[r.index(label) - 1] for r in rounds if r[0] != label} for label in labels}
    assert all(len(others) == 3 for others in before.values()), before
    assert {r[0] for r in rounds} == set(labels)
    assert all(r["frame_ms_runs"] == [100.0] * 8 for r in report["results"])
    lines = log.read_text().splitlines()  # results asked for once every case's runs are done
    ends = [n for n, line in enumerate(lines) if line.startswith("result ")]
    last_turn = max(n for n, line in enumerate(lines) if line.startswith("turn "))
    assert len(ends) == 4 and min(ends) > last_turn
    _assert_all_reaped(log)


def test_a_comparison_adds_the_median_of_its_paired_ratios(
    stand_in: Callable[[Plans], Path], capsys: pytest.CaptureFixture[str]
) -> None:
    """Round by round the reference took 100, 300, 1000 ms and the new tiles 50, 300, 100:
    p50 300 vs 100 ms (3.00x), p95 (here the largest) 1000 vs 300, the rounds' ratios 2, 1 and
    10 (median 2.00x)."""
    from c3_matcher.cli import main

    stand_in({"pytorch": {"ms": [100.0, 300.0, 1000.0]}, "engine": {"ms": [50.0, 300.0, 100.0]}})
    argv = _bench("--strategy", "disk_lightglue", "--no-modes", "--no-baseline", runs=3)
    assert main([*argv, "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    vs_torch = next(
        c for c in report["comparisons"] if c["comparison"].startswith("disk_lightglue (new")
    )
    assert vs_torch["speedup_p50"] == pytest.approx(3.0)
    assert vs_torch["speedup_paired"] == pytest.approx(2.0) and vs_torch["rounds"] == 3
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "vs PyTorch: 3.00x p50, 3.33x p95, 2.00x paired (median of 3 rounds)" in text


@pytest.mark.parametrize("die", [0, 2], ids=["while-loading", "mid-run"])
def test_a_worker_that_dies_is_reported_and_the_others_timed_to_the_end(
    die: int, stand_in: Callable[[Plans], Path], capsys: pytest.CaptureFixture[str]
) -> None:
    """A worker that fails (a plugin's reference that cannot be built, a crash) costs its case,
    not the figures of the others, which keep their rounds: printed, the failure named, exit 1."""
    from c3_matcher.cli import main

    log = stand_in({"pytorch": {"die": die}})
    argv = _bench("--strategy", "disk_lightglue", "--no-modes", runs=3)
    assert main([*argv, "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert [f["error"] for f in report["failed"]] == ["RuntimeError: worker died"]
    assert report["failed"][0]["label"].startswith("disk_lightglue[pytorch] (")
    assert {r["case"]["kind"] for r in report["results"]} == {"engine", "sift"}
    assert all(len(r["frame_ms_runs"]) == 3 for r in report["results"])
    assert not any("PyTorch" in c["comparison"] for c in report["comparisons"])
    turns = Counter(_turns(log))
    assert [n for label, n in turns.items() if "[pytorch]" in label] == ([die] if die else [])
    assert all(n == 3 for label, n in turns.items() if "[pytorch]" not in label)
    _assert_all_reaped(log)
    assert main(argv) == 1
    out = capsys.readouterr().out
    assert "disk_lightglue (new tiles" in out and "sift_magsac (" in out
    failed = [line for line in out.splitlines() if line.startswith("failed: ")]
    assert len(failed) == 1 and failed[0].startswith("failed: disk_lightglue[pytorch] (")
    assert failed[0].endswith(": RuntimeError: worker died")


@pytest.mark.parametrize("hang", [0, 2], ids=["while-loading", "mid-run"])
def test_a_worker_that_never_answers_is_stopped_and_the_others_timed_to_the_end(
    hang: int,
    stand_in: Callable[[Plans], Path],
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A worker that hangs (a deadlocked runtime, a plugin waiting on something that never
    comes) is stopped once it has not answered in the time limit: its case failed and said,
    the others timed to the end, every worker reaped, exit 1."""
    from c3_matcher.cli import main

    monkeypatch.setattr(bench_worker, "ANSWER_LIMIT_S", 8.0)  # the others start within it
    log = stand_in({"pytorch": {"hang": hang}})
    argv = _bench("--strategy", "xfeat", "--no-modes", "--no-baseline", runs=3)
    assert main([*argv, "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert [f["error"] for f in report["failed"]] == ["no answer in 8 s: stopped"]
    assert report["failed"][0]["label"].startswith("xfeat[pytorch] (")
    assert all(len(r["frame_ms_runs"]) == 3 for r in report["results"]) and report["results"]
    _assert_all_reaped(log)


def test_a_strategy_whose_every_worker_dies_loading_leaves_the_others_figures(
    stand_in: Callable[[Plans], Path], capsys: pytest.CaptureFixture[str]
) -> None:
    """A strategy none of whose cases loads (its engines missing) times no round and costs no
    other strategy its figures: both its cases named as failed, exit 1."""
    from c3_matcher.cli import main

    log = stand_in(
        {"aliked_lightglue:engine": {"die": 0}, "aliked_lightglue:engine+cache": {"die": 0}}
    )
    strategies = ["--strategy", "xfeat", "--strategy", "aliked_lightglue"]
    argv = _bench(*strategies, "--no-baseline", "--no-reference", "--no-modes", runs=2)
    assert main([*argv, "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert [r["label"].split(" (")[0] for r in report["results"]] == ["xfeat", "xfeat"]
    assert [f["label"].split(" (")[0] for f in report["failed"]] == ["aliked_lightglue"] * 2
    assert all("aliked" not in label for label in _turns(log))
    _assert_all_reaped(log)


def test_a_case_asked_for_twice_is_timed_once(
    stand_in: Callable[[Plans], Path], capsys: pytest.CaptureFixture[str]
) -> None:
    """The baseline named as a strategy too, and a strategy named twice: one case a label,
    the table in the order asked; the baseline stays the baseline (every strategy's "vs SIFT"),
    timed with the first strategy's cases."""
    from c3_matcher.cli import main

    stand_in({})
    strategies = ["--strategy", "sift_magsac", "--strategy", "xfeat", "--strategy", "xfeat"]
    argv = _bench(*strategies, "--no-reference", "--no-modes", runs=1)
    assert main([*argv, "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    labels = [r["label"] for r in report["results"]]
    assert len(labels) == len(set(labels)) == 4
    assert [label.split(" (")[0] for label in labels] == ["sift_magsac"] + ["xfeat"] * 2 + [
        "sift_magsac"
    ]
    assert [r["case"]["kind"] for r in report["results"]][-1] == "sift"
    assert report["interleaved"][0][-1] == labels[-1]  # with the first strategy's


@pytest.mark.parametrize("refuse", [0, 2], ids=["while-loading", "mid-run"])
def test_a_worker_refusing_its_input_stops_the_bench_and_every_worker(
    refuse: int, stand_in: Callable[[Plans], Path], capsys: pytest.CaptureFixture[str]
) -> None:
    """Exit 2, one line naming what was refused and in which case; the other workers, one of
    them deaf to its closed pipe and to SIGTERM, are killed and reaped."""
    from c3_matcher.cli import main

    log = stand_in({"engine+cache": {"refuse": refuse}, "engine": {"stubborn": True}})
    argv = _bench("--strategy", "xfeat", "--no-reference", "--no-baseline", runs=3)
    assert main(argv) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()[-1]
    assert err.startswith("c3-matcher: --data: frame 2 cannot be read (bench case xfeat (cached")
    assert captured.out == ""
    _assert_all_reaped(log)


def test_ctrl_c_mid_run_ends_every_worker(
    stand_in: Callable[[Plans], Path],
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from c3_matcher.cli import main

    log = stand_in({"engine": {"stubborn": True}})
    turn = bench_worker._turn
    calls = Counter[str]()

    def interrupted(worker: Any) -> dict[str, Any]:
        calls["turn"] += 1
        if calls["turn"] == 3:
            raise KeyboardInterrupt
        return turn(worker)

    monkeypatch.setattr(bench_worker, "_turn", interrupted)
    argv = _bench("--strategy", "xfeat", "--no-reference", runs=3)
    assert main(argv) == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == "c3-matcher: interrupted"
    assert len(_turns(log)) == 2
    _assert_all_reaped(log)


@pytest.mark.slow
def test_bench_times_a_real_engine_round_by_round(
    engine_dir: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The real worker and XFeat's engines, two rounds of the demo frame: each case's times
    round by round, the paired ratio computed from them, its threads' wait for idle measured."""
    from c3_matcher.cli import main
    from c3_matcher_tools.bench_report import paired_speedup

    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    argv = ["bench", "--runs", "2", "--strategy", "xfeat", "--no-reference", "--no-baseline"]
    assert main([*argv, "--data", str(DEMO), "--json"]) == 0, capsys.readouterr().err[-2000:]
    report = json.loads(capsys.readouterr().out)
    new, cached = report["results"]
    assert report["interleaved"] == [[new["label"], cached["label"]]]
    for r in (new, cached):
        assert len(r["frame_ms_runs"]) == 2 and all(ms > 0 for ms in r["frame_ms_runs"])
        assert r["frame_ms"]["p50"] == pytest.approx(sum(r["frame_ms_runs"]) / 2)
        # the wait for spinning threads stops at its limit (slack for a loaded machine)
        assert 0 <= r["settle_ms"]["p95"] <= 2e3 * SETTLE_LIMIT_S and r["peak_rss_mib"] > 50
    (cache,) = report["comparisons"]
    assert cache["comparison"] == "cached vs new tiles" and cache["rounds"] == 2
    assert cache["speedup_paired"] == pytest.approx(paired_speedup(new, cached))
    assert cached["feature_sources"] == {"cached": 6}
