"""``c3-matcher engines bench``: latency and peak memory of the engines on real imagery.

Each measurement runs in a fresh subprocess (``python -m c3_matcher_tools.engines.bench child ...``)
so that its peak RSS (``VmHWM`` from ``/proc/self/status``, else ``ru_maxrss``) belongs to that
case alone: interpreter + onnxruntime + one session + its runs. Latency: one warm-up run, then
``runs`` timed runs of ``InferenceRuntime.run`` (extractors: ``run_extractor``, LightGlue-family
matchers: ``OnnxLightGlueRuntime.match_pair`` in ``"full"`` mode, pre- and post-processing
included); median and p95 in ms.

Cases, per engine: an extractor (DISK, ALIKED, XFeat...) at two input sizes (512x512, 1024x1024
px, resized from the real orthophoto), and a matcher at two keypoint counts per side (512, 2048),
on its extractor's features of two overlapping real views (1024x1024). Each case is labelled by
its engine's key (``model/variant`` from the engine's manifest): ``aliked/n16 512x512``,
``lightglue/disk 512x512 kpts``. A steps engine (``pruning = "steps"``) loaded alone runs as
``match_pair`` runs it in full mode: every layer on every point, one graph call per layer, no
early exit or pruning (the adaptive figure depends on the pair: ``c3-matcher bench``); its label
says so (``lightglue/disk-steps 512x512 kpts, every layer``). No PyTorch.

Every case runs on the runtime the matcher builds from the ``[engines]`` settings (providers and
their options, ``intra_op_threads``, ``cpu_mem_arena``; ``--sweep-session-options`` varies the
arena and memory pattern); each result names the provider its sessions actually used and the
thread setting.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from c3_matcher.commands import EXIT_OK, bounded_int
from c3_matcher.config import EngineSettings
from c3_matcher.features import PairSide
from c3_matcher_tools.memory import current_rss_mib, peak_rss_mib

if TYPE_CHECKING:
    from c3_matcher.engines.runtime import OnnxInferenceRuntime

__all__ = [
    "BenchResult",
    "FailedCase",
    "extractor_label",
    "format_table",
    "matcher_label",
    "run_bench",
]

DISK_SIZES: tuple[tuple[int, int], ...] = ((512, 512), (1024, 1024))
LIGHTGLUE_COUNTS: tuple[int, ...] = (512, 2048)
CASE_WIDTH = 28
"""The table's narrowest case column (it widens to the longest label)."""


def extractor_label(key: str, width: int, height: int) -> str:
    """The case label of extractor engine ``key`` (``model/variant``) at ``width`` x ``height``."""
    return f"{key} {width}x{height}"


def matcher_label(key: str, steps: bool, n0: int, n1: int) -> str:
    """The case label of matcher engine ``key`` on ``n0`` x ``n1`` keypoints; a ``steps``
    engine is timed running every layer on every point (full mode), and says so."""
    return f"{key} {n0}x{n1} kpts" + (", every layer" if steps else "")


@dataclass(frozen=True, slots=True)
class BenchResult:
    """One case: ``engine`` file, ``case`` label, latency (ms) and memory (MiB); ``provider``
    the execution provider its session used, ``threads`` the ``intra_op_threads`` setting (0:
    one per core) and ``settings`` both with the session options, as the table shows them."""

    engine: str
    case: str
    runs: int
    median_ms: float
    p95_ms: float
    min_ms: float
    first_run_ms: float
    load_ms: float
    peak_rss_mib: float
    baseline_rss_mib: float
    settings: str
    detail: dict[str, Any]
    provider: str
    threads: int


@dataclass(frozen=True, slots=True)
class FailedCase:
    """A case whose process failed (an error, out of memory, killed): ``engine`` file, ``case``
    (the engine and the size or keypoint count it was to time), ``settings`` (the session
    options it was to run with) and ``failed``, how it ended and the last line it wrote."""

    engine: str
    case: str
    settings: str
    failed: str


def _read_rgb(path: Path, size: tuple[int, int] | None = None) -> NDArray[np.uint8]:
    import cv2

    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise FileNotFoundError(f"bench image {path} is missing or unreadable")
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    if size is not None:
        rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_LINEAR)
    return np.ascontiguousarray(rgb)


