"""Opening a matcher for a strategy, the one way every ground command does it: the
configuration with a run's :class:`Overrides`, composed by ``compose_root`` on the process's
plugin host (or, for a strategy's PyTorch reference, the same per-frame loop on the reference
backend), its FDR records and JSON logs in a run directory when it has one."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from c3_matcher.compose import ComposedRoot, build_plugin_host, strategy_settings
from c3_matcher.config import C3Settings
from c3_matcher.pipeline import FeatureBackend, PipelineMatcher
from c3_matcher.plugins.manager import PluginHost
from c3_matcher.protocols import Clock, CrossDomainMatcher, FdrClient
from c3_matcher_tools.run.outputs import forget_previous_run

__all__ = [
    "NO_OVERRIDES",
    "ComposedMatcher",
    "Overrides",
    "compose_matcher",
    "open_backend",
    "open_matcher",
]

_MATCHER_KEYS = ("max_keypoints", "tile_cache_size", "max_long_side", "stored_features")


@dataclass(frozen=True)
class Overrides:
    """What a ground run sets over the configuration (None: as configured): ``[matcher]``
    keypoint budget, tile cache, image long side (px) and stored features, ``[lightglue]``
    mode and ``[engines]`` intra-op threads."""

    max_keypoints: int | None = None
    tile_cache_size: int | None = None
    max_long_side: int | None = None
    stored_features: bool | None = None
    lightglue_mode: str | None = None
    intra_op_threads: int | None = None

    def apply(self, settings: C3Settings, strategy: str | None = None) -> C3Settings:
        """``settings`` with these overrides and ``[matcher] strategy`` = ``strategy``."""
        matcher: dict[str, Any] = {k: getattr(self, k) for k in _MATCHER_KEYS}
        matcher = {k: v for k, v in matcher.items() if v is not None}
        if strategy:
            matcher["strategy"] = strategy
        update: dict[str, Any] = {}
        if matcher:
            update["matcher"] = settings.matcher.model_copy(update=matcher)
        if self.lightglue_mode:
            update["lightglue"] = settings.lightglue.model_copy(
                update={"mode": self.lightglue_mode}
            )
        if self.intra_op_threads:
            update["engines"] = settings.engines.model_copy(
                update={"intra_op_threads": self.intra_op_threads}
            )
        return settings.model_copy(update=update) if update else settings


NO_OVERRIDES = Overrides()


@dataclass(frozen=True)
class ComposedMatcher:
    """A composed matcher, its execution provider (``"opencv"`` for the classical baseline)
    and the composition it came from (None for a PyTorch reference)."""

    matcher: CrossDomainMatcher
    provider: str
    root: ComposedRoot | None = None

    def close(self) -> None:
        if self.root is not None:
            self.root.close()


def compose_matcher(
    settings: C3Settings,
    *,
    fdr: FdrClient,
    clock: Clock,
    plugin_host: PluginHost | None = None,
    reference: bool = False,
) -> ComposedMatcher:
    """The matcher of ``[matcher] strategy`` recording to ``fdr``: through ``compose_root``
    with the default helpers, or with ``reference`` the strategy's PyTorch reference backend
    in the same per-frame loop (``LookupError`` when its plugin offers none)."""
    from c3_matcher.compose import build_default_helpers, compose_root

    host = plugin_host if plugin_host is not None else build_plugin_host()
    if reference:
        return _reference_matcher(settings, host, fdr, clock)
    helpers = build_default_helpers(settings, plugin_host=host)
    root = compose_root(
        settings,
        {**helpers, "c13_fdr": fdr, "clock": clock},
        plugin_host=host,
        configure_logs=False,
    )
    baseline = host.strategies().get(settings.matcher.strategy)
    provider = "opencv" if baseline is not None and baseline.baseline else None
    return ComposedMatcher(root.matcher, provider or helpers["c7_inference"].provider, root)


def _reference_matcher(
    settings: C3Settings, host: PluginHost, fdr: FdrClient, clock: Clock
) -> ComposedMatcher:
    from c3_matcher.health import RollingHealthWindow
    from c3_matcher.pipeline import PipelineSettings
    from c3_matcher.ransac import OpenCvRansacFilter

    strategy = settings.matcher.strategy
    settings = strategy_settings(settings, strategy, host)
    m = settings.matcher
    backend = host.reference_backend(strategy, settings)
    if backend is None:
        raise LookupError(f"no PyTorch reference for {strategy}")
    matcher = PipelineMatcher(
        backend,
        OpenCvRansacFilter(seed=m.ransac_seed),
        fdr,
        RollingHealthWindow(clock, m.min_inliers_threshold),
        clock,
        PipelineSettings.from_settings(m),
    )
    return ComposedMatcher(matcher, str(backend.provenance()["provider"]))


@contextmanager
def open_matcher(
    settings: C3Settings,
    strategy: str,
    out_dir: Path,
    *,
    plugin_host: PluginHost | None = None,
    overrides: Overrides = NO_OVERRIDES,
    log_level: str | None = None,
) -> Iterator[CrossDomainMatcher]:
    """A matcher for ``strategy`` (a linked strategy, or the ``sift_magsac`` baseline, also a
    strategy) with ``overrides``, whose FDR records go to ``out_dir/fdr.jsonl`` and JSON logs
    to ``out_dir/matcher.log``; closed on exit. A strategy this build cannot run is refused
    before any file is touched; both files are started afresh, and an earlier run's results
    removed (:func:`forget_previous_run`), only once this process holds the FDR's lock, so a
    run refused by it (another process writing ``out_dir``) leaves that run's files as they
    are."""
    from c3_matcher.fdr import JsonlFdrRecorder
    from c3_matcher.health import MonotonicClock
    from c3_matcher.logs import configure_logging

    host = plugin_host if plugin_host is not None else build_plugin_host()
    host.resolve(strategy)
    out_dir.mkdir(parents=True, exist_ok=True)
    clock = MonotonicClock()
    with ExitStack() as opened:  # closed in reverse, also when opening fails part-way
        fdr = JsonlFdrRecorder(
            out_dir / "fdr.jsonl", clock, max_bytes=settings.fdr.max_bytes, fresh=True
        )
        opened.callback(fdr.close)
        forget_previous_run(out_dir)  # the FDR is this run's now: so are the results
        log_stream = opened.enter_context((out_dir / "matcher.log").open("w", encoding="utf-8"))
        logs = configure_logging(fdr, level=log_level or settings.logging.level, stream=log_stream)
        opened.callback(logs.close)
        chosen = overrides.apply(settings, strategy)
        composed = compose_matcher(chosen, fdr=fdr, clock=clock, plugin_host=host)
        opened.callback(composed.close)
        yield composed.matcher


def open_backend(
    settings: C3Settings,
    strategy: str,
    *,
    plugin_host: PluginHost | None = None,
    overrides: Overrides = NO_OVERRIDES,
) -> FeatureBackend:
    """The feature backend ``strategy`` flies with (engines loaded, start-up probe run), its
    records kept in memory; ``ValueError`` for a strategy that does not run on the shared
    per-frame loop."""
    from c3_matcher.fdr import InMemoryFdr
    from c3_matcher.health import MonotonicClock

    chosen = overrides.apply(settings, strategy)
    composed = compose_matcher(
        chosen, fdr=InMemoryFdr(), clock=MonotonicClock(), plugin_host=plugin_host
    )
    if not isinstance(composed.matcher, PipelineMatcher):
        raise ValueError(f"strategy {strategy!r} has no feature backend (not a PipelineMatcher)")
    return composed.matcher.backend
