"""One ``c3-matcher bench`` case (:class:`BenchCase`) in a worker process of its own, so that its
peak memory is its own, and how ``bench`` drives its workers (:func:`time_interleaved`).

The worker (``python -m c3_matcher_tools.bench_worker CASE RUNS DATA [--config FILE]``) opens the
matcher through the run layer with the case's overrides and makes 2 warm-up matches, then writes
a line ``{"ready": true}`` on stdout; then, for each line it reads on stdin, it times one match of
the data's next frame and writes ``{"ms": ...}``; after ``RUNS`` of them, at one more line (or
the end of stdin), its result as one JSON line, and it ends: not before, since the work of ending
would fall in another worker's timed match. While it waits it is blocked on its stdin. Before it
answers, it waits until no other thread of its process is runnable (ONNX Runtime's intra-op
threads spin 20-40 ms after a run), so that its threads leave the cores to the next worker's turn
(``settle_ms``: how long that took). Stray prints of a library go to stderr, never into the
answers. A worker whose stdin closes before its runs are done (bench stopped) ends, exit 1; one
that has not answered in :data:`ANSWER_LIMIT_S` is stopped by bench, its case failed.

A frame whose match raised InsufficientInliersError is still timed (the matcher ran): its time
counts in ``frame_ms`` and its best inlier count as 0, and ``frames_raised`` counts it. Candidate
and stage times come from the diagnostics of a result, so only from frames that matched:
``per_candidate_ms`` is None when none did. ``frame_ms_runs``: each timed match's time, round by
round. ``peak_rss_mib``: the worker's own peak (:func:`~c3_matcher_tools.memory.peak_rss_mib`).
Bad input (``InvalidInputError``: a frame that cannot be read, say) exits 2 with one JSON line
``{"field", "reason"}`` on stderr, never a traceback; ``bench`` raises it as its own refusal."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import selectors
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Literal, TextIO

import numpy as np

from c3_matcher.commands import EXIT_OK, EXIT_USAGE, bounded_int
from c3_matcher.config import C3Settings, load_settings
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.memory import peak_rss_mib

if TYPE_CHECKING:
    from c3_matcher_tools.run.matcher import Overrides

__all__ = ["BenchCase", "round_order", "run_worker", "settle_ms", "time_interleaved"]

Kind = Literal["engine", "pytorch", "sift"]
WARM_UP_RUNS = 2
"""Matches each worker makes before its timed ones (sessions, arenas and caches filled)."""
STAGES = ("decode", "preprocess", "extract", "match", "ransac")
"""A candidate's stages listed whether or not it went through them (0 ms when not); the
others it records (``assemble`` of stored features, ``refine``) follow where it did."""
SETTLE_LIMIT_S = 1.0
"""The longest a worker waits for its threads to stop before it answers anyway."""
GRACE_S = 2.0
"""How long the workers have to end by themselves once bench closes their pipes (an idle one
ends at once) before the ones still running are killed."""
ANSWER_LIMIT_S = 600.0
"""The longest bench waits for a worker's answer (loading and warm-up included) before it stops
the worker as hung and reports its case failed."""
Result = dict[str, Any]


@dataclass(frozen=True)
class BenchCase:
    """One timed configuration: a strategy, how it runs, its tile cache and image rules."""

    strategy: str
    kind: Kind
    tile_cache_size: int
    max_long_side: int
    max_keypoints: int | None
    stored_features: bool = False
    lightglue_mode: str | None = None  # None: as configured
    intra_op_threads: int | None = None  # None: as configured

    @property
    def label(self) -> str:
        name = {
            "engine": self.strategy,
            "pytorch": f"{self.strategy}[pytorch]",
            "sift": "sift_magsac",
        }[self.kind]
        tiles = "cached" if self.tile_cache_size else "new"
        tiles = "stored" if self.stored_features else tiles
        budget = f"{self.max_keypoints} kp" if self.max_keypoints else "configured kp"
        extra = f", LG {self.lightglue_mode}" if self.lightglue_mode else ""
        extra += f", {self.intra_op_threads} thr" if self.intra_op_threads else ""
        return f"{name} ({tiles} tiles, {self.max_long_side}px, {budget}{extra})"


def round_order(cases: int, round_index: int) -> list[int]:
    """The order ``cases`` workers time their match in, in round ``round_index``: the rows of a
    Williams design in turn (row 0: 0, 1, n-1, 2, n-2, ...; row r adds r, modulo n; for an odd n
    the reversed rows follow), so that over n rounds (2n for an odd n) each case holds every
    place, and follows every other case, equally often. No cases: an empty order."""
    if cases == 0:
        return []
    first = [(k + 1) // 2 if k % 2 else (cases - k // 2) % cases for k in range(cases)]
    row = round_index % (cases if cases % 2 == 0 else 2 * cases)
    order = [(i + row) % cases for i in first]
    return order[::-1] if row >= cases else order


@dataclass(frozen=True)
class _Worker:
    """A case's worker process and the temporary file its stderr goes to."""

    case: BenchCase
    process: subprocess.Popen[str]
    stderr: IO[str]