def _pair_views(path: Path, side: int = 1024) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """Two overlapping real views (the top-left and bottom-right 80 % of the image), resized to
    ``side`` x ``side`` px."""
    import cv2

    full = _read_rgb(path)
    h, w = full.shape[:2]
    a = full[: int(h * 0.8), : int(w * 0.8)]
    b = full[h - int(h * 0.8) :, w - int(w * 0.8) :]
    return (
        np.ascontiguousarray(cv2.resize(a, (side, side), interpolation=cv2.INTER_LINEAR)),
        np.ascontiguousarray(cv2.resize(b, (side, side), interpolation=cv2.INTER_LINEAR)),
    )


def bench_runtime(
    engines: EngineSettings, *, mem_pattern: bool = False, arena: bool | None = None
) -> OnnxInferenceRuntime:
    """The runtime the matcher builds from ``engines`` (``OnnxInferenceRuntime.from_settings``:
    providers, their options, threads), with the memory pattern on if ``mem_pattern`` and the
    CPU arena as ``arena`` says (None: as ``engines`` does). ``EngineError`` naming the setting
    when no requested provider is installed."""
    from dataclasses import replace

    from c3_matcher.engines.runtime import OnnxInferenceRuntime, SessionSettings

    class _Runtime(OnnxInferenceRuntime):
        def __init__(self, *args: Any, settings: SessionSettings | None = None, **kw: Any) -> None:
            chosen = replace(settings or SessionSettings(), enable_mem_pattern=mem_pattern)
            super().__init__(*args, settings=chosen, **kw)

    if arena is not None:
        engines = engines.model_copy(update={"cpu_mem_arena": arena})
    return _Runtime.from_settings(engines)


def _settings_label(provider: str, threads: int, mem_pattern: str, arena: str) -> str:
    """The table's settings column: the provider (short name), the threads and the options."""
    short = provider.removesuffix("ExecutionProvider")
    return f"{short} threads={threads or 'auto'} mem_pattern={mem_pattern} arena={arena}"


def _time_runs(fn: Callable[[], object], runs: int) -> tuple[object, float, list[float]]:
    """The first run's result and time (ms), then ``runs`` more timed runs (ms)."""
    start = time.perf_counter()
    first_result = fn()
    first = (time.perf_counter() - start) * 1e3
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) * 1e3)
    return first_result, first, times


class _Case(NamedTuple):
    """One case set up in the child: label, timed call, engine load time (ms), and what its
    result reports (from the first run's result: nothing runs untimed before it)."""

    label: str
    fn: Callable[[], object]
    load_ms: float
    detail: Callable[[Any], dict[str, Any]]


def _extractor_case(args: argparse.Namespace, runtime: OnnxInferenceRuntime) -> _Case:
    """Load the extractor engine and set up its run on the real image at ``--size``."""
    from c3_matcher.engines.extract import run_extractor

    start = time.perf_counter()
    engine_id = runtime.load_engine(args.engine)
    load_ms = (time.perf_counter() - start) * 1e3
    width, height = args.size
    rgb = _read_rgb(Path(args.image), (width, height))
    mask = np.ones((height, width), dtype=bool)
    manifest = runtime.manifest(engine_id)
    label = extractor_label(f"{manifest.model}/{manifest.variant}", width, height)

    def fn() -> object:
        return run_extractor(runtime, engine_id, rgb, mask, 2048)

    return _Case(label, fn, load_ms, lambda f: {"keypoints": len(f)})


def _matcher_case(args: argparse.Namespace, runtime: OnnxInferenceRuntime) -> _Case:
    """Load the LightGlue engine and set up its match of the first ``--keypoints`` per side (in
    full mode: a steps engine loaded alone runs every layer on every point)."""
    from c3_matcher.engines.lightglue import OnnxLightGlueRuntime
    from c3_matcher.engines.lightglue_specs import STEPS_OPTION
    from c3_matcher.engines.manifest import read_manifest

    start = time.perf_counter()
    matcher = OnnxLightGlueRuntime(runtime, mode="full")
    matcher.load(args.feature_type, Path(args.engine))
    load_ms = (time.perf_counter() - start) * 1e3
    data = np.load(args.features)
    n = args.keypoints

    def side(i: int) -> PairSide:  # keypoints, descriptors and (width, height) of image i
        width, height = (int(v) for v in data[f"size{i}"])
        return PairSide(data[f"k{i}"][:n], data[f"d{i}"][:n], (width, height))

    side0, side1 = side(0), side(1)
    manifest = read_manifest(Path(args.engine))
    steps = manifest.options.get(STEPS_OPTION[0]) == STEPS_OPTION[1]
    key = f"{manifest.model}/{manifest.variant}"
    label = matcher_label(key, steps, len(side0.keypoints), len(side1.keypoints))

    def fn() -> object:
        return matcher.match_pair(side0, side1, feature_type=args.feature_type)

    def detail(m: Any) -> dict[str, Any]:  # how the runtime ran it: "full" or "steps-full"
        run = matcher.last_run
        return {"matches": len(m), "mode": run.get("mode"), "layers": run.get("layers")}

    return _Case(label, fn, load_ms, detail)


