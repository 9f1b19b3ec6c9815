"""``c3-matcher bench`` (C3-PT-01): per-frame and per-candidate latency (p50/p95, per stage) and
peak memory of each strategy on a demo-format frame with 3 candidates, beside, in the same run:

- the strategy's PyTorch reference (the upstream models through kornia, LightGlue with its
  adaptive depth and width ON, tiles re-extracted every frame), when the engine-build
  environment is installed and the strategy's plugin offers one (``c3_matcher_reference_backend``);
- the classical OpenCV SIFT + MAGSAC pipeline doing the same work;

as ratios. Engine runs are timed with every tile new (decoded and extracted every frame) and
with the tiles cached (the steady state of a flight whose candidates were seen before); in the
same run, when they apply:

- stored map features (``[matcher] stored_features`` on, tiles never extracted in flight) vs
  extraction, when ``--data`` is a flight whose store has features built
  (``c3-matcher features build``); the FDR-style source of every candidate's features is
  counted so a case that silently fell back to extraction shows it;
- full vs adaptive LightGlue (``[lightglue] mode``) for the LightGlue-family strategies.

Ratios are speed-ups of frame p50 (slower / faster, >1 means the case is faster), and the median
of the ratios of the two cases' matches of each round. ``--sweep`` adds image-size x
keypoint-budget variants; ``--max-keypoints N`` and ``--threads N`` (repeatable) add budget and
ONNX Runtime intra-op thread variants (new tiles).

Every case runs in a worker process of its own (``python -m c3_matcher_tools.bench_worker``), so
that its peak memory (its ``VmHWM``) is its own, and the cases are timed interleaved, so that load
from outside falls on every case alike: the workers of one strategy (the SIFT + MAGSAC baseline
joins the first strategy's) load and warm up one after another, then, round by round, each times
one match in turn while the others wait on their pipe, in an order that changes every round
(``bench_worker.round_order``). One strategy at a time, not the whole run, bounds the memory held
at once (a PyTorch worker ~1.1 GB, an engine one ~0.6 GB); every ratio the run reports is within
one strategy. On a failure or Ctrl-C every worker is ended and reaped.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from c3_matcher.commands import (
    EXIT_FAILURE,
    EXIT_OK,
    CommandRegistry,
    add_max_keypoints_option,
    bounded_int,
    keypoint_budget,
)
from c3_matcher.config import C3Settings
from c3_matcher.context import CommandContext
from c3_matcher.errors import InvalidInputError
from c3_matcher.tiles import DEFAULT_MAX_IMAGE_PIXELS
from c3_matcher_tools.args import add_strategies_option
from c3_matcher_tools.bench_report import (
    comparisons,
    format_report,
    latency_target,
    text_report,
)
from c3_matcher_tools.bench_worker import BenchCase, time_interleaved
from c3_matcher_tools.dataset.lock import reading_dataset
from c3_matcher_tools.extras import install_line, not_installed

if TYPE_CHECKING:
    from c3_matcher.plugins.manager import PluginHost

__all__ = [
    "BenchCase",
    "comparisons",
    "format_report",
    "interleaved_groups",
    "offers_reference",
    "pytorch_reference",
    "register_bench_command",
]

THREADS_PER_CORE = 4
"""``--threads`` goes up to this many intra-op threads a core (more only oversubscribes)."""


def max_threads() -> int:
    """The most ``--threads`` takes: :data:`THREADS_PER_CORE` a core of this machine, and never
    more than ``[engines] intra_op_threads`` allows (1024)."""
    return min(THREADS_PER_CORE * (os.cpu_count() or 1), 1024)


SWEEP_LONG_SIDES = (512, 1024)
SWEEP_KEYPOINTS = (512, 1024, 2048)


def stored_features_path(data_dir: Path) -> Path | None:
    """The features sidecar of a flight dataset's store (``<store>.features.sqlite``), if any."""
    from c3_matcher_tools.dataset.format import META_FILE, STORE_FILE, is_flight_dataset

    if not is_flight_dataset(data_dir):
        return None
    store = data_dir / str(json.loads((data_dir / META_FILE).read_text()).get("store", STORE_FILE))
    sidecar = store.with_name(store.name + ".features.sqlite")
    return sidecar if sidecar.is_file() else None