class _WorkerEndedError(Exception):
    """A worker ended before its result (the message: why, its stderr's last line)."""


def time_interleaved(
    cases: Sequence[BenchCase],
    runs: int,
    data: Path,
    config: Path | None,
    say: Callable[[str], None],
) -> tuple[list[Result], list[dict[str, str]]]:
    """The results of ``cases``, each timed ``runs`` times by a worker of its own, round by round
    in :func:`round_order`, and the cases whose worker failed and why (``say`` tells progress and
    failures as they come). A worker's refusal of its input is raised. Every worker is ended and
    reaped on the way out, whatever happens."""
    workers: list[_Worker] = []
    failed: list[dict[str, str]] = []
    with contextlib.ExitStack() as stack:
        stack.callback(_reap, workers)
        live: list[_Worker] = []
        for case in cases:  # one at a time: each loads and warms up alone
            say(f"bench: {case.label}: loading, {WARM_UP_RUNS} warm-up runs...")
            workers.append(_start(case, runs, data, config, stack))
            if _step(workers[-1], _reply, failed, say) is not None:
                live.append(workers[-1])
        for n in range(runs if live else 0):  # none left: no rounds, the failures said
            say(f"bench: round {n + 1}/{runs}, {len(live)} cases in turn...")
            turns = [live[i] for i in round_order(len(live), n)]
            gone = [w for w in turns if _step(w, _turn, failed, say) is None]
            live = [w for w in live if w not in gone]
        results = [r for w in live if (r := _step(w, _result, failed, say)) is not None]
    return results, failed


def _step(
    worker: _Worker,
    action: Callable[[_Worker], Result],
    failed: list[dict[str, str]],
    say: Callable[[str], None],
) -> Result | None:
    """``action``'s answer from ``worker``; None when the worker ended instead, its failure said
    and added to ``failed``."""
    try:
        return action(worker)
    except _WorkerEndedError as gone:
        say(f"bench: {worker.case.label} failed: {gone}")
        failed.append({"label": worker.case.label, "error": str(gone)})
        return None


def _start(
    case: BenchCase, runs: int, data: Path, config: Path | None, stack: contextlib.ExitStack
) -> _Worker:
    """``case``'s worker, started; its stderr to a temporary file (read if it fails) that
    ``stack`` closes."""
    command = _worker_command(case, runs, data, config)
    opened = tempfile.TemporaryFile("w+", encoding="utf-8", errors="replace")  # noqa: SIM115
    stderr = stack.enter_context(opened)  # closed with the stack
    pipe = subprocess.PIPE
    process = subprocess.Popen(
        command, stdin=pipe, stdout=pipe, stderr=stderr, text=True, encoding="utf-8"
    )
    return _Worker(case, process, stderr)


def _worker_command(case: BenchCase, runs: int, data: Path, config: Path | None) -> list[str]:
    """``python -m c3_matcher_tools.bench_worker CASE RUNS DATA [--config FILE]``."""
    options = ["--config", str(config)] if config else []
    module = "c3_matcher_tools.bench_worker"
    return [sys.executable, "-m", module, json.dumps(asdict(case)), str(runs), str(data), *options]