def _child(args: argparse.Namespace) -> int:
    """One measurement: set up the case, time its runs, print its ``BenchResult`` as JSON."""
    baseline = current_rss_mib()
    engines = EngineSettings.model_validate(json.loads(args.engine_settings))
    runtime = bench_runtime(engines, mem_pattern=args.mem_pattern == "on", arena=args.arena == "on")
    case = (_extractor_case if args.kind == "extractor" else _matcher_case)(args, runtime)
    first_result, first, times = _time_runs(case.fn, args.runs)
    ordered = sorted(times)
    p95 = ordered[min(len(ordered) - 1, int(np.ceil(0.95 * len(ordered))) - 1)]
    result = BenchResult(
        engine=Path(args.engine).name,
        case=case.label,
        runs=len(times),
        median_ms=round(statistics.median(times), 1),
        p95_ms=round(p95, 1),
        min_ms=round(ordered[0], 1),
        first_run_ms=round(first, 1),
        load_ms=round(case.load_ms, 1),
        peak_rss_mib=round(peak_rss_mib(), 1),
        baseline_rss_mib=round(baseline, 1),
        settings=_settings_label(
            runtime.provider, engines.intra_op_threads, args.mem_pattern, args.arena
        ),
        detail=case.detail(first_result),
        provider=runtime.provider,
        threads=engines.intra_op_threads,
    )
    print(json.dumps(asdict(result)))
    return EXIT_OK