def _uses_lightglue(strategy: str) -> bool:
    return "glue" in strategy


def _machine() -> dict[str, Any]:
    import onnxruntime as ort

    return {
        "platform": platform.platform(),
        "processor": platform.processor(),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "onnxruntime": ort.__version__,
        "available_providers": ort.get_available_providers(),
    }


def _has_torch() -> bool:
    return not not_installed("torch")


def pytorch_reference(
    args: argparse.Namespace, host: PluginHost, strategies: Sequence[str]
) -> dict[str, Any]:
    """Whether the PyTorch reference is timed for ``strategies`` (those whose plugin offers one,
    :func:`offers_reference`): ``timed``, and ``reason``, why not, where the run would time it
    but torch (the engine-build extra) is not installed; None where it is timed, left out with
    ``--no-reference`` or offered by none (a baseline has no reference)."""
    offered = any(offers_reference(host, name) for name in strategies)
    if args.no_reference or not offered:
        return {"timed": False, "reason": None}
    if not _has_torch():
        why = f"torch is not installed (the engine-build extra: {install_line('engine-build')})"
        return {"timed": False, "reason": why}
    return {"timed": True, "reason": None}


def offers_reference(host: PluginHost, strategy: str) -> bool:
    """Whether ``strategy``'s plugin offers a PyTorch reference
    (``c3_matcher_reference_backend``): a learned strategy's does, a baseline (SIFT + MAGSAC,
    ``StrategySpec.baseline``) has none. Told from its spec, without building the reference."""
    spec = host.strategies().get(strategy)
    return spec is not None and not spec.baseline


def cases_for(
    args: argparse.Namespace,
    settings: C3Settings,
    data: Path,
    plugin_host: PluginHost | None = None,
) -> list[BenchCase]:
    """The cases ``bench`` runs on ``data`` for the parsed command line ``args``, each label once;
    the PyTorch reference only for a strategy that offers one (:func:`offers_reference`)."""
    import onnxruntime as ort

    from c3_matcher.compose import build_plugin_host
    from c3_matcher.engines.lightglue import resolve_mode
    from c3_matcher.engines.runtime import resolve_providers

    m = settings.matcher
    cached = max(m.tile_cache_size, 3)
    stored = stored_features_path(data) is not None
    # the [lightglue] mode the configured provider runs, then the other one
    provider = resolve_providers(settings.engines.providers, ort.get_available_providers())
    mode = resolve_mode(settings.lightglue.mode, provider[0])
    other_mode = {"adaptive": "full", "full": "adaptive"}[mode]
    host = plugin_host if plugin_host is not None else build_plugin_host()
    strategies = args.strategy or [m.strategy]
    reference = pytorch_reference(args, host, strategies)["timed"]
    cases: list[BenchCase] = []  # a budget of None: the configured one (the strategy's own)
    for name in strategies:
        cases += [
            BenchCase(name, "engine", 0, m.max_long_side, None),
            BenchCase(name, "engine", cached, m.max_long_side, None),
        ]
        if stored and not args.no_stored:
            cases.append(BenchCase(name, "engine", 0, m.max_long_side, None, True))
        if _uses_lightglue(name) and not args.no_modes:
            cases.append(BenchCase(name, "engine", 0, m.max_long_side, None, False, other_mode))
        for kp in args.keypoints or ():
            cases.append(BenchCase(name, "engine", 0, m.max_long_side, kp))
        for threads in args.threads or ():
            cases.append(BenchCase(name, "engine", 0, m.max_long_side, None, False, None, threads))
        if reference and offers_reference(host, name):
            cases.append(BenchCase(name, "pytorch", 0, m.max_long_side, None))
        if args.sweep:
            cases += [
                BenchCase(name, "engine", 0, side, kp)
                for side in SWEEP_LONG_SIDES
                for kp in SWEEP_KEYPOINTS
                if (side, kp) != (m.max_long_side, m.max_keypoints)
            ]
    baseline = [] if args.no_baseline else [BenchCase(m.strategy, "sift", 0, m.max_long_side, None)]
    unique: dict[str, BenchCase] = {}  # one case per label: a strategy named twice is timed once,
    taken = {case.label for case in baseline}  # and sift_magsac's new-tiles case is the baseline
    for case in cases:
        if case.label not in taken:
            unique.setdefault(case.label, case)
    return [*unique.values(), *baseline]