def _turn(worker: _Worker) -> Result:
    """One timed match of ``worker``: its answer (``{"ms": ...}``)."""
    return _ask(worker, "time")


def _result(worker: _Worker) -> Result:
    """``worker``'s result, asked for once every case has made its last timed match."""
    return _ask(worker, "result")


def _ask(worker: _Worker, what: str) -> Result:
    """``worker``'s answer to a line ``what``."""
    stdin = worker.process.stdin
    assert stdin is not None
    with contextlib.suppress(BrokenPipeError):  # it has ended: _reply says why
        stdin.write(what + "\n")
        stdin.flush()
    return _reply(worker)


def _reply(worker: _Worker) -> Result:
    """``worker``'s next answer, a JSON line; _WorkerEndedError when it ended instead (its stderr's
    last line), or the InvalidInputError it refused its input with (exit 2)."""
    stdout = worker.process.stdout
    assert stdout is not None
    if not _readable_within(stdout, ANSWER_LIMIT_S):
        worker.process.kill()
        worker.process.wait()
        raise _WorkerEndedError(f"no answer in {ANSWER_LIMIT_S:g} s: stopped")
    line = stdout.readline()
    if line:
        answer: Result = json.loads(line)
        return answer
    status = worker.process.wait()
    worker.stderr.seek(0)
    stderr = worker.stderr.read()
    if status == EXIT_USAGE:  # the worker refused its input: one line, exit 2
        raise _worker_refusal(worker.case, stderr)
    lines = stderr.strip().splitlines()
    raise _WorkerEndedError(lines[-1] if lines else f"worker exit status {status}, no message")


def _readable_within(stream: IO[str], seconds: float) -> bool:
    """Whether ``stream`` (a pipe, answered a line at a time) has a line or its end to read
    within ``seconds``."""
    with selectors.DefaultSelector() as selector:
        selector.register(stream, selectors.EVENT_READ)
        return bool(selector.select(seconds))


def _worker_refusal(case: BenchCase, stderr: str) -> InvalidInputError:
    """The InvalidInputError a worker refused its case with (its last stderr line, JSON
    ``{"field", "reason"}``), the case named."""
    lines = stderr.strip().splitlines() or ["{}"]
    try:
        refused = json.loads(lines[-1])
        field, reason = str(refused["field"]), str(refused["reason"])
    except (ValueError, KeyError, TypeError):
        field, reason = "bench", lines[-1]
    return InvalidInputError(field, f"{reason} (bench case {case.label})")


def _reap(workers: Sequence[_Worker]) -> None:
    """End every worker: its pipes closed (an idle worker ends at once), then, :data:`GRACE_S`
    later, the ones still running killed; each waited for."""
    for worker in workers:
        for pipe in (worker.process.stdin, worker.process.stdout):
            if pipe is not None:
                with contextlib.suppress(OSError):
                    pipe.close()
    deadline = time.monotonic() + GRACE_S
    try:
        for worker in workers:
            with contextlib.suppress(subprocess.TimeoutExpired):
                worker.process.wait(timeout=max(0.0, deadline - time.monotonic()))
    finally:
        for worker in workers:
            if worker.process.poll() is None:
                worker.process.kill()
            worker.process.wait()


@dataclass(frozen=True)
class Sample:
    """One timed match: its time (ms), its best inlier count and its diagnostics (None: it
    raised InsufficientInliersError, inliers 0)."""

    ms: float
    best_inliers: int
    diagnostics: Mapping[str, Any] | None


def _percentiles(values: Sequence[float]) -> dict[str, float] | None:
    """p50 and p95 of ``values``; None when there is none."""
    if not values:
        return None
    arr = np.asarray(values, dtype=np.float64)
    return {"p50": float(np.percentile(arr, 50)), "p95": float(np.percentile(arr, 95))}