def _run_child(argv: list[str]) -> BenchResult | FailedCase:
    """Run one case (``_child_argv``) in a fresh process; a process that fails is a
    ``FailedCase`` and the other cases still run."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
    proc = subprocess.run(
        [sys.executable, "-m", "c3_matcher_tools.engines.bench", "child", *argv],
        capture_output=True,
        text=True,
        env=env,
        check=False,
    )
    if proc.returncode == 0:
        return BenchResult(**json.loads(proc.stdout.strip().splitlines()[-1]))
    code = proc.returncode
    ended = f"killed by signal {-code}" if code < 0 else f"exit status {code}"
    said = [line for line in proc.stderr.splitlines() if line.strip()]
    engine = Path(argv[2]).name
    what = " ".join(argv[argv.index("--size") + 1 :][:2]) if argv[0] == "extractor" else ""
    what = what.replace(" ", "x") if what else f"{argv[argv.index('--keypoints') + 1]} kpts"
    settings = f"mem_pattern={_flag(argv, '--mem-pattern')} arena={_flag(argv, '--arena')}"
    return FailedCase(
        engine, f"{engine} {what}", settings, ended + (f": {said[-1]}" if said else "")
    )


def _flag(argv: list[str], name: str) -> str:
    """The value of option ``name`` in ``argv`` ("?" without it)."""
    return argv[argv.index(name) + 1] if name in argv else "?"


def _prepare_features(
    extractor_engine: Path, image: Path, out: Path, max_keypoints: int, engines: EngineSettings
) -> None:
    from c3_matcher.engines.extract import run_extractor

    runtime = bench_runtime(engines)
    engine_id = runtime.load_engine(extractor_engine)
    a, b = _pair_views(image)
    fa = run_extractor(runtime, engine_id, a, np.ones(a.shape[:2], bool), max_keypoints)
    fb = run_extractor(runtime, engine_id, b, np.ones(b.shape[:2], bool), max_keypoints)
    np.savez(
        out,
        k0=fa.keypoints,
        d0=fa.descriptors,
        k1=fb.keypoints,
        d1=fb.descriptors,
        size0=np.array(fa.image_size),
        size1=np.array(fb.image_size),
    )


def run_bench(
    extractor_engine: Path,
    matcher_engines: Sequence[Path],
    image: Path,
    *,
    runs: int = 20,
    disk_sizes: Sequence[tuple[int, int]] = DISK_SIZES,
    lightglue_counts: Sequence[int] = LIGHTGLUE_COUNTS,
    feature_type: str = "disk",
    engines: EngineSettings | None = None,
    settings: Sequence[tuple[bool, bool]] | None = None,
    log: Callable[[str], None] | None = None,
) -> list[BenchResult | FailedCase]:
    """Measure every case, each in a fresh process (one that fails is a ``FailedCase``):
    ``extractor_engine`` at each of ``disk_sizes``, then each of ``matcher_engines``
    (``feature_type`` matchers, none: the extractor alone) at each of ``lightglue_counts`` on
    that extractor's features. Each runs on the runtime of the ``engines`` settings (default:
    ``[engines]``'s defaults); ``settings`` lists (memory pattern, arena) combinations to
    compare (default: the memory pattern off, as the runtime has it, and the arena as
    ``engines`` says)."""
    say = log or (lambda _line: None)
    engines = engines or EngineSettings()
    results: list[BenchResult | FailedCase] = []
    with tempfile.TemporaryDirectory(prefix="c3-bench-") as tmp:
        features = Path(tmp) / "features.npz"
        if matcher_engines:
            say(f"extracting real features with {extractor_engine.name} for the matcher cases")
            _prepare_features(extractor_engine, image, features, max(lightglue_counts), engines)
        for mem_pattern, arena in settings or ((False, engines.cpu_mem_arena),):
            flags = _setting_flags(mem_pattern, arena, runs, engines)
            where = f"({flags[1]} mem pattern, {flags[3]} arena)"
            for width, height in disk_sizes:
                say(f"{extractor_engine.name} {width}x{height} {where}")
                options = ["--image", str(image), "--size", str(width), str(height)]
                argv = _child_argv("extractor", extractor_engine, options, flags)
                results.append(_run_child(argv))
            for matcher_engine in matcher_engines:
                for count in lightglue_counts:
                    say(f"{matcher_engine.name} {count} keypoints/side {where}")
                    options = ["--features", str(features), "--keypoints", str(count)]
                    options += ["--feature-type", feature_type]
                    argv = _child_argv("matcher", matcher_engine, options, flags)
                    results.append(_run_child(argv))
    return results


def _setting_flags(mem_pattern: bool, arena: bool, runs: int, engines: EngineSettings) -> list[str]:
    """The child's options of one (memory pattern, arena) setting, its run count and the
    ``[engines]`` settings its runtime is built from."""
    return [
        "--mem-pattern",
        "on" if mem_pattern else "off",
        "--arena",
        "on" if arena else "off",
        "--runs",
        str(runs),
        "--engine-settings",
        engines.model_dump_json(),
    ]


def _child_argv(kind: str, engine: Path, options: Sequence[str], flags: list[str]) -> list[str]:
    """The child's arguments: the case ``kind``, its engine, its own options, the setting's."""
    return [kind, "--engine", str(engine), *options, *flags]


def format_table(results: Sequence[BenchResult | FailedCase]) -> str:
    """A fixed-width text table of ``results`` (the case column as wide as its longest label);
    a failed case's row says how it ended."""
    width = max([CASE_WIDTH, *(len(r.case) for r in results)])
    header = (
        f"{'case':<{width}} {'median ms':>10} {'p95 ms':>8} {'min ms':>8} {'peak MiB':>9} "
        f"{'base MiB':>9} {'load ms':>8}  settings"
    )
    lines = [header, "-" * len(header)]
    for r in results:
        if isinstance(r, FailedCase):
            lines.append(f"{r.case:<{width}} failed ({r.settings}): {r.failed}")
            continue
        lines.append(
            f"{r.case:<{width}} {r.median_ms:>10.1f} {r.p95_ms:>8.1f} {r.min_ms:>8.1f} "
            f"{r.peak_rss_mib:>9.0f} {r.baseline_rss_mib:>9.0f} {r.load_ms:>8.0f}  {r.settings}"
        )
    return "\n".join(lines)


def _main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m c3_matcher_tools.engines.bench")
    sub = parser.add_subparsers(dest="mode", required=True)
    child = sub.add_parser("child", help="one measurement (internal)")
    child.add_argument("kind", choices=["extractor", "matcher"])
    child.add_argument("--engine", required=True)
    child.add_argument("--image")
    child.add_argument("--size", nargs=2, type=int)
    child.add_argument("--features")
    child.add_argument("--keypoints", type=int)
    child.add_argument("--feature-type", default="disk")
    child.add_argument("--runs", type=bounded_int(), default=20)
    child.add_argument("--mem-pattern", choices=["on", "off"], default="off")
    child.add_argument("--arena", choices=["on", "off"], default="on")
    child.add_argument(
        "--engine-settings", default="{}", help="the [engines] settings, as JSON (internal)"
    )
    args = parser.parse_args(argv)
    return _child(args)


if __name__ == "__main__":
    raise SystemExit(_main())