def register_bench_command(commands: CommandRegistry) -> None:
    p = commands.add(
        "bench",
        help="latency and peak memory per strategy (the C3-PT-01 targets), beside the PyTorch "
        "reference and the SIFT + MAGSAC baseline",
    )
    p.add_argument(
        "--runs", type=bounded_int(), default=20, help="timed runs per case (default 20)"
    )
    add_strategies_option(p, "strategy to bench (repeatable; default: the configured one)")
    p.add_argument("--no-baseline", action="store_true", help="skip SIFT + MAGSAC")
    p.add_argument("--no-reference", action="store_true", help="skip the PyTorch reference")
    p.add_argument(
        "--sweep",
        action="store_true",
        help=f"also image long side {SWEEP_LONG_SIDES} x keypoints {SWEEP_KEYPOINTS}",
    )
    p.add_argument(
        "--data",
        type=Path,
        default=None,
        help="a flight dataset (c3-flight/1, its frames in turn) or a demo-format directory "
        "(default: the built-in demo frame of a source checkout)",
    )
    p.add_argument(
        "--no-stored",
        action="store_true",
        help="skip the stored-features case (added when --data's store has features built)",
    )
    p.add_argument(
        "--no-modes",
        action="store_true",
        help="skip the other [lightglue] mode (full vs adaptive) for LightGlue strategies",
    )
    add_max_keypoints_option(
        p,
        "also time a keypoint budget of N per image, new tiles (repeatable)",
        dest="keypoints",
        action="append",
    )
    p.add_argument(  # the former name, still accepted
        "--keypoints",
        dest="keypoints",
        type=keypoint_budget(),
        action="append",
        help=argparse.SUPPRESS,
    )
    most = max_threads()
    p.add_argument(
        "--threads",
        type=_threads,
        action="append",
        default=None,
        help=f"also time ONNX Runtime intra-op threads N, new tiles (repeatable; 1..{most}: "
        f"at most {THREADS_PER_CORE}x this machine's {os.cpu_count() or 1} cores)",
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of the table")
    p.set_defaults(handler=run_bench)


def _threads(text: str) -> int:
    """``--threads``: an int in 1..:func:`max_threads` (more threads than that never run
    faster, and ONNX Runtime would try to start every one), else a usage error."""
    value = bounded_int()(text)
    most = max_threads()
    if value > most:
        raise argparse.ArgumentTypeError(
            f"must be <= {most} ({THREADS_PER_CORE}x this machine's {os.cpu_count() or 1} "
            f"cores), got {value}"
        )
    return value


def demo_data(data: Path | None, max_pixels: int = DEFAULT_MAX_IMAGE_PIXELS) -> Path:
    """``--data``, checked before any case runs (a flight dataset, read as the cases will read
    it, or a demo-format directory, images within ``max_pixels``: ``[matcher]
    max_image_pixels``), or the built-in demo frame (``data/demo`` of the source checkout this
    runs from); installed from wheels there is none, and ``--data`` must name one
    (InvalidInputError, exit 2)."""
    if data is not None:
        return _checked_data(data, max_pixels)
    from c3_matcher.engines.store import checkout_root

    root = checkout_root()
    if root is None:  # bad input (exit 2)
        raise InvalidInputError(
            "--data",
            "required: the built-in demo frame ships with the source checkout (data/demo), and "
            "this c3-matcher is installed from wheels",
        )
    return root / "data" / "demo"


def _checked_data(data: Path, max_pixels: int) -> Path:
    """``data`` when it is a flight dataset that loads, tile store included (``dataset.json``),
    with a frame to time (``timed_frames``), each of those frames' images readable, within
    ``max_pixels`` and of its calibration's size (``check_flight``, as ``replay`` checks them),
    or a demo-format directory (``demo.json``) whose frame, tiles and calibration read (within
    ``max_pixels``); else InvalidInputError naming it (exit 2)."""
    from c3_matcher_tools.dataset.format import is_flight_dataset, load_dataset
    from c3_matcher_tools.run.flight import check_flight
    from c3_matcher_tools.run.inputs import demo_inputs, timed_frames

    if not data.is_dir():
        raise InvalidInputError("--data", f"no such directory: {data}")
    if is_flight_dataset(data):
        dataset = load_dataset(data, max_pixels)
        with dataset.open_store():  # its frames, calibration and tile store
            frames = timed_frames(dataset)
        try:
            check_flight(dataset, frames)
        except InvalidInputError as exc:
            raise InvalidInputError("--data", str(exc)) from exc
    elif (data / "demo.json").is_file():
        try:
            # what a case reads of it: its frame, tiles and calibration
            demo_inputs(data, max_pixels)
        except InvalidInputError as exc:
            raise InvalidInputError("--data", str(exc)) from exc
        except (KeyError, TypeError, ValueError, OSError) as exc:
            why = f"missing key {exc}" if isinstance(exc, KeyError) else str(exc)
            raise InvalidInputError("--data", f"{data / 'demo.json'}: {why}") from exc
    else:
        raise InvalidInputError(
            "--data",
            f"{data}: neither a flight dataset (dataset.json) nor a demo-format directory "
            "(demo.json)",
        )
    return data


def run_bench(args: argparse.Namespace, ctx: CommandContext) -> int:
    """Run every case in a worker process of its own, the cases of a group interleaved round by
    round (the module docstring); a case whose worker fails is reported beside the others'
    figures (exit 1), a worker's refusal of its input stops the bench (2). A ``--data`` dataset
    is held from its check to the last case (``reading_dataset``: not replaced under them)."""
    strategies = args.strategy or [ctx.settings.matcher.strategy]
    for name in strategies:
        ctx.plugin_host.resolve(name)  # one this build cannot run: refused before any case
    with reading_dataset(args.data) if args.data is not None else contextlib.nullcontext():
        data = demo_data(args.data, ctx.settings.matcher.max_image_pixels)
        cases = cases_for(args, ctx.settings, data, ctx.plugin_host)
        groups = interleaved_groups(cases)
        results: list[dict[str, Any]] = []
        failed: list[dict[str, str]] = []
        for group in groups:
            timed, lost = time_interleaved(group, args.runs, data, args.config, ctx.err)
            results += timed
            failed += lost
    planned = {case.label: n for n, case in enumerate(cases)}  # the table in the plan's order
    results.sort(key=lambda r: planned[r["label"]])
    failed.sort(key=lambda f: planned[f["label"]])
    report: dict[str, Any] = {
        "machine": _machine(),
        "runs": args.runs,
        "data": str(data),
        "interleaved": [[case.label for case in group] for group in groups],
        "pytorch_reference": pytorch_reference(args, ctx.plugin_host, strategies),
        "results": results,
        "latency_target": latency_target(results),
        "comparisons": comparisons(results),
        "failed": failed,
    }
    ctx.out(json.dumps(report, indent=2) if args.json else text_report(report))
    return EXIT_FAILURE if failed else EXIT_OK


def interleaved_groups(cases: list[BenchCase]) -> list[list[BenchCase]]:
    """The cases timed together, round by round: those of one strategy, in the plan's order,
    the SIFT + MAGSAC baseline with the first strategy's."""
    groups: dict[str, list[BenchCase]] = {}
    for case in cases:
        key = next(iter(groups), case.strategy) if case.kind == "sift" else case.strategy
        groups.setdefault(key, []).append(case)
    return list(groups.values())
