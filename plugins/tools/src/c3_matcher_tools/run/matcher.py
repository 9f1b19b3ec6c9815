"""Opening a matcher for a strategy, the one way every ground command does it: the
configuration with a run's :class:`Overrides`, composed by ``compose_root`` on the process's
plugin host (or, for a strategy's PyTorch reference, the same per-frame loop on the reference
backend), its FDR records and JSON logs in a run directory when it has one: composed first
(:func:`prepare_matcher`, engines loaded), so a run that cannot start touches no file, and only
then given its directory (:meth:`PreparedMatcher.start`)."""

from __future__ import annotations

import io
import time
from collections.abc import Iterator, Mapping
from contextlib import ExitStack, contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from c3_matcher.commands import with_keypoint_budget
from c3_matcher.compose import ComposedRoot, build_plugin_host, open_recorder, strategy_settings
from c3_matcher.config import C3Settings
from c3_matcher.logs import LoggingHandle
from c3_matcher.pipeline import FeatureBackend, PipelineMatcher
from c3_matcher.plugins.manager import PluginHost
from c3_matcher.protocols import Clock, CrossDomainMatcher, FdrClient
from c3_matcher.stages.extract import backend_budget
from c3_matcher_tools.run.outputs import forget_previous_run

__all__ = [
    "FDR_LOG",
    "NO_OVERRIDES",
    "ComposedMatcher",
    "Overrides",
    "PreparedMatcher",
    "compose_matcher",
    "open_backend",
    "open_matcher",
    "prepare_matcher",
]

FDR_LOG = "fdr.jsonl"
"""A run's flight-data log, in its output directory (:meth:`PreparedMatcher.start`)."""

_MATCHER_KEYS = ("tile_cache_size", "max_long_side", "stored_features")


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
        """``settings`` with these overrides and ``[matcher] strategy`` = ``strategy``; a
        keypoint budget overrides the strategies' own options too (``with_keypoint_budget``)."""
        if self.max_keypoints is not None:
            settings = with_keypoint_budget(settings, self.max_keypoints)
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
    """The strategy's PyTorch reference backend in the per-frame loop its engines fly in: the
    settings composed for the strategy (its defaults where unset), the same thresholds and tile
    cache, RANSAC with the strategy's refit."""
    from c3_matcher.health import RollingHealthWindow
    from c3_matcher.pipeline import PipelineSettings
    from c3_matcher.ransac import OpenCvRansacFilter
    from c3_matcher.strategy import PipelineHelpers, pipeline_matcher

    strategy = settings.matcher.strategy
    settings = strategy_settings(settings, strategy, host)
    m = settings.matcher
    backend = host.reference_backend(strategy, settings)
    if backend is None:
        raise LookupError(f"no PyTorch reference for {strategy}")
    helpers = PipelineHelpers(
        OpenCvRansacFilter.from_settings(m),  # as the engine cases' (the strategy's refit)
        fdr,
        RollingHealthWindow(clock, m.min_inliers_threshold),
        clock,
    )
    matcher = pipeline_matcher(backend, PipelineSettings.from_settings(m), helpers)
    return ComposedMatcher(matcher, str(backend.provenance()["provider"]))


class _HeldBackFdr:
    """The FDR a matcher is composed with before its run directory is taken: its records wait
    in memory (a run refused at start-up writes nothing) until :meth:`attach` writes them, in
    order, to the run's recorder, which every later record goes straight to."""

    def __init__(self) -> None:
        self._held: list[tuple[str, Mapping[str, Any]]] = []
        self._to: FdrClient | None = None

    def record(self, kind: str, payload: Mapping[str, Any]) -> None:
        if self._to is None:
            self._held.append((kind, payload))
        else:
            self._to.record(kind, payload)

    def attach(self, fdr: FdrClient) -> None:
        from c3_matcher.fdr import FdrWriteError

        held, self._held, self._to = self._held, [], fdr
        for kind, payload in held:
            with suppress(FdrWriteError):  # kept pending by the recorder: the next record writes it
                fdr.record(kind, payload)


class _HeldBackLog(io.StringIO):
    """The matcher's JSON log lines, kept in memory until the run's ``matcher.log`` is opened
    (:meth:`attach`), then written there with every later line; ``lost``: those held back that
    it could not take (a full disk; a later line lost is counted by the log's sink)."""

    def __init__(self) -> None:
        super().__init__()
        self._to: TextIO | None = None
        self.lost = 0

    def write(self, text: str) -> int:
        return super().write(text) if self._to is None else self._to.write(text)

    def flush(self) -> None:
        if self._to is not None:
            self._to.flush()

    def attach(self, stream: TextIO) -> None:
        held = self.getvalue()
        try:
            stream.write(held)
            stream.flush()
        except OSError:
            self.lost = held.count("\n")
        self._to = stream