def _overrides(case: BenchCase) -> Overrides:
    """The case's settings over the configuration (the keypoint budget as the case has it)."""
    from c3_matcher_tools.run.matcher import Overrides

    return Overrides(
        tile_cache_size=case.tile_cache_size,
        max_long_side=case.max_long_side,
        max_keypoints=case.max_keypoints,
        stored_features=case.stored_features,
        lightglue_mode=case.lightglue_mode,
        intra_op_threads=case.intra_op_threads,
    )


def run_worker(
    case: BenchCase,
    runs: int,
    data_dir: Path,
    settings: C3Settings,
    commands: TextIO,
    answers: TextIO,
) -> dict[str, Any]:
    """Open ``case``'s matcher, warm it up and time ``runs`` matches of the data's frames, one
    for each line read from ``commands``, answering on ``answers`` (the module docstring)."""
    from c3_matcher.fdr import JsonlFdrRecorder
    from c3_matcher.health import MonotonicClock
    from c3_matcher_tools.baselines import SIFT_LABEL
    from c3_matcher_tools.run.inputs import flight_inputs
    from c3_matcher_tools.run.matcher import compose_matcher

    strategy = SIFT_LABEL if case.kind == "sift" else case.strategy
    settings = _overrides(case).apply(settings, strategy)  # no budget: the configured one
    clock = MonotonicClock()
    limit = settings.matcher.max_image_pixels
    with (
        flight_inputs(data_dir, limit) as inputs,
        tempfile.TemporaryDirectory(prefix="c3-bench-") as tmp,
    ):
        fdr = JsonlFdrRecorder(Path(tmp) / "fdr.jsonl", clock)
        started = time.perf_counter()
        try:
            composed = compose_matcher(
                settings, fdr=fdr, clock=clock, reference=case.kind == "pytorch"
            )
        except LookupError as exc:
            raise SystemExit(str(exc)) from None
        startup_s = time.perf_counter() - started
        samples, settled = _serve(composed.matcher, inputs, runs, commands, answers)
    peak_mib = peak_rss_mib()
    return {
        "case": asdict(case),
        "label": case.label,
        "provider": composed.provider,
        "runs": runs,
        "startup_s": startup_s,
        **summary(samples),
        "settle_ms": _percentiles(settled),
        "peak_rss_mib": peak_mib,
    }


def _serve(
    matcher: Any, inputs: Sequence[Any], runs: int, commands: TextIO, answers: TextIO
) -> tuple[list[Sample], list[float]]:
    """The warm-up matches, then ``runs`` timed ones, one a line of ``commands``; each answered
    once this process's threads are idle. The samples and how long each wait for idle took."""
    for i in range(WARM_UP_RUNS):
        timed_match(matcher, inputs, i)
    _answer(answers, {"ready": True, "settle_ms": settle_ms()})
    samples: list[Sample] = []
    settled: list[float] = []
    for n in range(runs):
        if not commands.readline():
            raise SystemExit(f"bench worker: its input closed after {n} of {runs} timed runs")
        samples.append(timed_match(matcher, inputs, WARM_UP_RUNS + n))
        settled.append(settle_ms())
        _answer(answers, {"ms": samples[-1].ms})
    commands.readline()  # every case timed: only now end (ending takes CPU from a turn)
    return samples, settled


def timed_match(matcher: Any, inputs: Sequence[Any], i: int) -> Sample:
    """Match ``i``: of the ``i % len(inputs)``-th frame, timed."""
    from c3_matcher.errors import InsufficientInliersError

    frame, rerank, calibration = inputs[i % len(inputs)]
    t0 = time.perf_counter()
    try:
        result = matcher.match(frame, rerank, calibration)
    except InsufficientInliersError:
        return Sample((time.perf_counter() - t0) * 1e3, 0, None)
    elapsed = (time.perf_counter() - t0) * 1e3
    diag = result.diagnostics  # what :func:`summary` reads of it, no more held
    kept = {
        k: diag[k]
        for k in ("candidate_features", "timings_ms", "per_candidate_timings_ms")
        if k in diag
    }
    return Sample(elapsed, result.per_candidate[0].inlier_count, kept)