@dataclass
class PreparedMatcher:
    """A matcher composed for a run (engines loaded, start-up probe run) that has touched no
    file yet: its FDR records and log lines wait in memory until :meth:`start` opens the run's
    directory. ``settings``: what it was composed with (the run's overrides and strategy
    applied); ``startup_s``: how long composing took."""

    matcher: CrossDomainMatcher
    strategy: str
    settings: C3Settings
    startup_s: float
    _fdr: _HeldBackFdr
    _log: _HeldBackLog
    _started: ExitStack
    _clock: Clock
    _logs: LoggingHandle

    @property
    def provenance(self) -> dict[str, Any]:
        """Its feature backend's execution provider and engines, as its FDR records them (each
        frame's record); ``provenance_error`` saying why where it could not be read (the run's
        output is kept); empty for a matcher not on the shared per-frame loop."""
        matcher = self.matcher
        return matcher.provenance() if isinstance(matcher, PipelineMatcher) else {}

    @property
    def keypoint_budget(self) -> int | None:
        """The keypoints per image its feature backend keeps: the strategy's own default where
        no setting names one, cut to its extractor engine's top-K (None: it declares none)."""
        matcher = self.matcher
        backend = matcher.backend if isinstance(matcher, PipelineMatcher) else None
        return None if backend is None else backend_budget(backend)

    @property
    def log_lines_lost(self) -> int:
        """The log lines ``matcher.log`` could not take (a full disk): dropped, counted."""
        return self._log.lost + self._logs.lines_lost

    def start(self, out_dir: Path) -> None:
        """Record to ``out_dir/fdr.jsonl`` and log to ``out_dir/matcher.log``, both started
        afresh, an earlier run's results removed (:func:`forget_previous_run`), only once this
        process holds the FDR's lock: a run refused by it (another process writing
        ``out_dir``) leaves that run's files as they are. What the matcher recorded and logged
        while it was composed comes first."""
        out_dir.mkdir(parents=True, exist_ok=True)
        fdr = open_recorder(self.settings.fdr, self._clock, path=out_dir / FDR_LOG, fresh=True)
        self._started.callback(fdr.close)
        forget_previous_run(out_dir)  # the FDR is this run's now: so are the results
        log = self._started.enter_context((out_dir / "matcher.log").open("w", encoding="utf-8"))
        self._log.attach(log)
        self._fdr.attach(fdr)


@contextmanager
def prepare_matcher(
    settings: C3Settings,
    strategy: str,
    *,
    plugin_host: PluginHost | None = None,
    overrides: Overrides = NO_OVERRIDES,
    log_level: str | None = None,
) -> Iterator[PreparedMatcher]:
    """A :class:`PreparedMatcher` for ``strategy`` (a linked strategy, or the ``sift_magsac``
    baseline, also a strategy) with ``overrides``: everything that can fail at start-up (an
    unknown strategy, a missing or broken engine) fails here, before any file is touched.
    Closed on exit, with the FDR and log :meth:`~PreparedMatcher.start` opened."""
    from c3_matcher.health import MonotonicClock
    from c3_matcher.logs import configure_logging

    host = plugin_host if plugin_host is not None else build_plugin_host()
    host.resolve(strategy)
    clock = MonotonicClock()
    started = time.perf_counter()
    with ExitStack() as opened:  # closed in reverse, also when opening fails part-way
        run_files = opened.enter_context(ExitStack())  # the FDR and log: closed last
        fdr, log = _HeldBackFdr(), _HeldBackLog()
        logs = configure_logging(fdr, level=log_level or settings.logging.level, stream=log)
        opened.callback(logs.close)
        chosen = overrides.apply(settings, strategy)
        composed = compose_matcher(chosen, fdr=fdr, clock=clock, plugin_host=host)
        opened.callback(composed.close)
        startup_s = time.perf_counter() - started
        yield PreparedMatcher(
            composed.matcher, strategy, chosen, startup_s, fdr, log, run_files, clock, logs
        )


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
    """A matcher for ``strategy`` with ``overrides``, whose FDR records go to
    ``out_dir/fdr.jsonl`` and JSON logs to ``out_dir/matcher.log``; closed on exit. It is
    composed first (:func:`prepare_matcher`): a strategy this build cannot run, or one that
    cannot start (a missing engine), is refused before any file is touched, ``out_dir`` not
    made; then :meth:`PreparedMatcher.start` takes ``out_dir``."""
    with prepare_matcher(
        settings, strategy, plugin_host=plugin_host, overrides=overrides, log_level=log_level
    ) as prepared:
        prepared.start(out_dir)
        yield prepared.matcher


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