def summary(samples: Sequence[Sample]) -> dict[str, Any]:
    """Frame, candidate and stage times (ms) of ``samples``, the median best inlier count, how
    many raised InsufficientInliersError and where the candidates' features came from (see the
    module docstring)."""
    candidate_ms: list[float] = []
    stages: dict[str, list[float]] = {s: [] for s in ("query_preprocess", "query_extract", *STAGES)}
    sources: dict[str, int] = {}
    for diag in (s.diagnostics for s in samples if s.diagnostics is not None):
        for source in diag.get("candidate_features", ()):
            sources[source] = sources.get(source, 0) + 1
        for key in ("query_preprocess", "query_extract"):
            stages[key].append(diag["timings_ms"][key])
        for cand in diag["per_candidate_timings_ms"]:
            candidate_ms.append(sum(cand.values()))  # every stage it went through
            for s in (*STAGES, *(k for k in cand if k not in STAGES)):
                stages.setdefault(s, []).append(cand.get(s, 0.0))
    frame_ms = [s.ms for s in samples]
    return {
        "best_inliers": int(np.median([s.best_inliers for s in samples])),
        "frames_raised": sum(s.diagnostics is None for s in samples),
        "frame_ms": _percentiles(frame_ms),
        "frame_ms_runs": frame_ms,
        "per_candidate_ms": _percentiles(candidate_ms),  # None: no frame matched
        "stages_ms": {k: _percentiles(v) for k, v in stages.items() if v},
        "feature_sources": sources,
    }


def settle_ms(limit_s: float = SETTLE_LIMIT_S) -> float:
    """Wait until no other thread of this process is runnable (state R in /proc: a thread that
    spins waiting for work, as ONNX Runtime's and OpenMP's do for a while after a run, is R even
    while another process holds the core), at most ``limit_s``; the ms waited. Where /proc has
    no threads to read, none is waited for."""
    start = time.perf_counter()
    me = threading.get_native_id()
    while _runnable_threads(me) and time.perf_counter() - start < limit_s:
        time.sleep(0.002)
    return (time.perf_counter() - start) * 1e3


def _runnable_threads(me: int) -> int:
    """How many threads of this process other than ``me`` are runnable (running or waiting for
    a core)."""
    try:
        tasks = [t for t in Path("/proc/self/task").iterdir() if t.name != str(me)]
    except OSError:
        return 0
    runnable = 0
    for task in tasks:
        try:
            stat = (task / "stat").read_text()
        except OSError:  # it ended meanwhile
            continue
        runnable += stat.rpartition(")")[2].split()[:1] == ["R"]
    return runnable


def _answer(answers: TextIO, value: Mapping[str, Any]) -> None:
    answers.write(json.dumps(value) + "\n")
    answers.flush()


def _worker_main(argv: list[str], commands: TextIO, answers: TextIO) -> int:
    parser = argparse.ArgumentParser(prog="python -m c3_matcher_tools.bench_worker")
    parser.add_argument("case", help="BenchCase as JSON")
    parser.add_argument("runs", type=bounded_int())
    parser.add_argument("data", type=Path)
    parser.add_argument("--config", type=Path, default=None)
    args = parser.parse_args(argv)
    from loguru import logger

    logger.remove()
    case = BenchCase(**json.loads(args.case))
    try:
        settings = load_settings(args.config)
        result = run_worker(case, args.runs, args.data, settings, commands, answers)
    except InvalidInputError as exc:  # bad input, never a traceback: the parent says it
        print(json.dumps({"field": exc.field, "reason": exc.reason}), file=sys.stderr)
        return EXIT_USAGE
    _answer(answers, result)
    return EXIT_OK


def _process_main() -> int:
    """As a process of its own: the answers on a copy of stdout, and stdout itself pointed at
    stderr, so that nothing a library prints can come between them."""
    answers = os.fdopen(os.dup(sys.stdout.fileno()), "w", encoding="utf-8")
    sys.stdout.flush()
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    return _worker_main(sys.argv[1:], sys.stdin, answers)


if __name__ == "__main__":
    sys.exit(_process_main())
